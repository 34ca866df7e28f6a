r"""Canonical piecewise-linear (PWL) form of nonsmooth scalar functions.

A scalar function :math:`f(s)` of one symbol built from ``Heaviside``, ``sign``, ``Abs``,
``Max``, ``Min``, ``Piecewise`` and linear arithmetic is brought to the canonical form

.. math::

    f(s) = k_i\,s + c_i \qquad \text{for } d_i < s < d_{i+1}, \quad i = 0, \dots, m,

with breakpoints :math:`d_1 < \dots < d_m` (:math:`d_0 = -\infty`, :math:`d_{m+1} = +\infty`).
Equivalently (:meth:`PiecewiseLinear.ramp_step_form`) as a base line plus ramps and steps,

.. math::

    f(s) = k_0 s + c_0 + \sum_{i=1}^{m}
        \Big[\Delta k_i\,(s - d_i)\,H(s - d_i) + J_i\,H(s - d_i)\Big],
    \qquad \Delta k_i = k_i - k_{i-1},\quad J_i = f(d_i^+) - f(d_i^-),

which is what :mod:`perturb.fourier.coefficients` consumes: every term has a closed-form Fourier
series.

Conventions a caller must know
------------------------------
* **Segments are open intervals.** The value *at* a breakpoint is not represented: ``Heaviside(0)``
  conventions (``H0``), ``sign(0) = 0`` and the closed/open sides of ``Piecewise`` conditions are
  forgotten. Only the one-sided limits :math:`f(d_i^\pm)` are kept. The numeric evaluators
  (:meth:`NumericPWL.__call__`, :meth:`PiecewiseLinear.as_piecewise`) return the right limit
  :math:`f(d_i^+)` at a breakpoint.
* **Ordering of symbolic breakpoints** uses SymPy's assumptions only: two breakpoints
  :math:`a, b` are ordered when the sign of :math:`a - b` can be decided (e.g. ``-d < d`` for
  ``d = Symbol('d', positive=True)``). Otherwise :class:`~perturb.errors.NonsmoothError` is raised
  naming the pair; pass ``values=`` or declare assumptions. Breakpoints whose difference is zero
  merge. Breakpoints ordered only non-strictly (``d <= d + e`` for a nonnegative ``e``) stay
  distinct; the segment between them may be empty for some values, and
  :meth:`PiecewiseLinear.subs` removes it when the values make them coincide. A sign of a
  symbolic switch coefficient (``Heaviside(k*x)``) must be decidable in the same way.
* **Coefficients contain no switch functions.** A switch whose argument does not depend on the
  variable (``sign(v)``, ``Heaviside(d)``) is resolved by the sign of its argument, which must
  therefore be decidable; a switch on another state variable is rejected.
* **Canonical = minimal.** Adjacent segments whose slope and offset are provably equal are merged,
  so a breakpoint survives only where the slope or the value changes (or where that cannot be
  decided symbolically, e.g. a slope ``k`` next to a slope ``1``).
* Heaviside, sign, Abs, Max, Min or Piecewise of a *nonlinear* argument, nonlinear pieces,
  non-switch functions of the variable (``sin``, ``exp``) and ``DiracDelta`` are rejected; no
  root-finding is attempted.
"""

from __future__ import annotations

import functools
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
import sympy
from sympy import Abs, DiracDelta, Heaviside, Max, Min, Piecewise, sign
from sympy.core.function import AppliedUndef
from sympy.core.relational import Relational
from sympy.logic.boolalg import And, BooleanAtom, BooleanFalse, BooleanTrue, Not, Or

from perturb.errors import NonsmoothError, ParameterError

__all__ = [
    "PiecewiseLinear",
    "NumericPWL",
    "Segment",
    "RampStepForm",
    "to_pwl",
    "is_nonsmooth",
    "is_pwl",
    "MAX_BREAKPOINTS",
    "MAX_SWITCH_NESTING",
]

#: Functions that switch between linear pieces; their arguments define the breakpoints.
_SWITCHES = (Heaviside, sign, Abs, Max, Min, Piecewise)
#: Everything :func:`is_nonsmooth` looks for.
_NONSMOOTH = (*_SWITCHES, DiracDelta)

_RELATIONS = {
    "<": lambda sg: sg < 0,
    "<=": lambda sg: sg <= 0,
    ">": lambda sg: sg > 0,
    ">=": lambda sg: sg >= 0,
    "==": lambda sg: sg == 0,
    "!=": lambda sg: sg != 0,
}

_PRIMARY_FACTS = (
    "positive",
    "negative",
    "nonnegative",
    "nonpositive",
    "zero",
    "nonzero",
    "integer",
    "real",
)

_VALUES_HINT = (
    "give parameter values (to_pwl(expr, symbol, values={...}) or PiecewiseLinear.subs) "
    "or declare assumptions on the symbols (e.g. Symbol('d', positive=True))"
)


# --------------------------------------------------------------------------------------------
# small symbolic helpers
# --------------------------------------------------------------------------------------------


def _as_expr(value: Any, what: str) -> sympy.Expr:
    """Convert a SymPy object or a number to a SymPy expression; never parse strings."""
    if isinstance(value, str):
        raise TypeError(
            f"{what} must be a SymPy expression or a number, not the string {value!r}; "
            "parse text with perturb's model parser first"
        )
    try:
        out = sympy.sympify(value, strict=True)
    except (sympy.SympifyError, TypeError) as exc:
        raise TypeError(f"{what} must be a SymPy expression or a number, got {value!r}") from exc
    if not isinstance(out, sympy.Expr):
        raise TypeError(f"{what} must be a scalar SymPy expression, got {out!r} ({type(out)})")
    return out


def _sign(e: sympy.Expr) -> int | None:
    """Sign (-1, 0, 1) of an s-free expression if SymPy can decide it, else ``None``.

    Cheap assumption queries first; ``expand`` and ``simplify`` only when those fail, because
    e.g. ``(d + 1)**2 - d**2 - 2*d`` is zero but not obviously so.
    """
    candidates = (lambda: e, lambda: sympy.expand(e), lambda: sympy.simplify(e))
    for make in candidates:
        c = make()
        if c.is_zero:
            return 0
        if c.is_positive:
            return 1
        if c.is_negative:
            return -1
    return None


