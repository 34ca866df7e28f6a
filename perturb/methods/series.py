r"""The Lindstedt–Poincaré series engine shared by :mod:`perturb.methods.lindstedt` and
:mod:`perturb.methods.modified_lindstedt`.

Both methods expand the response in harmonics of a strained phase and solve order by order;
what they share lives here, with public names:

* exact arithmetic on Laurent polynomials with rational coefficients over "atoms" (symbols,
  the closed-form Fourier coefficient functions of :mod:`perturb.fourier.symbols`, any other
  opaque factor): :class:`LaurentPolynomial`, :data:`ZERO`, :data:`ONE`, :func:`lift`. No
  SymPy ``expand`` runs inside the perturbation loop;
* trigonometric series ``{n: (cos coefficient, sin coefficient)}`` with such coefficients
  (:data:`Series`), multiplied by the product-to-sum rules: :func:`series_combine`,
  :func:`series_mul`, :func:`series_derivative`, :func:`series_solve`, ... ;
* the split of an oscillator's restoring force about a reference linear frequency
  (:func:`split_model`, :class:`SplitModel`, :class:`Force`: polynomial part and ramps/steps
  of a piecewise-linear part) and the Taylor composition ``[eps^n] g(X)`` along the expansion
  (:class:`Expansion`);
* the derivation text: :func:`equation`, :func:`derivation_step`, :func:`tidy_coefficient`,
  :func:`closed_form_step`, :func:`is_short`;
* small shared checks and symbols: :func:`check_options`, :func:`method_dummy`,
  :func:`free_symbol`, :func:`vanishes`, :func:`omega0_coefficient`.

The atom table behind :class:`LaurentPolynomial` is module state: one table for both methods,
so an atom keeps its index (and monomials their order) across derivations.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from functools import cache, lru_cache
from typing import Any

import sympy as sp

from perturb.approximation import Step
from perturb.errors import FourierError, ModelError, NonsmoothError, ParameterError
from perturb.fourier.symbols import DiracCoefficient, RampCoefficient, StepCoefficient, closed_form
from perturb.fourier.trig import fold_mirror_angles, from_harmonics
from perturb.methods.applicability import expression_argument
from perturb.model.oscillator import Oscillator
from perturb.model.parsing import parse_expression, real_symbol
from perturb.model.pwl import to_pwl
from perturb.printing import latex

__all__ = [
    "AMPLITUDES",
    "PWL_MAX_ORDER",
    "Coeff",
    "Expansion",
    "Force",
    "LaurentPolynomial",
    "Mono",
    "ONE",
    "Series",
    "SplitModel",
    "ZERO",
    "check_options",
    "closed_form_step",
    "derivation_step",
    "equation",
    "free_symbol",
    "is_short",
    "lift",
    "method_dummy",
    "omega0_coefficient",
    "series_at_zero",
    "series_combine",
    "series_derivative",
    "series_mul",
    "series_solve",
    "series_to_sympy",
    "series_truncate",
    "split_model",
    "tidy_coefficient",
    "vanishes",
]

#: Amplitude conventions: ``A`` is the first-harmonic amplitude, or the initial value x(0).
AMPLITUDES = ("first_harmonic", "initial")

_COEFFICIENT_FUNCTIONS = (StepCoefficient, RampCoefficient, DiracCoefficient)

#: Highest order for piecewise-linear forces. Order 3 is computable (its Taylor term has
#: Dirac-delta coefficients) but the products of whole truncated series it needs grow past
#: 10^5 operations (about 30 s): measured for ``nsd``, of no practical use.
PWL_MAX_ORDER = 2


# ---------------------------------------------------------------------------------------------
# Laurent polynomials over "atoms" (symbols, coefficient functions, any other opaque factor)
# ---------------------------------------------------------------------------------------------
_QQ = sp.QQ
_Q0 = _QQ(0)
_Q1 = _QQ(1)
_ATOM_ID: dict[sp.Basic, int] = {}
_ATOMS: list[sp.Basic] = []

#: A monomial: sorted ``(atom index, exponent)`` pairs, exponents non-zero.
Mono = tuple[tuple[int, int], ...]


def _atom_id(atom: sp.Basic) -> int:
    i = _ATOM_ID.get(atom)
    if i is None:
        i = _ATOM_ID[atom] = len(_ATOMS)
        _ATOMS.append(atom)
    return i


@lru_cache(maxsize=1 << 17)
def _mono_mul(a: Mono, b: Mono) -> Mono:
    if not a:
        return b
    if not b:
        return a
    d = dict(a)
    for g, e in b:
        s = d.get(g, 0) + e
        if s:
            d[g] = s
        else:
            del d[g]
    return tuple(sorted(d.items()))


def _q(value: Any):
    """An exact rational (floats from user text are read as the nearest short rational)."""
    if isinstance(value, int):
        return _QQ(value)
    if isinstance(value, sp.Float):
        value = sp.nsimplify(value, rational=True)
    if isinstance(value, sp.Rational):
        return _QQ(int(value.p), int(value.q))
    return value  # already a QQ element


class LaurentPolynomial:
    """A Laurent polynomial ``sum_m c_m prod_i atom_i**e_i`` with rational ``c_m``.

    Exact, and fast for the products the perturbation orders need; division is only by
    monomials (``A``, ``omega_0``, ``nu``, numbers), which is all the methods need.
    """

    __slots__ = ("t",)

    def __init__(self, terms: dict[Mono, Any] | None = None) -> None:
        self.t: dict[Mono, Any] = terms if terms is not None else {}

    # -- construction ----------------------------------------------------------------------
    @staticmethod
    def const(value: Any) -> LaurentPolynomial:
        q = _q(value)
        return LaurentPolynomial({(): q}) if q else LaurentPolynomial()

    @staticmethod
    def atom(atom: sp.Basic, exp: int = 1) -> LaurentPolynomial:
        return LaurentPolynomial({((_atom_id(atom), exp),): _Q1})

    @staticmethod
    def from_sympy(expr: Any) -> LaurentPolynomial:
        expr = sp.expand(sp.sympify(expr))
        out: dict[Mono, Any] = {}
        for term in sp.Add.make_args(expr):
            coeff, factors = term.as_coeff_mul()
            mono: dict[int, int] = {}
            c = coeff
            for f in factors:
                base, ex = f.as_base_exp()
                if ex.is_Integer and not base.is_Number:
                    i, e = _atom_id(base), int(ex)
                elif f.is_Rational or isinstance(f, sp.Float):
                    c = c * f
                    continue
                else:
                    i, e = _atom_id(f), 1
                mono[i] = mono.get(i, 0) + e
            key = tuple(sorted((g, e) for g, e in mono.items() if e))
            out[key] = out.get(key, _Q0) + _q(c)
        return LaurentPolynomial({m: c for m, c in out.items() if c})

    # -- arithmetic ------------------------------------------------------------------------
    def __bool__(self) -> bool:
        return bool(self.t)

    def __neg__(self) -> LaurentPolynomial:
        return LaurentPolynomial({m: -c for m, c in self.t.items()})

    def __add__(self, other: Any) -> LaurentPolynomial:
        other = lift(other)
        out = dict(self.t)
        for m, c in other.t.items():
            s = out.get(m, _Q0) + c
            if s:
                out[m] = s
            else:
                out.pop(m, None)
        return LaurentPolynomial(out)

    __radd__ = __add__

    def __sub__(self, other: Any) -> LaurentPolynomial:
        return self + (-lift(other))

    def __rsub__(self, other: Any) -> LaurentPolynomial:
        return lift(other) - self

    def __mul__(self, other: Any) -> LaurentPolynomial:
        if not isinstance(other, LaurentPolynomial):
            q = _q(other) if not isinstance(other, sp.Basic) or other.is_Number else None
            if q is not None:
                return (
                    LaurentPolynomial({m: c * q for m, c in self.t.items()})
                    if q
                    else LaurentPolynomial()
                )
            other = lift(other)
        acc: dict[Mono, Any] = {}
        _addmul(acc, self, other, _Q1)
        return LaurentPolynomial({m: c for m, c in acc.items() if c})

    __rmul__ = __mul__

    def __truediv__(self, other: Any) -> LaurentPolynomial:
        other = lift(other)
        if len(other.t) != 1:
            raise ZeroDivisionError(f"division by the sum {other.to_sympy()}")
        ((m, c),) = other.t.items()
        inv = LaurentPolynomial({tuple((g, -e) for g, e in m): _Q1 / c})
        return self * inv

    def __pow__(self, k: int) -> LaurentPolynomial:
        out = LaurentPolynomial.const(1)
        for _ in range(k):
            out = out * self
        return out

    # -- conversion ------------------------------------------------------------------------
    def to_sympy(self) -> sp.Expr:
        return sp.Add(*(_term_sympy(m, c) for m, c in self.t.items()))

    def degree(self, atom: sp.Basic) -> tuple[int, int]:
        """(lowest, highest) exponent of ``atom`` (0 when absent)."""
        i = _ATOM_ID.get(atom)
        exps = [dict(m).get(i, 0) for m in self.t] or [0]
        return min(exps), max(exps)

    def __repr__(self) -> str:
        return f"LaurentPolynomial({self.to_sympy()})"


def _term_sympy(m: Mono, c: Any) -> sp.Expr:
    return sp.Mul(
        sp.Rational(int(c.numerator), int(c.denominator)), *(_ATOMS[g] ** e for g, e in m)
    )


def lift(value: Any) -> LaurentPolynomial:
    """``value`` (a number, a SymPy expression or a :class:`LaurentPolynomial`) as a
    Laurent polynomial."""
    if isinstance(value, LaurentPolynomial):
        return value
    if isinstance(value, sp.Basic) and not value.is_Number:
        return LaurentPolynomial.from_sympy(value)
    return LaurentPolynomial.const(value)


def _addmul(acc: dict[Mono, Any], a: LaurentPolynomial, b: LaurentPolynomial, q: Any) -> None:
    """``acc += q * a * b`` in place (the inner loop of every product)."""
    for ma, ca in a.t.items():
        cq = ca * q
        for mb, cb in b.t.items():
            m = _mono_mul(ma, mb)
            acc[m] = acc.get(m, _Q0) + cq * cb


#: The Laurent polynomials 0 and 1.
ZERO = LaurentPolynomial()
ONE = LaurentPolynomial.const(1)


def equation(lhs: sp.Expr, rhs: sp.Expr) -> sp.Equality:
    """An unevaluated equation for the derivation text (evaluating asks SymPy's assumption
    system whether the sides are equal, which costs more than the derivation itself)."""
    return sp.Eq(lhs, rhs, evaluate=False)


@lru_cache(maxsize=1 << 14)
def _width(expr: sp.Basic) -> int:
    """Rough printed width of ``expr`` in glyphs, estimated on the expression tree (printing
    every candidate row would cost more than the derivation): a fraction counts its wider
    part, binary operators their spacing, a coefficient function its short name."""
    if isinstance(expr, _COEFFICIENT_FUNCTIONS):
        return 12
    if expr.is_Rational:
        p, q = len(str(abs(expr.p))), len(str(expr.q))
        return max(p, q) + (expr.p < 0)
    if expr.is_Number:
        return len(str(expr))
    if isinstance(expr, sp.Symbol):
        return 2 if len(expr.name) > 1 else 1
    if isinstance(expr, sp.Add):
        return sum(_width(a) + 3 for a in expr.args)
    if isinstance(expr, sp.Pow):
        base = _width(expr.base) + (2 if isinstance(expr.base, sp.Add) else 0)
        if expr.exp.is_negative:
            return base + 1
        return base + 1 + (_width(expr.exp) > 2)
    if isinstance(expr, sp.Mul):
        num = den = 0
        for f in expr.args:
            paren = 2 if isinstance(f, sp.Add) else 0
            if isinstance(f, sp.Pow) and f.exp.is_negative:
                den += _width(1 / f) + paren
            else:
                num += _width(f) + paren
        return max(num, den) + 1
    if isinstance(expr, sp.Derivative):
        return _width(expr.expr) + 6
    if isinstance(expr, sp.Function | sp.Equality):
        return 4 + sum(_width(a) + 1 for a in expr.args)
    return len(sp.sstr(expr))


def _size(expr: sp.Basic, cap: int = 400) -> int:
    """Number of nodes of ``expr``'s tree, counted up to ``cap`` (cheaper than printing)."""
    n = 0
    for _ in sp.preorder_traversal(expr):
        n += 1
        if n >= cap:
            break
    return n


