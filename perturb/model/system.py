r"""Systems of several coordinates: ``M q'' + C q' + K q + f(q, q', t) = F(t)`` and first-order
states.

A :class:`System` holds ``n2`` second-order coordinates ``q`` and ``n1`` first-order states
``p`` (a pressure, a flow: states whose equation has a rate but no inertia). Its equations,
one per coordinate or state, are

.. math::

    M q'' + D p' + C q' + K q + E p
        + \sum_e w_e\, f_e(c_e \cdot y) = F(t),
    \qquad y = (q, q', p),

with :math:`[M\ D]` square and invertible, so that the same object is the first-order system

.. math::

    y' = A y + g(y) + b(t).

Every nonlinearity is an :class:`Element`: a scalar function :math:`f_e` of one **linear
combination** :math:`s = c_e \cdot y` of the state (a relative displacement ``x1 - x2``, a
velocity ``x'``, a pressure), whose force enters the equations through the distribution vector
:math:`w_e` (one entry per equation). Kinds:

* ``"nonsmooth"``: built from Heaviside, Max, Min, Abs, sign, Piecewise (PWL springs and dampers,
  gaps, dead zones, steps, saturation; or nonsmooth but not piecewise linear);
* ``"friction"``: a function of a **velocity** combination containing ``sign`` (Coulomb or
  Stribeck friction): declared as such so that an event-driven solver may stick on ``s = 0``
  (the discontinuity; an offset belt speed is part of ``f``, ``sign(s - v_b)``);
* ``"smooth"``: a smooth nonlinear term (polynomial, ``exp``);
* ``"stop"``: a rigid unilateral stop on a position combination, ``lower <= c.y <= upper``,
  with a restitution coefficient (0 = plastic). A stop exerts no force in free flight; while a
  stop rests (or a friction contact sticks) its force is the constraint force (see
  :meth:`System.field` and :meth:`System.piecewise_affine`, argument ``active``).

Input
-----
* :meth:`System.parse`: one equation string per coordinate, read by the safe parser
  (:mod:`perturb.model.parsing`, no ``eval``). ``x1''`` marks a second-order coordinate,
  ``x1'`` its velocity. **A name whose derivatives appear only with a single prime
  (``p1'``) is a first-order state**: writing ``"C1*p1' = A_r*v - q_i"`` is the
  declaration. Every name that is not a coordinate, state or the time is a parameter.
* :meth:`System.from_sympy`: SymPy equations (applied functions ``x1(t)`` with ``Derivative``,
  or symbols named ``x1'``/``x1''``).
* :meth:`System.from_matrices`: ``M, C, K`` plus elements from the factories
  (:func:`pwl_spring`, :func:`gap`, :func:`dead_zone`, :func:`step`, :func:`saturation`,
  :func:`coulomb`, :func:`polynomial`, :func:`element`, :func:`stop`).
* :meth:`System.from_oscillator`: the SDOF :class:`~perturb.model.oscillator.Oscillator` as the
  case ``n2 = 1``.

From parsed equations the elements are found automatically: every switch atom's argument must
be affine in the states (its linear part is the combination), every term holding a switch must be
a function of that one combination, and terms equal up to a constant factor in several equations
are one element with that factor in its distribution vector.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from fractions import Fraction
from types import MappingProxyType
from typing import Any

import numpy as np
import sympy as sp

from perturb.checks import state
from perturb.errors import ModelError, NonsmoothError, ParameterError, ParseError
from perturb.model.affine import PiecewiseAffineSystem
from perturb.model.oscillator import Oscillator, validate_parameter_value
from perturb.model.parsing import parse_equation, parse_expression, real_symbol
from perturb.model.pwl import to_pwl

__all__ = [
    "Constraint",
    "Element",
    "System",
    "S",
    "pwl_spring",
    "gap",
    "dead_zone",
    "step",
    "saturation",
    "coulomb",
    "polynomial",
    "element",
    "stop",
    "MAX_REGIONS",
]

#: The symbol of an element's scalar function ``f(s)``.
S = real_symbol("s")

#: Most regions :meth:`System.piecewise_affine` enumerates (the product over the combinations of
#: their breakpoint counts + 1); beyond this the caller should reduce the model.
MAX_REGIONS = 4096

_SWITCHES = (sp.Heaviside, sp.Max, sp.Min, sp.Abs, sp.sign, sp.Piecewise)
_KINDS = ("nonsmooth", "friction", "smooth", "stop")
# Primes are rewritten to name suffixes before the safe parser sees the text, because that
# parser accepts derivatives of one variable only (its SDOF contract). The suffix cannot be
# typed by a user (checked) and the rewrite is purely lexical: no evaluation.
_PRIMED = re.compile(r"(?<![A-Za-z0-9_.])([A-Za-z][A-Za-z0-9_]*)\s*('+)")
_SUFFIX = {1: "__d1", 2: "__d2"}
_RESERVED = re.compile(r"__d[12]\b")


def _rewrite(text: Any, what: str) -> tuple[str, dict[str, tuple[str, int]]]:
    """``x1'' + x2'`` -> ``x1__d2 + x2__d1`` and the map suffix name -> (name, order)."""
    if not isinstance(text, str):
        raise ParseError(f"{what}: expected a string, got {type(text).__name__}")
    if _RESERVED.search(text):
        raise ParseError(f"{what} = {text!r}: names ending in __d1/__d2 are reserved")
    found: dict[str, tuple[str, int]] = {}

    def repl(m: re.Match) -> str:
        order = len(m.group(2))
        if order > 2:
            raise ParseError(
                f"{m.group(0)!r} in {what} = {text!r}: only first (x') and second (x'') "
                "derivatives are supported"
            )
        new = m.group(1) + _SUFFIX[order]
        found[new] = (m.group(1), order)
        return new

    return _PRIMED.sub(repl, text), found


def _clip(expr: Any, width: int = 70) -> str:
    text = sp.sstr(expr)
    return text if len(text) <= width else text[: width - 3] + "..."


# ------------------------------------------------------------------------------ elements --
@dataclass(frozen=True)
class Element:
    """One nonlinear element ``w * f(c . y)``.

    Parameters
    ----------
    name
        Unique within the system (``"nonsmooth(x1 - x2)"``, ``"decoupler"``).
    kind
        ``"nonsmooth"``, ``"friction"``, ``"smooth"`` or ``"stop"`` (see the module docstring).
    combination
        ``c``: one SymPy coefficient per state of ``y = (q, q', p)``; ``None`` for a smooth
        term that is not a function of one combination (then ``function`` is in the states).
    function
        ``f(s)`` in the symbol :data:`S` (no force for a stop: 0).
    distribution
        ``w``: one SymPy coefficient per equation.
    limits
        ``(lower, upper)`` of a stop (SymPy; ``-oo``/``oo`` for a one-sided stop).
    restitution
        A stop's coefficient of restitution (0: plastic).
    """

    name: str
    kind: str
    combination: tuple[sp.Expr, ...] | None
    function: sp.Expr
    distribution: tuple[sp.Expr, ...]
    limits: tuple[sp.Expr, sp.Expr] | None = None
    restitution: float = 0.0

    def describe(self, state_names: Sequence[str]) -> str:
        if self.combination is None:
            return f"{self.name} [{self.kind}]: {_clip(self.function)}"
        comb = _combination_text(self.combination, state_names)
        if self.kind == "stop":
            lo, hi = self.limits or (-sp.oo, sp.oo)
            return f"{self.name} [stop]: {lo} <= {comb} <= {hi}, restitution {self.restitution:g}"
        w = ", ".join(sp.sstr(v) for v in self.distribution)
        return f"{self.name} [{self.kind}]: f(s) = {_clip(self.function)}, s = {comb}, w = ({w})"


def _combination_text(c: Sequence[sp.Expr], names: Sequence[str]) -> str:
    return sp.sstr(sum((ci * sp.Symbol(n) for ci, n in zip(c, names, strict=True)), sp.S.Zero))


@dataclass(frozen=True)
class _ElementSpec:
    """An element before its combination is resolved against a system's coordinates."""

    name: str
    kind: str
    on: str
    function: sp.Expr
    force: Mapping[str, Any] | None = None
    limits: tuple[Any, Any] | None = None
    restitution: float = 0.0