def _weak_sign(e: sympy.Expr) -> int | None:
    """Like :func:`_sign`, but also +1 for provably ``e >= 0`` and -1 for ``e <= 0``.

    Used to order breakpoints known only non-strictly (``d <= d + e`` for a nonnegative
    ``e``): they stay distinct, and the segment between them may be empty for some values.
    """
    sg = _sign(e)
    if sg is not None:
        return sg
    for c in (e, sympy.expand(e)):
        if c.is_nonnegative:
            return 1
        if c.is_nonpositive:
            return -1
    return None


def _tidy(e: sympy.Expr) -> sympy.Expr:
    """Light canonical tidying of a coefficient (numbers are left as they are)."""
    e = sympy.expand(e)
    if e.free_symbols and e.is_rational_function():
        e = sympy.cancel(e)
    return e


def _simplified(e: sympy.Expr) -> sympy.Expr:
    e = sympy.expand(e)
    return sympy.simplify(e) if e.free_symbols else e


def _linear_parts(e: sympy.Expr, s: sympy.Symbol) -> tuple[sympy.Expr, sympy.Expr] | None:
    """Return ``(slope, offset)`` with ``e == slope*s + offset`` or ``None`` if not linear."""
    for attempt in (sympy.expand, lambda z: sympy.expand(sympy.cancel(z)), sympy.simplify):
        z = attempt(e)
        slope = sympy.diff(z, s)
        if slope.has(s):
            continue
        offset = sympy.expand(z - slope * s)
        if not offset.has(s):
            return _tidy(slope), _tidy(offset)
    return None


def _describe_interval(s: sympy.Symbol, lo: sympy.Expr, hi: sympy.Expr) -> str:
    if lo == -sympy.oo and hi == sympy.oo:
        return f"all {s}"
    if lo == -sympy.oo:
        return f"{s} < {hi}"
    if hi == sympy.oo:
        return f"{s} > {lo}"
    return f"{lo} < {s} < {hi}"


def _bad_values(expr: sympy.Expr) -> bool:
    return bool(expr.has(sympy.oo, -sympy.oo, sympy.zoo, sympy.nan))


#: Most breakpoints (kinks and jumps) a piecewise-linear form may have. The canonicaliser's
#: work grows with the square of the breakpoints times the number of switches (each segment
#: resolves every switch); nested switches can double the breakpoints per level
#: (``Abs(Abs(Abs(x) - 1) - 1/2)``...), so 45 levels would mean 2**45 of them. Physical models
#: have a handful; 100 take a few seconds.
MAX_BREAKPOINTS = 100


#: Deepest nesting of switch functions inside one another that :func:`to_pwl` canonicalises.
#: Every level is canonicalised once, on every segment of the level above, so the work grows
#: with the fourth power of the depth (45 levels of ``Abs(... - i)`` took 54 s; 16 take about
#: a second). The equation parser allows 8 (:data:`perturb.model.parsing.MAX_SWITCH_NESTING`).
MAX_SWITCH_NESTING = 16

#: Most candidate breakpoints (before duplicates are merged) collected for one expression.
_MAX_CANDIDATES = 2 * MAX_BREAKPOINTS


def _switch_depth(expr: sympy.Basic, memo: dict[sympy.Basic, int]) -> int:
    """How many switch functions are nested inside one another in ``expr``."""
    if expr in memo:
        return memo[expr]
    inner = max((_switch_depth(a, memo) for a in expr.args), default=0)
    out = inner + 1 if isinstance(expr, _SWITCHES) else inner
    memo[expr] = out
    return out


def _too_many(expr: sympy.Basic, count: int) -> NonsmoothError:
    text = sympy.sstr(expr)
    text = text if len(text) <= 80 else text[:77] + "..."
    return NonsmoothError(
        f"{text} has {count} candidate breakpoints: expected at most {MAX_BREAKPOINTS} "
        "(write the force with fewer switches or less nesting)"
    )


class _Unordered(Exception):
    """Internal: two breakpoints whose order cannot be decided."""

    def __init__(self, a: sympy.Expr, b: sympy.Expr) -> None:
        super().__init__(a, b)
        self.pair = (a, b)


# --------------------------------------------------------------------------------------------
# the canonicaliser
# --------------------------------------------------------------------------------------------