def _row_terms(expr: sp.Expr) -> list[sp.Expr]:
    """Additive terms for display rows: a large product ``c*(s_1 + ... + s_k)*trig`` is
    distributed over its largest sum, recursively."""
    out: list[sp.Expr] = []
    stack = list(reversed(sp.Add.make_args(expr)))
    while stack:
        t = stack.pop()
        if isinstance(t, sp.Mul) and _size(t, 60) >= 60:
            adds = [f for f in t.args if isinstance(f, sp.Add)]
            if adds:
                big = max(adds, key=lambda a: len(a.args))
                rest = sp.Mul(*(f for f in t.args if f is not big))
                stack.extend(reversed([rest * term for term in big.args]))
                continue
        out.append(t)
    return out


def is_short(expr: sp.Expr, limit: int = 60) -> bool:
    """Whether ``expr`` has at most ``limit`` display terms."""
    return len(_row_terms(expr)) <= limit


def derivation_step(title: str, math: Iterable[sp.Basic] = (), text: str = "") -> Step:
    """A derivation step; a long left side over "= 0" is written as "0 = ..." instead (the
    writer, :mod:`perturb.report.latex`, breaks long right sides over lines)."""
    items = []
    for item in math:
        if (
            isinstance(item, sp.Equality)
            and item.rhs == 0
            and (_size(item.lhs) >= 400 or _width(item.lhs) > 24)
        ):
            item = equation(sp.Integer(0), item.lhs)
        items.append(item)
    return Step(title, tuple(items), text)


