"""Harmonic bookkeeping for the perturbation engines.

Every order of Lindstedt–Poincaré, multiple scales or averaging produces a right-hand side
that is a trigonometric polynomial in a phase ``psi``; the secular conditions are its
``cos(psi)``/``sin(psi)`` components and the particular solution divides each harmonic by
``1 - n**2``. Expanding with ``trigsimp``/``dsolve`` on whole expressions is what makes
symbolic tools slow. Here a trigonometric polynomial is turned into a Laurent polynomial in
``z = exp(i psi)`` once, its coefficients are read off, and the result is rebuilt from real
cosines and sines — linear in the size of the expression.

Only arguments of the form ``n*psi + c`` (``n`` an integer, ``c`` free of ``psi``) are
handled; anything else raises :class:`~perturb.errors.PerturbError` naming the term.
"""

from __future__ import annotations

from collections.abc import Mapping

import sympy as sp

from perturb.errors import PerturbError
from perturb.model.parsing import expression_argument

__all__ = [
    "Harmonics",
    "harmonics",
    "from_harmonics",
    "solve_harmonic_oscillator",
    "fold_mirror_angles",
    "split_argument",
]

Harmonics = Mapping[int, tuple[sp.Expr, sp.Expr]]


def split_argument(arg: sp.Expr, psi: sp.Symbol) -> tuple[int, sp.Expr]:
    """Split a trigonometric argument ``n*psi + c`` into ``(n, c)``.

    Parameters
    ----------
    arg : sympy.Expr
        The argument of a ``cos``/``sin``.
    psi : sympy.Symbol
        The phase.

    Returns
    -------
    n : int
        The integer multiple of ``psi``.
    c : sympy.Expr
        The rest, free of ``psi`` (expanded).

    Raises
    ------
    PerturbError
        If ``arg`` is not linear in ``psi`` with an integer coefficient (e.g. ``psi/2``,
        ``psi**2``, ``a*psi`` with a symbolic ``a``).
    """
    arg = sp.expand(arg)
    n = arg.coeff(psi)
    rest = sp.expand(arg - n * psi)
    if rest.has(psi) or not n.is_Integer:
        raise PerturbError(f"trigonometric argument {arg}: expected n*{psi} + c with an integer n")
    return int(n), rest


def harmonics(expr: sp.Expr, psi: sp.Symbol) -> dict[int, tuple[sp.Expr, sp.Expr]]:
    """Components of a trigonometric polynomial in ``psi``.

    Returns ``{n: (c_n, s_n)}`` with ``expr = sum_n c_n cos(n psi) + s_n sin(n psi)`` (``s_0``
    is 0; ``c_0`` is the mean). Coefficients are expanded but otherwise unsimplified.

    Raises
    ------
    PerturbError
        If ``expr`` contains ``psi`` other than through ``cos``/``sin`` of ``n*psi + c``
        (a string ``expr`` goes through :func:`perturb.model.parsing.parse_expression`).
    """
    expr = expression_argument(expr, "expr")  # strings: the safe parser, never sympify
    z = sp.Dummy("z")
    reps: dict[sp.Basic, sp.Expr] = {}
    for f in expr.atoms(sp.cos, sp.sin):
        if not f.has(psi):
            continue
        n, c = split_argument(f.args[0], psi)
        e_plus = z**n * sp.exp(sp.I * c)
        e_minus = z ** (-n) * sp.exp(-sp.I * c)
        reps[f] = (
            (e_plus + e_minus) / 2 if isinstance(f, sp.cos) else (e_plus - e_minus) / (2 * sp.I)
        )
    laurent = sp.expand(expr.xreplace(reps))
    if laurent.has(psi):
        bad = [t for t in sp.Add.make_args(laurent) if t.has(psi)][:1]
        raise PerturbError(f"term {bad[0]} depends on {psi} other than through cos/sin")
    coeffs: dict[int, sp.Expr] = {}
    for term in sp.Add.make_args(laurent):
        powers = [p for p in sp.Mul.make_args(term) if p.has(z)]
        n = 0
        for p in powers:
            base, ex = p.as_base_exp()
            if base != z or not ex.is_Integer:
                raise PerturbError(f"unexpected factor {p} in the harmonic expansion")
            n += int(ex)
        coeffs[n] = coeffs.get(n, sp.Integer(0)) + term / z**n
    out: dict[int, tuple[sp.Expr, sp.Expr]] = {}
    for n in sorted({abs(k) for k in coeffs}):
        cp, cm = coeffs.get(n, sp.Integer(0)), coeffs.get(-n, sp.Integer(0))
        if n == 0:
            c, s = cp, sp.Integer(0)
        else:
            c, s = cp + cm, sp.I * (cp - cm)
        c = sp.expand(sp.expand_complex(sp.expand(c).rewrite(sp.cos)))
        s = sp.expand(sp.expand_complex(sp.expand(s).rewrite(sp.cos)))
        if c != 0 or s != 0:
            out[n] = (c, s)
    return out