class _Canon:
    """Bring expressions in one symbol ``s`` to (breakpoints, slopes, offsets).

    Route: (1) collect candidate breakpoints = zeros of every switch argument (arguments of
    Heaviside/sign/Abs, pairwise differences of Max/Min arguments, ``lhs - rhs`` of Piecewise
    conditions); arguments that are themselves PWL are canonicalised recursively and their
    zeros found segment by segment. (2) Order them symbolically. (3) On each open segment
    resolve every switch *structurally* from the sign of its argument there — the sign of a
    linear argument ``a*s + c`` on a segment follows from the sign of ``a`` and from which side
    of the segment its root ``-c/a`` lies (the root is itself a breakpoint, so this needs no
    numeric test point and symbolic parameters survive). (4) Read off slope and offset and
    check linearity.
    """

    def __init__(self, s: sympy.Symbol) -> None:
        self.s = s
        # nested switches (Abs(Abs(x) - 1)) ask for the same inner canonical form from
        # candidates() and from zeros(): without these caches the work doubles per level
        self._candidates: dict[sympy.Basic, list[sympy.Expr]] = {}
        self._canonical: dict[sympy.Basic, tuple] = {}

    # ---- step 1: candidate breakpoints --------------------------------------------------

    def _reject_foreign(self, e: sympy.Basic) -> None:
        """Reject DiracDelta and functions of other variables anywhere in ``e``."""
        for node in sympy.preorder_traversal(e):
            if isinstance(node, DiracDelta):
                raise NonsmoothError(
                    f"{node} is a distribution (Dirac delta), not a function, and has no "
                    "piecewise-linear form; keep impulsive terms out of the PWL force — the "
                    "Fourier engine (perturb.fourier.coefficients) handles DiracDelta terms "
                    "separately"
                )
            if isinstance(node, AppliedUndef | sympy.Derivative):
                raise NonsmoothError(
                    f"{node} is a function of another variable; a single-variable "
                    f"piecewise-linear form in {self.s} cannot depend on other state variables"
                )

    def candidates(self, e: sympy.Basic) -> list[sympy.Expr]:
        if e not in self._candidates:
            out = self._candidates_uncached(e)
            # the same numbers arrive from several switches (and a nested switch's own
            # breakpoints from every level above it): merge them as they come
            out = list(dict.fromkeys(out)) if all(b.is_Rational for b in out) else out
            if len(out) > _MAX_CANDIDATES:
                raise _too_many(e, len(out))
            self._candidates[e] = out
        return list(self._candidates[e])

    def _candidates_uncached(self, e: sympy.Basic) -> list[sympy.Expr]:
        s = self.s
        self._reject_foreign(e)
        if not e.has(s) or e == s:
            return []
        if isinstance(e, sympy.Add | sympy.Mul):
            return [b for a in e.args for b in self.candidates(a)]
        if isinstance(e, sympy.Pow):
            if e.exp.has(s):
                raise NonsmoothError(
                    f"{e} has the variable {s} in an exponent; expected linear arithmetic of "
                    f"{s} and switch functions (Heaviside, sign, Abs, Max, Min, Piecewise)"
                )
            # Whether the power is linear on each segment (Heaviside(x)**2 is, x**2 is not)
            # is checked after resolution.
            return self.candidates(e.base)
        if isinstance(e, Heaviside | sign | Abs):
            if any(a.has(s) for a in e.args[1:]):
                raise NonsmoothError(f"{e}: the value at zero must not depend on {s}")
            arg = e.args[0]
            return self.candidates(arg) + self.zeros(arg, e)
        if isinstance(e, Max | Min):
            pairs = len(e.args) * (len(e.args) - 1) // 2
            if pairs > _MAX_CANDIDATES:
                raise _too_many(e, pairs)
            out = [b for a in e.args for b in self.candidates(a)]
            for i, a in enumerate(e.args):
                for b in e.args[i + 1 :]:
                    out += self.zeros(a - b, e)
                    if len(out) > _MAX_CANDIDATES:  # checked as they come: each costs work
                        raise _too_many(e, len(out))
            return out
        if isinstance(e, Piecewise):
            out = []
            for piece, cond in e.args:
                out += self.candidates(piece)
                out += self.condition_candidates(cond, e)
            return out
        raise NonsmoothError(
            f"{e} is not piecewise linear in {s}: only linear arithmetic of {s} and the "
            "switch functions Heaviside, sign, Abs, Max, Min and Piecewise are supported "
            f"({type(e).__name__} of {s} is not)"
        )

    def condition_candidates(self, cond: sympy.Basic, pw: Piecewise) -> list[sympy.Expr]:
        if isinstance(cond, BooleanAtom):
            return []
        if isinstance(cond, And | Or | Not):
            return [b for c in cond.args for b in self.condition_candidates(c, pw)]
        if isinstance(cond, Relational) and cond.rel_op in _RELATIONS:
            g = cond.lhs - cond.rhs
            return self.candidates(g) + self.zeros(g, pw, what=f"condition {cond}")
        raise NonsmoothError(
            f"{pw}: the condition {cond} is not supported; expected comparisons (<, <=, >, >=, "
            "==, !=) of linear functions combined with And/Or/Not"
        )

    def zeros(self, g: sympy.Expr, switch: sympy.Basic, what: str = "") -> list[sympy.Expr]:
        """Points where the switch argument ``g`` changes sign (and ``g``'s own kinks)."""
        s = self.s
        if not g.has(s):
            return []

        def where() -> str:  # printed only for an error: printing costs more than the rest
            return f"{switch}: the switch argument {g}" + (f" (from the {what})" if what else "")

        if not g.has(*_SWITCHES):
            parts = _linear_parts(g, s)
            if parts is None:
                raise NonsmoothError(
                    f"{where()} is not linear in {s} (expected a*{s} + c with a, c independent "
                    f"of {s}); a switch of a nonlinear argument is not piecewise linear and "
                    "perturb does not root-find — rewrite it with linear arguments"
                )
            a, c = parts
            sa = _sign(a)
            if sa == 0:
                return []
            if sa is None:
                raise NonsmoothError(
                    f"{where()}: cannot decide the sign of the coefficient {a} of {s}, which "
                    f"decides on which side of {-c / a} the switch is on; {_VALUES_HINT}"
                )
            return [-c / a]
        # A PWL argument (nested switches): canonicalise it, then collect its zero crossings.
        try:
            bps, slopes, offsets = self.canonical(g)
        except NonsmoothError as exc:
            raise NonsmoothError(f"{where()} is not piecewise linear: {exc}") from exc
        out = list(bps)
        lows = (-sympy.oo, *bps)
        highs = (*bps, sympy.oo)
        for lo, hi, a, c in zip(lows, highs, slopes, offsets, strict=True):
            sa = _sign(a)
            if sa == 0:
                # constant on the segment: no isolated zero (its sign is decided later)
                continue
            if sa is None:
                raise NonsmoothError(
                    f"{where()}: cannot decide whether its slope {a} on "
                    f"{_describe_interval(s, lo, hi)} is zero; {_VALUES_HINT}"
                )
            root = _tidy(-c / a)
            above = 1 if lo == -sympy.oo else _weak_sign(root - lo)
            below = 1 if hi == sympy.oo else _weak_sign(hi - root)
            if above is not None and below is not None and (above <= 0 or below <= 0):
                continue  # provably outside the open segment (or at one of its ends)
            if above is None or below is None:
                raise NonsmoothError(
                    f"{where()}: cannot decide whether its zero {root} lies in "
                    f"{_describe_interval(s, lo, hi)}; {_VALUES_HINT}"
                )
            # inside, possibly only weakly (it may coincide with an end for some values)
            out.append(root)
        return out

    # ---- step 2: ordering -----------------------------------------------------------------

    def order(self, candidates: list[sympy.Expr], expr: sympy.Expr) -> list[sympy.Expr]:
        unique: list[sympy.Expr] = []
        if all(b.is_Rational for b in candidates):
            # numbers: exact duplicates are equal rationals, no pairwise sign tests needed
            return sorted(set(candidates))
        for b in candidates:
            b = _tidy(b)
            if _bad_values(b) or b.is_extended_real is False:
                raise NonsmoothError(
                    f"{expr}: the breakpoint {b} is not a finite real number; switch "
                    f"arguments must be real linear functions of {self.s}"
                )
            if not any(_sign(b - u) == 0 for u in unique):
                unique.append(b)

        def compare(a: sympy.Expr, b: sympy.Expr) -> int:
            sg = _weak_sign(a - b)
            if sg is None:
                raise _Unordered(a, b)
            return sg

        try:
            return sorted(unique, key=functools.cmp_to_key(compare))
        except _Unordered as exc:
            a, b = exc.pair
            raise NonsmoothError(
                f"could not order the breakpoints {a} and {b} of {expr} in {self.s}: the sign "
                f"of {a} - ({b}) cannot be decided; {_VALUES_HINT}"
            ) from None

    # ---- step 3: structural resolution on one segment ------------------------------------

    def side(self, root: sympy.Expr, bps: Sequence[sympy.Expr], i: int) -> int | None:
        """+1 if segment ``i`` lies right of ``root``, -1 if left, ``None`` if undecidable."""
        lo = bps[i - 1] if i > 0 else None
        hi = bps[i] if i < len(bps) else None
        if root.is_Rational and (lo is None or lo.is_Rational) and (hi is None or hi.is_Rational):
            # numbers: compare with the two ends of the (sorted) segment only, instead of
            # testing the root against every breakpoint
            if lo is not None and lo >= root:
                return 1
            if hi is not None and root >= hi:
                return -1
            return None
        for j, b in enumerate(bps):
            if _sign(root - b) == 0:
                # segment i is (bps[i-1], bps[i]): a breakpoint with j < i is at or below it
                return 1 if j < i else -1
        if i > 0 and _weak_sign(bps[i - 1] - root) in (0, 1):
            return 1
        if i < len(bps) and _weak_sign(root - bps[i]) in (0, 1):
            return -1
        return None

    def sign_on(
        self,
        g: sympy.Expr,
        bps: Sequence[sympy.Expr],
        i: int,
        memo: dict,
        switch: sympy.Basic,
    ) -> int:
        """Sign of the switch argument ``g`` on the open segment ``i``."""
        s = self.s
        lo = bps[i - 1] if i > 0 else -sympy.oo
        hi = bps[i] if i < len(bps) else sympy.oo
        where = _describe_interval(s, lo, hi)
        parts = _linear_parts(self.resolve(g, bps, i, memo), s)
        if parts is None:  # pragma: no cover - nonlinear arguments are rejected in step 1
            raise NonsmoothError(f"{switch}: the argument {g} is not linear in {s} on {where}")
        a, c = parts
        sa = _sign(a)
        if sa == 0:
            sc = _sign(c)
            if sc is None:
                if not g.has(s):
                    raise NonsmoothError(
                        f"{switch}: its switch argument {g} does not depend on {s} and its "
                        "sign cannot be decided; the canonical form keeps no switch functions in "
                        "its coefficients, and a switch on another state variable cannot be "
                        f"part of a single-variable piecewise-linear form in {s}. For "
                        f"parameters ({', '.join(map(str, sorted(g.free_symbols, key=str)))}), "
                        f"{_VALUES_HINT}"
                    )
                raise NonsmoothError(
                    f"{switch}: its argument {g} equals {c} on {where}, whose sign cannot be "
                    f"decided; {_VALUES_HINT}"
                )
            return sc
        side = None if sa is None else self.side(_tidy(-c / a), bps, i)
        if side is None:
            raise NonsmoothError(
                f"{switch}: cannot decide the sign of its argument {g} on {where} (it is "
                f"{a}*{s} + {c} there); {_VALUES_HINT}"
            )
        return sa * side

    def truth(
        self, cond: sympy.Basic, bps: Sequence[sympy.Expr], i: int, memo: dict, pw: Piecewise
    ) -> bool:
        if isinstance(cond, BooleanTrue):
            return True
        if isinstance(cond, BooleanFalse):
            return False
        if isinstance(cond, And):
            return all(self.truth(c, bps, i, memo, pw) for c in cond.args)
        if isinstance(cond, Or):
            return any(self.truth(c, bps, i, memo, pw) for c in cond.args)
        if isinstance(cond, Not):
            return not self.truth(cond.args[0], bps, i, memo, pw)
        if isinstance(cond, Relational) and cond.rel_op in _RELATIONS:
            sg = self.sign_on(cond.lhs - cond.rhs, bps, i, memo, pw)
            return _RELATIONS[cond.rel_op](sg)
        raise NonsmoothError(f"{pw}: unsupported condition {cond}")

    def resolve(self, e: sympy.Basic, bps: Sequence[sympy.Expr], i: int, memo: dict) -> Any:
        """``e`` with every switch replaced by its branch on segment ``i``."""
        if e in memo:
            return memo[e]
        if not e.has(*_SWITCHES):
            out = e
        elif isinstance(e, Heaviside):
            sg = self.sign_on(e.args[0], bps, i, memo, e)
            out = sympy.Heaviside(0, *e.args[1:]) if sg == 0 else sympy.Integer(sg > 0)
        elif isinstance(e, sign):
            out = sympy.Integer(self.sign_on(e.args[0], bps, i, memo, e))
        elif isinstance(e, Abs):
            sg = self.sign_on(e.args[0], bps, i, memo, e)
            out = sg * self.resolve(e.args[0], bps, i, memo)
        elif isinstance(e, Max | Min):
            want = 1 if isinstance(e, Max) else -1
            values = [self.resolve(a, bps, i, memo) for a in e.args]
            best = 0
            for k in range(1, len(e.args)):
                # the sign of args[k] - args[best] is constant on the segment because the
                # zeros of all pairwise differences are breakpoints
                if self.sign_on(e.args[k] - e.args[best], bps, i, memo, e) == want:
                    best = k
            out = values[best]
        elif isinstance(e, Piecewise):
            for piece, cond in e.args:
                if self.truth(cond, bps, i, memo, e):
                    out = self.resolve(piece, bps, i, memo)
                    break
            else:
                lo = bps[i - 1] if i > 0 else -sympy.oo
                hi = bps[i] if i < len(bps) else sympy.oo
                raise NonsmoothError(
                    f"{e} is undefined on {_describe_interval(self.s, lo, hi)} (no condition "
                    "holds there); add an otherwise branch (expr, True)"
                )
        else:
            out = e.func(*[self.resolve(a, bps, i, memo) for a in e.args])
        memo[e] = out
        return out

    # ---- step 4: the whole thing ----------------------------------------------------------

    def canonical(
        self, expr: sympy.Expr
    ) -> tuple[tuple[sympy.Expr, ...], tuple[sympy.Expr, ...], tuple[sympy.Expr, ...]]:
        if expr not in self._canonical:
            self._canonical[expr] = self._canonical_uncached(expr)
        return self._canonical[expr]

    def _canonical_uncached(
        self, expr: sympy.Expr
    ) -> tuple[tuple[sympy.Expr, ...], tuple[sympy.Expr, ...], tuple[sympy.Expr, ...]]:
        s = self.s
        bps = self.order(self.candidates(expr), expr)
        if len(bps) > MAX_BREAKPOINTS:
            raise _too_many(expr, len(bps))
        slopes: list[sympy.Expr] = []
        offsets: list[sympy.Expr] = []
        for i in range(len(bps) + 1):
            memo: dict = {}
            piece = self.resolve(expr, bps, i, memo)
            parts = None if _bad_values(piece) else _linear_parts(piece, s)
            if parts is None or any(_bad_values(p) for p in parts):
                raise self._nonlinear_error(expr, piece, bps, i, memo)
            slopes.append(parts[0])
            offsets.append(parts[1])
        return _merge_equal(tuple(bps), tuple(slopes), tuple(offsets))

    def _nonlinear_error(
        self, expr: sympy.Expr, piece: sympy.Expr, bps: Sequence[sympy.Expr], i: int, memo: dict
    ) -> NonsmoothError:
        """Name the additive term (and its smallest sub-expression) that is not linear."""
        s = self.s
        lo = bps[i - 1] if i > 0 else -sympy.oo
        hi = bps[i] if i < len(bps) else sympy.oo
        where = _describe_interval(s, lo, hi)

        def linear(e: sympy.Basic) -> bool:
            r = self.resolve(e, bps, i, memo)
            return not _bad_values(r) and _linear_parts(r, s) is not None

        term = next((t for t in sympy.Add.make_args(expr) if not linear(t)), expr)
        culprit = term
        while True:
            inner = [a for a in culprit.args if isinstance(a, sympy.Expr) and not linear(a)]
            if not inner:
                break
            culprit = inner[0]
        detail = "" if culprit == term else f" (its sub-expression {culprit} is not linear)"
        return NonsmoothError(
            f"{term} is not piecewise linear in {s}: on {where} it equals "
            f"{self.resolve(term, bps, i, memo)}, which is not of the form slope*{s} + offset"
            f"{detail}"
        )