# ---------------------------------------------------------------------------------------------
# trigonometric series: {n: (cos coefficient, sin coefficient)}, n >= 0, Laurent-polynomial
# coefficients; the n = 0 entry is the mean (the convention of perturb.fourier.trig.harmonics)
# ---------------------------------------------------------------------------------------------
#: ``{n: (cos coefficient, sin coefficient)}`` of a trigonometric series in the phase.
Series = dict[int, tuple[LaurentPolynomial, LaurentPolynomial]]
#: A coefficient accepted by :func:`series_combine` and :func:`series_solve` (lifted).
Coeff = LaurentPolynomial | int | sp.Expr


def _s_clean(acc: Mapping[int, tuple[dict, dict]]) -> Series:
    out: Series = {}
    for n in sorted(acc):
        c, s = acc[n]
        c = LaurentPolynomial({m: v for m, v in c.items() if v})
        s = LaurentPolynomial({m: v for m, v in s.items() if v}) if n else ZERO
        if c or s:
            out[n] = (c, s)
    return out


def series_combine(*terms: tuple[Coeff, Series]) -> Series:
    """``sum_i c_i * s_i`` for pairs ``(c_i, s_i)``."""
    acc: dict[int, tuple[dict, dict]] = {}
    for coeff, ser in terms:
        coeff = lift(coeff)
        if not coeff:
            continue
        for n, (c, s) in ser.items():
            slot = acc.setdefault(n, ({}, {}))
            _addmul(slot[0], coeff, c, _Q1)
            _addmul(slot[1], coeff, s, _Q1)
    return _s_clean(acc)