def _expr(value: Any, what: str) -> sp.Expr:
    if isinstance(value, str):
        return parse_expression(value)
    if isinstance(value, sp.Basic):
        return sp.sympify(value)  # already SymPy: no text involved
    if isinstance(value, bool) or not isinstance(value, int | float | Fraction):
        raise ParameterError(f"{what} = {value!r}: expected a number, SymPy expression or text")
    if isinstance(value, float) and not math.isfinite(value):
        raise ParameterError(f"{what} = {value!r}: expected a finite number")
    return sp.nsimplify(value) if isinstance(value, Fraction) else sp.sympify(value)


def pwl_spring(
    on: str,
    breakpoints: Sequence[Any],
    slopes: Sequence[Any],
    value_at_zero: Any = 0,
    *,
    name: str | None = None,
    force: Mapping[str, Any] | None = None,
) -> _ElementSpec:
    """A continuous PWL force of ``s = on`` with slopes ``slopes[i]`` between the sorted
    ``breakpoints`` (``len(slopes) = len(breakpoints) + 1``) and ``f(0) = value_at_zero``.

    ``force`` maps coordinate names to the distribution coefficients; by default the force acts
    along ``on`` itself (equal and opposite on ``x1`` and ``x2`` for ``"x1 - x2"``).
    """
    bps = [_expr(b, "breakpoint") for b in breakpoints]
    ks = [_expr(k, "slope") for k in slopes]
    if len(ks) != len(bps) + 1:
        raise ModelError(
            f"pwl_spring on {on!r}: {len(bps)} breakpoints need {len(bps) + 1} slopes, "
            f"got {len(ks)}"
        )
    # f(s) = k0 s + sum (k_i - k_{i-1}) (s - d_i) H(s - d_i), shifted so that f(0) is as given
    f = ks[0] * S + sum(
        ((ks[i + 1] - ks[i]) * (S - d) * sp.Heaviside(S - d) for i, d in enumerate(bps)),
        sp.S.Zero,
    )
    f = f - f.subs(S, 0) + _expr(value_at_zero, "value_at_zero")
    return _ElementSpec(name or f"pwl({on})", "nonsmooth", on, f, force)


def gap(
    on: str, clearance: Any, stiffness: Any, *, name: str | None = None, force=None
) -> _ElementSpec:
    """Two-sided clearance (backlash): ``k[(s - g)H(s - g) + (s + g)H(-s - g)]``."""
    g, k = _expr(clearance, "clearance"), _expr(stiffness, "stiffness")
    f = k * ((S - g) * sp.Heaviside(S - g) + (S + g) * sp.Heaviside(-S - g))
    return _ElementSpec(name or f"gap({on})", "nonsmooth", on, f, force)


def dead_zone(
    on: str, width: Any, stiffness: Any, *, name: str | None = None, force=None
) -> _ElementSpec:
    """Dead zone ``k (s - Max(-d, Min(d, s)))`` (no force for ``|s| < d``)."""
    d, k = _expr(width, "width"), _expr(stiffness, "stiffness")
    f = k * (S - sp.Max(-d, sp.Min(d, S)))
    return _ElementSpec(name or f"dead_zone({on})", "nonsmooth", on, f, force)


def step(on: str, at: Any, jump: Any, *, name: str | None = None, force=None) -> _ElementSpec:
    """A Heaviside step ``J H(s - a)`` (a force that jumps)."""
    a, j = _expr(at, "at"), _expr(jump, "jump")
    return _ElementSpec(name or f"step({on})", "nonsmooth", on, j * sp.Heaviside(S - a), force)


def saturation(
    on: str, limit: Any, stiffness: Any, *, name: str | None = None, force=None
) -> _ElementSpec:
    """Saturation ``k Max(-d, Min(d, s))``."""
    d, k = _expr(limit, "limit"), _expr(stiffness, "stiffness")
    f = k * sp.Max(-d, sp.Min(d, S))
    return _ElementSpec(name or f"saturation({on})", "nonsmooth", on, f, force)


def coulomb(
    on: str, level: Any, *, offset: Any = 0, name: str | None = None, force=None
) -> _ElementSpec:
    """Coulomb friction ``F sign(s - v0)`` on a velocity combination (may stick at ``s = v0``)."""
    fl, v0 = _expr(level, "level"), _expr(offset, "offset")
    return _ElementSpec(name or f"coulomb({on})", "friction", on, fl * sp.sign(S - v0), force)


def polynomial(
    on: str, coefficients: Sequence[Any], *, name: str | None = None, force=None
) -> _ElementSpec:
    """A smooth polynomial ``sum_k a_k s^k`` (``coefficients[k] = a_k``)."""
    f = sum((_expr(a, "coefficient") * S**k for k, a in enumerate(coefficients)), sp.S.Zero)
    return _ElementSpec(name or f"polynomial({on})", "smooth", on, f, force)


def element(
    on: str,
    function: str | sp.Expr,
    *,
    kind: str = "nonsmooth",
    name: str | None = None,
    force=None,
) -> _ElementSpec:
    """Any element ``f(s)``; ``function`` is text in ``s`` (safe parser) or SymPy in :data:`S`."""
    if kind not in _KINDS[:3]:
        raise ModelError(f"element kind {kind!r}: expected one of {', '.join(_KINDS[:3])}")
    f = _expr(function, "function")
    f = f.xreplace({sym: S for sym in f.free_symbols if sym.name == "s"})
    return _ElementSpec(name or f"{kind}({on})", kind, on, f, force)


def stop(
    on: str,
    lower: Any,
    upper: Any,
    *,
    restitution: float = 0.0,
    name: str | None = None,
    force=None,
) -> _ElementSpec:
    """A rigid unilateral stop ``lower <= on <= upper`` on a position combination."""
    lo, hi = _expr(lower, "lower"), _expr(upper, "upper")
    e = float(restitution)
    if not (0.0 <= e <= 1.0):
        raise ParameterError(f"restitution = {restitution!r}: expected a number in [0, 1]")
    return _ElementSpec(name or f"stop({on})", "stop", on, sp.S.Zero, force, (lo, hi), e)


@dataclass(frozen=True)
class Constraint:
    """A stop or friction contact in numbers (see :meth:`System.constraints`).

    ``normal . y`` is the combination (a position for a stop, a velocity for friction; the
    friction law's offset, e.g. the belt speed, is inside the element's ``f``); ``lower`` /
    ``upper`` are a stop's limits (NaN for friction); ``distribution`` is how its force enters
    the equations (one entry per equation, in the rows of ``[M D]``).
    """

    name: str
    kind: str
    normal: np.ndarray
    lower: float
    upper: float
    restitution: float
    distribution: np.ndarray