def _merge_equal(
    bps: tuple[sympy.Expr, ...], slopes: tuple[sympy.Expr, ...], offsets: tuple[sympy.Expr, ...]
) -> tuple[tuple[sympy.Expr, ...], tuple[sympy.Expr, ...], tuple[sympy.Expr, ...]]:
    """Drop breakpoints where neither slope nor offset provably changes."""
    out_b: list[sympy.Expr] = []
    out_k = [slopes[0]]
    out_c = [offsets[0]]
    for b, k, c in zip(bps, slopes[1:], offsets[1:], strict=True):
        if _sign(k - out_k[-1]) == 0 and _sign(c - out_c[-1]) == 0:
            continue
        out_b.append(b)
        out_k.append(k)
        out_c.append(c)
    return tuple(out_b), tuple(out_k), tuple(out_c)


def _substitution(
    values: Mapping[Any, Any] | None, symbols: set[sympy.Symbol], variable: sympy.Symbol
) -> dict[sympy.Symbol, sympy.Expr]:
    """Map ``values`` (keys: names or Symbols) onto the Symbols actually present.

    Keys that name no symbol of the expression are ignored, so the whole parameter dictionary
    of an oscillator can be passed. A value that contradicts an assumption of its symbol (e.g.
    ``d = -1`` for a positive ``d``) raises: the canonical form may have used that assumption.
    """
    if values is None:
        return {}
    if not isinstance(values, Mapping):
        raise TypeError(f"values must be a mapping from names/Symbols to numbers, got {values!r}")
    by_name: dict[str, list[sympy.Symbol]] = {}
    for sym in symbols:
        by_name.setdefault(sym.name, []).append(sym)
    out: dict[sympy.Symbol, sympy.Expr] = {}
    for key, raw in values.items():
        if isinstance(key, str):
            targets = by_name.get(key, [])
            is_variable = key == variable.name
        elif isinstance(key, sympy.Symbol):
            targets = [key] if key in symbols else []
            is_variable = key == variable
        else:
            raise TypeError(f"values keys must be names or Symbols, got {key!r}")
        if is_variable:
            raise ParameterError(
                f"values must not assign the variable {variable} itself (got {key!r}: {raw!r})"
            )
        value = _as_expr(raw, f"the value of {key}")
        if value.free_symbols or not value.is_number:
            raise ParameterError(f"the value of {key} must be a number, got {value}")
        if _bad_values(value) or value.is_finite is False or value.is_extended_real is False:
            raise ParameterError(f"the value of {key} must be a finite real number, got {value}")
        for sym in targets:
            facts = sym.assumptions0
            # report the familiar facts (positive, ...) before derived ones (extended_...)
            ordered = [f for f in _PRIMARY_FACTS if f in facts] + sorted(
                set(facts) - set(_PRIMARY_FACTS)
            )
            for fact in ordered:
                expected = facts[fact]
                actual = getattr(value, f"is_{fact}", None)
                if expected is not None and actual is not None and actual != expected:
                    raise ParameterError(
                        f"the value {value} of {sym} contradicts its assumption "
                        f"{fact}={expected}, which the canonical form may rely on; use a symbol "
                        "without that assumption or a value that satisfies it"
                    )
            out[sym] = value
    return out