_HALF = _QQ(1, 2)


def series_mul(a: Series, b: Series, nmax: int | None = None) -> Series:
    """Product of two series by the product-to-sum rules, keeping harmonics ``<= nmax``."""
    acc: dict[int, tuple[dict, dict]] = {}

    def put(n: int, kind: int, x: LaurentPolynomial, y: LaurentPolynomial, q: Any) -> None:
        # cos(-n) = cos(n), sin(-n) = -sin(n); sin(0) = 0
        if n < 0:
            n = -n
            if kind:
                q = -q
        if (nmax is not None and n > nmax) or (kind and n == 0):
            return
        _addmul(acc.setdefault(n, ({}, {}))[kind], x, y, q)

    for i, (ci, si) in a.items():
        for j, (cj, sj) in b.items():
            if ci and cj:  # cos i cos j = [cos(i+j) + cos(i-j)]/2
                put(i + j, 0, ci, cj, _HALF)
                put(i - j, 0, ci, cj, _HALF)
            if si and sj:  # sin i sin j = [cos(i-j) - cos(i+j)]/2
                put(i - j, 0, si, sj, _HALF)
                put(i + j, 0, si, sj, -_HALF)
            if ci and sj:  # cos i sin j = [sin(i+j) - sin(i-j)]/2
                put(i + j, 1, ci, sj, _HALF)
                put(i - j, 1, ci, sj, -_HALF)
            if si and cj:  # sin i cos j = [sin(i+j) + sin(i-j)]/2
                put(i + j, 1, si, cj, _HALF)
                put(i - j, 1, si, cj, _HALF)
    return _s_clean(acc)


def series_derivative(a: Series, k: int = 1) -> Series:
    """``d^k/dpsi^k`` of a series."""
    out = dict(a)
    for _ in range(k):
        out = {n: (s * n, c * (-n)) for n, (c, s) in out.items() if n != 0}
    return out


def series_at_zero(a: Series) -> LaurentPolynomial:
    """Value at ``psi = 0``: the sum of the cosine coefficients."""
    total = ZERO
    for c, _ in a.values():
        total = total + c
    return total