# -------------------------------------------------------------------------------- system --
@dataclass(frozen=True)
class System:
    """``M q'' + D p' + C q' + K q + E p + sum_e w_e f_e(c_e . y) = F(t)``, ``y = (q, q', p)``.

    Build with :meth:`parse`, :meth:`from_sympy`, :meth:`from_matrices` or
    :meth:`from_oscillator`. Rows of the matrices are the equations (as many as ``n2 + n1``).
    """

    name: str
    coordinates: tuple[str, ...]
    first_order: tuple[str, ...]
    t: sp.Symbol
    M: sp.ImmutableMatrix
    D: sp.ImmutableMatrix
    C: sp.ImmutableMatrix
    K: sp.ImmutableMatrix
    E: sp.ImmutableMatrix
    F: sp.ImmutableMatrix
    elements: tuple[Element, ...]
    params: Mapping[str, float | None]
    source: str = ""
    _cache: dict = field(default_factory=dict, compare=False, repr=False, hash=False)

    # ------------------------------------------------------------------- construction --
    @classmethod
    def parse(
        cls,
        equations: Sequence[str],
        params: Mapping[str, Any] | None = None,
        *,
        time: str = "t",
        name: str = "custom",
        coordinates: Sequence[str] | None = None,
        elements: Sequence[_ElementSpec] = (),
    ) -> System:
        """Read one equation string per coordinate / first-order state.

        Parameters
        ----------
        equations
            ``["x1'' + c1*x1' + k1*x1 + k2*(x1 - x2) = F*cos(Omega*t)",
            "m2*x2'' + k2*(x2 - x1) = 0"]``. A name with ``''`` somewhere is a second-order
            coordinate; a name with only ``'`` is a first-order state (``"C1*p1' = -q"``).
        params
            Values of some or all parameters.
        coordinates
            The order of the states; default: second-order coordinates in the order their
            derivatives first appear, then first-order states likewise.
        elements
            Extra elements (stops, friction laws) from the factories.

        Raises
        ------
        ParseError, ModelError, ParameterError
        """
        if isinstance(equations, str) or not isinstance(equations, Sequence):
            raise ModelError(
                f"equations = {equations!r}: expected a list of equation strings, one per "
                "coordinate"
            )
        rows: list[sp.Expr] = []
        orders: dict[str, int] = {}
        for i, text in enumerate(equations):
            rewritten, found = _rewrite(text, f"equation {i + 1}")
            parsed = parse_equation(rewritten)
            reps = {}
            for sym in parsed.symbols:
                if sym.name in found:
                    base, order = found[sym.name]
                    orders[base] = max(orders.get(base, 0), order)
                    reps[sym] = real_symbol(base + "'" * order)
            rows.append((parsed.lhs - parsed.rhs).xreplace(reps))
        return cls._assemble(
            rows, orders, coordinates, time, params, name, list(equations), elements
        )

    @classmethod
    def from_sympy(
        cls,
        equations: Sequence[sp.Basic],
        coordinates: Sequence[str],
        params: Mapping[str, Any] | None = None,
        *,
        time: str = "t",
        name: str = "custom",
        elements: Sequence[_ElementSpec] = (),
    ) -> System:
        """SymPy equations (``Eq`` or expressions ``= 0``) in ``coordinates``: applied
        functions ``x1(t)`` with ``Derivative``, or symbols named ``x1``, ``x1'``, ``x1''``."""
        names = [str(c) for c in coordinates]
        rows: list[sp.Expr] = []
        orders: dict[str, int] = {}
        for eq in equations:
            if isinstance(eq, sp.Equality):
                expr = eq.lhs - eq.rhs
            elif isinstance(eq, sp.Expr):
                expr = eq
            else:
                raise ModelError(f"expected SymPy Eq or Expr, got {type(eq).__name__}: {eq!r}")
            reps: dict[sp.Basic, sp.Basic] = {}
            for d in expr.atoms(sp.Derivative):
                base = (
                    d.expr.func.__name__
                    if isinstance(d.expr, sp.core.function.AppliedUndef)
                    else str(d.expr)
                )
                order = sum(c for _, c in d.variable_count)
                if base not in names or order > 2:
                    raise ModelError(
                        f"derivative {d}: expected a first or second derivative of one of "
                        f"{', '.join(names)}"
                    )
                reps[d] = real_symbol(base + "'" * order)
            expr = expr.xreplace(reps)
            for f in expr.atoms(sp.core.function.AppliedUndef):
                if f.func.__name__ not in names:
                    raise ModelError(f"unknown function {f}: expected one of {', '.join(names)}")
                expr = expr.xreplace({f: real_symbol(f.func.__name__)})
            expr = expr.xreplace({s: real_symbol(s.name) for s in expr.free_symbols})
            for sym in expr.free_symbols:
                base, primes = sym.name.rstrip("'"), len(sym.name) - len(sym.name.rstrip("'"))
                if primes and base in names:
                    orders[base] = max(orders.get(base, 0), primes)
            rows.append(expr)
        return cls._assemble(
            rows, orders, names, time, params, name, [str(e) for e in equations], elements
        )

    @classmethod
    def from_matrices(
        cls,
        M: Any,
        C: Any,
        K: Any,
        *,
        elements: Sequence[_ElementSpec] = (),
        forcing: Sequence[Any] | None = None,
        coordinates: Sequence[str] | None = None,
        params: Mapping[str, Any] | None = None,
        time: str = "t",
        name: str = "custom",
    ) -> System:
        """``M q'' + C q' + K q + sum_e w_e f_e(c_e . y) = F(t)`` from square matrices.

        ``forcing``: one entry per coordinate (text in ``t`` and parameters, SymPy, or a
        number). Only second-order coordinates: a first-order part is declared through
        :meth:`parse` (single-prime equations).

        Raises
        ------
        ModelError
            Mismatched dimensions, a singular ``M``, an element on an unknown coordinate or on
            a combination that is identically zero.
        """
        mats = []
        for label, value in (("M", M), ("C", C), ("K", K)):
            try:
                rows = [[_expr(v, f"{label} entry") for v in row] for row in value]
            except TypeError:
                raise ModelError(f"{label} = {value!r}: expected a square matrix") from None
            mats.append(rows)
        n = len(mats[0])
        for label, rows in zip("MCK", mats, strict=True):
            if len(rows) != n or any(len(r) != n for r in rows):
                shape = (len(rows), *{len(r) for r in rows})
                raise ModelError(
                    f"{label} has shape {shape}: expected ({n}, {n}) like M (mismatched dimensions)"
                )
        names = list(coordinates) if coordinates is not None else [f"x{i + 1}" for i in range(n)]
        if len(names) != n:
            raise ModelError(
                f"coordinates = {names}: {len(names)} names for {n} rows of M (mismatched "
                "dimensions)"
            )
        if forcing is None:
            fvec = [sp.S.Zero] * n
        else:
            fvec = [_expr(f, "forcing entry") for f in forcing]
            if len(fvec) != n:
                raise ModelError(
                    f"forcing has {len(fvec)} entries: expected {n}, one per coordinate "
                    "(mismatched dimensions)"
                )
        q = [real_symbol(c) for c in names]
        v = [real_symbol(c + "'") for c in names]
        a = [real_symbol(c + "''") for c in names]
        rows = []
        for i in range(n):
            rows.append(
                sum(
                    (
                        mats[0][i][j] * a[j] + mats[1][i][j] * v[j] + mats[2][i][j] * q[j]
                        for j in range(n)
                    ),
                    sp.S.Zero,
                )
                - fvec[i].xreplace({s: real_symbol(s.name) for s in fvec[i].free_symbols})
            )
        orders = {c: 2 for c in names}
        return cls._assemble(rows, orders, names, time, params, name, ["<matrices>"], elements)

    @classmethod
    def from_oscillator(cls, osc: Oscillator) -> System:
        """The SDOF oscillator ``x'' + g(x, x', t) = f(t)`` as a one-coordinate system (same
        parameters and values)."""
        a = real_symbol(osc.x.name + "''")
        row = a + osc.g - osc.forcing.expr(osc.t)
        values = {k: v for k, v in osc.params.items() if v is not None}
        out = cls._assemble(
            [row], {osc.x.name: 2}, [osc.x.name], osc.t.name, None, osc.name, [osc.source], ()
        )
        extra = {k: None for k in osc.params if k not in out.params}
        out = _replace(out, params=MappingProxyType({**out.params, **extra}))
        return out.with_params(values) if values else out

    @classmethod
    def _assemble(
        cls,
        rows: list[sp.Expr],
        orders: Mapping[str, int],
        coordinates: Sequence[str] | None,
        time: str,
        params: Mapping[str, Any] | None,
        name: str,
        source: list[str],
        specs: Sequence[_ElementSpec],
    ) -> System:
        t = real_symbol(time)
        if coordinates is None:
            second = [c for c, o in orders.items() if o == 2]
            first = [c for c, o in orders.items() if o == 1]
        else:
            names = [str(c) for c in coordinates]
            unknown = [c for c in names if c not in orders]
            if unknown:
                raise ModelError(
                    f"coordinates {unknown} have no derivative in the equations: expected "
                    f"coordinates among {', '.join(orders) or 'none'}"
                )
            missing = [c for c in orders if c not in names]
            if missing:
                raise ModelError(f"coordinates = {names} misses {missing}, which have derivatives")
            second = [c for c in names if orders[c] == 2]
            first = [c for c in names if orders[c] == 1]
        if not second and not first:
            raise ModelError(
                "no derivative in the equations: expected x'' for a coordinate or p' for a "
                "first-order state"
            )
        n2, n1 = len(second), len(first)
        if len(rows) != n2 + n1:
            raise ModelError(
                f"{len(rows)} equation(s) for {n2 + n1} coordinate(s)/state(s) "
                f"({', '.join(second + first)}): expected one equation per coordinate "
                "(mismatched dimensions)"
            )
        q = [real_symbol(c) for c in second]
        v = [real_symbol(c + "'") for c in second]
        acc = [real_symbol(c + "''") for c in second]
        p = [real_symbol(c) for c in first]
        pd = [real_symbol(c + "'") for c in first]
        states = q + v + p
        state_names = tuple(s.name for s in states)
        highest = acc + pd
        all_state = set(states) | set(highest)
        m = len(rows)
        Mm = sp.zeros(m, n2)
        Dm = sp.zeros(m, n1)
        Cm = sp.zeros(m, n2)
        Km = sp.zeros(m, n2)
        Em = sp.zeros(m, n1)
        Fv = sp.zeros(m, 1)
        lin_cols = {s: (Km, j) for j, s in enumerate(q)}
        lin_cols.update({s: (Cm, j) for j, s in enumerate(v)})
        lin_cols.update({s: (Em, j) for j, s in enumerate(p)})
        lin_cols.update({s: (Mm, j) for j, s in enumerate(acc)})
        lin_cols.update({s: (Dm, j) for j, s in enumerate(pd)})
        found: list[tuple[int, tuple[sp.Expr, ...] | None, str, sp.Expr]] = []
        for r, row in enumerate(rows):
            if row.has(sp.DiracDelta):
                raise ModelError(f"equation {r + 1} holds DiracDelta: expected no impulses")
            for term in sp.Add.make_args(sp.expand(row)):
                syms = term.free_symbols & all_state
                if not syms:
                    if term.has(*_SWITCHES):
                        raise ModelError(
                            f"{_clip(term)} in equation {r + 1} switches on no coordinate or "
                            f"state ({', '.join(state_names)}): is a name in it a coordinate "
                            "without a derivative in any equation?"
                        )
                    Fv[r] -= term
                    continue
                if term.has(t):
                    raise ModelError(
                        f"{_clip(term)} in equation {r + 1} depends on both the state and the "
                        f"time {t}: expected forcing terms free of the state (no parametric "
                        "excitation)"
                    )
                sw = [a for a in _switch_atoms(term) if a.free_symbols & all_state]
                if syms & set(highest):
                    coeff = [term.coeff(h) for h in highest if term.has(h)]
                    if len(syms) != 1 or sw or coeff[0].free_symbols & all_state:
                        raise ModelError(
                            f"{_clip(term)} in equation {r + 1}: the highest derivatives "
                            f"({', '.join(str(h) for h in highest)}) must enter linearly with "
                            "constant coefficients"
                        )
                    h = next(iter(syms))
                    mat, j = lin_cols[h]
                    mat[r, j] += term / h
                    continue
                if not sw and len(syms) == 1:
                    h = next(iter(syms))
                    c = term / h
                    if not c.free_symbols & all_state:
                        mat, j = lin_cols[h]
                        mat[r, j] += c
                        continue
                if sw:
                    comb = _switch_combination(term, sw, states, r)
                    found.append((r, comb, "switch", term))
                else:
                    found.append((r, None, "smooth", term))
        mass = Mm.row_join(Dm)
        if mass.shape[0] == mass.shape[1]:
            det = sp.simplify(mass.det())
            singular = det == 0
        else:
            singular = True
        if singular:
            raise ModelError(
                f"the matrix of the highest derivatives [M D] = {mass.tolist()} (columns "
                f"{', '.join(str(h) for h in highest)}) is singular: expected an invertible "
                "mass matrix; declare coordinates without inertia as first-order states "
                "(write only their first derivative, p' , in an equation of its own)"
            )
        elements = _group_elements(found, states, m)
        elements += _resolve_specs(specs, states, second, first, m, elements)
        symbols: set[sp.Symbol] = set()
        for mat in (Mm, Dm, Cm, Km, Em, Fv):
            symbols |= mat.free_symbols
        for e in elements:
            for part in (*(e.combination or ()), e.function, *e.distribution, *(e.limits or ())):
                symbols |= sp.sympify(part).free_symbols
        symbols -= set(states) | {t, S}
        values: dict[str, float | None] = {s.name: None for s in sorted(symbols, key=str)}
        out = cls(
            name=name,
            coordinates=tuple(second),
            first_order=tuple(first),
            t=t,
            M=sp.ImmutableMatrix(Mm),
            D=sp.ImmutableMatrix(Dm),
            C=sp.ImmutableMatrix(Cm),
            K=sp.ImmutableMatrix(Km),
            E=sp.ImmutableMatrix(Em),
            F=sp.ImmutableMatrix(Fv),
            elements=tuple(elements),
            params=MappingProxyType(values),
            source="; ".join(source),
        )
        return out.with_params(params) if params else out

    # -------------------------------------------------------------------- parameters --
    def with_params(self, values: Mapping[str, Any] | None = None, **kw: Any) -> System:
        """A copy with some parameter values set (``None`` frees one again).

        Raises
        ------
        ParameterError
            For an unknown name or a value that is not a finite real number.
        """
        new = dict(self.params)
        for key, value in dict(values or {}, **kw).items():
            key = str(key)
            if key not in new:
                raise ParameterError(
                    f"unknown parameter {key!r} for system {self.name!r}: expected one of "
                    f"{', '.join(new) or 'none'}"
                )
            new[key] = None if value is None else validate_parameter_value(key, value)
        return _replace(self, params=MappingProxyType(new))

    @property
    def free_parameters(self) -> tuple[str, ...]:
        return tuple(k for k, v in self.params.items() if v is None)

    def _values(self) -> dict[sp.Symbol, sp.Float]:
        free = self.free_parameters
        if free:
            raise ParameterError(
                f"system {self.name!r} needs values for {', '.join(free)}: pass them as params "
                "or with_params(...)"
            )
        return {real_symbol(k): sp.Float(v) for k, v in self.params.items()}

    # -------------------------------------------------------------------- properties --
    @property
    def state_names(self) -> tuple[str, ...]:
        """``(q..., q'..., p...)``."""
        return (*self.coordinates, *(c + "'" for c in self.coordinates), *self.first_order)

    @property
    def states(self) -> tuple[sp.Symbol, ...]:
        return tuple(real_symbol(n) for n in self.state_names)

    @property
    def n(self) -> int:
        """Number of first-order states, ``2 n2 + n1``."""
        return 2 * len(self.coordinates) + len(self.first_order)

    def element(self, name: str) -> Element:
        for e in self.elements:
            if e.name == name:
                return e
        raise ModelError(
            f"no element {name!r} in system {self.name!r}: expected one of "
            f"{', '.join(e.name for e in self.elements) or 'none'}"
        )

    @property
    def is_piecewise_linear(self) -> bool:
        """True when every element (stops aside) has a piecewise-linear form."""
        vals = {} if self.free_parameters else self._values()
        try:
            self._pwl_forms(vals, check_only=True)
        except (ModelError, ParameterError):
            return False
        return True

    def output(self, expr: str | sp.Expr) -> np.ndarray:
        """The combination vector over :attr:`state_names` of a coordinate name or a linear
        combination (``"x1 - x2"``, ``"x1'"``, ``"2*p1"``), parameter values substituted.

        Raises
        ------
        ModelError
            For anything else (unknown names, nonlinear terms, a constant term, zero).
        """
        states = self.states
        if isinstance(expr, str):
            text, found = _rewrite(expr, "output")
            e = parse_expression(text)
            e = e.xreplace(
                {
                    s: real_symbol(found[s.name][0] + "'" * found[s.name][1])
                    for s in e.free_symbols
                    if s.name in found
                }
            )
        elif isinstance(expr, sp.Expr):
            e = expr.xreplace({s: real_symbol(s.name) for s in expr.free_symbols})
        else:
            raise ModelError(f"output = {expr!r}: expected a coordinate name or combination text")
        what = (
            f"output {expr!r}: expected a coordinate ({', '.join(self.state_names)}) or a "
            "linear combination of them such as 'x1 - x2'"
        )
        others = e.free_symbols - set(states)
        if others - {real_symbol(k) for k in self.params}:
            raise ModelError(f"{what}; unknown name(s) {sorted(map(str, others))}")
        c = [sp.diff(e, s) for s in states]
        if any(ci.free_symbols & set(states) for ci in c) or e.has(*_SWITCHES):
            raise ModelError(f"{what}; it is not linear in the states")
        if sp.simplify(e - sum((ci * s for ci, s in zip(c, states, strict=True)), sp.S.Zero)) != 0:
            raise ModelError(f"{what}; it has a constant term")
        vals = self._values() if any(ci.free_symbols for ci in c) else {}
        vec = np.array([float(ci.xreplace(vals)) for ci in c])
        if not np.any(vec):
            raise ModelError(f"{what}; it is identically zero")
        return vec

    # ----------------------------------------------------------------- numeric forms --
    def numeric_form(self) -> dict[str, Any]:
        """The system in numbers, cached per parameter set: the matrices of the linear part
        (``B = [M D]``, its equilibrated inverse), the elements' combinations, distributions
        and compiled functions, and the harmonic inputs ``(omega, u, v)`` (used by the flows
        built from this system)."""
        key = ("numeric", tuple(self.params.items()))
        if key in self._cache:
            return self._cache[key]
        vals = self._values()

        def arr(mat: sp.Matrix) -> np.ndarray:
            return np.array(mat.xreplace(vals).evalf(), dtype=float).reshape(mat.shape)

        B = np.hstack([arr(self.M), arr(self.D)])
        # equilibrate rows and columns first: the mount's compliances (4e-11) and inertances
        # (6e6) differ by 17 decades without the matrix being anywhere near singular
        Bs = B / np.maximum(np.abs(B).max(axis=1, keepdims=True), 1e-300)
        Bs = Bs / np.maximum(np.abs(Bs).max(axis=0, keepdims=True), 1e-300)
        cond = np.linalg.cond(Bs)
        if not np.isfinite(cond) or cond > 1e14:
            raise ModelError(
                f"the mass matrix [M D] = {B.tolist()} of {self.name!r} is singular for the "
                f"parameter values (condition number {cond:.3g}): expected an invertible matrix"
            )
        n2 = len(self.coordinates)
        L = np.hstack([arr(self.K), arr(self.C), arr(self.E)])  # columns: y = (q, q', p)
        harmonics = _harmonics(self.F.xreplace(vals), self.t)
        comb = {}
        for e in self.elements:
            c = (
                None
                if e.combination is None
                else np.array([float(sp.sympify(ci).xreplace(vals)) for ci in e.combination])
            )
            w = np.array([float(sp.sympify(wi).xreplace(vals)) for wi in e.distribution])
            if c is not None and not np.any(c):
                raise ModelError(
                    f"element {e.name!r}: its combination {e.combination} is identically zero "
                    "for the parameter values, so its switching function never changes sign; "
                    "expected a nonzero combination of the states"
                )
            if c is not None:
                # a switch whose argument loses s for these values never changes sign
                # (Heaviside(a*s - 1) with a = 0); a zero multiplier (nsd with k = 1) is fine
                for atom in _switch_atoms(e.function):
                    if atom.has(S) and not atom.xreplace(vals).has(S):
                        raise ModelError(
                            f"element {e.name!r}: {atom} is {atom.xreplace(vals)} for the "
                            "parameter values, so its switching function never changes sign; "
                            "expected a switch of a nonzero combination of the states"
                        )
            comb[e.name] = (c, w)
        out = {
            "B": B,
            "Binv": np.linalg.inv(B),
            "L": L,
            "harmonics": harmonics,
            "comb": comb,
            "vals": vals,
            "n2": n2,
        }
        self._cache[key] = out
        return out

    def _function(self, e: Element):
        key = ("f", e.name, tuple(self.params.items()))
        if key not in self._cache:
            vals = self.numeric_form()["vals"]
            args = [S] if e.combination is not None else list(self.states)
            self._cache[key] = sp.lambdify(args, e.function.xreplace(vals), modules="numpy")
        return self._cache[key]

    def constraint_projection(
        self, active: Mapping[str, int] | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """(P_acc, P_vel): the constrained acceleration map applied after ``B^-1`` and the
        velocity projection, for the active stops / sticking friction contacts."""
        num = self.numeric_form()
        n2, neq = num["n2"], num["B"].shape[0]
        P = np.eye(neq)
        Pv = np.eye(n2)
        names = {k: v for k, v in dict(active or {}).items() if v is not None}
        if not names:
            return P, Pv
        W, R, Wq = [], [], []
        for nm, side in names.items():
            e = self.element(nm)
            if e.kind not in ("stop", "friction"):
                raise ModelError(
                    f"active element {nm!r} is {e.kind}: expected a stop or a friction contact"
                )
            if e.kind == "stop" and side not in (-1, 1):
                raise ModelError(f"active stop {nm!r}: side = {side!r}, expected -1 or +1")
            c, w = num["comb"][nm]
            cq, cv, cp = c[:n2], c[n2 : 2 * n2], c[2 * n2 :]
            if (
                np.any(cp)
                or (e.kind == "stop" and np.any(cv))
                or (e.kind == "friction" and np.any(cq))
            ):
                raise ModelError(
                    f"element {nm!r}: a {e.kind} constraint must act on "
                    f"{'positions' if e.kind == 'stop' else 'velocities'} of second-order "
                    "coordinates only"
                )
            wa = cq if e.kind == "stop" else cv
            W.append(np.concatenate([wa, np.zeros(neq - n2)]))
            R.append(w)
            if e.kind == "stop":
                Wq.append(cq)
        W, R = np.array(W).T, np.array(R).T
        Binv = num["Binv"]
        G = W.T @ Binv @ R
        P = np.eye(neq) - Binv @ R @ np.linalg.solve(G, W.T)
        if Wq:
            Q = np.array(Wq).T
            Pv = np.eye(n2) - Q @ np.linalg.solve(Q.T @ Q, Q.T)
        return P, Pv

    def constraints(self) -> tuple[Constraint, ...]:
        """The stops and friction contacts, numeric (parameter values substituted), for the
        event-driven solvers: where they act, their limits and how their force enters."""
        num = self.numeric_form()
        out = []
        for e in self.elements:
            if e.kind not in ("stop", "friction"):
                continue
            c, w = num["comb"][e.name]
            if e.kind == "stop":
                lo, hi = (float(sp.sympify(v).xreplace(num["vals"])) for v in e.limits)
            else:
                lo = hi = math.nan
            out.append(Constraint(e.name, e.kind, c, lo, hi, e.restitution, w))
        return tuple(out)

    def invariants(self, rtol: float = 1e-10) -> np.ndarray:
        r"""The conserved linear combinations of the state: the rows ``c`` (over
        :attr:`state_names`) whose rate depends on the time only, ``c . y' = c . b(t)``.

        Such a ``c`` is a left null vector of the linear part ``A`` (``c^T A = 0``) that also
        annihilates every element's force ``B^-1 w_e`` (stops and friction contacts included:
        their constraint forces act along the same ``w_e``), so that ``c^T A_i = 0`` and
        ``c^T b_i = 0`` in every region of :meth:`piecewise_affine`, whatever the element's
        law. Then ``c . y(t) = c . y(0) + int_0^t c . b``: with a forcing whose ``c . b`` has
        zero mean, periodic orbits come in continuous families along the invariant (the mount's
        ``C1 p1 + C2 p2 - A_r x`` in ``mount_linear``), one orbit per value of it; with a
        nonzero mean the combination drifts and there is no periodic orbit.

        Parameters
        ----------
        rtol
            Numeric rank tolerance: a left singular vector counts as null when its singular
            value is at most ``rtol`` times the largest one, after equilibrating the rows and
            columns of ``[A, B^-1 w_1, ...]`` (the mount's rates differ by 17 decades without
            being nearly dependent; a left null vector of the scaled matrix is one of the
            original after undoing the row scaling).

        Returns
        -------
        ndarray, shape (r, n)
            A basis of the invariants in reduced row-echelon form (each row's pivot entry 1,
            the other rows 0 there), ``r = 0`` rows when there is none.

        Raises
        ------
        ParameterError
            Free parameters in the matrices or the elements' distributions (a free forcing
            frequency is fine), or ``rtol`` not in ``(0, 1)``.
        ModelError
            A singular mass matrix.
        """
        if isinstance(rtol, bool) or not isinstance(rtol, int | float) or not 0 < rtol < 1:
            raise ParameterError(f"rtol = {rtol!r}: expected a relative tolerance in (0, 1)")
        key = ("invariants", float(rtol), tuple(self.params.items()))
        if key in self._cache:
            return self._cache[key].copy()
        # only the linear part and the elements' distributions matter: a forcing frequency
        # (Omega) still free does not
        vals = {real_symbol(k): sp.Float(v) for k, v in self.params.items() if v is not None}
        mats = [self.M, self.D, self.K, self.C, self.E]
        mats += [sp.Matrix([e.distribution]) for e in self.elements]
        free = sorted({str(x) for m in mats for x in m.xreplace(vals).free_symbols})
        if free:
            raise ParameterError(
                f"system {self.name!r} needs values for {', '.join(free)} (in its matrices or "
                "elements) to find its invariants"
            )

        def arr(mat: Any) -> np.ndarray:
            return np.array(mat.xreplace(vals).evalf(), dtype=float).reshape(mat.shape)

        n, n2 = self.n, len(self.coordinates)
        try:
            Binv = np.linalg.inv(np.hstack([arr(self.M), arr(self.D)]))
        except np.linalg.LinAlgError:
            raise ModelError(
                f"the mass matrix [M D] of {self.name!r} is singular: expected an invertible matrix"
            ) from None
        cols = [np.zeros((n, n))]
        cols[0][:n2, n2 : 2 * n2] = np.eye(n2)
        cols[0][n2:, :] = -Binv @ np.hstack([arr(self.K), arr(self.C), arr(self.E)])
        for e in self.elements:
            g = np.zeros((n, 1))
            g[n2:, 0] = Binv @ arr(sp.Matrix(list(e.distribution)))[:, 0]
            cols.append(g)
        # balance A by a diagonal similarity T^-1 A T (the states' natural scales: the mount's
        # pressures and flows differ by 10 decades), then scale every column to max 1: a left
        # null vector c_b of the scaled matrix is c = T^-1 c_b, its rounding relative to each
        # state's own scale, so entries at rounding level are recognised and set to 0
        scale = _balance(cols[0])
        mat = np.hstack(cols) / scale[:, None]
        mat[:, :n] *= scale[None, :]
        col = np.abs(mat).max(axis=0)
        mat = mat / np.where(col > 0, col, 1.0)[None, :]
        U, sv, _ = np.linalg.svd(mat)
        top = float(sv[0]) if sv.size and sv[0] > 0 else 1.0
        rank = int(np.sum(sv > rtol * top)) if float(np.abs(mat).max()) > 0 else 0
        cb = _row_echelon(U[:, rank:].T)
        cb[np.abs(cb) <= 1e-12] = 0.0
        out = _row_echelon(cb / scale[None, :]) if cb.size else np.zeros((0, n))
        self._cache[key] = out
        return out.copy()

    def field(self, t: float, y: Sequence[float], active: Mapping[str, int] | None = None):
        """The vector field ``y'`` at time ``t`` (any elements; parameter values needed).

        ``active`` maps the names of resting stops (side -1 lower / +1 upper) and sticking
        friction contacts (any value) to their mode: their force is then the constraint force
        that keeps the combination's acceleration zero (a belt of constant speed, a plate on
        its stop), and a resting stop's combination rate is projected out.
        """
        num = self.numeric_form()
        y = state(y, self.n, "y", require_finite=False)
        n2 = num["n2"]
        rhs = -num["L"] @ y
        for t0, (om, cu, cv) in enumerate(num["harmonics"]):
            del t0
            rhs = rhs + (cu * math.cos(om * t) + cv * math.sin(om * t) if om else cu)
        act = {k: v for k, v in dict(active or {}).items() if v is not None}
        for e in self.elements:
            if e.kind == "stop" or e.name in act:
                continue
            c, w = num["comb"][e.name]
            f = self._function(e)
            val = f(float(c @ y)) if c is not None else f(*y)
            rhs = rhs - w * float(val)
        P, Pv = self.constraint_projection(act)
        z = P @ (num["Binv"] @ rhs)
        return np.concatenate([Pv @ y[n2 : 2 * n2], z])

    def _pwl_forms(self, vals, check_only: bool = False):
        out = {}
        for e in self.elements:
            if e.kind == "stop":
                continue
            if e.kind == "smooth" or e.combination is None:
                raise ModelError(
                    f"element {e.name!r} of {self.name!r} ({_clip(e.function)}) is smooth "
                    "nonlinear, not piecewise linear: expected only piecewise-linear elements"
                )
            try:
                pw = to_pwl(e.function.xreplace(vals), S)
                out[e.name] = pw.numeric() if not check_only else pw
            except NonsmoothError as exc:
                if check_only and "not numeric" in str(exc):
                    continue
                raise ModelError(
                    f"element {e.name!r} of {self.name!r} (f(s) = {_clip(e.function)}) is not "
                    f"piecewise linear: {exc}"
                ) from None
        return out

    def piecewise_affine(self, active: Mapping[str, int] | None = None) -> PiecewiseAffineSystem:
        """The system as a :class:`~perturb.model.affine.PiecewiseAffineSystem`.

        Surfaces ``c . y = d`` at every breakpoint of every element (elements on parallel
        combinations share their surfaces; a surface listed once); regions are the sign
        patterns that can occur for each combination (its breakpoints are crossed in order),
        in every product over the combinations. When the combinations' directions are
        linearly dependent (``x1``, ``x2`` and ``x1 - x2`` all switching) some of those
        products may be empty polyhedra; they are listed anyway (never reached, harmless).
        The state order is :attr:`state_names`, ``(q, q', p)``.
        Harmonic forcing terms become ``inputs``, a constant forcing part enters ``b``; the
        period is that of the forcing (``None`` without harmonics).

        Parameters
        ----------
        active
            Resting stops and sticking friction contacts (see :meth:`field`); their elements
            contribute no surface. A system with stops must name every stop here (``None`` for
            free flight), since the stop itself is a constraint, not a force.

        Raises
        ------
        ModelError
            A non-PWL element (named), a stop not named in ``active``, too many regions.
        ParameterError
            Free parameters.
        """
        act = dict(active or {})
        stops = [e.name for e in self.elements if e.kind == "stop"]
        missing = [s for s in stops if s not in act]
        if missing:
            raise ModelError(
                f"system {self.name!r} has the stop(s) {missing}: pass active={{name: None "
                "(free), -1 or +1 (resting on the lower/upper limit)}} for each"
            )
        act = {k: v for k, v in act.items() if v is not None}
        num = self.numeric_form()
        vals = num["vals"]
        pwls = {k: v for k, v in self._pwl_forms(vals).items() if k not in act}
        n, n2 = self.n, num["n2"]
        # group elements by the direction of their combination
        groups: list[dict[str, Any]] = []
        for nm, pw in pwls.items():
            c, w = num["comb"][nm]
            for g in groups:
                alpha = _parallel(g["c"], c)
                if alpha is not None:
                    break
            else:
                g = {"c": c, "members": [], "bps": []}
                groups.append(g)
                alpha = 1.0
            g["members"].append((nm, alpha, pw, c, w))
            g["bps"].extend(float(b) / alpha for b in pw.breakpoints)
        surfaces = []
        for g in groups:
            bps = sorted(set(g["bps"]))
            merged: list[float] = []
            for b in bps:  # breakpoints equal to rounding: one surface
                if merged and abs(b - merged[-1]) <= 1e-12 * max(1.0, abs(b)):
                    continue
                merged.append(b)
            g["bps"] = merged
            for b in merged:
                label = _numeric_label(g["c"], self.state_names) + f" = {b:.12g}"
                surfaces.append((tuple(g["c"]), b, label))
        count = math.prod(len(g["bps"]) + 1 for g in groups)
        if count > MAX_REGIONS:
            raise ModelError(
                f"system {self.name!r} has {count} regions: expected at most {MAX_REGIONS}"
            )
        P, Pv = self.constraint_projection(act)
        Binv = P @ num["Binv"]
        base_L = num["L"].copy()
        regions = {}
        for idx in np.ndindex(*(len(g["bps"]) + 1 for g in groups)):
            L = base_L.copy()
            const = np.zeros(base_L.shape[0])
            pattern: list[int] = []
            for g, i in zip(groups, idx, strict=True):
                bps = g["bps"]
                lo = bps[i - 1] if i > 0 else None
                hi = bps[i] if i < len(bps) else None
                u = (
                    0.0
                    if lo is None and hi is None
                    else hi - 1.0
                    if lo is None
                    else lo + 1.0
                    if hi is None
                    else 0.5 * (lo + hi)
                )
                pattern.extend(1 if j < i else -1 for j in range(len(bps)))
                for _nm, alpha, pw, c, w in g["members"]:
                    seg = int(pw.segment_index(alpha * u))
                    L += np.outer(w, pw.slopes[seg] * c)
                    const += w * pw.offsets[seg]
            A = np.zeros((n, n))
            A[:n2, n2 : 2 * n2] = Pv
            A[n2:, :] = -Binv @ L
            b = np.concatenate([np.zeros(n2), -Binv @ const])
            regions[tuple(pattern)] = (A, b)
        inputs = []
        omegas = []
        b0 = np.zeros(n)
        for om, cu, cv in num["harmonics"]:
            if om == 0.0:
                b0[n2:] += Binv @ cu
                continue
            omegas.append(om)
            inputs.append(
                (
                    om,
                    np.concatenate([np.zeros(n2), Binv @ cu]),
                    np.concatenate([np.zeros(n2), Binv @ cv]),
                )
            )
        regions = {k: (A, b + b0) for k, (A, b) in regions.items()}
        return PiecewiseAffineSystem.build(
            self.state_names, surfaces, regions, inputs, common_period(omegas)
        )

    # -------------------------------------------------------------------------- text --
    def equations_text(self) -> list[str]:
        """One line per equation, elements written as ``w*f(s)`` with their ``s``."""
        highest = [real_symbol(c + "''") for c in self.coordinates] + [
            real_symbol(c + "'") for c in self.first_order
        ]
        states = self.states
        lines = []
        for r in range(self.M.shape[0]):
            lhs = sum((self.M.row_join(self.D)[r, j] * h for j, h in enumerate(highest)), sp.S.Zero)
            L = self.C.row_join(self.K).row_join(self.E)
            cols = (
                [real_symbol(c + "'") for c in self.coordinates]
                + list(states[: len(self.coordinates)])
                + [real_symbol(c) for c in self.first_order]
            )
            lhs += sum((L[r, j] * s for j, s in enumerate(cols)), sp.S.Zero)
            text = sp.sstr(lhs)
            for e in self.elements:
                if e.kind != "stop" and e.distribution[r] != 0:
                    text += f" + ({sp.sstr(e.distribution[r])})*{e.name}"
            lines.append(f"{text} = {sp.sstr(self.F[r])}")
        return lines

    def __str__(self) -> str:
        vals = ", ".join(f"{k}={'free' if v is None else f'{v:g}'}" for k, v in self.params.items())
        out = [
            f"{self.name}: {len(self.coordinates)} coordinate(s) "
            f"{', '.join(self.coordinates) or '-'}; first-order state(s) "
            f"{', '.join(self.first_order) or '-'}; state y = ({', '.join(self.state_names)})"
        ]
        out += ["  " + line for line in self.equations_text()]
        out += ["  " + e.describe(self.state_names) for e in self.elements]
        if vals:
            out.append(f"  [{vals}]")
        return "\n".join(out)


# ------------------------------------------------------------------------------ helpers --
def _replace(obj: System, **changes: Any) -> System:
    from dataclasses import replace

    return replace(obj, _cache={}, **changes)


def _switch_atoms(expr: sp.Basic) -> list[sp.Basic]:
    return [a for a in sp.preorder_traversal(expr) if isinstance(a, _SWITCHES)]


def _switch_arguments(atom: sp.Basic) -> list[sp.Expr]:
    if isinstance(atom, sp.Heaviside | sp.Abs | sp.sign):
        return [atom.args[0]]
    if isinstance(atom, sp.Max | sp.Min):
        return list(atom.args)
    out = []
    for e, cond in atom.args:  # Piecewise
        out.append(e)
        if isinstance(cond, sp.core.relational.Relational):
            out.append(cond.lhs - cond.rhs)
    return out


def _normalise(c: list[sp.Expr]) -> tuple[sp.Expr, ...]:
    j = next(i for i, ci in enumerate(c) if ci != 0)
    return tuple(sp.simplify(ci / c[j]) for ci in c)


def _switch_combination(term, atoms, states, r) -> tuple[sp.Expr, ...]:
    found: tuple[sp.Expr, ...] | None = None
    for atom in atoms:
        for arg in _switch_arguments(atom):
            # a switch nested in the argument is an atom of its own (visited separately)
            arg = arg.replace(lambda a: isinstance(a, _SWITCHES), lambda a: sp.S.Zero)
            c = [sp.diff(arg, s) for s in states]
            if any(ci.free_symbols & set(states) for ci in c):
                raise ModelError(
                    f"{_clip(atom)} in equation {r + 1}: its argument {_clip(arg)} is not affine "
                    "in the states; expected a switch of a linear combination (x1 - x2 - d)"
                )
            if not any(ci != 0 for ci in c):
                continue
            key = _normalise(c)
            if found is None:
                found = key
            elif any(sp.simplify(a - b) != 0 for a, b in zip(found, key, strict=True)):
                raise ModelError(
                    f"{_clip(term)} in equation {r + 1} switches on two different combinations "
                    "of the state: expected each term to depend on one combination (split it)"
                )
    if found is None:
        raise ModelError(f"{_clip(term)} in equation {r + 1}: no switch depends on the state")
    return found


def _smooth_combination(term, states) -> tuple[sp.Expr, ...] | None:
    grad = [sp.diff(term, s) for s in states]
    nz = [g for g in grad if g != 0]
    ref = nz[0]
    c = []
    for g in grad:
        ratio = sp.cancel(g / ref)
        if ratio.free_symbols & set(states):
            return None
        c.append(ratio)
    return _normalise(c)


def _in_s(term: sp.Expr, c: tuple[sp.Expr, ...], states, r) -> sp.Expr:
    """``term`` as a function of ``s = c . y`` (``c`` normalised: first nonzero entry 1)."""
    j = next(i for i, ci in enumerate(c) if ci != 0)
    others = sum(
        (ci * s for i, (ci, s) in enumerate(zip(c, states, strict=True)) if i != j), sp.S.Zero
    )
    h = sp.expand(term.xreplace({states[j]: S - others}))
    h = h.replace(
        lambda a: isinstance(a, _SWITCHES), lambda a: a.func(*[sp.expand(x) for x in a.args])
    )
    if h.free_symbols & set(states):
        h2 = sp.simplify(h)
        if h2.free_symbols & set(states):
            raise ModelError(
                f"{_clip(term)} in equation {r + 1} is not a function of the one combination "
                f"{_combination_text(c, [s.name for s in states])}: expected each nonlinear term "
                "to act on one linear combination of the state"
            )
        h = h2
    return h


def _group_elements(found, states, m) -> list[Element]:
    names = [s.name for s in states]
    per_key: dict[tuple, dict[int, sp.Expr]] = {}
    loose: list[tuple[int, sp.Expr]] = []
    # smooth terms: expansion split (x1 - x2)**3 into monomials that are functions of the
    # combination only together; try the row's sum first, then each term on its own
    smooth: dict[int, list[sp.Expr]] = {}
    for r, _comb, kind, term in found:
        if kind == "smooth":
            smooth.setdefault(r, []).append(term)
    found = [f for f in found if f[2] != "smooth"]
    for r, terms in smooth.items():
        total = sp.Add(*terms)
        comb = _smooth_combination(total, states)
        if comb is not None:
            found.append((r, comb, "smooth", total))
            continue
        for term in terms:
            found.append((r, _smooth_combination(term, states), "smooth", term))
    for r, comb, kind, term in found:
        if comb is None:
            loose.append((r, term))
            continue
        # expansion split (x1 - x2 - d)*H(...) into terms that are functions of the
        # combination only together: sum a row's terms on one combination first
        key = (comb, kind)
        per_key.setdefault(key, {})
        per_key[key][r] = per_key[key].get(r, sp.S.Zero) + term
    for key, by_row in per_key.items():
        for r, total in by_row.items():
            by_row[r] = _in_s(total, key[0], states, r)
    elements: list[Element] = []
    used: set[str] = set()

    def unique(base: str) -> str:
        nm, k = base, 2
        while nm in used:
            nm, k = f"{base}#{k}", k + 1
        used.add(nm)
        return nm

    for (comb, kind), by_row in per_key.items():
        pending = [(r, h) for r, h in sorted(by_row.items()) if h != 0]
        while pending:
            r0, f = pending.pop(0)
            w = [sp.S.Zero] * m
            w[r0] = sp.S.One
            rest = []
            for r, h in pending:
                ratio = sp.cancel(h / f)
                if ratio.has(S) or ratio.has(*_SWITCHES):
                    rest.append((r, h))
                else:
                    w[r] = ratio
            pending = rest
            velocity_only = all(
                ci == 0 for ci, n in zip(comb, names, strict=True) if not n.endswith("'")
            )
            ek = kind
            if kind == "switch":
                ek = "friction" if velocity_only and f.has(sp.sign) else "nonsmooth"
            text = _combination_text(comb, names)
            elements.append(Element(unique(f"{ek}({text})"), ek, comb, f, tuple(w)))
    for r, term in loose:
        w = [sp.S.Zero] * m
        w[r] = sp.S.One
        elements.append(Element(unique(f"smooth[{r + 1}]"), "smooth", None, term, tuple(w)))
    return elements


def _resolve_specs(specs, states, second, first, m, existing) -> list[Element]:
    names = [s.name for s in states]
    rows_of = {c: i for i, c in enumerate([*second, *first])}
    used = {e.name for e in existing}
    out = []
    for spec in specs:
        if not isinstance(spec, _ElementSpec):
            raise ModelError(
                f"element {spec!r}: expected one made by pwl_spring, gap, dead_zone, step, "
                "saturation, coulomb, polynomial, element or stop"
            )
        text, found = _rewrite(spec.on, f"element {spec.name!r}")
        e = parse_expression(text)
        e = e.xreplace(
            {
                s: real_symbol(found[s.name][0] + "'" * found[s.name][1])
                for s in e.free_symbols
                if s.name in found
            }
        )
        syms = {s.name for s in e.free_symbols}
        bad = sorted(s for s in syms if s not in names)
        if bad:
            raise ModelError(
                f"element {spec.name!r} acts on {spec.on!r}, which names the unknown "
                f"coordinate(s) {bad}: expected a combination of {', '.join(names)}"
            )
        c = [sp.diff(e, s) for s in states]
        if any(ci.free_symbols & set(states) for ci in c) or e.has(*_SWITCHES):
            raise ModelError(
                f"element {spec.name!r} acts on {spec.on!r}: expected a linear combination of "
                f"{', '.join(names)}"
            )
        if all(sp.simplify(ci) == 0 for ci in c):
            raise ModelError(
                f"element {spec.name!r} acts on {spec.on!r}, which is identically zero: its "
                "switching function never changes sign; expected a nonzero combination"
            )
        const = sp.simplify(e - sum((ci * s for ci, s in zip(c, states, strict=True)), sp.S.Zero))
        f = spec.function.xreplace({S: S + const}) if const != 0 else spec.function
        limits = None
        if spec.limits is not None:
            limits = (spec.limits[0] - const, spec.limits[1] - const)
        if spec.force is None:
            # equal and opposite: the combination's coefficients on the coordinates it names
            w = [sp.S.Zero] * m
            for ci, n in zip(c, names, strict=True):
                base = n.rstrip("'")
                if ci != 0:
                    w[rows_of[base]] += ci
        else:
            w = [sp.S.Zero] * m
            for k, val in spec.force.items():
                if k not in rows_of:
                    raise ModelError(
                        f"element {spec.name!r}: force on unknown coordinate {k!r}; expected "
                        f"one of {', '.join(rows_of)}"
                    )
                w[rows_of[k]] = _expr(val, f"force on {k}")
        if spec.name in used:
            raise ModelError(f"element name {spec.name!r} is used twice: expected unique names")
        used.add(spec.name)
        out.append(Element(spec.name, spec.kind, tuple(c), f, tuple(w), limits, spec.restitution))
    return out


def _numeric_label(c: np.ndarray, names: Sequence[str]) -> str:
    parts = []
    for ci, nm in zip(c, names, strict=True):
        if ci == 0:
            continue
        mag = "" if abs(ci) == 1 else f"{abs(ci):.6g}*"
        parts.append(("-" if ci < 0 else "+") + " " + mag + nm)
    text = " ".join(parts)
    return text[2:] if text.startswith("+ ") else "-" + text[2:]


def _parallel(a: np.ndarray, b: np.ndarray) -> float | None:
    """``alpha`` with ``b = alpha a`` (to rounding), else None."""
    j = int(np.argmax(np.abs(a)))
    if a[j] == 0:
        return None
    alpha = b[j] / a[j]
    if alpha != 0 and np.allclose(b, alpha * a, rtol=1e-13, atol=1e-14 * np.abs(b).max()):
        return float(alpha)
    return None


def _balance(A: np.ndarray, sweeps: int = 64) -> np.ndarray:
    """Diagonal ``T`` (powers of 2) with ``T^-1 A T`` balanced: each state's off-diagonal row
    and column norms brought within a factor 2 of each other (Parlett-Reinsch, at most
    ``sweeps`` sweeps). States that no other state touches keep scale 1."""
    B = np.abs(np.array(A, dtype=float))
    np.fill_diagonal(B, 0.0)
    n = B.shape[0]
    t = np.ones(n)
    for _ in range(sweeps):  # bounded: converges in a few sweeps for these sizes
        done = True
        for i in range(n):
            c = float(np.sum(B[:, i] * t[i] / t))  # column i of T^-1 A T: A_ji t_i / t_j
            r = float(np.sum(B[i, :] * t / t[i]))  # row i: A_ij t_j / t_i
            if c == 0.0 or r == 0.0:
                continue
            f = 2.0 ** round(0.5 * math.log2(r / c))
            if f != 1.0:
                t[i] *= f
                done = False
        if done:
            break
    return t


def _row_echelon(rows: np.ndarray) -> np.ndarray:
    """Reduced row-echelon form of independent ``rows`` (partial pivoting on the largest
    entry of each column in turn; entries below ``1e-14`` of a row's scale set to 0), for
    :meth:`System.invariants`: a basis that does not depend on the SVD's rotation."""
    R = np.array(rows, dtype=float).reshape(-1, rows.shape[-1] if rows.ndim == 2 else 0)
    r, n = R.shape
    lead = 0
    for i in range(r):
        while lead < n:
            j = i + int(np.argmax(np.abs(R[i:, lead])))
            if abs(R[j, lead]) > 1e-12 * max(float(np.abs(R[i:]).max()), 1e-300):
                break
            lead += 1
        if lead == n:
            break
        R[[i, j]] = R[[j, i]]
        R[i] = R[i] / R[i, lead]
        for k in range(r):
            if k != i:
                R[k] = R[k] - R[k, lead] * R[i]
        lead += 1
    R[np.abs(R) <= 1e-14 * np.maximum(np.abs(R).max(axis=1, keepdims=True), 1e-300)] = 0.0
    return R


def _harmonics(F: sp.Matrix, t: sp.Symbol) -> list[tuple[float, np.ndarray, np.ndarray]]:
    """``F(t)`` (numbers substituted) as ``[(omega, u, v)]`` with ``F = sum u cos + v sin``;
    ``omega = 0`` holds the constant part."""
    m = F.shape[0]
    table: dict[float, tuple[np.ndarray, np.ndarray]] = {}

    def slot(om: float):
        for k in table:
            if abs(k - om) <= 1e-13 * max(1.0, om):
                return table[k]
        table[om] = (np.zeros(m), np.zeros(m))
        return table[om]

    for r in range(m):
        for term in sp.Add.make_args(sp.expand(F[r])):
            if term == 0:
                continue
            if not term.has(t):
                slot(0.0)[0][r] += float(term)
                continue
            trig = [a for a in term.atoms(sp.cos, sp.sin) if a.has(t)]
            ok = len(trig) == 1
            if ok:
                arg = sp.expand(trig[0].args[0])
                om = sp.diff(arg, t)
                coeff = term / trig[0]
                ok = not om.has(t) and sp.simplify(arg - om * t) == 0 and not coeff.has(t)
            if not ok:
                raise ModelError(
                    f"forcing term {_clip(term)}: expected constants and terms a*cos(w*t), "
                    "a*sin(w*t)"
                )
            w = float(om)
            sgn = 1.0
            if w < 0:  # cos(-wt) = cos(wt), sin(-wt) = -sin(wt)
                w, sgn = -w, -1.0
            u, v = slot(w)
            if isinstance(trig[0], sp.cos):
                u[r] += float(coeff)
            else:
                v[r] += sgn * float(coeff)
    return [(om, u, v) for om, (u, v) in sorted(table.items())]


def common_period(omegas: list[float]) -> float | None:
    """The common period of the harmonic inputs: ``2 pi / w0`` with every frequency an integer
    multiple of ``w0`` (ratios read as fractions with denominators up to 64)."""
    if not omegas:
        return None
    w_min = min(omegas)
    den = 1
    for w in omegas:
        fr = Fraction(w / w_min).limit_denominator(64)
        if abs(float(fr) - w / w_min) > 1e-12 * (w / w_min):
            raise ModelError(
                f"forcing frequencies {sorted(omegas)} are incommensurate: expected integer "
                "ratios (a periodic forcing)"
            )
        den = math.lcm(den, fr.denominator)
    return 2 * math.pi * den / w_min