def from_harmonics(parts: Mapping[int, tuple[sp.Expr, sp.Expr]], psi: sp.Symbol) -> sp.Expr:
    """Inverse of :func:`harmonics`."""
    return sp.Add(
        *(c * sp.cos(n * psi) + s * sp.sin(n * psi) if n else c for n, (c, s) in parts.items())
    )


def solve_harmonic_oscillator(
    parts: Mapping[int, tuple[sp.Expr, sp.Expr]], psi: sp.Symbol, omega2: sp.Expr = 1
) -> sp.Expr:
    """Periodic particular solution of ``omega2 * (u'' + u) = rhs`` in ``psi`` (``'`` =
    d/dpsi) once the resonant ``n = 1`` terms have been removed: each harmonic ``n != 1`` is
    divided by ``omega2 (1 - n**2)``.

    Raises
    ------
    PerturbError
        If the ``n = 1`` component is still present (a secular term).
    """
    if 1 in parts and any(sp.simplify(v) != 0 for v in parts[1]):
        raise PerturbError("secular terms remain: remove the cos(psi), sin(psi) components first")
    return sp.Add(
        *(
            (c * sp.cos(n * psi) + s * sp.sin(n * psi)) / (omega2 * (1 - n**2)) if n else c / omega2
            for n, (c, s) in parts.items()
            if n != 1
        )
    )


def fold_mirror_angles(
    exprs: tuple[sp.Expr, ...], definitions: tuple[tuple[sp.Symbol, sp.Expr], ...]
) -> tuple[tuple[sp.Expr, ...], tuple[tuple[sp.Symbol, sp.Expr], ...]]:
    """Closed forms of a symmetric force written with one crossing angle, for display.

    :func:`~perturb.fourier.symbols.closed_form` gives the switching points ``-d`` and ``d``
    the angles ``theta_1 = arccos(-d/A)`` and ``theta_2 = arccos(d/A)``; since
    ``theta_1 = pi - theta_2`` a term in ``theta_1`` folds into ``theta_2``, e.g. the dead-zone
    describing function ``k_1 + 2 k_2 (theta - sin(theta) cos(theta))/pi`` with
    ``theta = arccos(d/a)``. The angle left alone is renamed ``theta``.
    """
    values = dict(definitions)
    reps: dict[sp.Symbol, sp.Expr] = {}
    for s1, v1 in definitions:
        for s2, v2 in definitions:
            if s1 is s2 or s2 in reps or s1 in reps or not isinstance(v1, sp.acos):
                continue
            if isinstance(v2, sp.acos) and sp.expand(v1.args[0] + v2.args[0]) == 0:
                if v1.args[0].could_extract_minus_sign():  # fold arccos(-u) into arccos(u)
                    reps[s1] = sp.pi - s2
    if not reps:
        return exprs, definitions
    left = [s for s in values if s not in reps]
    out = []
    for e in exprs:
        e = sp.expand(e.xreplace(reps))
        const, rest = e.as_independent(*left, as_Add=True)
        tidy = min(sp.factor_terms(rest), sp.factor(rest), key=sp.count_ops)
        out.append(const + tidy)
    defs = tuple((s, values[s]) for s in left)
    if len(left) == 1 and left[0].name.startswith("theta_"):
        # the assumptions as given (not the inferred closure assumptions0): an equal Symbol
        # built from the closure prints differently, and SymPy's cache then hands either
        # spelling to later expressions, so saved derivations would depend on call order
        given = getattr(left[0], "_assumptions_orig", None) or left[0].assumptions0
        theta = sp.Symbol("theta", **given)
        out = [e.xreplace({left[0]: theta}) for e in out]
        defs = ((theta, values[left[0]]),)
    return tuple(out), defs