def series_truncate(a: Series, nmax: int | None) -> Series:
    """The harmonics ``<= nmax`` of ``a`` (all of them for ``None``), as a new series."""
    return dict(a) if nmax is None else {n: v for n, v in a.items() if n <= nmax}


def series_solve(rhs: Series, inv_omega2: Coeff = 1) -> Series:
    """Periodic solution of ``omega2 (u'' + u) = rhs`` without the resonant ``n = 1`` part
    (removed beforehand by the secular condition) and without homogeneous terms."""
    inv = lift(inv_omega2)
    return {
        n: (c * inv * _QQ(1, 1 - n * n), s * inv * _QQ(1, 1 - n * n))
        for n, (c, s) in rhs.items()
        if n != 1
    }


def series_to_sympy(a: Series, psi: sp.Expr, tidy: bool = False) -> sp.Expr:
    """The series as an expression of ``psi``, harmonics in increasing order."""
    conv = tidy_coefficient if tidy else (lambda lp: lp.to_sympy())
    return from_harmonics({n: (conv(c), conv(s)) for n, (c, s) in sorted(a.items())}, psi)


def tidy_coefficient(lp: LaurentPolynomial) -> sp.Expr:
    """A readable SymPy form for the derivation text: terms grouped by their
    coefficient-function factors, and each group's common monomial and rational content taken
    out (``A**2*(9*a3*w**2 - 10*a2**2)/(24*w**3)``), computed on the Laurent form — SymPy's
    ``factor`` would cost more than the derivation."""
    groups: dict[Mono, dict[Mono, Any]] = {}
    for m, c in lp.t.items():
        fn = tuple((g, e) for g, e in m if isinstance(_ATOMS[g], _COEFFICIENT_FUNCTIONS))
        rest = tuple((g, e) for g, e in m if (g, e) not in fn)
        groups.setdefault(fn, {})[rest] = c
    out = []
    for fn, poly in groups.items():
        out.append(_content_form(poly) * _term_sympy(fn, _Q1))
    return sp.Add(*out)


def _content_form(poly: dict[Mono, Any]) -> sp.Expr:
    if len(poly) == 1:
        ((m, c),) = poly.items()
        return _term_sympy(m, c)
    atoms = {g for m in poly for g, _ in m}
    common = tuple(
        sorted((g, e) for g in atoms if (e := min(dict(m).get(g, 0) for m in poly)) != 0)
    )
    num = 0
    den = 1
    for c in poly.values():
        num = sp.igcd(num, int(c.numerator))
        den = sp.ilcm(den, int(c.denominator))
    content = _QQ(num, den)
    if all(c < 0 for c in poly.values()):  # an overall minus sign goes outside
        content = -content
    inv = tuple((g, -e) for g, e in common)
    inner = _factored(frozenset((_mono_mul(m, inv), c / content) for m, c in poly.items()))
    outer = _term_sympy(common, content)
    if outer == 1:
        return inner
    return sp.Mul(outer, inner, evaluate=False)


@lru_cache(maxsize=4096)
def _factored(terms: frozenset) -> sp.Expr:
    """A small polynomial factored (``(1 - k)**2`` rather than its expansion); large ones as
    they are. Cached: the same parameter polynomials recur in every harmonic."""
    expr = LaurentPolynomial(dict(terms)).to_sympy()
    if 1 < len(terms) <= 8 and not any(
        isinstance(_ATOMS[g], _COEFFICIENT_FUNCTIONS) for m, _ in terms for g, _ in m
    ):
        return sp.factor(expr)
    return expr


@lru_cache(maxsize=64)
def _cos_power(m: int) -> tuple[tuple[int, Any], ...]:
    """Harmonics of cos(psi)**m: cos^m = 2^-m sum_i C(m, i) cos((m - 2i) psi)."""
    acc: dict[int, Any] = {}
    for i in range(m + 1):
        h = abs(m - 2 * i)
        acc[h] = acc.get(h, _Q0) + _QQ(int(sp.binomial(m, i)), 2**m)
    return tuple(sorted(acc.items()))


# ---------------------------------------------------------------------------------------------
# the force g: polynomial + piecewise-linear part, and the Fourier series of its derivatives
# along x0 = A cos(psi)
# ---------------------------------------------------------------------------------------------
def _step_coeff(m: int, A: sp.Expr, d: sp.Expr) -> sp.Expr:
    """a_m of H(x - d), x = A cos psi. A negative breakpoint is reflected: H(x + e) =
    1 - H(-x - e), and psi -> psi + pi turns H(-x - e) into (-1)^m a_m of H(x - e)."""
    if d.is_negative:
        return (2 if m == 0 else 0) - (-1) ** m * StepCoefficient(m, A, 0, -d)
    return StepCoefficient(m, A, 0, d)


