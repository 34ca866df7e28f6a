"""Does a method apply to a model? One place for the checks every symbolic engine shares.

Zero-mean ansatz
    ``hb1``, ``kb``, ``vdp``, ``ms``, ``mlp``, ``lp`` and the symbolic ``hb`` without bias
    start from an orbit centred on ``x = 0`` (``x = A cos psi`` plus corrections). That is
    consistent only when the force is odd, ``g(-x, -v) = -g(x, v)``, and there is no static
    load. A polynomial even part (``alpha2 x**2``) is a weak-nonlinearity term the
    perturbation methods treat consistently order by order (its effect on the frequency is of
    second order; :func:`lindstedt_poincare` and :func:`multiple_scales` at order 2 recover
    it). A piecewise-linear even part (a one-sided spring, a bilinear spring, ``Abs(x)``) or a
    static load moves the orbit off centre at order one: a zero-mean method then answers with a
    confident and wrong curve (on the one-sided spring ``x'' + 0.1 x' + x + 4 (x - 0.5)
    H(x - 0.5) = 0.8 cos(Omega t)`` first-order mLP had a max relative amplitude error of 12.7
    against the exact response, with a fold that does not exist). :func:`require_centred`
    refuses those cases with a :class:`ModelError` that names what does apply.

Bounded work
    :data:`ORDER_LIMITS` is the one table of the largest expansion order (or harmonic count)
    each engine accepts; :func:`check_order` enforces it.

Caller strings
    :func:`expression_argument` (defined in :mod:`perturb.model.parsing`, re-exported here)
    turns a caller's value into a SymPy expression: strings only through the safe parser
    :func:`perturb.model.parsing.parse_expression` (never ``sympify``).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import sympy as sp

from perturb.errors import ModelError, ParameterError
from perturb.methods.limits import ORDER_LIMITS
from perturb.model.oscillator import Oscillator
from perturb.model.parsing import expression_argument  # re-exported: the engines' import
from perturb.model.pwl import is_nonsmooth

__all__ = [
    "APPLIES_OFF_CENTRE",
    "ORDER_LIMITS",
    "check_order",
    "even_part",
    "expression_argument",
    "is_odd",
    "require_centred",
]

#: What answers a model whose orbits are off centre (non-odd force or static load).
APPLIES_OFF_CENTRE = (
    "'hb' (numeric harmonic balance with the mean among its unknowns, exact for "
    "piecewise-linear forces: `perturb frc MODEL --method hb` or "
    "perturb.frequency_response(osc, 'hb')), 'exact' (exact periodic orbits: `--method "
    "exact`), or the symbolic harmonic_balance(osc, (1,), bias=True) (one harmonic plus a bias)"
)


def check_order(method: str, order: Any, what: str = "order") -> int:
    """Check an expansion order (or harmonic) against :data:`ORDER_LIMITS`.

    Parameters
    ----------
    method
        Key of :data:`ORDER_LIMITS`.
    order
        The requested value (an integer >= 1).
    what
        Its name in the message (``"order"``, ``"harmonic"``).

    Returns
    -------
    int
        ``order``.

    Raises
    ------
    ParameterError
        If ``order`` is not an integer in ``[1, ORDER_LIMITS[method]]``.
    """
    limit = ORDER_LIMITS[method]
    if isinstance(order, bool) or not isinstance(order, int | np.integer) or order < 1:
        raise ParameterError(f"{what} = {order!r}: expected an integer from 1 to {limit}")
    if order > limit:
        raise ParameterError(
            f"{what} = {order} for method {method!r}: expected at most {limit} (the derivation "
            "grows too fast beyond it; see perturb.methods.applicability.ORDER_LIMITS). For a "
            "more accurate response use numeric harmonic balance ('hb') or 'exact'"
        )
    return int(order)


def _scale(expr: sp.Expr) -> float:
    """Largest magnitude among the numbers in ``expr`` (at least 1, at most 1e6)."""
    nums = [abs(float(n)) for n in expr.atoms(sp.Number) if n.is_finite and n.is_real]
    return float(min(max([1.0, *nums]), 1e6))


def is_odd(
    expr: sp.Expr,
    symbols: tuple[sp.Symbol, ...],
    values: Mapping[sp.Symbol, Any] | None = None,
) -> bool:
    """Whether ``expr(-s) = -expr(s)`` for the state ``s = symbols``.

    Exact when SymPy simplifies ``expr(s) + expr(-s)`` to zero; otherwise (piecewise forms
    do not always simplify) decided numerically at the parameter ``values`` (parameters
    without a value at two random draws in ``[0.3, 1.7]``) on points from ``1e-3`` to ``10``
    times the largest number in the expression, relative tolerance ``1e-10``.

    Parameters
    ----------
    expr
        A function of ``symbols`` (and parameters).
    symbols
        The state variables flipped together (``(x,)`` or ``(x, v)``).
    values
        Parameter symbol -> value; may be empty or None.
    """
    flip = {s: -s for s in symbols}
    diff = expr + expr.xreplace(flip)
    if diff == 0:
        return True
    try:
        if sp.expand(diff) == 0:
            return True
    except (TypeError, ValueError):  # pragma: no cover - expand of exotic forms
        pass
    fixed = dict(values or {})
    rng = np.random.default_rng(12345)
    for _ in range(2):
        subs = dict(fixed)
        for s in (expr.free_symbols | diff.free_symbols) - set(symbols) - set(subs):
            subs[s] = sp.Float(rng.uniform(0.3, 1.7))
        e = expr.xreplace(subs)
        scale = _scale(e)
        mags = np.geomspace(1e-3, 10.0, 60) * scale
        # an even count of points, none at 0 or exactly on a round breakpoint
        base = np.concatenate([-mags[::-1], mags]) * (1 + 1e-7 * np.pi)
        if len(symbols) == 1:
            grids = (base,)
        else:
            rot = np.roll(base, 17)  # velocities paired with other positions
            grids = (base, rot) + tuple(np.roll(base, 5 * k) for k in range(2, len(symbols)))
        fn = sp.lambdify(symbols, e, modules=["numpy"])
        with np.errstate(all="ignore"):
            plus = np.broadcast_to(np.asarray(fn(*grids), dtype=float), base.shape)
            minus = np.broadcast_to(np.asarray(fn(*(-g for g in grids)), dtype=float), base.shape)
        if not np.all(np.isfinite(plus) & np.isfinite(minus)):
            return False
        if not np.all(np.abs(plus + minus) <= 1e-10 * (1 + np.abs(plus) + np.abs(minus))):
            return False
    return True


def even_part(osc: Oscillator) -> frozenset[str]:
    """What makes the orbits of ``osc`` off centre, if anything.

    Returns
    -------
    frozenset of str
        ``"load"`` for a static load (a constant on the right, or a constant term in ``g``);
        ``"nonsmooth"`` when the nonsmooth terms of ``g(x, x')`` (parametric terms aside) are
        not odd in ``(x, x')``; ``"polynomial"`` when the smooth terms are not odd (an
        ``x**2``, an ``x*x'``). Empty when the force is odd and there is no load.
    """
    values = osc.substitutions()
    out: set[str] = set()
    if _load(osc) != 0:
        out.add("load")
    g = osc.g - osc.parametric
    state = (osc.x, osc.v)
    terms = sp.Add.make_args(g)
    rough = sp.Add(*(t for t in terms if is_nonsmooth(t)))
    smooth = sp.Add(*(t for t in terms if not is_nonsmooth(t) and t.has(osc.x, osc.v)))
    if rough != 0 and not is_odd(rough, state, values):
        out.add("nonsmooth")
    if smooth != 0 and not is_odd(smooth, state, values):
        out.add("polynomial")
    return frozenset(out)


def _load(osc: Oscillator) -> sp.Expr:
    """The static load: the constant on the right minus a constant term of ``g`` (zero when
    its value is zero)."""
    load = osc.forcing.constant
    if osc.polynomial != 0:
        load -= sp.Poly(osc.polynomial, osc.x).coeff_monomial(1)
    load = sp.sympify(load)
    return sp.Integer(0) if load.xreplace(osc.substitutions()).is_zero is True else load


def require_centred(
    osc: Oscillator, method: str, *, polynomial: bool = True, load: bool = False
) -> None:
    """Refuse a model whose orbits are off centre for a zero-mean method.

    Parameters
    ----------
    osc
        The model.
    method
        The method's name, for the message (e.g. ``"multiple scales (ms)"``).
    polynomial
        Whether a smooth (polynomial) even part is acceptable: True for the perturbation
        methods, which treat it consistently order by order; False for single-harmonic
        balance, whose ansatz has no room for it at any order.
    load
        Whether a static load is acceptable on a force without nonsmooth terms
        (Lindstedt-Poincare expands it with the other terms, and its mean comes out right
        order by order).

    Raises
    ------
    ModelError
        For a static load, a non-odd nonsmooth (piecewise-linear) part, or
        (``polynomial=False``) a non-odd smooth part; the message names what applies.
    """
    kinds = set(even_part(osc))
    if polynomial:
        kinds.discard("polynomial")
    if load and osc.nonsmooth == 0:
        kinds.discard("load")
    if not kinds:
        return
    if "load" in kinds:
        why = (
            f"model {osc.name!r} has a static load {_load(osc)}: its orbits have a mean, and "
            f"{method} assumes an orbit centred on x = 0 (it leaves the mean out or gets it wrong)"
        )
    else:
        g = osc.g - osc.parametric
        force = g if osc.velocity != 0 else osc.restoring_force
        why = (
            f"the force {force} of model {osc.name!r} is not odd (g(-x, -x') != -g(x, x')"
            + ("; a piecewise-linear part is one-sided" if "nonsmooth" in kinds else "")
            + f"), so its orbits have a mean; {method} assumes an orbit centred on x = 0"
        )
    raise ModelError(f"{why}, so it does not apply. Use instead: {APPLIES_OFF_CENTRE}")