# --------------------------------------------------------------------------------------------
# public data objects
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Segment:
    """One open segment ``lower < s < upper`` on which ``f(s) = slope*s + offset``.

    ``lower`` is ``-oo`` for the first segment and ``upper`` is ``oo`` for the last.
    """

    lower: sympy.Expr
    upper: sympy.Expr
    slope: sympy.Expr
    offset: sympy.Expr


class RampStepForm(NamedTuple):
    r"""``f(s) = base_slope*s + base_offset + Σ_i [slope_jumps[i]*(s - d_i)*H(s - d_i)
    + value_jumps[i]*H(s - d_i)]`` with ``d_i = breakpoints[i]``.

    A plain 5-tuple (it unpacks as ``k0, c0, d, dk, J = pwl.ramp_step_form()``). Entries are
    SymPy expressions for :class:`PiecewiseLinear` and floats / float arrays for
    :class:`NumericPWL`.
    """

    base_slope: Any
    base_offset: Any
    breakpoints: Any
    slope_jumps: Any
    value_jumps: Any


@dataclass(frozen=True)
class PiecewiseLinear:
    r"""Canonical piecewise-linear function of one symbol.

    .. math::

        f(s) = k_i s + c_i \quad\text{on}\quad d_i < s < d_{i+1},\qquad
        d_0 = -\infty,\ d_{m+1} = +\infty .

    Parameters
    ----------
    symbol : sympy.Symbol
        The variable :math:`s`.
    breakpoints : tuple of sympy.Expr
        :math:`d_1 < \dots < d_m` (may be symbolic).
    slopes, offsets : tuple of sympy.Expr
        :math:`k_0..k_m` and :math:`c_0..c_m` (``m + 1`` entries each, free of ``symbol``).

    Notes
    -----
    Segments are open intervals: the value at a breakpoint is not represented. The constructor
    rejects breakpoints that are provably not strictly increasing; when the order of symbolic
    breakpoints cannot be decided it trusts the caller (:func:`to_pwl` only produces decided
    orders).
    """

    symbol: sympy.Symbol
    breakpoints: tuple[sympy.Expr, ...]
    slopes: tuple[sympy.Expr, ...]
    offsets: tuple[sympy.Expr, ...]

    def __post_init__(self) -> None:
        if not isinstance(self.symbol, sympy.Symbol):
            raise TypeError(f"symbol must be a sympy.Symbol, got {self.symbol!r}")
        for name in ("breakpoints", "slopes", "offsets"):
            raw = getattr(self, name)
            if isinstance(raw, str | sympy.Basic) or not isinstance(raw, Sequence):
                raise TypeError(f"{name} must be a sequence, got {raw!r}")
            entries = tuple(_as_expr(v, f"{name} entry") for v in raw)
            for v in entries:
                if v.has(self.symbol):
                    raise NonsmoothError(f"{name} entry {v} depends on the variable {self.symbol}")
                if _bad_values(v):
                    raise NonsmoothError(f"{name} entry {v} is not finite")
            object.__setattr__(self, name, entries)
        m = len(self.breakpoints)
        if len(self.slopes) != m + 1 or len(self.offsets) != m + 1:
            raise NonsmoothError(
                f"{m} breakpoints need {m + 1} slopes and offsets, got {len(self.slopes)} "
                f"slopes and {len(self.offsets)} offsets"
            )
        for a, b in zip(self.breakpoints, self.breakpoints[1:], strict=False):
            if _sign(b - a) in (-1, 0):
                raise NonsmoothError(
                    f"breakpoints must be strictly increasing, but {a} is not below {b}"
                )

    # ---- derived quantities --------------------------------------------------------------

    @property
    def segments(self) -> tuple[Segment, ...]:
        """The ``m + 1`` open segments, left to right, with ``±oo`` ends."""
        lows = (-sympy.oo, *self.breakpoints)
        highs = (*self.breakpoints, sympy.oo)
        return tuple(
            Segment(lo, hi, k, c)
            for lo, hi, k, c in zip(lows, highs, self.slopes, self.offsets, strict=True)
        )

    def __iter__(self) -> Iterator[Segment]:
        return iter(self.segments)

    def __len__(self) -> int:
        return len(self.slopes)

    @property
    def slope_jumps(self) -> tuple[sympy.Expr, ...]:
        r""":math:`\Delta k_i = k_i - k_{i-1}` at each breakpoint, simplified."""
        return tuple(_simplified(b - a) for a, b in zip(self.slopes, self.slopes[1:], strict=False))

    @property
    def jumps(self) -> tuple[sympy.Expr, ...]:
        r"""Value jumps :math:`J_i = f(d_i^+) - f(d_i^-) = \Delta k_i d_i + c_i - c_{i-1}`."""
        return tuple(
            _simplified((self.slopes[i + 1] - self.slopes[i]) * d + self.offsets[i + 1] - c)
            for i, (d, c) in enumerate(zip(self.breakpoints, self.offsets, strict=False))
        )

    @property
    def is_continuous(self) -> bool:
        """True iff every jump is provably zero.

        A symbolic jump whose vanishing cannot be decided (e.g. ``f0`` for an unconstrained
        ``f0``) counts as discontinuous, so ``False`` means "not proven continuous".
        """
        return all(_sign(j) == 0 for j in self.jumps)

    @property
    def free_symbols(self) -> set[sympy.Symbol]:
        """Parameters occurring in breakpoints, slopes or offsets."""
        out: set[sympy.Symbol] = set()
        for e in (*self.breakpoints, *self.slopes, *self.offsets):
            out |= e.free_symbols
        return out

    @property
    def is_numeric(self) -> bool:
        """True when no breakpoint, slope or offset contains a free symbol."""
        return not self.free_symbols

    def ramp_step_form(self) -> RampStepForm:
        r"""Base line plus ramps and steps at each breakpoint.

        .. math::

            f(s) = k_0 s + c_0 + \sum_i \Delta k_i (s - d_i) H(s - d_i) + J_i H(s - d_i)

        The offset bookkeeping: crossing :math:`d_i` changes the slope by :math:`\Delta k_i`
        and the offset by :math:`-\Delta k_i d_i + J_i`.
        """
        return RampStepForm(
            self.slopes[0], self.offsets[0], self.breakpoints, self.slope_jumps, self.jumps
        )

    # ---- conversions ----------------------------------------------------------------------

    def as_piecewise(self) -> sympy.Piecewise:
        """``Piecewise((k0*s + c0, s < d1), (k1*s + c1, s < d2), ..., (km*s + cm, True))``.

        At a breakpoint it takes the right limit :math:`f(d_i^+)`.
        """
        s = self.symbol
        pieces = [
            (k * s + c, s < d)
            for k, c, d in zip(self.slopes, self.offsets, self.breakpoints, strict=False)
        ]
        pieces.append((self.slopes[-1] * s + self.offsets[-1], True))
        return sympy.Piecewise(*pieces)

    def as_heaviside(self) -> sympy.Expr:
        """The ramp/step form as a SymPy expression (``Heaviside(0) = 1/2`` at breakpoints)."""
        s = self.symbol
        k0, c0, bps, dks, jumps = self.ramp_step_form()
        out = k0 * s + c0
        for d, dk, jump in zip(bps, dks, jumps, strict=True):
            step = sympy.Heaviside(s - d)
            out += dk * (s - d) * step + jump * step
        return out

    def subs(self, values: Mapping[str | sympy.Symbol, Any]) -> PiecewiseLinear:
        """Substitute parameter values and re-canonicalise.

        Breakpoints that the values make coincide merge (the segment between them vanishes),
        then adjacent segments with equal slope and offset merge. Keys naming no symbol are
        ignored.

        Raises
        ------
        NonsmoothError
            If the values reverse the order of two breakpoints (the form was derived under a
            different order: call :func:`to_pwl` on the expression with ``values=``) or leave
            the order undecidable.
        ParameterError
            If a value is not a finite real number or contradicts a symbol's assumptions.
        """
        mapping = _substitution(values, self.free_symbols, self.symbol)
        if not mapping:
            return self
        bps = [_tidy(b.xreplace(mapping)) for b in self.breakpoints]
        slopes = [_tidy(k.xreplace(mapping)) for k in self.slopes]
        offsets = [_tidy(c.xreplace(mapping)) for c in self.offsets]
        keep_b: list[sympy.Expr] = []
        keep_k = [slopes[0]]
        keep_c = [offsets[0]]
        for i, b in enumerate(bps):
            if keep_b:
                sg = _sign(b - keep_b[-1])
                if sg is None:
                    raise NonsmoothError(
                        f"after substituting {values}, the order of the breakpoints "
                        f"{keep_b[-1]} and {b} cannot be decided; {_VALUES_HINT}"
                    )
                if sg < 0:
                    raise NonsmoothError(
                        f"the values {values} reverse the order of the breakpoints "
                        f"{self.breakpoints[i - 1]} and {self.breakpoints[i]} (now {keep_b[-1]} "
                        f"and {b}); the canonical form was derived for the other order — call "
                        "to_pwl(expr, symbol, values=...) on the original expression"
                    )
                if sg == 0:
                    # the segment between coinciding breakpoints is empty: replace it
                    keep_k[-1] = slopes[i + 1]
                    keep_c[-1] = offsets[i + 1]
                    continue
            keep_b.append(b)
            keep_k.append(slopes[i + 1])
            keep_c.append(offsets[i + 1])
        merged = _merge_equal(tuple(keep_b), tuple(keep_k), tuple(keep_c))
        return PiecewiseLinear(self.symbol, *merged)

    def numeric(self) -> NumericPWL:
        """Float version for fast vectorised evaluation.

        Raises
        ------
        NonsmoothError
            If breakpoints, slopes or offsets still contain free symbols (named in the message).
        """
        free = self.free_symbols
        if free:
            names = ", ".join(sorted(map(str, free)))
            raise NonsmoothError(
                f"the piecewise-linear form in {self.symbol} is not numeric: it contains the "
                f"free symbols {names}; substitute them first with .subs({{...}}) or "
                "to_pwl(..., values={...})"
            )

        def floats(entries: tuple[sympy.Expr, ...], name: str) -> np.ndarray:
            try:
                return np.array([float(e) for e in entries], dtype=float)
            except TypeError as exc:
                raise NonsmoothError(f"{name} {entries} are not all real numbers") from exc

        return NumericPWL(
            floats(self.breakpoints, "breakpoints"),
            floats(self.slopes, "slopes"),
            floats(self.offsets, "offsets"),
        )

    def __str__(self) -> str:
        s = self.symbol
        rows = [
            (_describe_interval(s, seg.lower, seg.upper), str(seg.slope), str(seg.offset))
            for seg in self.segments
        ]
        header = ("segment", "slope", "offset")
        widths = [max(len(r[j]) for r in (header, *rows)) for j in range(3)]
        jumps = self.jumps
        if all(_sign(j) == 0 for j in jumps):
            status = "continuous"
        elif any(_sign(j) not in (0, None) for j in jumps):
            status = "discontinuous"
        else:
            status = "continuity undecided"
        lines = [f"PiecewiseLinear in {s}: {len(rows)} segment(s), {status}"]
        for r in (header, *rows):
            lines.append(
                "  " + "  ".join(v.ljust(w) for v, w in zip(r, widths, strict=True)).rstrip()
            )
        return "\n".join(lines)