def _ramp_coeff(m: int, A: sp.Expr, d: sp.Expr) -> sp.Expr:
    """a_m of (x - d) H(x - d); a negative breakpoint is reflected as in :func:`_step_coeff`:
    (x + e) H(x + e) = (x + e) + [(x' - e) H(x' - e)], x' = -x, harmonic m times (-1)^m."""
    if d.is_negative:
        e = -d
        line = 2 * e if m == 0 else (A if m == 1 else 0)
        return line + (-1) ** m * RampCoefficient(m, A, 0, e)
    return RampCoefficient(m, A, 0, d)


def _dirac_coeff(m: int, A: sp.Expr, d: sp.Expr) -> sp.Expr:
    if d.is_negative:
        return (-1) ** m * DiracCoefficient(m, A, 0, -d)
    return DiracCoefficient(m, A, 0, d)


@dataclass(frozen=True)
class Force:
    """``g(x) = sum_m poly[m] x**m + sum_i [dk_i (x - d_i) H(x - d_i) + J_i H(x - d_i)]``."""

    poly: tuple[tuple[int, sp.Expr], ...] = ()
    ramps: tuple[tuple[sp.Expr, sp.Expr, sp.Expr], ...] = ()  # (d_i, dk_i, J_i)
    _cache: dict = field(default_factory=dict, compare=False, repr=False)

    def expr(self, x: sp.Symbol) -> sp.Expr:
        out = sp.Add(*(c * x**m for m, c in self.poly))
        for d, dk, jump in self.ramps:
            out += dk * (x - d) * sp.Heaviside(x - d) + jump * sp.Heaviside(x - d)
        return out

    def derivative_series(self, k: int, A: sp.Expr, nmax: int | None) -> Series:
        """Harmonics (``<= nmax``) of ``g^(k)(A cos psi) / k!``.

        Raises
        ------
        FourierError
            When the term needs the derivative of a Dirac delta (k = 2 with a jump of the
            force, k >= 3 with any breakpoint).
        """
        key = (k, A, nmax)
        if key in self._cache:
            return self._cache[key]
        acc: dict[int, tuple[dict, dict]] = {}
        for m, c in self.poly:
            if m < k:
                continue
            coeff = LaurentPolynomial.from_sympy(c * sp.binomial(m, k) * A ** (m - k))
            for h, r in _cos_power(m - k):
                _addmul(acc.setdefault(h, ({}, {}))[0], coeff, ONE, r)
        if self.ramps and any(dk != 0 or j != 0 for _, dk, j in self.ramps):
            if nmax is None:
                raise FourierError("a piecewise-linear force needs a harmonic truncation")
            if k >= 3 or (k == 2 and any(j != 0 for _, _, j in self.ramps)):
                raise FourierError(
                    f"the Taylor term of order {k} needs the derivative of a Dirac delta at a "
                    "breakpoint of the force, which has no Fourier coefficient: lower the order "
                    "(a continuous piecewise-linear force allows order 3, one with jumps 2)"
                )
            fact = sp.factorial(k)
            for h in range(nmax + 1):
                terms = []
                for d, dk, jump in self.ramps:
                    if k == 0:
                        terms += [dk * _ramp_coeff(h, A, d), jump * _step_coeff(h, A, d)]
                    elif k == 1:
                        terms += [dk * _step_coeff(h, A, d), jump * _dirac_coeff(h, A, d)]
                    else:
                        terms.append(dk * _dirac_coeff(h, A, d) / fact)
                value = sp.Add(*terms) / (2 if h == 0 else 1)  # a_0 is twice the mean
                _addmul(
                    acc.setdefault(h, ({}, {}))[0], LaurentPolynomial.from_sympy(value), ONE, _Q1
                )
        out = series_truncate(_s_clean(acc), nmax)
        self._cache[key] = out
        return out


def _pwl_of(expr: sp.Expr, x: sp.Symbol, values: Mapping[str, float]):
    try:
        return to_pwl(expr, x)
    except NonsmoothError:
        if not values:
            raise
        # symbolic breakpoints that cannot be ordered: order them by the parameter values
        return to_pwl(expr, x, values=values)


@dataclass(frozen=True)
class SplitModel:
    """What the engines need from an oscillator: the reference frequency and the force
    ``g = f - omega_0^2 x`` (the static load moved into it)."""

    w0: sp.Expr
    w2: sp.Expr
    poly: dict[int, sp.Expr]
    ramps: tuple[tuple[sp.Expr, sp.Expr, sp.Expr], ...]
    default_w0: bool

    @property
    def force(self) -> Force:
        return Force(tuple(sorted(self.poly.items())), self.ramps)

    def g(self, x: sp.Symbol) -> sp.Expr:
        """``g`` in canonical ramp/step form."""
        return self.force.expr(x)

    def g_written(self, osc: Oscillator) -> sp.Expr:
        """``g = f - omega_0^2 x`` as the user wrote ``f`` (for the derivation text)."""
        return sp.Add(osc.restoring_force, -self.w2 * osc.x, -osc.forcing.constant)


def split_model(osc: Oscillator, omega0: Any) -> SplitModel:
    """The restoring force of ``osc`` split as ``f = omega_0**2 x + g`` (the static load
    moved into ``g``), about ``omega0`` or by default the linear stiffness (plus, for a
    piecewise-linear part, the mean of its outer slopes).

    Raises
    ------
    ModelError
        A non-polynomial smooth term, or a non-positive default reference stiffness.
    ParameterError
        An ``omega0`` that is not a positive number or expression.
    """
    x = osc.x
    if osc.smooth != 0:
        raise ModelError(
            f"model {osc.name!r} has the non-polynomial term {osc.smooth}: the perturbation "
            "engines take polynomial and piecewise-linear restoring forces (write a truncated "
            "polynomial if a Taylor expansion is what you want)"
        )
    poly: dict[int, sp.Expr] = {}
    if osc.polynomial != 0:
        for (deg,), c in sp.Poly(osc.polynomial, x).terms():
            poly[deg] = poly.get(deg, 0) + c
    poly[1] = poly.get(1, 0) + osc.linear_stiffness
    if osc.forcing.constant != 0:  # a static load F0 on the right is -F0 in the force
        poly[0] = poly.get(0, 0) - osc.forcing.constant
    ramps: tuple[tuple[sp.Expr, sp.Expr, sp.Expr], ...] = ()
    outer = sp.Integer(0)
    if osc.nonsmooth != 0:
        values = {n: v for n, v in osc.params.items() if v is not None}
        pwl = _pwl_of(osc.nonsmooth, x, values)
        k0, c0, points, dks, jumps = pwl.ramp_step_form()
        poly[1] = poly.get(1, 0) + k0
        poly[0] = poly.get(0, 0) + c0
        ramps = tuple(zip(points, dks, jumps, strict=True))
        outer = (pwl.slopes[0] + pwl.slopes[-1]) / 2
    if omega0 is not None:
        w0 = _parse_omega0(omega0)
        w2 = w0**2
    else:
        w2 = sp.expand(poly.get(1, 0) - (pwl.slopes[0] - outer if ramps else 0))
        w2 = sp.nsimplify(w2) if w2.is_number else w2
        if w2 == 0 or w2.is_nonpositive:
            raise ModelError(
                f"model {osc.name!r}: the reference stiffness omega0**2 = {w2} is not positive, "
                "so there is no linear oscillation to perturb; pass omega0= (for example the "
                "stiffness of the outer segments)"
            )
        # omega0**2 written as s**2 with s a symbol: omega_0 = s (taken positive), else sqrt
        if isinstance(w2, sp.Pow) and w2.exp == 2 and isinstance(w2.base, sp.Symbol):
            w0 = w2.base
        else:
            w0 = sp.sqrt(w2)
    poly[1] = sp.expand(poly.get(1, 0) - w2)
    poly = {m: sp.expand(c) for m, c in poly.items() if sp.expand(c) != 0}
    return SplitModel(w0, w2, poly, ramps, omega0 is None)


def _parse_omega0(omega0: Any) -> sp.Expr:
    if isinstance(omega0, str):
        w0 = parse_expression(omega0)
    elif isinstance(omega0, bool):
        w0 = None
    else:
        try:
            w0 = (
                sp.nsimplify(omega0)
                if isinstance(omega0, float)
                else expression_argument(omega0, "omega0")
            )
        except (sp.SympifyError, TypeError, ParameterError):
            w0 = None
    if w0 is None or (w0.is_number and not (w0.is_extended_real and w0 > 0)):
        raise ParameterError(f"omega0 = {omega0!r}: expected a positive number or expression")
    return w0