@dataclass(frozen=True, eq=False)
class NumericPWL:
    """Float piecewise-linear function: ``f(x) = slopes[i]*x + offsets[i]`` on segment ``i``.

    Segment ``i`` is ``breakpoints[i-1] < x < breakpoints[i]``. The arrays are copied and made
    read-only. At a breakpoint the right limit is returned (``np.searchsorted(...,
    side='right')``).
    """

    breakpoints: np.ndarray
    slopes: np.ndarray
    offsets: np.ndarray

    def __post_init__(self) -> None:
        arrays = {}
        for name in ("breakpoints", "slopes", "offsets"):
            a = np.array(getattr(self, name), dtype=float)  # copy: the object is immutable
            if a.ndim != 1:
                raise NonsmoothError(f"{name} must be one-dimensional, got shape {a.shape}")
            if not np.all(np.isfinite(a)):
                raise NonsmoothError(f"{name} must be finite, got {a}")
            a.setflags(write=False)
            arrays[name] = a
            object.__setattr__(self, name, a)
        m = arrays["breakpoints"].size
        if arrays["slopes"].size != m + 1 or arrays["offsets"].size != m + 1:
            raise NonsmoothError(f"{m} breakpoints need {m + 1} slopes and offsets")
        if m > 1 and not np.all(np.diff(arrays["breakpoints"]) > 0):
            raise NonsmoothError(
                f"breakpoints must be strictly increasing, got {arrays['breakpoints']}"
            )

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, NumericPWL):
            return NotImplemented
        return all(
            np.array_equal(getattr(self, n), getattr(other, n))
            for n in ("breakpoints", "slopes", "offsets")
        )

    __hash__ = None  # type: ignore[assignment]  # arrays: equal objects, no stable hash

    def segment_index(self, x: Any) -> np.ndarray:
        """Index ``i`` of the segment containing each ``x`` (right segment at a breakpoint)."""
        return np.searchsorted(self.breakpoints, np.asarray(x, dtype=float), side="right")

    def __call__(self, x: Any) -> Any:
        """Vectorised evaluation; a scalar in gives a float out."""
        xs = np.asarray(x, dtype=float)
        i = self.segment_index(xs)
        out = self.slopes[i] * xs + self.offsets[i]
        return float(out) if out.ndim == 0 else out

    @property
    def slope_jumps(self) -> np.ndarray:
        return np.diff(self.slopes)

    @property
    def jumps(self) -> np.ndarray:
        """``f(d_i+) - f(d_i-)`` at each breakpoint."""
        return self.slope_jumps * self.breakpoints + np.diff(self.offsets)

    def ramp_step_form(self) -> RampStepForm:
        """Floats/arrays version of :meth:`PiecewiseLinear.ramp_step_form`."""
        return RampStepForm(
            float(self.slopes[0]),
            float(self.offsets[0]),
            self.breakpoints,
            self.slope_jumps,
            self.jumps,
        )


# --------------------------------------------------------------------------------------------
# module functions
# --------------------------------------------------------------------------------------------


def to_pwl(
    expr: sympy.Expr,
    symbol: sympy.Symbol,
    values: Mapping[str | sympy.Symbol, Any] | None = None,
    *,
    parameters: Sequence[str | sympy.Symbol] | None = None,
) -> PiecewiseLinear:
    """Canonical piecewise-linear form of ``expr`` in ``symbol``.

    Parameters
    ----------
    expr : sympy.Expr
        Built from Heaviside, sign, Abs, Max, Min, Piecewise (conditions comparing linear
        functions of ``symbol``) and linear arithmetic; products of a linear function with
        piecewise-constant switches are fine, products making a piece nonlinear are not.
    symbol : sympy.Symbol
        The variable.
    values : mapping, optional
        Parameter values (keys: names or Symbols) substituted before canonicalisation. Keys
        naming no symbol of ``expr`` are ignored.
    parameters : sequence, optional
        If given, the only symbols besides ``symbol`` that ``expr`` may contain (after
        ``values``); any other symbol is taken as another state variable and rejected.

    Returns
    -------
    PiecewiseLinear

    Raises
    ------
    NonsmoothError
        For anything without a canonical PWL form (the message names the offending
        sub-expression): nonlinear pieces, switches of nonlinear arguments, other functions of
        ``symbol``, DiracDelta, undecidable order of symbolic breakpoints or signs of symbolic
        coefficients, switches of other variables.
    ParameterError
        For bad ``values``.
    TypeError
        If ``expr`` is not a SymPy expression (strings are never parsed here).
    """
    expr = _as_expr(expr, "expr")
    if not isinstance(symbol, sympy.Symbol):
        raise TypeError(f"symbol must be a sympy.Symbol, got {symbol!r}")
    mapping = _substitution(values, expr.free_symbols - {symbol}, symbol)
    if mapping:
        expr = expr.xreplace(mapping)
    if parameters is not None:
        allowed = {p if isinstance(p, str) else p.name for p in parameters}
        foreign = sorted(
            (str(f) for f in expr.free_symbols - {symbol} if f.name not in allowed), key=str
        )
        if foreign:
            raise NonsmoothError(
                f"{expr} depends on {', '.join(foreign)}, which is neither the variable "
                f"{symbol} nor a declared parameter; a single-variable piecewise-linear form "
                "cannot depend on other state variables"
            )
    if _bad_values(expr):
        raise NonsmoothError(f"{expr} is not finite")
    depth = _switch_depth(expr, {})
    if depth > MAX_SWITCH_NESTING:
        text = sympy.sstr(expr)
        raise NonsmoothError(
            f"{text if len(text) <= 80 else text[:77] + '...'} nests {depth} switch functions "
            f"inside one another: expected at most {MAX_SWITCH_NESTING}"
        )
    bps, slopes, offsets = _Canon(symbol).canonical(expr)
    return PiecewiseLinear(symbol, bps, slopes, offsets)


def is_nonsmooth(expr: sympy.Basic) -> bool:
    """True if ``expr`` contains Heaviside, Max, Min, Abs, sign, Piecewise or DiracDelta."""
    if not isinstance(expr, sympy.Basic):
        expr = _as_expr(expr, "expr")
    return bool(expr.has(*_NONSMOOTH))


def is_pwl(expr: sympy.Expr, symbol: sympy.Symbol) -> bool:
    """True iff :func:`to_pwl` succeeds, i.e. ``expr`` has a canonical PWL form in ``symbol``.

    Note that an expression whose symbolic breakpoints cannot be ordered gives ``False``
    (the form exists for each parameter value but not symbolically).
    """
    try:
        to_pwl(expr, symbol)
    except NonsmoothError:
        return False
    return True