def omega0_coefficient(w0: sp.Expr) -> LaurentPolynomial:
    """omega_0 as a coefficient: a number, or one atom (so that dividing by it is exact)."""
    return LaurentPolynomial.const(w0) if w0.is_Rational else LaurentPolynomial.atom(w0)


def vanishes(expr: sp.Expr, osc: Oscillator) -> bool:
    """True when ``expr`` is zero at the oscillator's parameter values (``Float(0.0) == 0`` is
    False in SymPy >= 1.13, hence ``is_zero``)."""
    return sp.sympify(expr).xreplace(osc.substitutions()).is_zero is True


def check_options(order: Any, amplitude: str, harmonics: Any) -> int:
    """``order`` after checking the options both methods share (order >= 1, an amplitude
    convention of :data:`AMPLITUDES`, at least 3 harmonics).

    Raises
    ------
    ParameterError
        Naming the bad value and what was expected.
    """
    if isinstance(order, bool) or not isinstance(order, int) or order < 1:
        raise ParameterError(f"order = {order!r}: expected an integer >= 1")
    if amplitude not in AMPLITUDES:
        raise ParameterError(f"amplitude = {amplitude!r}: expected one of {', '.join(AMPLITUDES)}")
    if isinstance(harmonics, bool) or not isinstance(harmonics, int) or harmonics < 3:
        raise ParameterError(f"harmonics = {harmonics!r}: expected an integer >= 3")
    return order


@cache
def method_dummy(name: str) -> sp.Dummy:
    """The method's own symbol ``name`` (epsilon, nu, alpha, omega_n, delta_n): a Dummy, so it
    never clashes with a parameter of the model, and one per name so that repeated derivations
    do not grow the atom table."""
    return sp.Dummy(name)


def free_symbol(osc: Oscillator, name: str) -> sp.Symbol:
    """A real symbol for a quantity of the method, not clashing with a parameter name."""
    taken = set(osc.params) | {osc.x.name, osc.v.name, osc.t.name}
    while name in taken:
        name += "_r"
    return real_symbol(name)


class Expansion:
    r"""The expansion :math:`X = \sum_n \epsilon^n x_n` and the Taylor coefficients
    :math:`[\epsilon^n] g(X) = \sum_k g^{(k)}(x_0)/k!\,[\epsilon^n](X - x_0)^k`, built order by
    order as the :math:`x_n` become known (powers of :math:`X - x_0` are memoised)."""

    def __init__(self, x0: Series, A: sp.Expr, nmax: int | None) -> None:
        self.x: list[Series] = [x0]
        self.A = A
        self.nmax = nmax
        self._pow: dict[tuple[int, int], Series] = {}

    def push(self, xn: Series) -> None:
        self.x.append(series_truncate(xn, self.nmax))

    def power(self, k: int, n: int) -> Series:
        r""":math:`[\epsilon^n] (X - x_0)^k` (needs :math:`x_1, \dots, x_{n-k+1}`)."""
        if k == 0:
            return {0: (ONE, ZERO)} if n == 0 else {}
        if n < k:
            return {}
        if k == 1:
            return self.x[n]
        key = (k, n)
        if key not in self._pow:
            prods = [
                (1, series_mul(self.x[j], self.power(k - 1, n - j), self.nmax))
                for j in range(1, n - k + 2)
            ]
            self._pow[key] = series_combine(*prods)
        return self._pow[key]

    def compose(self, force: Force, n: int) -> Series:
        r""":math:`[\epsilon^n] g(X)`, harmonics up to ``nmax``."""
        terms = []
        for k in range(n + 1):
            pk = self.power(k, n)
            if not pk:
                continue
            need = None if self.nmax is None else self.nmax + max(pk)
            dk = force.derivative_series(k, self.A, need if force.ramps else None)
            if dk:
                terms.append((1, series_mul(dk, pk, self.nmax)))
        return series_combine(*terms)


def closed_form_step(label: sp.Expr, value: sp.Expr, title: str) -> Step | None:
    """The theta-form of a coefficient that contains step/ramp/Dirac functions."""
    if not value.has(*_COEFFICIENT_FUNCTIONS):
        return None
    closed, definitions, domains = closed_form(value)
    (closed,), definitions = fold_mirror_angles((closed,), definitions)
    return derivation_step(
        title,
        (equation(label, closed),) + tuple(equation(s, v) for s, v in definitions),
        "Valid while the orbit crosses every switching point ("
        + ", ".join(f"${latex(c)}$" for c in domains)
        + "); elsewhere the switch terms are exactly zero or linear.",
    )
