r"""The method of multiple scales, orders 1 to N, in complex-amplitude form.

Problem
-------
The oscillator ``x'' + g(x, x', t) = f(t)`` is written

.. math::

    \ddot x + \omega_0^2 x = \sum_{k \ge 0} \varepsilon^k R_k(x, \dot x, t),

where :math:`\omega_0^2` is the linear stiffness at :math:`\varepsilon = 0`, :math:`R_0` may only
hold a *hard* (order-one) forcing and every other term (damping, nonlinearity, parametric
excitation, soft forcing) sits at a positive power of the bookkeeping parameter. Two ways to
introduce :math:`\varepsilon` (option ``epsilon``):

* ``epsilon="eps"`` names a parameter of the model that already orders the terms (the user wrote
  ``x'' + 2*eps*mu*x' + omega0**2*x + eps*alpha*x**3 = eps*k*cos(Omega*t)``). Each term's order is
  its power of ``eps``; terms above the requested order are dropped.
* ``epsilon=None`` (default): weak-nonlinearity scaling as in Nayfeh & Mook (1979): every
  term but :math:`\ddot x + \omega_0^2 x` is put at :math:`O(\varepsilon)` — damping,
  nonlinearity, parametric excitation and the forcing, except a *hard* forcing at super- and
  subharmonic resonance, which stays at :math:`O(1)` — and :math:`\varepsilon = 1` at the end,
  so results are in the model's own parameters. For amplitude ordering of polynomial terms
  (``x = eps*y``: quadratic at ``eps``, cubic at ``eps**2``) write ``eps`` into the model and
  use the first form.

Resonance and detuning
----------------------
With a forcing (or parametric) base frequency :math:`\Omega` and a resonance
:math:`\Omega \approx (p/q)\,\omega_0` (``resonance``: primary ``1/1``, superharmonic ``1/3``,
subharmonic ``3/1``, principal parametric ``2/1``, or any ``(p, q)``) the response locks to
:math:`\omega_r = q\Omega/p`. The nearness is expressed in one of two ways (``detuning``):

* ``"frequency"`` (Nayfeh & Mook): :math:`q\Omega = p\,\omega_0 + \varepsilon\sigma`; the
  unperturbed operator is :math:`D_0^2 + \omega_0^2`. The oracle forms of the course — e.g.
  :math:`[\mu^2 + (\sigma - 3\alpha a^2/8\omega_0)^2]a^2 = k^2/4\omega_0^2` — are in this form.
* ``"stiffness"``: :math:`\omega_0^2 = \omega_r^2 - \varepsilon\Delta`; the unperturbed operator is
  :math:`D_0^2 + \omega_r^2` and the mismatch :math:`\varepsilon\Delta x` is a perturbation. This is
  the Zou–Nagarajaiah / modified Lindstedt–Poincaré choice: at first order the steady states are
  exactly those of single-harmonic balance and the frequency response is a polynomial in
  :math:`\Omega^2`; it also works for a negative :math:`\omega_0^2` (the ``nsd`` model).
* ``"auto"`` (default): ``"stiffness"`` for forced models with nonsmooth terms or a linear
  stiffness that is not positive, else ``"frequency"``.

Method
------
Time scales :math:`T_k = \varepsilon^k t`, :math:`d/dt = D_0 + \varepsilon D_1 + \dots`, and
:math:`x = x_p + y_0 + \varepsilon y_1 + \dots`, where :math:`x_p` is the exact response of
:math:`\ddot x + \omega_0^2 x = R_0(t)` to the hard forcing (:math:`\Lambda = F/(\omega_0^2 -
\Omega^2)` of Nayfeh & Mook, kept exact). With :math:`\theta = \omega_r t` (the resonant phase; in
the frequency form :math:`\theta = \omega_0 T_0 + \sigma T_1/p`),

.. math::

    y_0 = B(T_1, T_2, \dots)\,e^{i\theta} + \mathrm{cc}, \qquad
    A = B\,e^{i\sigma T_1/p} \quad\text{(Nayfeh's amplitude)},

so every forcing term :math:`e^{i\Omega t} = e^{ip\theta/q}` is an exact Fourier mode in
:math:`\theta/q` and the modulation equations are autonomous. At order :math:`\varepsilon^k`

.. math::

    D_0^2 y_k + \nu^2 y_k = S_k, \qquad
    S_k = [R]_k - \sum_{\substack{i + j + l = k\\ l < k}} D_i D_j y_l ,

(:math:`\nu` the operator's frequency). :math:`S_k` is a finite sum of modes
:math:`e^{im\theta/q}` with coefficients polynomial in :math:`B, \bar B`. The coefficient of
:math:`e^{\pm i\theta}` is secular; removing it gives the solvability condition
:math:`2i\nu\,D_k B = [S_k]_{e^{i\theta}}` and the other modes are divided by
:math:`\nu^2(1 - m^2/q^2)` — no ``dsolve``, no ``simplify``: the algebra is done in a sparse
polynomial ring over the Gaussian rationals in :math:`B, \bar B` and opaque coefficient symbols,
which is what keeps fourth order well under a second. Lower-order :math:`D_j B` met at higher
orders are replaced by their solvability conditions (chain rule), and the reconstituted
modulation equation is

.. math:: \frac{dB}{dt} = \sum_{k=1}^N \varepsilon^k G_k(B, \bar B).

Polar form :math:`B = \tfrac12 a e^{-i\gamma/p}` (forced;
:math:`x \approx a\cos(\omega_r t - \gamma/p)`, Nayfeh's :math:`\gamma = \sigma T_1 - p\beta`) or
:math:`B = \tfrac12 a e^{i\beta}` (autonomous; :math:`x \approx a\cos(\omega_0 t + \beta)`);
Cartesian form :math:`B = \tfrac12(u - iv)`, :math:`x \approx u\cos\theta + v\sin\theta`.
Steady states are the fixed points of the slow flow; their stability is decided by the
eigenvalues of its Jacobian (:meth:`ModulationEquations.jacobian`).

Frequency responses
-------------------
:meth:`ModulationEquations.approximation` returns the method contract. For first-order primary
resonance with the *stiffness* detuning the phase-eliminated relation is an exact quadratic in
:math:`\Omega^2` (``frequency_polynomial``), so
:func:`perturb.numeric.amplitude.approximation_response` traces every branch. With the
*frequency* detuning the relation is a quadratic in :math:`\Omega` (through :math:`\sigma`), not in
:math:`\Omega^2`; the only polynomial in :math:`\Omega^2` with its roots,
:math:`r(\Omega)r(-\Omega)`, also carries the mirrored negative roots as spurious branches, so
none is provided (use :meth:`ModulationEquations.steady_states`, or ``detuning="stiffness"``).

Piecewise-linear terms
----------------------
A nonsmooth restoring term :math:`f(x)` enters at first order only through the first Fourier
coefficient :math:`a_1(a)` of :math:`f(a\cos\psi)` (``perturb.fourier.symbols``: closed form in
:math:`\theta = \arccos(d/a)`, never a Taylor series); its secular part is
:math:`a_1(a)\,B/a`. Higher orders with nonsmooth terms need Dirac terms and are not provided.
"""

from __future__ import annotations

import math
import time as _time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from fractions import Fraction
from types import MappingProxyType
from typing import Any

import numpy as np
import sympy as sp
from sympy import QQ_I
from sympy.polys.rings import PolyElement, PolyRing

from perturb.approximation import Approximation, Step
from perturb.errors import ModelError, ParameterError, PerturbError
from perturb.fourier.symbols import NUMERIC_IMPLEMENTATIONS, closed_form, series_coefficient
from perturb.fourier.trig import fold_mirror_angles
from perturb.methods.applicability import check_order, expression_argument, require_centred
from perturb.methods.caveats import states_caveats
from perturb.model.oscillator import Oscillator
from perturb.model.parsing import real_symbol
from perturb.model.pwl import is_nonsmooth
from perturb.printing import latex

__all__ = [
    "ModulationEquations",
    "SteadyState",
    "modulation_equations",
    "multiple_scales",
    "transition_curves",
    "RESONANCES",
]

#: Named resonances as ``(p, q)`` with ``q*Omega ~ p*omega0``, i.e. ``Omega/omega0 ~ p/q``.
RESONANCES: Mapping[str, tuple[int, int]] = MappingProxyType(
    {
        "primary": (1, 1),
        "superharmonic": (1, 3),
        "subharmonic": (3, 1),
        "parametric": (2, 1),
    }
)

_DETUNINGS = ("auto", "frequency", "stiffness")
_FULL_ORDERS = 2  # orders whose whole right-hand side is printed in the derivation
_I = QQ_I(0, 1)

FastPoly = dict[int, PolyElement]  # mode m -> coefficient of exp(i m theta / q)


# ----------------------------------------------------------------------------- options --
def _parse_resonance(spec: Any) -> tuple[int, int]:
    """``(p, q)`` from a name, ``"name:n"``, a ratio string, a Fraction/number or a pair."""
    if isinstance(spec, tuple | list) and len(spec) == 2:
        p, q = spec
        if not all(isinstance(k, int | sp.Integer) and int(k) > 0 for k in (p, q)):
            raise ParameterError(f"resonance = {spec!r}: expected two positive integers (p, q)")
        p, q = int(p), int(q)
        g = math.gcd(p, q)
        return p // g, q // g
    if isinstance(spec, str):
        s = spec.strip().lower()
        if s in RESONANCES:
            return RESONANCES[s]
        name, _, n = s.partition(":")
        if name in ("superharmonic", "subharmonic") and n.strip().isdigit() and int(n) > 1:
            return (1, int(n)) if name == "superharmonic" else (int(n), 1)
        try:
            r = Fraction(s)
        except (ValueError, ZeroDivisionError):
            raise ParameterError(
                f"resonance = {spec!r}: expected one of {', '.join(RESONANCES)}, "
                "'superharmonic:n', 'subharmonic:n', a ratio 'p/q' (Omega/omega0) or a pair (p, q)"
            ) from None
        spec = r
    if isinstance(spec, int | Fraction | sp.Rational) and not isinstance(spec, bool):
        r = Fraction(int(sp.Rational(spec).p), int(sp.Rational(spec).q))
        if r > 0:
            return r.numerator, r.denominator
    raise ParameterError(
        f"resonance = {spec!r}: expected a name, a positive ratio Omega/omega0 or a pair (p, q)"
    )


def _fresh(name: str, taken: set[str], **assumptions: Any) -> sp.Symbol:
    while name in taken:
        name += "_"
    return sp.Symbol(name, **assumptions) if assumptions else real_symbol(name)


# ------------------------------------------------------------------- the perturbation --
@dataclass
class _Monomial:
    """One term ``coeff * x**xdeg * v**vdeg * trig(t)`` of the perturbation at ``order``."""

    order: int
    xdeg: int
    vdeg: int
    trig: tuple[sp.Expr, ...]
    coeff: sp.Expr
    tag: str = ""


def _eps_order(term: sp.Expr, eps: sp.Symbol | None, what: str) -> tuple[int, sp.Expr]:
    """``term = c * eps**k`` -> ``(k, c)``; with no named epsilon every term is order 1."""
    if eps is None:
        return 1, term
    indep, dep = term.as_independent(eps, as_Add=False)
    if dep == 1:
        return 0, indep
    base, ex = dep.as_base_exp()
    if base != eps or not ex.is_Integer or ex < 0:
        raise ModelError(
            f"the {what} term {term} depends on {eps} other than through a factor {eps}**k: "
            "multiple scales needs each term's order to be a power of the bookkeeping parameter"
        )
    return int(ex), indep


def _eps_split(expr: sp.Expr, eps: sp.Symbol | None, what: str) -> dict[int, sp.Expr]:
    """Split ``expr`` by powers of ``eps`` (expanded; for polynomial-type parts)."""
    out: dict[int, sp.Expr] = {}
    if expr == 0:
        return out
    if eps is None:
        return {1: expr}
    for term in sp.Add.make_args(sp.expand(expr)):
        k, c = _eps_order(term, eps, what)
        out[k] = out.get(k, sp.Integer(0)) + c
    return out


def _monomials(
    expr: sp.Expr, order: int, x: sp.Symbol, v: sp.Symbol, t: sp.Symbol, what: str
) -> list[_Monomial]:
    tag = what if what in ("damping", "forcing") else ""
    out = []
    for term in sp.Add.make_args(sp.expand(expr)):
        xdeg = vdeg = 0
        trig: list[sp.Expr] = []
        coeff: sp.Expr = sp.Integer(1)
        for factor in sp.Mul.make_args(term):
            base, ex = factor.as_base_exp()
            if base == x and ex.is_Integer and ex > 0:
                xdeg += int(ex)
            elif base == v and ex.is_Integer and ex > 0:
                vdeg += int(ex)
            elif isinstance(base, sp.cos | sp.sin) and base.has(t) and ex.is_Integer and ex > 0:
                trig.extend([base] * int(ex))
            elif factor.has(x, v, t):
                raise ModelError(
                    f"the {what} term {term} is not a polynomial in x, x' and cos/sin of t: "
                    "multiple scales handles polynomial terms at any order and piecewise-linear "
                    "restoring terms at first order"
                )
            else:
                coeff *= factor
        out.append(_Monomial(order, xdeg, vdeg, tuple(trig), coeff, tag))
    return out


# ------------------------------------------------------------------- opaque constants --
class _Opaque:
    """Coefficients as opaque real symbols, so the ring arithmetic stays over QQ(i).

    ``get(expr)`` returns ``r * c_j`` with ``r`` rational and ``c_j`` a fresh symbol standing
    for the rest of ``expr`` (shared between equal rests); rational ``expr`` stays a number.
    """

    def __init__(self) -> None:
        self.symbols: dict[tuple[str, sp.Expr], sp.Symbol] = {}

    def get(self, expr: sp.Expr, tag: str = "") -> sp.Expr:
        """``tag`` keeps categories apart (``"forcing"``, ``"damping"``) so that they can be
        switched off later (the backbone is the free undamped system)."""
        expr = sp.sympify(expr)
        if expr.is_Rational:
            return expr
        coeff, rest = expr.as_coeff_Mul()
        if not coeff.is_Rational:
            coeff, rest = sp.Integer(1), expr
        if (tag, rest) not in self.symbols:
            self.symbols[(tag, rest)] = sp.Dummy(f"c{len(self.symbols)}", real=True)
        return coeff * self.symbols[(tag, rest)]

    def tagged(self, tag: str) -> set[sp.Symbol]:
        return {s for (tg, _), s in self.symbols.items() if tg == tag}

    @property
    def back(self) -> dict[sp.Symbol, sp.Expr]:
        return {s: e for (_, e), s in self.symbols.items()}


# -------------------------------------------------------------------------- the engine --
class _Engine:
    """Order-by-order multiple scales on Fourier modes ``exp(i m theta/q)``.

    Coefficients are elements of a sparse polynomial ring over QQ(i) in ``B, Bb`` (the complex
    amplitude and its conjugate), ``sh`` (the scaled detuning sigma/nu, frequency form only) and
    the opaque coefficient symbols. Time is scaled by the operator frequency (``tau = nu t``)
    so that the operator is ``D0**2 + 1`` and every divisor is rational.
    """

    def __init__(
        self,
        ring: PolyRing,
        q: int,
        p: int,
        sigma_gen: PolyElement | None,
        perturbation: Sequence[tuple[int, int, int, FastPoly, PolyElement]],
        x_p: FastPoly,
        v_p: FastPoly,
    ) -> None:
        self.R = ring
        self.q, self.p = q, p
        self.B, self.Bb = ring.gens[0], ring.gens[1]
        self.sigma_gen = sigma_gen
        self.terms = perturbation
        self.x_p, self.v_p = x_p, v_p
        self.G: dict[int, tuple[PolyElement, PolyElement]] = {}
        self.y: list[FastPoly] = [{q: self.B, -q: self.Bb}]
        self.S: list[FastPoly] = [{}]
        self._d: dict[tuple[int, ...], FastPoly] = {}
        self.timings: list[float] = []

    # fast-poly arithmetic ---------------------------------------------------------------
    @staticmethod
    def add(*polys: FastPoly) -> FastPoly:
        out: FastPoly = {}
        for poly in polys:
            for m, c in poly.items():
                out[m] = out[m] + c if m in out else c
        return {m: c for m, c in out.items() if c}

    @staticmethod
    def scale(poly: FastPoly, c: Any) -> FastPoly:
        out = {m: v * c for m, v in poly.items()}
        return {m: v for m, v in out.items() if v}

    @staticmethod
    def mul(a: FastPoly, b: FastPoly) -> FastPoly:
        out: FastPoly = {}
        for m1, c1 in a.items():
            for m2, c2 in b.items():
                m = m1 + m2
                prod = c1 * c2
                out[m] = out[m] + prod if m in out else prod
        return {m: c for m, c in out.items() if c}

    def series_mul(self, a: list[FastPoly], b: list[FastPoly], top: int) -> list[FastPoly]:
        out = []
        for s in range(top + 1):
            acc: FastPoly = {}
            for i in range(s + 1):
                if i < len(a) and s - i < len(b) and a[i] and b[s - i]:
                    acc = self.add(acc, self.mul(a[i], b[s - i]))
            out.append(acc)
        return out

    # derivatives ---------------------------------------------------------------------
    def D(self, j: int, poly: FastPoly) -> FastPoly:
        """``D_j`` of a fast polynomial: the fast phase (j = 0, and j = 1 through sigma)
        plus the chain rule through the known ``D_j B``."""
        q = self.q
        out: FastPoly = {}
        if j == 0:
            for m, c in poly.items():
                out[m] = c * QQ_I(0, Fraction(m, q))
            return {m: c for m, c in out.items() if c}
        for m, c in poly.items():
            acc = self.R.zero
            if j == 1 and self.sigma_gen is not None and m:
                acc += c * self.sigma_gen * QQ_I(0, Fraction(m, q * self.p))
            if j in self.G:
                g, gb = self.G[j]
                dB, dBb = c.diff(self.B), c.diff(self.Bb)
                if dB:
                    acc += dB * g
                if dBb:
                    acc += dBb * gb
            if acc:
                out[m] = acc
        return out

    def Dy(self, ops: tuple[int, ...], l: int) -> FastPoly:
        """``D_{ops[0]} D_{ops[1]} ... y_l``, cached once every ``D_j`` involved is known."""
        key = (*ops, -1 - l)
        if key in self._d:
            return self._d[key]
        inner = self.y[l] if len(ops) == 1 else self.Dy(ops[1:], l)
        out = self.D(ops[0], inner)
        if all(j == 0 or j in self.G for j in ops):
            self._d[key] = out
        return out

    # one order -----------------------------------------------------------------------
    def order(self, k: int, need_solution: bool) -> None:
        start = _time.perf_counter()
        top = k - 1
        # x and dx/dtau as eps-series known through order k - 1
        X = [self.add(self.x_p, self.y[0])] + [self.y[l] for l in range(1, k)]
        V: list[FastPoly] = []
        for s in range(k):
            parts = [self.Dy((i,), s - i) for i in range(s + 1) if i == 0 or i in self.G]
            if s == 0:
                parts.append(self.v_p)
            V.append(self.add(*parts))
        xmax = max((t[1] for t in self.terms), default=0)
        vmax = max((t[2] for t in self.terms), default=0)
        xpow: list[list[FastPoly]] = [[{0: self.R.one}]]
        for _ in range(xmax):
            xpow.append(self.series_mul(xpow[-1], X, top))
        vpow: list[list[FastPoly]] = [[{0: self.R.one}]]
        for _ in range(vmax):
            vpow.append(self.series_mul(vpow[-1], V, top))
        prod_cache: dict[tuple[int, int], list[FastPoly]] = {}
        rhs: FastPoly = {}
        for order, a, b, trig, coeff in self.terms:
            if order > k or order < 1:
                continue
            if (a, b) not in prod_cache:
                prod_cache[(a, b)] = self.series_mul(xpow[a], vpow[b], top)
            piece = prod_cache[(a, b)][k - order] if k - order < len(prod_cache[(a, b)]) else {}
            if piece:
                rhs = self.add(rhs, self.scale(self.mul(piece, trig), coeff))
        # D_i D_j y_l with i + j + l = k, l < k; the unknown D_k B is left out (set below)
        lhs: list[FastPoly] = []
        for l in range(k):
            for i in range(k - l + 1):
                j = k - l - i
                if l == 0 and (i, j) in ((0, k), (k, 0)):
                    continue
                lhs.append(self.Dy((i, j), l))
        if k == 1 and self.sigma_gen is not None:
            # known part of (D0 D1 + D1 D0) y0: the slow phase of exp(i theta)
            s = self.sigma_gen * QQ_I(Fraction(-1, self.p))  # i * (i sigma/p)
            lhs.append({self.q: 2 * s * self.B, -self.q: 2 * s * self.Bb})
        S = self.add(rhs, *(self.scale(p_, -1) for p_ in lhs))
        q = self.q
        zero = self.R.zero
        g = S.get(q, zero) * QQ_I(0, Fraction(-1, 2))
        gb = S.get(-q, zero) * QQ_I(0, Fraction(1, 2))
        self.G[k] = (g, gb)
        self.S.append(S)
        if need_solution:
            self.y.append(
                {m: c * QQ_I(Fraction(q * q, q * q - m * m)) for m, c in S.items() if abs(m) != q}
            )
        self.timings.append(_time.perf_counter() - start)


# ------------------------------------------------------------------------------ result --
@dataclass(frozen=True)
class SteadyState:
    """A fixed point of the slow flow: amplitude, phase, Jacobian eigenvalues, stability and
    (limit cycles) the oscillation frequency."""

    amplitude: float
    phase: float
    eigenvalues: tuple[complex, ...]
    stable: bool
    frequency: float | None = None


@dataclass(frozen=True)
class ModulationEquations:
    r"""Everything a multiple-scales derivation produces (immutable).

    Attributes
    ----------
    oscillator, order
        The model and the order :math:`N` of the modulation equations.
    epsilon
        The bookkeeping parameter (the model's own, or a fresh symbol when ``scaled`` is True, to
        be set to 1).
    scaled
        True for the automatic weak-nonlinearity scaling (results used with
        :math:`\varepsilon = 1`).
    resonance
        ``(p, q)`` with :math:`q\Omega \approx p\omega_0`, or None for an autonomous system.
    detuning
        ``"frequency"`` or ``"stiffness"`` (module docstring).
    omega0, nu
        :math:`\omega_0` and the operator frequency :math:`\nu` (:math:`\omega_0` or
        :math:`\omega_r = q\Omega/p`).
    frequency
        :math:`\Omega` (forced/parametric) or the response frequency symbol :math:`\omega`
        (autonomous).
    sigma, detuning_relation
        The detuning symbol (:math:`\sigma` or :math:`\Delta`) and its definition as an equation.
    B, Bbar
        The complex amplitude and its conjugate (a symbol and ``conjugate(B)``).
    complex_orders
        :math:`G_1, \dots, G_N` with :math:`dB/dt = \sum_k \varepsilon^k G_k` (t-units).
    amplitude, phase
        :math:`a` and :math:`\gamma` (forced) or :math:`\beta` (autonomous).
    polar, polar_orders
        :math:`(da/dt, d\,\mathrm{phase}/dt)`, reconstituted, and per order.
    u, v, cartesian, cartesian_orders
        Cartesian variables and :math:`(du/dt, dv/dt)`, reconstituted and per order.
    response
        The frequency-response relation ``F(a, sigma) = 0`` (phase eliminated), when the slow
        flow is linear in :math:`\cos\gamma, \sin\gamma`; else None.
    backbone
        Frequency of the free undamped oscillation as a function of :math:`a`:
        :math:`\omega_0 + \dot\beta(a)` with the forcing, the linear damping and the detuning
        removed (frequency detuning only; None for the stiffness detuning).
    waveform
        :math:`x` in :math:`\tau` (:math:`\tau = \Omega t` forced, :math:`\omega t` autonomous)
        and the polar unknowns, through :math:`\varepsilon^{N-1} y_{N-1}`, plus the exact
        hard-forcing response.
    tau
        The phase variable of ``waveform``.
    fourier
        The Fourier coefficients of nonsmooth terms used (``a_1``).
    steps
        The derivation (for :func:`perturb.report.latex.latex_document`).
    timings, sizes
        Seconds of the engine per order (plus the whole derivation, last) and the number of
        terms of :math:`G_k` per order.
    response_coefficients
        :math:`(P_1, C_1, S_1, P_2, C_2, S_2)` with :math:`\dot a = P_1 + C_1\cos\gamma +
        S_1\sin\gamma`, :math:`a\dot\gamma = P_2 + C_2\cos\gamma + S_2\sin\gamma` (None
        when the flow has higher phase harmonics).
    definitions
        Symbols introduced by the derivation (Nayfeh & Mook's :math:`\Lambda` of a hard
        forcing) as equations; :meth:`in_frequency` substitutes them.
    a_phase_rate
        :math:`a\,d\gamma/dt`, the second steady-state residual.
    """

    oscillator: Oscillator
    order: int
    epsilon: sp.Symbol
    scaled: bool
    resonance: tuple[int, int] | None
    detuning: str
    omega0: sp.Expr
    nu: sp.Expr
    frequency: sp.Symbol
    sigma: sp.Symbol | None
    detuning_relation: sp.Equality | None
    B: sp.Symbol
    Bbar: sp.Expr
    complex_orders: tuple[sp.Expr, ...]
    amplitude: sp.Symbol
    phase: sp.Symbol
    polar: tuple[sp.Expr, sp.Expr]
    polar_orders: tuple[tuple[sp.Expr, sp.Expr], ...]
    u: sp.Symbol
    v: sp.Symbol
    cartesian: tuple[sp.Expr, sp.Expr]
    cartesian_orders: tuple[tuple[sp.Expr, sp.Expr], ...]
    response: sp.Expr | None
    backbone: sp.Expr | None
    waveform: sp.Expr
    tau: sp.Symbol
    fourier: Mapping[str, sp.Expr] = field(default_factory=lambda: MappingProxyType({}))
    steps: tuple[Step, ...] = ()
    timings: tuple[float, ...] = ()
    sizes: tuple[int, ...] = ()
    response_coefficients: tuple[sp.Expr, sp.Expr, sp.Expr, sp.Expr, sp.Expr, sp.Expr] | None = None
    definitions: tuple[sp.Equality, ...] = ()
    a_phase_rate: sp.Expr | None = None

    # ------------------------------------------------------------------------------
    @property
    def is_forced(self) -> bool:
        return self.resonance is not None

    def jacobian(self, coordinates: str = "polar") -> sp.Matrix:
        r"""Jacobian of the slow flow, in ``"polar"`` :math:`(a, \text{phase})` or
        ``"cartesian"`` :math:`(u, v)` coordinates. At a steady state its eigenvalues decide
        stability (both real parts negative: stable; a zero determinant: a saddle-node, the
        vertical tangent of the response curve)."""
        if coordinates == "polar":
            return sp.Matrix(self.polar).jacobian([self.amplitude, self.phase])
        if coordinates == "cartesian":
            return sp.Matrix(self.cartesian).jacobian([self.u, self.v])
        raise ParameterError(f"coordinates = {coordinates!r}: expected 'polar' or 'cartesian'")

    def in_frequency(self, expr: sp.Expr) -> sp.Expr:
        r"""``expr`` with the detuning replaced by the forcing frequency (and
        :math:`\varepsilon = 1` when the scaling was automatic)."""
        expr = expression_argument(expr, "expr")
        if self.definitions:
            expr = expr.xreplace({d.lhs: d.rhs for d in self.definitions})
        if self.sigma is not None and self.detuning_relation is not None:
            expr = expr.xreplace({self.sigma: self.detuning_relation.rhs})
        if self.scaled:
            expr = expr.xreplace({self.epsilon: sp.Integer(1)})
        return expr

    def _values(self, values: Mapping[str, float] | None) -> dict[sp.Symbol, sp.Float]:
        subs = dict(self.oscillator.substitutions())
        for name, val in (values or {}).items():
            subs[real_symbol(name)] = sp.Float(float(val))
        return subs

    def _numeric(self, exprs: Sequence[sp.Expr], args: Sequence[sp.Symbol], subs: Mapping):
        bound = [sp.sympify(e).xreplace(subs) for e in exprs]
        free = set().union(*(b.free_symbols for b in bound)) - set(args)
        if free:
            raise ParameterError(
                f"values needed for {', '.join(sorted(s_.name for s_ in free))} to evaluate the "
                "slow flow numerically: pass them in values or set them on the oscillator"
            )
        return sp.lambdify(args, bound, modules=[NUMERIC_IMPLEMENTATIONS, "numpy"])

    def steady_states(
        self,
        Omega: float,
        values: Mapping[str, float] | None = None,
        *,
        amplitude_range: tuple[float, float] = (1e-6, 1e3),
        points: int = 4000,
    ) -> tuple[SteadyState, ...]:
        r"""All nontrivial steady states of a forced slow flow at the forcing frequency
        ``Omega``, sorted by amplitude.

        When the slow flow is linear in :math:`\cos\gamma, \sin\gamma` (first order, and
        higher orders where it stays so), the roots :math:`a` of the phase-eliminated relation
        (``response``) are bracketed on a logarithmic grid over ``amplitude_range`` and refined
        by ``brentq``; the phase follows from the two steady-state equations. Otherwise (higher
        harmonics of the phase at higher orders) the first-order steady states seed a Newton
        solve of the full reconstituted flow :math:`\dot a = 0, a\dot\gamma = 0`. Stability
        comes from the eigenvalues of the polar Jacobian (:meth:`jacobian`).

        Parameters
        ----------
        Omega
            Forcing frequency.
        values
            Parameter values (name -> number) overriding the oscillator's; the bookkeeping
            parameter too when it is the model's.

        Raises
        ------
        PerturbError
            For an autonomous system, or a first-order flow that is not linear in
            :math:`\cos\gamma, \sin\gamma`.
        """
        # scipy.optimize is half the import time of perturb; only the numeric helpers need it
        from scipy.optimize import brentq, fsolve

        if not self.is_forced:
            raise PerturbError("steady_states is for forced models; use limit_cycles")
        subs = self._values(values)
        subs[self.frequency] = sp.Float(float(Omega))
        a, g = self.amplitude, self.phase
        exact = self.response_coefficients is not None
        if exact:
            coeff_exprs = self.response_coefficients
        else:
            first = [_phase_components(e, g) for e in self.polar_orders[0]]
            if first[0] is None or first[1] is None:
                raise PerturbError(
                    "steady_states: the first-order slow flow is not linear in cos(gamma), "
                    "sin(gamma); no seeds for the higher-order solve"
                )
            coeff_exprs = (*first[0], *(sp.expand(a * c) for c in first[1]))
        P1, C1, S1, P2, C2, S2 = coeff_exprs
        rel_expr = (S1 * P2 - S2 * P1) ** 2 + (C2 * P1 - C1 * P2) ** 2 - (C1 * S2 - S1 * C2) ** 2
        rel = self._numeric([self.in_frequency(rel_expr)], [a], subs)
        coeffs = self._numeric([self.in_frequency(c) for c in coeff_exprs], [a], subs)
        jac = self._numeric([self.in_frequency(e) for e in self.jacobian()], [a, g], subs)
        flow = self._numeric(
            [self.in_frequency(self.polar[0]), self.in_frequency(self.a_phase_rate)], [a, g], subs
        )
        grid = np.geomspace(*amplitude_range, int(points))
        vals = np.asarray(rel(grid)[0], dtype=float)
        out: list[SteadyState] = []
        for i in np.nonzero(np.sign(vals[:-1]) * np.sign(vals[1:]) < 0)[0]:
            root = brentq(lambda z: float(rel(z)[0]), grid[i], grid[i + 1], xtol=1e-14)
            p1, c1, s1, p2, c2, s2 = (float(c) for c in coeffs(root))
            det = c1 * s2 - s1 * c2
            gamma = math.atan2((c2 * p1 - c1 * p2) * det, (s1 * p2 - s2 * p1) * det)
            if not exact:
                # the first-order state seeds Newton on the full reconstituted flow
                sol = fsolve(
                    lambda z: np.asarray(flow(z[0], z[1]), dtype=float),
                    [root, gamma],
                    full_output=True,
                    xtol=1e-13,
                )
                if sol[2] != 1 or sol[0][0] <= 0:
                    continue
                root, gamma = float(sol[0][0]), math.remainder(float(sol[0][1]), 2 * math.pi)
                if any(abs(root - o.amplitude) < 1e-9 * max(1.0, root) for o in out):
                    continue
            eig = np.linalg.eigvals(np.asarray(jac(root, gamma), dtype=float).reshape(2, 2))
            out.append(
                SteadyState(
                    float(root), gamma, tuple(complex(e) for e in eig), bool(np.all(eig.real < 0))
                )
            )
        return tuple(sorted(out, key=lambda st: st.amplitude))

    def limit_cycles(
        self,
        values: Mapping[str, float] | None = None,
        *,
        amplitude_range: tuple[float, float] = (1e-6, 1e3),
        points: int = 4000,
    ) -> tuple[SteadyState, ...]:
        r"""Limit cycles of an autonomous slow flow: roots :math:`a > 0` of :math:`\dot a(a) = 0`,
        with ``frequency`` :math:`\omega_0 + \dot\beta(a)` and stability from
        :math:`d\dot a/da < 0` (the single eigenvalue in ``eigenvalues``)."""
        from scipy.optimize import brentq

        if self.is_forced:
            raise PerturbError("limit_cycles is for autonomous models; use steady_states")
        subs = self._values(values)
        a = self.amplitude
        fns = self._numeric(
            [
                self.in_frequency(e)
                for e in (self.polar[0], self.polar[1], sp.diff(self.polar[0], a))
            ],
            [a],
            subs,
        )
        grid = np.geomspace(*amplitude_range, int(points))
        vals = np.asarray(fns(grid)[0], dtype=float) * np.ones_like(grid)
        out = []
        for i in np.nonzero(np.sign(vals[:-1]) * np.sign(vals[1:]) < 0)[0]:
            root = brentq(lambda z: float(fns(z)[0]), grid[i], grid[i + 1], xtol=1e-14)
            _, rate, slope = (float(v) for v in fns(root))
            omega0 = float(sp.sympify(self.in_frequency(self.omega0)).xreplace(subs))
            out.append(SteadyState(float(root), 0.0, (complex(slope),), slope < 0, omega0 + rate))
        return tuple(out)

    def approximation(self) -> Approximation:
        """The method-contract view (:class:`~perturb.approximation.Approximation`): unknowns
        ``(a, phase)``, residuals and slow flow in the forcing frequency, the waveform and, for
        first-order primary resonance, the frequency polynomial in ``Omega**2``."""
        return _to_approximation(self)

    def __str__(self) -> str:
        lines = [f"multiple scales, order {self.order}, of {self.oscillator}"]
        if self.detuning_relation is not None:
            lines.append(f"  detuning: {sp.sstr(self.detuning_relation)}")
        lines.append(f"  d{self.amplitude}/dt = {sp.sstr(self.polar[0])}")
        lines.append(f"  d{self.phase}/dt = {sp.sstr(self.polar[1])}")
        if self.response is not None:
            lines.append(f"  response: 0 = {sp.sstr(self.response)}")
        if self.backbone is not None:
            lines.append(f"  backbone: omega = {sp.sstr(self.backbone)}")
        return "\n".join(lines)


# ------------------------------------------------------------------------ front doors --
def multiple_scales(
    oscillator: Oscillator,
    order: int = 1,
    *,
    resonance: Any = None,
    epsilon: str | None = None,
    detuning: str = "auto",
    hard_forcing: bool | None = None,
) -> Approximation:
    """Multiple scales as an :class:`~perturb.approximation.Approximation` (the method
    contract). Arguments as :func:`modulation_equations`; this is
    ``modulation_equations(...).approximation()``."""
    return modulation_equations(
        oscillator,
        order,
        resonance=resonance,
        epsilon=epsilon,
        detuning=detuning,
        hard_forcing=hard_forcing,
    ).approximation()


def modulation_equations(
    oscillator: Oscillator,
    order: int = 1,
    *,
    resonance: Any = None,
    epsilon: str | None = None,
    detuning: str = "auto",
    hard_forcing: bool | None = None,
) -> ModulationEquations:
    r"""Derive the modulation (slow-flow) equations of ``oscillator`` to order ``order``.

    Parameters
    ----------
    oscillator
        ``x'' + g(x, x', t) = f(t)`` with ``g`` made of linear damping, polynomial terms in
        ``x`` and ``x'``, parametric terms (polynomial in ``x``, ``x'`` times cos/sin of ``t``)
        and, at first order, piecewise-linear restoring terms; ``f`` a constant plus harmonics.
    order
        :math:`N \ge 1`: modulation equations through :math:`\varepsilon^N` (reconstituted).
    resonance
        ``"primary"`` (default for forced models), ``"superharmonic"`` (:math:`\Omega\approx
        \omega_0/3`), ``"subharmonic"`` (:math:`\Omega \approx 3\omega_0`), ``"parametric"``
        (:math:`\Omega\approx 2\omega_0`, default for parametric models), ``"superharmonic:n"``,
        ``"subharmonic:n"``, a ratio ``"p/q"`` or a pair ``(p, q)`` for
        :math:`\Omega\approx(p/q)\omega_0`. Ignored (must be None) for autonomous models.
    epsilon
        Name of the model parameter that orders the terms, or None for the automatic
        weak-nonlinearity scaling (module docstring).
    detuning
        ``"frequency"`` (:math:`q\Omega = p\omega_0 + \varepsilon\sigma`), ``"stiffness"``
        (:math:`\omega_0^2 = \omega_r^2 - \varepsilon\Delta`) or ``"auto"``.
    hard_forcing
        With automatic scaling: keep the forcing at :math:`O(1)`. Default: True for super- and
        subharmonic resonance, False otherwise. (With a named epsilon the forcing's own power
        of epsilon decides.)

    Returns
    -------
    ModulationEquations

    Raises
    ------
    ParameterError
        For a bad order (above :data:`~perturb.methods.applicability.ORDER_LIMITS`
        ``["ms"]`` too), resonance, detuning or epsilon name.
    ModelError
        For models outside the method (terms at order one other than the linear operator and
        a hard forcing, damping at order one, hard forcing at the resonant frequency, smooth
        non-polynomial terms, nonsmooth terms above first order or together with hard forcing,
        a non-positive or undefined :math:`\omega_0^2` with frequency detuning, a static load
        or a piecewise-linear force that is not odd (the message names what applies)).
    """
    return _derive(oscillator, order, resonance, epsilon, detuning, hard_forcing)


# ---------------------------------------------------------------------------- derivation --
def _positive_sqrt(expr: sp.Expr) -> sp.Expr:
    # frequencies are positive: sqrt(omega0**2) is omega0, not |omega0|
    return sp.sqrt(expr).replace(sp.Abs, lambda z: z)


def _base_frequency(freqs: Sequence[sp.Expr]) -> sp.Expr:
    ref = freqs[0]
    ratios = [sp.nsimplify(sp.simplify(w / ref)) for w in freqs]
    for w, r in zip(freqs, ratios, strict=True):
        if not r.is_Rational:
            raise ModelError(
                f"frequencies {ref} and {w} of the forcing/parametric terms are not commensurate"
            )
    den = sp.ilcm(*[sp.fraction(r)[1] for r in ratios]) if len(ratios) > 1 else 1
    num = sp.igcd(*[sp.fraction(r)[0] for r in ratios]) if len(ratios) > 1 else 1
    base = ref * num / den
    return sp.Abs(base) if base.is_number else base


def _split_arg(arg: sp.Expr, t: sp.Symbol) -> tuple[sp.Expr, sp.Expr]:
    arg = sp.expand(arg)
    w = arg.coeff(t)
    rest = sp.expand(arg - w * t)
    if w == 0 or rest.has(t) or w.has(t):
        raise ModelError(f"time-dependent argument {arg}: expected w*{t} + phase")
    return w, rest


@dataclass
class _Problem:
    """The model in multiple-scales form: bookkeeping parameter, resonance, linear operator
    and the perturbation ``R = sum eps^k R_k`` (monomials), hard forcing and the first-order
    nonsmooth force."""

    osc: Oscillator
    order: int
    taken: set[str]
    eps: sp.Symbol
    named: sp.Symbol | None
    Omega: sp.Expr | None
    pq: tuple[int, int] | None
    freq_symbol: sp.Symbol
    detuning: str = ""
    stiff: dict[int, sp.Expr] = field(default_factory=dict)
    L0: sp.Expr = sp.Integer(0)
    omega0: sp.Expr = sp.Integer(0)
    nu: sp.Expr = sp.Integer(0)
    monos: list[_Monomial] = field(default_factory=list)
    hard: list[tuple[sp.Expr, sp.Expr, sp.Expr]] = field(default_factory=list)
    hard_const: sp.Expr = sp.Integer(0)
    Delta: sp.Symbol | None = None
    ns_first: sp.Expr = sp.Integer(0)

    @property
    def forced(self) -> bool:
        return self.pq is not None

    @property
    def p(self) -> int:
        return self.pq[0] if self.pq is not None else 1

    @property
    def q(self) -> int:
        return self.pq[1] if self.pq is not None else 1

    @property
    def sigma_form(self) -> bool:
        """Frequency detuning of a forced model: the slow phase carries ``sigma``."""
        return self.detuning == "frequency" and self.forced


@dataclass
class _FastForm:
    """The perturbation on fast Fourier modes in ``tau = nu t``: opaque coefficients, the
    engine that solved the orders, the hard-forcing amplitudes ``Lambda`` and ``sh`` (the
    ring generator of ``sigma/nu``)."""

    opaque: _Opaque
    engine: _Engine
    sh: sp.Symbol
    lambdas: list[sp.Symbol]
    definitions: list[sp.Equality]


def _derive(
    osc: Oscillator,
    order: int,
    resonance: Any,
    epsilon: str | None,
    detuning: str,
    hard_forcing: bool | None,
) -> ModulationEquations:
    """The method, stage by stage: ordering of the terms, resonance and detuning, the
    perturbation on fast Fourier modes, the orders (secular conditions → modulation equations
    of B), then the polar/Cartesian slow flow, the response, the backbone and the steps."""
    t_start = _time.perf_counter()
    order = check_order("ms", order)
    if detuning not in _DETUNINGS:
        raise ParameterError(f"detuning = {detuning!r}: expected one of {', '.join(_DETUNINGS)}")
    prob = _resonance_problem(osc, order, resonance, epsilon)
    _linear_operator(prob, detuning)
    prob.monos = _perturbation(prob)
    _forcing_terms(prob, hard_forcing)
    prob.ns_first = _nonsmooth_first(prob)
    fast = _solve_orders(prob)
    fields, a1_name = _modulation_fields(prob, fast)
    context = _StepContext(
        monos=[m for m in prob.monos if m.order <= order],
        wave_parts=fields.pop("wave_parts"),
        hard=prob.hard,
        hard_const=prob.hard_const,
        L0=prob.L0,
        ns_first=prob.ns_first,
        engine=fast.engine,
        rest_syms=fields.pop("rest_syms"),
        Omega=prob.Omega,
        named=prob.named,
    )
    a, phase_sym = fields["amplitude"], fields["phase"]
    fields["steps"] = _steps(
        {
            **fields,
            "polar_names": tuple(sp.Symbol(f"\\dot{{{sp.latex(s_)}}}") for s_ in (a, phase_sym)),
        },
        context,
    )
    a1_value = fields["fourier"].get("a_1")
    if a1_value is not None:
        _concrete_a1(fields, a1_name, a1_value, a)
    fields["timings"] = (*fast.engine.timings, _time.perf_counter() - t_start)
    return ModulationEquations(**fields)


def _resonance_problem(
    osc: Oscillator, order: int, resonance: Any, epsilon: str | None
) -> _Problem:
    """Bookkeeping parameter (a named model parameter, or a fresh one for the automatic
    weak-nonlinearity scaling) and the resonance ``q Omega ~ p omega0`` of the forcing and
    parametric frequencies."""
    x, v, t = osc.x, osc.v, osc.t
    taken = set(osc.params) | {x.name, v.name, t.name}
    if epsilon is not None:
        if epsilon not in osc.params:
            raise ParameterError(
                f"epsilon = {epsilon!r} is not a parameter of model {osc.name!r}: expected one "
                f"of {', '.join(osc.params) or 'none'}, or None for automatic scaling"
            )
        eps = real_symbol(epsilon)
        named: sp.Symbol | None = eps
    else:
        eps = _fresh("epsilon", taken, positive=True)
        named = None
    if osc.smooth != 0:
        raise ModelError(
            f"model {osc.name!r} has smooth non-polynomial terms {osc.smooth}: multiple scales "
            "here handles polynomial and piecewise-linear terms (expand the function into a "
            "polynomial in the model if that is intended)"
        )
    # a static load or a one-sided piecewise-linear force: the orbit's mean is of order one
    # (the nonsmooth terms are expanded about x = a cos(psi), first order only)
    require_centred(osc, "multiple scales (ms)")

    freqs = [h.frequency for h in osc.forcing.harmonics]
    for f in osc.parametric.atoms(sp.cos, sp.sin):
        if f.has(t):
            freqs.append(_split_arg(f.args[0], t)[0])
    if named is not None and any(w.has(named) for w in freqs):
        raise ModelError(
            f"a forcing or parametric frequency of model {osc.name!r} depends on {named}: write "
            "the frequency as a parameter (e.g. Omega); the detuning is derived from it"
        )
    if freqs:
        Omega = _base_frequency(freqs)
        pq = _parse_resonance(
            resonance
            if resonance is not None
            else ("primary" if osc.forcing.harmonics else "parametric")
        )
        freq_symbol = Omega if isinstance(Omega, sp.Symbol) else _fresh("Omega", taken)
    else:
        if resonance is not None:
            raise ParameterError(
                f"resonance = {resonance!r} given for the autonomous model {osc.name!r}: it has "
                "no forcing or parametric frequency"
            )
        Omega = None
        pq = None
        freq_symbol = _fresh("omega", taken)
    return _Problem(osc, order, taken, eps, named, Omega, pq, freq_symbol)


def _linear_operator(prob: _Problem, detuning: str) -> None:
    """The operator at order one, ``x'' + omega0**2 x``, and the detuning form: frequency
    (``nu = omega0``) or stiffness (``nu = (q/p) Omega``, the operator at the response
    frequency); sets ``L0``, ``detuning``, ``omega0``, ``nu`` and the stiffness split."""
    osc, named, forced = prob.osc, prob.named, prob.forced
    stiff = _eps_split(osc.linear_stiffness * osc.x, named, "linear stiffness")
    L0 = (stiff.pop(0, sp.Integer(0)) / osc.x) if named is not None else osc.linear_stiffness
    prob.stiff = stiff if named is not None else {}
    L0_value = L0.xreplace(osc.substitutions()) if L0 != 0 else sp.Integer(0)
    if detuning == "auto":
        nonpositive = L0_value.is_number and L0_value <= 0
        detuning = "stiffness" if forced and (osc.nonsmooth != 0 or nonpositive) else "frequency"
    if detuning == "stiffness" and not forced:
        raise ParameterError(
            f"detuning = 'stiffness' needs a forcing or parametric frequency; model {osc.name!r} "
            "is autonomous"
        )
    if detuning == "frequency":
        if L0 == 0 or (L0_value.is_number and L0_value <= 0):
            raise ModelError(
                f"the linear stiffness of model {osc.name!r} at epsilon = 0 is {L0}"
                + (f" = {L0_value}" if L0_value != L0 else "")
                + ": the frequency detuning needs omega0**2 > 0; use detuning='stiffness' "
                "(the operator at the response frequency) for a forced model"
            )
        prob.omega0 = _positive_sqrt(L0)
        prob.nu = prob.omega0
    else:
        prob.omega0 = _positive_sqrt(L0) if L0 != 0 else sp.Integer(0)
        prob.nu = sp.Rational(prob.q, prob.p) * prob.Omega
    prob.L0, prob.detuning = L0, detuning


def _perturbation(prob: _Problem) -> list[_Monomial]:
    """The perturbation ``R = sum eps^k R_k`` as monomials: stiffness beyond order one,
    damping, polynomial, velocity and parametric terms (each must be at order >= 1)."""
    osc, named, eps = prob.osc, prob.named, prob.eps
    x, v, t = osc.x, osc.v, osc.t
    monos: list[_Monomial] = []
    for k, c in prob.stiff.items():
        monos += _monomials(-c, k, x, v, t, "linear stiffness")
    damping = _eps_split(osc.damping * v, named, "damping")
    if 0 in damping:
        raise ModelError(
            f"model {osc.name!r} has damping {damping[0] / v} at order one: multiple scales needs "
            f"the damping scaled by {eps} (light damping)"
        )
    for k, c in damping.items():
        monos += _monomials(-c, k, x, v, t, "damping")
    for part, what in ((osc.polynomial, "polynomial"), (osc.velocity, "velocity")):
        if is_nonsmooth(part):
            raise ModelError(
                f"the {what} term {part} of model {osc.name!r} is nonsmooth in x': only "
                "piecewise-linear restoring terms (in x) are supported"
            )
        for k, c in _eps_split(part, named, what).items():
            if k == 0:
                raise ModelError(
                    f"the {what} term {c} of model {osc.name!r} is at order one: scale it by {eps}"
                )
            monos += _monomials(-c, k, x, v, t, what)
    for k, c in _eps_split(osc.parametric, named, "parametric").items():
        if k == 0:
            raise ModelError(
                f"the parametric term {c} of model {osc.name!r} is at order one: scale it by {eps}"
            )
        monos += _monomials(-c, k, x, v, t, "parametric")
    return monos


def _forcing_terms(prob: _Problem, hard_forcing: bool | None) -> None:
    """Forcing: hard (order one) harmonics and constant go to the exact particular response
    ``x_p`` (``prob.hard``, ``prob.hard_const``); soft ones join the perturbation. With the
    stiffness detuning the mismatch ``Delta x`` joins it too."""
    osc, named, pq = prob.osc, prob.named, prob.pq
    x, v, t = osc.x, osc.v, osc.t
    if hard_forcing is None:
        hard_forcing = pq is not None and prob.p != prob.q and bool(osc.forcing.harmonics)
    for h in osc.forcing.harmonics:
        if named is not None:
            split = _eps_split(h.amplitude, named, "forcing")
        else:
            split = {0 if hard_forcing else 1: h.amplitude}
        for k, amp in split.items():
            if k == 0:
                prob.hard.append((amp, h.frequency, h.phase))
            else:
                wave = amp * sp.cos(h.frequency * t + h.phase)
                prob.monos += _monomials(wave, k, x, v, t, "forcing")
    if osc.forcing.constant != 0:
        split = (
            _eps_split(osc.forcing.constant, named, "forcing")
            if named is not None
            else {0 if hard_forcing else 1: osc.forcing.constant}
        )
        for k, c in split.items():
            if k == 0:
                prob.hard_const += c
            else:
                prob.monos += _monomials(c, k, x, v, t, "forcing")
    if prob.detuning == "stiffness":
        prob.Delta = _fresh("Delta", prob.taken)
        prob.monos.append(_Monomial(1, 1, 0, (), prob.Delta))


def _nonsmooth_first(prob: _Problem) -> sp.Expr:
    """The piecewise-linear restoring terms at first order (they enter through their first
    Fourier coefficient ``a_1(a)``); refused above first order and with a hard forcing."""
    osc, nonsmooth = prob.osc, prob.osc.nonsmooth
    ns_first: sp.Expr = sp.Integer(0)
    if nonsmooth == 0:
        return ns_first
    if nonsmooth.has(osc.v) or nonsmooth.has(osc.t):
        raise ModelError(
            f"the nonsmooth term {nonsmooth} of model {osc.name!r} depends on x' or t: only "
            "piecewise-linear restoring terms f(x) are supported"
        )
    for term in sp.Add.make_args(nonsmooth):
        k, c = _eps_order(term, prob.named, "nonsmooth")
        if k == 0:
            raise ModelError(
                f"the nonsmooth term {term} of model {osc.name!r} is at order one: scale it "
                f"by {prob.eps}, or use epsilon=None"
            )
        if k == 1:
            ns_first += c
    if prob.order > 1:
        raise ModelError(
            f"model {osc.name!r} has nonsmooth terms: multiple scales is provided at first "
            "order for them (higher orders need Dirac-delta terms); use order=1"
        )
    if prob.hard or prob.hard_const != 0:
        raise ModelError(
            f"model {osc.name!r} combines nonsmooth terms with a hard forcing: the Fourier "
            "engine expands f(a cos psi), not a two-frequency argument; use a soft forcing"
        )
    return ns_first


def _fast_monomials(prob: _Problem, opaque: _Opaque) -> list[tuple]:
    """Each monomial up to the order in ``tau = nu t``: its opaque coefficient (times
    ``nu**(vdeg - 2)``) and its forcing/parametric factor as Fourier modes."""
    mono_specs = []
    for mono in prob.monos:
        if mono.order > prob.order:
            continue
        coeff = opaque.get(mono.coeff * prob.nu ** (mono.vdeg - 2), mono.tag)
        trig_modes: dict[int, sp.Expr] = {0: sp.Integer(1)}
        for f in mono.trig:
            w, phase = _split_arg(f.args[0], prob.osc.t)
            modes = _harmonic_modes(
                w, phase, prob.Omega, prob.p, opaque, sine=isinstance(f, sp.sin)
            )
            new: dict[int, sp.Expr] = {}
            for m1, c1 in trig_modes.items():
                for m2, c2 in modes.items():
                    new[m1 + m2] = new.get(m1 + m2, 0) + c1 * c2
            trig_modes = new
        mono_specs.append((mono.order, mono.xdeg, mono.vdeg, trig_modes, coeff))
    return mono_specs


def _hard_response(prob: _Problem, opaque: _Opaque) -> tuple[dict, dict, list, list]:
    """Order one with a hard forcing: the exact particular response ``x_p = 2 Lambda cos(w t +
    phase)`` (Nayfeh & Mook's Lambda, kept as a symbol) and its velocity, as Fourier modes;
    refused at the resonant frequency."""
    xp_modes: dict[int, sp.Expr] = {}
    vp_modes: dict[int, sp.Expr] = {}
    lambdas: list[sp.Symbol] = []
    definitions: list[sp.Equality] = []
    hard = prob.hard
    for j, (amp, w, phase) in enumerate(hard):
        m = int(sp.nsimplify(w / prob.Omega)) * prob.p
        if abs(m) == prob.q:
            raise ModelError(
                f"the hard forcing {amp}*cos({w}*t) of model {prob.osc.name!r} is at the "
                "resonant frequency: its order-one response is unbounded; scale the forcing by "
                f"{prob.eps} (soft forcing) or choose the resonance it excites"
            )
        # Nayfeh & Mook's Lambda, kept as a symbol: x_p = 2 Lambda cos(w t + phase)
        lam_sym = _fresh("Lambda" if len(hard) == 1 else f"Lambda_{j + 1}", prob.taken)
        lambdas.append(lam_sym)
        definitions.append(_eq(lam_sym, amp / (2 * (prob.L0 - w**2))))
        lam = opaque.get(lam_sym, "forcing")
        what = opaque.get(w / prob.nu)
        e_plus = _phase_factor(phase, opaque)
        e_minus = sp.conjugate(e_plus)
        for mm, e in ((m, e_plus), (-m, e_minus)):
            xp_modes[mm] = xp_modes.get(mm, 0) + lam * e
            vp_modes[mm] = vp_modes.get(mm, 0) + sp.sign(mm) * sp.I * what * lam * e
    if prob.hard_const != 0:
        xp_modes[0] = xp_modes.get(0, 0) + opaque.get(prob.hard_const / prob.L0, "forcing")
    return xp_modes, vp_modes, lambdas, definitions


def _solve_orders(prob: _Problem) -> _FastForm:
    """Orders ``eps^1 .. eps^N`` on fast Fourier modes: at each the secular coefficient of
    ``exp(i theta)`` gives ``D_k B`` (the modulation equation) and the other modes ``y_k``
    (the engine, in a polynomial ring over QQ(i))."""
    opaque = _Opaque()
    mono_specs = _fast_monomials(prob, opaque)
    xp_modes, vp_modes, lambdas, definitions = _hard_response(prob, opaque)
    B_sym, Bb_sym = sp.Dummy("B"), sp.Dummy("Bb")
    sh = sp.Dummy("sh", real=True)
    gens = [B_sym, Bb_sym] + ([sh] if prob.sigma_form else [])
    gens += list(opaque.symbols.values())
    ring = PolyRing(gens, QQ_I)
    conv = ring.from_expr

    def fast(modes: Mapping[int, sp.Expr]) -> FastPoly:
        out = {m: conv(sp.expand(c)) for m, c in modes.items()}
        return {m: c for m, c in out.items() if c}

    terms = [(o, a, b, fast(tm), conv(c)) for o, a, b, tm, c in mono_specs]
    engine = _Engine(
        ring,
        prob.q,
        prob.p,
        ring.gens[2] if prob.sigma_form else None,
        terms,
        fast(xp_modes),
        fast(vp_modes),
    )
    for k in range(1, prob.order + 1):
        engine.order(k, need_solution=k < prob.order)
    return _FastForm(opaque, engine, sh, lambdas, definitions)


def _modulation_fields(prob: _Problem, fast: _FastForm) -> tuple[dict[str, Any], Any]:
    """Back to expressions: the fields of :class:`ModulationEquations` (complex, polar and
    Cartesian slow flow, detuning relation, waveform, response, backbone), plus the wave parts
    and ring symbols the steps need; returns the fields and the ``a_1`` function name."""
    osc, order, taken, eps, nu = prob.osc, prob.order, prob.taken, prob.eps, prob.nu
    engine = fast.engine
    sigma = _fresh("sigma", taken) if prob.sigma_form else None
    back = fast.opaque.back
    back[fast.sh] = sigma / nu if sigma is not None else sp.Integer(0)
    a = _fresh("a", taken, positive=True)
    phase_sym = _fresh("gamma" if prob.forced else "beta", taken)
    u_sym, v_sym = _fresh("u", taken), _fresh("v", taken)
    Bc = _fresh("B", taken, complex=True)
    rest_syms = [sym.xreplace(back) for sym in engine.R.symbols[2:]]
    slow = _polar_flow(prob, engine, rest_syms, Bc, a, phase_sym)
    cart_orders = _cartesian(engine, order, u_sym, v_sym, nu, back)
    if slow["a1"] is not None:
        r = sp.sqrt(u_sym**2 + v_sym**2)
        a1_uv = slow["a1_name"](r)
        # dB/dt gains i a_1 B/(2 nu a) with B = (u - i v)/2: du/dt = 2 Re, dv/dt = -2 Im
        cart_orders[0] = (
            cart_orders[0][0] + v_sym * a1_uv / (2 * nu * r),
            cart_orders[0][1] - u_sym * a1_uv / (2 * nu * r),
        )
    cart = tuple(
        sp.Add(*(eps ** (k + 1) * co[i] for k, co in enumerate(cart_orders))) for i in (0, 1)
    )
    rel, det_symbol = _detuning_relation(prob, sigma)
    tau = _fresh("tau", taken)
    wave_parts, waveform = _waveform_of(prob, fast, a, phase_sym, tau, back)
    response, coeffs = _eliminate_phase(slow["harm"], a, eps, sigma, order == 1)
    backbone = None
    if prob.detuning == "frequency":
        off = fast.opaque.tagged("forcing") | fast.opaque.tagged("damping") | {fast.sh}
        backbone = _backbone(engine, order, a, prob.omega0, nu, eps, back, off)
        if backbone is not None and slow["a1"] is not None:
            backbone += eps * slow["a1"] / (2 * nu * a)
    fourier = {"a_1": slow["a1_value"]} if slow["a1_value"] is not None else {}
    fields: dict[str, Any] = dict(
        oscillator=osc,
        order=order,
        epsilon=eps,
        scaled=prob.named is None,
        resonance=prob.pq,
        detuning=prob.detuning,
        omega0=prob.omega0,
        nu=nu,
        frequency=prob.freq_symbol,
        sigma=det_symbol,
        detuning_relation=rel,
        B=Bc,
        Bbar=sp.conjugate(Bc),
        complex_orders=tuple(slow["complex_orders"]),
        amplitude=a,
        phase=phase_sym,
        polar=slow["polar"],
        polar_orders=slow["polar_orders"],
        u=u_sym,
        v=v_sym,
        cartesian=cart,
        cartesian_orders=tuple(cart_orders),
        response=response,
        backbone=backbone,
        waveform=waveform,
        tau=tau,
        fourier=MappingProxyType(fourier),
        sizes=tuple(len(engine.G[k][0]) for k in range(1, order + 1)),
        response_coefficients=coeffs,
        definitions=tuple(fast.definitions),
        a_phase_rate=slow["a_phase_rate"],
    )
    return {**fields, "wave_parts": wave_parts, "rest_syms": rest_syms}, slow["a1_name"]


def _polar_flow(
    prob: _Problem,
    engine: _Engine,
    rest_syms: list[sp.Expr],
    Bc: sp.Symbol,
    a: sp.Symbol,
    phase_sym: sp.Symbol,
) -> dict[str, Any]:
    """The complex modulation equations ``dB/dt = nu G(tau)`` order by order (with the
    nonsmooth secular term ``-a_1(a) B/a`` at first order), and their polar form: the
    harmonics of ``da/dt`` and ``d(phase)/dt``, summed, and ``a d(phase)/dt``."""
    osc, order, eps, nu, forced = prob.osc, prob.order, prob.eps, prob.nu, prob.forced
    Bbar = sp.conjugate(Bc)
    complex_orders = [
        _poly_expr(engine.G[k][0], [Bc, Bbar, *rest_syms], nu) for k in range(1, order + 1)
    ]
    a1 = a1_value = a1_name = None
    if prob.ns_first != 0:
        values = {n: val for n, val in osc.params.items() if val is not None}
        a1_value = series_coefficient(prob.ns_first, osc.x, 1, a, 0, values=values)
        # written by name, a_1(a), as a paper would; the coefficient goes in at the end
        a1_name = sp.Function("a_1")
        a1 = a1_name(a)
        # secular part of -f(y0) is -a_1(a) B / a; G gains -(i/2) of it, times 1/nu^2, times nu
        complex_orders[0] += (
            sp.I * a1_name(2 * sp.sqrt(Bc * Bbar)) * Bc / (4 * sp.sqrt(Bc * Bbar) * nu)
        )
    harm = [
        _polar_harmonics(engine.G[k][0], rest_syms, a, prob.p, forced, nu)
        for k in range(1, order + 1)
    ]
    if a1 is not None:
        # -a_1 B/a in the secular term -> d(phase)/dt gains a_1/(2 nu a) (sign by phase form)
        harm[0][1][("c", 0)] = harm[0][1].get(("c", 0), sp.Integer(0)) + (
            -prob.p if forced else 1
        ) * a1 / (2 * nu * a)
    polar_orders = tuple((_trig_expr(h[0], phase_sym), _trig_expr(h[1], phase_sym)) for h in harm)
    polar = (
        sp.Add(*(eps ** (k + 1) * polar_orders[k][0] for k in range(order))),
        sp.Add(*(eps ** (k + 1) * polar_orders[k][1] for k in range(order))),
    )
    # a * d(phase)/dt, term by term (the steady-state residual; no expand of the whole)
    a_phase_rate = sp.Add(
        *(
            eps ** (k + 1)
            * _trig_expr(
                {key: sp.Add(*(a * t_ for t_ in sp.Add.make_args(c_))) for key, c_ in h[1].items()},
                phase_sym,
            )
            for k, h in enumerate(harm)
        )
    )
    return dict(
        complex_orders=complex_orders,
        a1=a1,
        a1_value=a1_value,
        a1_name=a1_name,
        harm=harm,
        polar_orders=polar_orders,
        polar=polar,
        a_phase_rate=a_phase_rate,
    )


def _detuning_relation(
    prob: _Problem, sigma: sp.Symbol | None
) -> tuple[sp.Equality | None, sp.Symbol | None]:
    """The detuning relation and its symbol: ``sigma = (q Omega - p omega0)/eps`` (frequency
    form), ``Delta = (nu**2 - omega0**2)/eps`` (stiffness form), none when autonomous."""
    if sigma is not None:
        return _eq(sigma, (prob.q * prob.Omega - prob.p * prob.omega0) / prob.eps), sigma
    if prob.detuning == "stiffness":
        return _eq(prob.Delta, (prob.nu**2 - prob.L0) / prob.eps), prob.Delta
    return None, None


def _waveform_of(
    prob: _Problem, fast: _FastForm, a: sp.Symbol, phase_sym: sp.Symbol, tau: sp.Symbol, back
) -> tuple[list[sp.Expr], sp.Expr]:
    """The approximate solution ``x = sum eps^k y_k`` in ``tau`` plus the hard-forcing
    response ``2 Lambda cos(...)`` and the static part; returns the parts and the sum."""
    wave_parts = _waveform(
        fast.engine, prob.order, a, phase_sym, prob.p, prob.q, prob.forced, tau, back
    )
    waveform = sp.Add(*(prob.eps**k * part for k, part in enumerate(wave_parts)))
    for lam_sym, (_, w, ph) in zip(fast.lambdas, prob.hard, strict=True):
        waveform += 2 * lam_sym * sp.cos(sp.nsimplify(w / prob.Omega) * tau + ph)
    if prob.hard_const != 0:
        waveform += prob.hard_const / prob.L0
    return wave_parts, waveform


def _concrete_a1(fields: dict[str, Any], a1_name: Any, a1_value: sp.Expr, a: sp.Symbol) -> None:
    """The derivation shows ``a_1(.)`` by name; the fields carry the coefficient itself."""

    def concrete(expr: Any) -> Any:
        if isinstance(expr, tuple):
            return tuple(concrete(e) for e in expr)
        if isinstance(expr, sp.Basic):
            return expr.replace(a1_name, lambda z: a1_value.xreplace({a: z}))
        return expr

    for key in (
        "complex_orders",
        "polar",
        "polar_orders",
        "cartesian",
        "cartesian_orders",
        "response",
        "backbone",
        "response_coefficients",
        "a_phase_rate",
    ):
        fields[key] = concrete(fields[key])


def _phase_factor(phase: sp.Expr, opaque: _Opaque) -> sp.Expr:
    """``exp(i phase)`` as ``c + i s`` with exact or opaque real parts."""
    if phase == 0:
        return sp.Integer(1)
    c, s = sp.cos(phase), sp.sin(phase)
    return opaque.get(c) + sp.I * opaque.get(s)


def _harmonic_modes(
    w: sp.Expr, phase: sp.Expr, Omega: sp.Expr, p: int, opaque: _Opaque, *, sine: bool
) -> dict[int, sp.Expr]:
    ratio = sp.nsimplify(sp.simplify(w / Omega))
    if not ratio.is_Integer:
        raise ModelError(f"frequency {w} is not an integer multiple of the base frequency {Omega}")
    m = int(ratio) * p
    e = _phase_factor(phase, opaque)
    eb = sp.conjugate(e)
    if sine:  # sin(psi) = (e^{i psi} - e^{-i psi}) / (2i)
        return {m: -sp.I * e / 2, -m: sp.I * eb / 2}
    return {m: e / 2, -m: eb / 2}


# -------------------------------------------------------------------- conversions --
def _coeff(c: Any) -> sp.Expr:
    return sp.Rational(c.x) + sp.I * sp.Rational(c.y)


def _poly_expr(poly: PolyElement, syms: Sequence[sp.Expr], factor: sp.Expr = 1) -> sp.Expr:
    """A ring element as an expression, term by term (no ``expand``: the opaque coefficients
    map back to monomials, so the terms come out collected)."""
    return sp.Add(
        *(
            sp.Mul(factor, _coeff(c), *(s**e for s, e in zip(syms, monom, strict=True) if e))
            for monom, c in poly.items()
        )
    )


Harmonic = dict[tuple[str, int], sp.Expr]  # ("c"|"s", n) -> coefficient of cos/sin(n phase)


def _polar_harmonics(
    g: PolyElement,
    rest_syms: Sequence[sp.Expr],
    a: sp.Symbol,
    p: int,
    forced: bool,
    nu: sp.Expr,
) -> tuple[Harmonic, Harmonic]:
    r"""``(da/dt, d phase/dt)`` of one order :math:`G_k`, as cos/sin components in the phase.

    With :math:`B = \frac a2 e^{i\phi}`, :math:`\dot a + i a\dot\phi = 2 e^{-i\phi}\dot B`;
    :math:`\phi = \beta` (autonomous) or :math:`-\gamma/p` (forced). A monomial
    :math:`B^j\bar B^l` gives :math:`e^{i(j - l - 1)\phi}`; real and imaginary parts are taken
    term by term, exactly.
    """
    re_parts: dict[tuple[str, int], list[sp.Expr]] = {}
    im_parts: dict[tuple[str, int], list[sp.Expr]] = {}

    def put(parts: dict, kind: str, n: int, value: sp.Expr) -> None:
        if kind == "s" and n == 0:
            return
        parts.setdefault((kind, n), []).append(value)

    for monom, c in g.items():
        j, l = monom[0], monom[1]
        n = j - l - 1
        if forced:
            if n % p:
                raise PerturbError(f"internal: slow phase {n}/{p} of {g} is not integral")
            n = -(n // p)  # n*phi = -(n/p)*gamma
        sign = -1 if n < 0 else 1
        n = abs(n)
        rest = [s**e for s, e in zip(rest_syms, monom[2:], strict=True) if e]
        mag = sp.Mul(2 * nu, sp.Rational(1, 2 ** (j + l)), a ** (j + l), *rest)
        cr, ci = sp.Rational(c.x), sp.Rational(c.y)
        # (cr + i ci)(cos n phi + i sign sin n phi)
        if cr:
            put(re_parts, "c", n, cr * mag)
            put(im_parts, "s", n, sign * cr * mag)
        if ci:
            put(re_parts, "s", n, -sign * ci * mag)
            put(im_parts, "c", n, ci * mag)
    factor = (-p if forced else 1) / a
    da = {key: sp.Add(*vals) for key, vals in re_parts.items()}
    dphase = {key: sp.Add(*(factor * val for val in vals)) for key, vals in im_parts.items()}
    return da, dphase


def _phase_components(expr: sp.Expr, phase: sp.Symbol) -> tuple[sp.Expr, ...] | None:
    """``expr = P + C cos(phase) + S sin(phase)`` -> ``(P, C, S)``, or None."""
    expr = sp.expand(expr)
    C, S = expr.coeff(sp.cos(phase)), expr.coeff(sp.sin(phase))
    P = sp.expand(expr - C * sp.cos(phase) - S * sp.sin(phase))
    if P.has(phase) or C.has(phase) or S.has(phase):
        return None
    return P, C, S


def _trig_expr(h: Harmonic, phase: sp.Symbol) -> sp.Expr:
    terms = []
    for (kind, n), c in sorted(h.items()):
        if n == 0:
            terms.append(c)
        else:
            terms.append(c * (sp.cos(n * phase) if kind == "c" else sp.sin(n * phase)))
    return sp.Add(*terms)


def _backbone(
    engine: _Engine,
    order: int,
    a: sp.Symbol,
    omega0: sp.Expr,
    nu: sp.Expr,
    eps: sp.Symbol,
    back: Mapping[sp.Symbol, sp.Expr],
    switched_off: set[sp.Symbol],
) -> sp.Expr | None:
    r"""Free undamped frequency :math:`\omega(a) = \omega_0 + \dot\beta(a)`: the forcing, the
    linear damping and the detuning set to zero in :math:`G_k` (then :math:`\theta = \omega_0 t`
    and :math:`B = \frac a2 e^{i\beta}`)."""
    R = engine.R
    rest_syms = [s.xreplace(back) for s in R.symbols[2:]]
    gens = [g for g, s in zip(R.gens, R.symbols, strict=True) if s in switched_off]
    total = []
    for k in range(1, order + 1):
        g = engine.G[k][0]
        for gen in gens:
            g = g.subs(gen, 0)
        _, dbeta = _polar_harmonics(g, rest_syms, a, 1, False, nu)
        if any(n for (_, n) in dbeta):
            return None
        total.append(eps**k * dbeta.get(("c", 0), sp.Integer(0)))
    return omega0 + sp.Add(*total)


def _cartesian(
    engine: _Engine,
    order: int,
    u: sp.Symbol,
    v: sp.Symbol,
    nu: sp.Expr,
    back: Mapping[sp.Symbol, sp.Expr],
) -> list[tuple[sp.Expr, sp.Expr]]:
    r"""With :math:`B = (u - iv)/2`: :math:`\dot u = 2\,\mathrm{Re}\,\dot B`,
    :math:`\dot v = -2\,\mathrm{Im}\,\dot B`, computed exactly in a ring over QQ(i)."""
    R = engine.R
    rest = list(R.symbols[2:])
    R2 = PolyRing([u, v, *rest], QQ_I)
    U, V = R2.gens[0], R2.gens[1]
    half = QQ_I(Fraction(1, 2))
    Bu, Bbu = (U - V * _I) * half, (U + V * _I) * half
    syms = [u, v, *(s.xreplace(back) for s in rest)]
    du: list[sp.Expr] = []
    dv: list[sp.Expr] = []
    powers: dict[tuple[int, int], PolyElement] = {}
    for k in range(1, order + 1):
        acc = R2.zero
        for monom, c in engine.G[k][0].items():
            key = (monom[0], monom[1])
            if key not in powers:
                powers[key] = Bu ** monom[0] * Bbu ** monom[1]
            term = powers[key] * c
            for gen, e in zip(R2.gens[2:], monom[2:], strict=True):
                if e:
                    term *= gen**e
            acc += term
        re = R2({m: QQ_I(c.x) for m, c in acc.items() if c.x})
        im = R2({m: QQ_I(c.y) for m, c in acc.items() if c.y})
        du.append(_poly_expr(re, syms, 2 * nu))
        dv.append(_poly_expr(im, syms, -2 * nu))
    return list(zip(du, dv, strict=True))


def _waveform(
    engine: _Engine,
    order: int,
    a: sp.Symbol,
    phase: sp.Symbol,
    p: int,
    q: int,
    forced: bool,
    tau: sp.Symbol,
    back: Mapping[sp.Symbol, sp.Expr],
) -> list[sp.Expr]:
    r""":math:`y_0, \dots, y_{N-1}` in real form. A mode :math:`e^{im\theta/q}` is
    :math:`e^{im\tau/p}` (forced, :math:`\tau = \Omega t`) or :math:`e^{im\tau}` (autonomous,
    :math:`\tau = \omega t`)."""
    R = engine.R
    rest_syms = [s.xreplace(back) for s in R.symbols[2:]]
    parts: list[sp.Expr] = []
    for k in range(order):
        total: list[sp.Expr] = []
        y = engine.y[k]
        for m, c in y.items():
            if m < 0:
                continue
            fast = sp.Rational(m, p) * tau if forced else sp.Rational(m, q) * tau
            for monom, cc in c.items():
                j, l = monom[0], monom[1]
                rest = sp.Mul(*(s**e for s, e in zip(rest_syms, monom[2:], strict=True) if e))
                slow = (j - l) * (-phase / p if forced else phase)
                arg = fast + slow
                cr, ci = sp.Rational(cc.x), sp.Rational(cc.y)
                weight = 1 if m == 0 else 2
                total.append(
                    weight * (a / 2) ** (j + l) * rest * (cr * sp.cos(arg) - ci * sp.sin(arg))
                )
        parts.append(sp.Add(*total))
    return parts


def _eliminate_phase(
    harm: Sequence[tuple[Harmonic, Harmonic]],
    a: sp.Symbol,
    eps: sp.Symbol,
    sigma: sp.Symbol | None,
    expand: bool,
) -> tuple[sp.Expr | None, tuple | None]:
    r"""If :math:`\dot a = P_1 + C_1\cos\gamma + S_1\sin\gamma` and
    :math:`a\dot\gamma = P_2 + C_2\cos\gamma + S_2\sin\gamma`, eliminate :math:`\gamma`:
    :math:`\cos\gamma = (S_1P_2 - S_2P_1)/\det`, :math:`\sin\gamma = (C_2P_1 - C_1P_2)/\det`,
    :math:`\det = C_1S_2 - S_1C_2`, and :math:`\cos^2 + \sin^2 = 1`. Returns the relation
    (expanded and stripped of constant factors when ``expand``) and ``(P1, C1, S1, P2, C2, S2)``."""
    parts = []
    for idx in (0, 1):
        comp: dict[tuple[str, int], list[sp.Expr]] = {}
        for k, h in enumerate(harm):
            for key, c in h[idx].items():
                comp.setdefault(key, []).append(eps ** (k + 1) * (c if idx == 0 else a * c))
        if any(n > 1 for (_, n) in comp):
            return None, None
        parts.append(tuple(sp.Add(*comp.get(key, [])) for key in (("c", 0), ("c", 1), ("s", 1))))
    (P1, C1, S1), (P2, C2, S2) = parts
    if C1 == S1 == C2 == S2 == 0:
        return None, None
    rel = (S1 * P2 - S2 * P1) ** 2 + (C2 * P1 - C1 * P2) ** 2 - (C1 * S2 - S1 * C2) ** 2
    if expand:
        rel = sp.factor_terms(sp.expand(rel))
        keep = (a,) if sigma is None else (a, sigma)
        _, rel = rel.as_independent(*keep, as_Add=False)
    return rel, (P1, C1, S1, P2, C2, S2)


# ----------------------------------------------------------------------- approximation --
@states_caveats
def _to_approximation(mod: ModulationEquations) -> Approximation:
    osc = mod.oscillator
    a, phase = mod.amplitude, mod.phase
    flow = tuple(mod.in_frequency(e) for e in mod.polar)
    poly = None
    phase_from = None
    p, q = mod.resonance or (1, 1)
    Omega = mod.frequency
    if (
        mod.is_forced
        and mod.order == 1
        and mod.response_coefficients is not None
        and (p, q) == (1, 1)
    ):
        P1, C1, S1, P2, C2, S2 = (mod.in_frequency(e) for e in mod.response_coefficients)
        det = C1 * S2 - S1 * C2
        # cos(gamma), sin(gamma) times det**2 > 0: the phase by arctan2
        phase_from = (sp.expand((S1 * P2 - S2 * P1) * det), sp.expand((C2 * P1 - C1 * P2) * det))
        if mod.detuning == "stiffness":
            poly = _frequency_polynomial(mod.in_frequency(mod.response), Omega)
    if mod.is_forced:
        residuals = (flow[0], mod.in_frequency(mod.a_phase_rate))
    else:
        residuals = (flow[0],)
    waveform = mod.in_frequency(mod.waveform)
    backbone = mod.in_frequency(mod.backbone) if mod.backbone is not None else None
    harmonics = _harmonic_count(waveform, mod.tau)
    options: dict[str, Any] = {"order": mod.order}
    if mod.resonance is not None:
        options["resonance"] = f"{p}/{q}"
    options["detuning"] = mod.detuning
    options["epsilon"] = "scaled" if mod.scaled else mod.epsilon.name
    options["harmonics"] = harmonics
    return Approximation(
        oscillator=osc,
        method="multiple_scales",
        options=MappingProxyType(options),
        unknowns=(a, phase),
        residuals=residuals,
        waveform=waveform,
        tau=mod.tau,
        frequency=Omega,
        slow_flow=flow,
        amplitude=a,
        frequency_polynomial=poly,
        phase_from=phase_from,
        backbone=backbone,
        fourier=mod.fourier,
        steps=mod.steps,
    )


def _harmonic_count(waveform: sp.Expr, tau: sp.Symbol) -> int:
    top = 1
    for f in waveform.atoms(sp.cos, sp.sin):
        c = sp.expand(f.args[0]).coeff(tau)
        if c.is_Rational:
            top = max(top, int(math.ceil(abs(c))))
    return top


def _frequency_polynomial(rel: sp.Expr, Omega: sp.Symbol) -> tuple[sp.Expr, ...] | None:
    r"""Coefficients ``(c0, c1, c2)`` of the response relation as a polynomial in
    :math:`W = \Omega^2`, or None when it is not one of degree <= 2.

    Only the stiffness form qualifies: its relation is even in :math:`\Omega` (operator at
    :math:`\Omega`, detuning :math:`\varepsilon\Delta = \Omega^2 - \omega_0^2`). In the frequency
    form the relation is a quadratic :math:`r(\Omega)` (through :math:`\sigma`); the only
    polynomial in :math:`W` with its roots is :math:`r(\Omega)\,r(-\Omega)`, which also has the
    mirrored roots of :math:`r(-\Omega)` — spurious small-amplitude branches wherever
    :math:`r` has a negative root (far from resonance, inside ordinary frequency windows). So the
    frequency form provides none; use ``detuning="stiffness"`` for amplitude parametrisation.
    """
    num, _ = sp.fraction(sp.together(rel))
    try:
        P = sp.Poly(sp.expand(num), Omega)
    except sp.PolynomialError:
        return None
    coeffs = P.all_coeffs()[::-1]
    if any(c != 0 for c in coeffs[1::2]) or len(coeffs) > 5:
        return None
    return tuple(sp.expand(c) for c in coeffs[0::2])


# -------------------------------------------------------------------------- steps --
@dataclass(frozen=True)
class _StepContext:
    monos: list[_Monomial]
    hard: list[tuple[sp.Expr, sp.Expr, sp.Expr]]
    hard_const: sp.Expr
    L0: sp.Expr
    ns_first: sp.Expr
    engine: _Engine
    rest_syms: list[sp.Expr]
    Omega: sp.Expr | None
    named: sp.Symbol | None
    wave_parts: list[sp.Expr]


def _eq(lhs: sp.Basic, rhs: sp.Basic) -> sp.Equality:
    # unevaluated: deciding whether two large expressions are equal costs seconds
    return sp.Eq(lhs, rhs, evaluate=False)


def _modes_expr(
    poly: FastPoly, syms: Sequence[sp.Expr], theta: sp.Symbol, q: int, factor: sp.Expr
) -> sp.Expr:
    """``sum_m c_m exp(i m theta/q)`` over ``m >= 0`` plus the symbol ``cc``."""
    terms = []
    for m in sorted(k for k in poly if k >= 0):
        terms.append(_poly_expr(poly[m], syms, factor) * sp.exp(sp.I * sp.Rational(m, q) * theta))
    if any(k > 0 for k in poly):
        terms.append(sp.Symbol("cc"))
    return sp.Add(*terms)


@dataclass(frozen=True)
class _Notation:
    """The derivation's notation: slow times ``T_k``, derivatives ``D_k``, the orders ``y_k``
    of the expansion and the resonant phase ``theta``."""

    Ts: list[sp.Symbol]
    Ds: list[sp.Symbol]
    ys: list[sp.Symbol]
    theta: sp.Symbol

    @classmethod
    def of_order(cls, N: int) -> _Notation:
        return cls(
            [sp.Symbol(f"T_{k}") for k in range(N + 1)],
            [sp.Symbol(f"D_{k}") for k in range(N + 1)],
            [sp.Symbol(f"y_{k}") for k in range(N + 1)],
            real_symbol("theta"),
        )


def _steps(f: Mapping[str, Any], c: _StepContext) -> tuple[Step, ...]:
    """The derivation as a paper writes it (rendered by :mod:`perturb.report.latex`; the text
    is plain prose, the mathematics SymPy): ordering, detuning, time scales, order zero, the
    nonsmooth coefficient, each order, the reconstituted modulation equation, the polar and
    Cartesian slow flow, steady states, stability and the approximate solution."""
    osc: Oscillator = f["oscillator"]
    N = f["order"]
    nt = _Notation.of_order(N)
    steps: list[Step] = [Step("Equation of motion", (osc.equation,)), _ordering_step(f, c)]
    if f["resonance"] is not None:
        steps.append(_detuning_step(f, c))
    steps.append(_time_scales_step(f, c, nt))
    steps.append(_order_zero_step(f, c, nt))
    if f["fourier"]:
        steps.append(_nonsmooth_coefficient_step(f))
    steps += [_order_step(f, c, nt, k) for k in range(1, N + 1)]
    steps.append(_reconstituted_step(f))
    polar, rates = _polar_step(f, c)
    steps += [polar, _cartesian_step(f, nt), _steady_state_step(f, rates), _stability_step(f)]
    steps.append(_solution_step(f, c, nt))
    return tuple(steps)


def _ordering_step(f: Mapping[str, Any], c: _StepContext) -> Step:
    """Step "Ordering": every term with its power of the bookkeeping parameter."""
    osc: Oscillator = f["oscillator"]
    x, v, t = osc.x, osc.v, osc.t
    eps, nu = f["epsilon"], f["nu"]
    stiffness = f["detuning"] == "stiffness"
    rhs = [eps**m.order * m.coeff * x**m.xdeg * v**m.vdeg * sp.Mul(*m.trig) for m in c.monos]
    if c.ns_first != 0:
        rhs.append(-eps * c.ns_first)
    rhs += [amp * sp.cos(w * t + ph) for amp, w, ph in c.hard]
    rhs.append(c.hard_const)
    lhs = real_symbol(x.name + "''") + (nu**2 if stiffness else c.L0) * x
    if c.named is None:
        text = (
            "Weak-nonlinearity scaling (Nayfeh and Mook): every term except the linear operator"
            + (" and the hard forcing" if c.hard else "")
            + " is put at first order in the bookkeeping parameter, which is set to 1 at the end."
        )
    else:
        text = (
            f"The model's parameter ${latex(c.named)}$ is the bookkeeping parameter: each "
            f"term's order is its power of ${latex(c.named)}$; terms beyond order ${f['order']}$ "
            "are dropped."
        )
    return Step("Ordering", (_eq(lhs, sp.Add(*rhs)),), text)


def _detuning_step(f: Mapping[str, Any], c: _StepContext) -> Step:
    """Step "Resonance and detuning" (forced models): frequency or stiffness detuning."""
    eps, nu = f["epsilon"], f["nu"]
    p, q = f["resonance"]
    det = f["detuning_relation"]
    if f["detuning"] == "stiffness":
        math_ = (_eq(f["omega0"] ** 2, nu**2 - eps * f["sigma"]), det)
        text = (
            "The operator is taken at the response frequency and the stiffness mismatch is "
            "a perturbation (modified Lindstedt–Poincaré form)."
        )
    else:
        math_ = (_eq(q * c.Omega, p * f["omega0"] + eps * f["sigma"]), det)
        text = "The nearness to the resonance is expressed by the detuning $\\sigma$."
    return Step("Resonance and detuning", math_, text)


def _time_scales_step(f: Mapping[str, Any], c: _StepContext, nt: _Notation) -> Step:
    """Step "Time scales and expansion": slow times, derivative expansion and the ansatz."""
    osc: Oscillator = f["oscillator"]
    x, t = osc.x, osc.t
    eps, N = f["epsilon"], f["order"]
    x_exp = sp.Add(*(eps**k * nt.ys[k] for k in range(N)))
    if c.hard or c.hard_const != 0:
        x_exp = sp.Symbol("x_p") + x_exp
    return Step(
        "Time scales and expansion",
        (
            _eq(nt.Ts[1], eps * t),
            _eq(
                sp.Derivative(sp.Function("x")(t), t),
                sp.Add(*(eps**k * nt.Ds[k] * x for k in range(N + 1))),
            ),
            _eq(x, x_exp + sp.Order(eps**N)),
        ),
        "Slow times $T_k = \\varepsilon^k t$ and the derivatives $D_k$ with respect to "
        "them; the complex amplitude $B(T_1, T_2, \\ldots)$ depends on the slow times, and "
        f"the expansion is carried to order ${N}$ in the modulation equations.",
    )


def _order_zero_step(f: Mapping[str, Any], c: _StepContext, nt: _Notation) -> Step:
    """Step "Order 0": the generating solution ``B e^{i theta} + cc`` (and ``x_p``)."""
    t = f["oscillator"].t
    nu, p = f["nu"], (f["resonance"] or (1, 1))[0]
    forced = f["resonance"] is not None
    stiffness = f["detuning"] == "stiffness"
    Ts, Ds, ys, theta = nt.Ts, nt.Ds, nt.ys, nt.theta
    theta_def = (
        _eq(theta, nu * Ts[0] + f["sigma"] * Ts[1] / p)
        if forced and not stiffness
        else _eq(theta, nu * Ts[0])
    )
    zero = [
        _eq(Ds[0] ** 2 * ys[0] + nu**2 * ys[0], 0),
        _eq(ys[0], f["B"] * sp.exp(sp.I * theta) + f["Bbar"] * sp.exp(-sp.I * theta)),
        theta_def,
    ]
    if c.hard or c.hard_const != 0:
        xp = sp.Add(
            *(
                2 * d.lhs * sp.cos(w * t + ph)
                for d, (_, w, ph) in zip(f["definitions"], c.hard, strict=True)
            )
        ) + (c.hard_const / c.L0 if c.hard_const != 0 else 0)
        zero[0:0] = [_eq(sp.Symbol("x_p"), xp), *f["definitions"]]
    text = "The complex amplitude $B$ depends on the slow times only."
    if forced and not stiffness:
        text += (
            " The resonant phase $\\theta$ carries the detuning, so the modulation equations "
            "are autonomous (Nayfeh's amplitude $A$ is $B$ times the slow phase factor)."
        )
    if c.hard:
        text += " $x_p$ is the exact order-one response to the hard forcing."
    return Step("Order 0", tuple(zero), text)


def _nonsmooth_coefficient_step(f: Mapping[str, Any]) -> Step:
    """Step "First Fourier coefficient of the nonsmooth term": ``a_1(a)`` in closed form."""
    a1 = f["fourier"]["a_1"]
    a1s = sp.Function("a_1")(f["amplitude"])
    closed, defs, domains = closed_form(a1)
    (closed,), defs = fold_mirror_angles((closed,), defs)
    return Step(
        "First Fourier coefficient of the nonsmooth term",
        (_eq(a1s, a1), _eq(a1s, closed), *(_eq(s_, e_) for s_, e_ in defs)),
        "The nonsmooth force under $x = a\\cos\\psi$ has the first Fourier coefficient "
        "$a_1(a)$, in closed form through the crossing angles (no Taylor series); its "
        "secular part at order 1 is $-a_1(a)\\,B/a$"
        + (
            ". Valid where " + ", ".join(f"${latex(d)}$" for d in domains) + "." if domains else "."
        ),
    )


def _order_step(f: Mapping[str, Any], c: _StepContext, nt: _Notation, k: int) -> Step:
    """Step "Order k": the right-hand side collected by mode, its secular coefficient set to
    zero (the modulation equation of order k) and, below the top order, ``y_k``."""
    nu, N = f["nu"], f["order"]
    q = (f["resonance"] or (1, 1))[1]
    B, Bbar = f["B"], f["Bbar"]
    Ts, Ds, ys, theta = nt.Ts, nt.Ds, nt.ys, nt.theta
    syms = [B, Bbar, *c.rest_syms]
    eng = c.engine
    Bfun = sp.Function("B")(*Ts[1:])
    S = eng.S[k]
    full = k <= _FULL_ORDERS
    modes = sorted(m for m in S if m >= 0) if full else [q]
    names = {m: sp.Symbol(f"S_{{{k},{m}}}") for m in modes}
    expo = {m: sp.exp(sp.I * sp.Rational(m, q) * theta) for m in modes}
    rhs_k = sp.Add(*(names[m] * expo[m] for m in modes)) + sp.Symbol("cc")
    if not full:
        rhs_k += sp.Symbol("NST")
    math_ = [_eq(Ds[0] ** 2 * ys[k] + nu**2 * ys[k], rhs_k)]
    for m in modes:
        coeff = _poly_expr(S.get(m, eng.R.zero), syms, nu**2)
        if m == q:
            coeff = -2 * sp.I * nu * sp.Derivative(Bfun, Ts[k]) + coeff
            if k == 1 and f["fourier"]:
                modulus = 2 * sp.sqrt(B * Bbar)
                coeff -= sp.Function("a_1")(modulus) * B / modulus
        math_.append(_eq(names[m], coeff))
    math_.append(_eq(sp.Derivative(Bfun, Ts[k]), f["complex_orders"][k - 1]))
    if k < N and full:
        y_k = sp.Add(
            *(
                names[m] * expo[m] / (nu**2 * (1 - sp.Rational(m * m, q * q)))
                for m in modes
                if m != q
            )
        )
        math_.append(_eq(ys[k], y_k + sp.Symbol("cc")))
    text = (
        "Lower-order derivatives of $B$ are replaced by their solvability conditions (chain "
        "rule). The coefficient of $e^{i\\theta}$ is secular; setting it to zero gives the "
        f"modulation equation at order ${k}$"
    )
    if k < N:
        text += f"; the other modes, divided by their distance from resonance, give $y_{k}$"
    if not full:
        text += "; the non-secular terms are not printed"
    return Step(f"Order {k}", tuple(math_), text + ".")


def _reconstituted_step(f: Mapping[str, Any]) -> Step:
    """Step "Modulation equation (reconstituted)": the solvability conditions summed."""
    eps, t = f["epsilon"], f["oscillator"].t
    dB = sp.Derivative(sp.Function("B")(t), t)
    return Step(
        "Modulation equation (reconstituted)",
        (_eq(dB, sp.Add(*(eps ** (k + 1) * g for k, g in enumerate(f["complex_orders"])))),),
        "The sum of the solvability conditions of all orders, in the original time.",
    )


def _polar_step(f: Mapping[str, Any], c: _StepContext) -> tuple[Step, list[sp.Expr]]:
    """Step "Slow flow, polar form" (``B = (a/2) e^{...}``); returns it and the two rates
    (by name ``f_k``, ``g_k`` above first order) that the steady-state step reuses."""
    t, eps, N = f["oscillator"].t, f["epsilon"], f["order"]
    p, q = f["resonance"] or (1, 1)
    a, phase, B = f["amplitude"], f["phase"], f["B"]
    if f["resonance"] is not None:
        polar_def = _eq(B, a / 2 * sp.exp(-sp.I * phase / p))
        lead = a * sp.cos(sp.Rational(q, p) * c.Omega * t - phase / p)
    else:
        polar_def = _eq(B, a / 2 * sp.exp(sp.I * phase))
        lead = a * sp.cos(f["omega0"] * t + phase)
    # at higher orders each order gets its own row (one line of a page each, at best)
    if N == 1:
        rates = list(f["polar"])
        rows: list[sp.Basic] = []
    else:
        names_a = [sp.Symbol(f"f_{k}") for k in range(1, N + 1)]
        names_g = [sp.Symbol(f"g_{k}") for k in range(1, N + 1)]
        rates = [
            sp.Add(*(eps ** (k + 1) * s_ for k, s_ in enumerate(names)))
            for names in (names_a, names_g)
        ]
        rows = [_eq(names_a[k], f["polar_orders"][k][0]) for k in range(N)]
        rows += [_eq(names_g[k], f["polar_orders"][k][1]) for k in range(N)]
    step = Step(
        "Slow flow, polar form",
        (
            polar_def,
            _eq(sp.Symbol("y_0"), lead),
            _eq(sp.Derivative(a, t), rates[0]),
            _eq(sp.Derivative(phase, t), rates[1]),
            *rows,
        ),
    )
    return step, rates


def _cartesian_step(f: Mapping[str, Any], nt: _Notation) -> Step:
    """Step "Slow flow, Cartesian form": ``B = (u - i v)/2``."""
    t, eps, N = f["oscillator"].t, f["epsilon"], f["order"]
    u, vv, B = f["u"], f["v"], f["B"]
    if N == 1:
        cart_rows = [
            _eq(sp.Derivative(w_, t), rate)
            for w_, rate in zip((u, vv), f["cartesian"], strict=True)
        ]
    else:
        names_u = [sp.Symbol(f"U_{k}") for k in range(1, N + 1)]
        names_v = [sp.Symbol(f"V_{k}") for k in range(1, N + 1)]
        cart_rows = [
            _eq(sp.Derivative(w_, t), sp.Add(*(eps ** (k + 1) * s_ for k, s_ in enumerate(nm))))
            for w_, nm in ((u, names_u), (vv, names_v))
        ]
        cart_rows += [_eq(names_u[k], f["cartesian_orders"][k][0]) for k in range(N)]
        cart_rows += [_eq(names_v[k], f["cartesian_orders"][k][1]) for k in range(N)]
    return Step(
        "Slow flow, Cartesian form",
        (
            _eq(B, (u - sp.I * vv) / 2),
            _eq(sp.Symbol("y_0"), u * sp.cos(nt.theta) + vv * sp.sin(nt.theta)),
            *cart_rows,
        ),
    )


def _steady_state_step(f: Mapping[str, Any], rates: list[sp.Expr]) -> Step:
    """Step "Steady states": fixed points (forced) or limit cycles, response, backbone."""
    steady: list[sp.Basic] = []
    if f["resonance"] is not None:
        steady += [_eq(rates[0], 0), _eq(rates[1], 0)]
        text = "Steady states are the fixed points of the slow flow"
        if f["response"] is not None and f["order"] == 1:
            steady.append(_eq(f["response"], 0))
            text += "; eliminating the phase gives the frequency-response equation"
        text += "."
    else:
        steady.append(_eq(rates[0], 0))
        text = (
            "Limit cycles are the roots of the amplitude equation; the oscillation frequency is "
            "$\\omega_0$ plus the phase rate there."
        )
    if f["backbone"] is not None:
        steady.append(_eq(real_symbol("omega"), f["backbone"]))
        text += " The backbone is the frequency of the free undamped oscillation."
    return Step("Steady states", tuple(steady), text)


def _stability_step(f: Mapping[str, Any]) -> Step:
    """Step "Stability": the slow-flow Jacobian (by name above first order)."""
    a, phase = f["amplitude"], f["phase"]
    if f["order"] == 1:
        J = sp.Matrix(f["polar"]).jacobian([a, phase])
    else:  # printed by name: the entries of a high-order Jacobian fill pages
        J = sp.Matrix(
            2,
            2,
            [sp.Derivative(e, s_, evaluate=False) for e in f["polar_names"] for s_ in (a, phase)],
        )
    return Step(
        "Stability",
        (_eq(sp.Symbol("J"), J),),
        "A steady state is asymptotically stable when both eigenvalues of the slow-flow "
        "Jacobian $J$ have negative real parts. A vanishing determinant marks a saddle-node "
        "bifurcation, a vertical tangent of the response curve; a vanishing trace with a "
        "positive determinant marks a Hopf bifurcation.",
    )


def _solution_step(f: Mapping[str, Any], c: _StepContext, nt: _Notation) -> Step:
    """Step "Approximate solution": the waveform (by orders ``y_k`` above first order)."""
    x, eps, N = f["oscillator"].x, f["epsilon"], f["order"]
    wave_rows: list[sp.Basic] = []
    if N == 1:
        wave_rows.append(_eq(x, f["waveform"]))
    else:
        xp_part = f["waveform"] - sp.Add(*(eps**k * part for k, part in enumerate(c.wave_parts)))
        wave_rows.append(_eq(x, xp_part + sp.Add(*(eps**k * nt.ys[k] for k in range(N)))))
        wave_rows += [_eq(nt.ys[k], part) for k, part in enumerate(c.wave_parts)]
    return Step(
        "Approximate solution",
        tuple(wave_rows),
        ("With $\\tau = \\Omega t$" if f["resonance"] is not None else "With $\\tau = \\omega t$")
        + f", through order ${N - 1}$ in the expansion of $x$.",
    )


# ------------------------------------------------------------------- transition curves --
def transition_curves(
    oscillator: Oscillator,
    n: int = 1,
    order: int = 2,
    *,
    parameter: str | None = None,
    epsilon: str | None = None,
) -> tuple[sp.Expr, ...]:
    r"""Transition curves :math:`\delta(\varepsilon)` of a linear parametrically excited
    oscillator near the :math:`n`-th resonance :math:`\omega_0 = n\Omega/2`.

    For ``x'' + c x' + (delta + eps P(t)) x = 0`` (``P`` periodic with base frequency
    :math:`\Omega`) the curves bound the regions where the trivial solution is unstable; on
    them a solution of period :math:`2\pi/\Omega` or :math:`4\pi/\Omega` exists.

    Method (:math:`n \ge 1`): multiple scales to order ``order`` with the stiffness detuning
    :math:`\delta = \omega_r^2 - \varepsilon\Delta`, :math:`\omega_r = n\Omega/2`. The slow flow is
    linear, :math:`(\dot u, \dot v) = M(\Delta, \varepsilon)(u, v)`, and a transition is a zero
    eigenvalue: :math:`\det M = 0`. With :math:`\Delta = d_1 + \varepsilon d_2 + \dots`, the
    coefficients of :math:`\det M` in powers of :math:`\varepsilon` are solved one after the
    other (the lowest non-vanishing one fixes the next :math:`d_j`; a double root, as at
    :math:`n = 2`, defers the split to a higher power). Result through :math:`\varepsilon^N`.

    For :math:`n = 0` the multiple-scales ansatz degenerates (:math:`\omega_0 = 0`: the
    amplitude obeys a second-order slow equation); the curve is then found from the
    periodicity of :math:`x = 1 + \varepsilon x_1 + \dots` with
    :math:`\delta = \varepsilon d_1 + \varepsilon^2 d_2 + \dots` (no damping allowed).

    Parameters
    ----------
    oscillator
        A linear model with a parametric term and no forcing.
    n
        Resonance index, ``delta ~ (n Omega/2)**2``.
    order
        :math:`N`: the curves are returned through :math:`\varepsilon^N`.
    parameter
        The stiffness parameter :math:`\delta` (default: the linear stiffness when it is a
        single symbol).
    epsilon
        The model's bookkeeping parameter, or None to scale the parametric term (and damping)
        by a fresh :math:`\varepsilon` set to 1 in the result.

    Returns
    -------
    tuple of sympy expressions
        :math:`\delta(\varepsilon)` for each curve, in increasing order for small
        :math:`\varepsilon`.

    Examples
    --------
    ``x'' + (delta + 2*eps*cos(2*t))*x = 0`` with ``epsilon="eps"``: ``n = 1, order = 3`` gives
    :math:`1 - \varepsilon - \varepsilon^2/8 + \varepsilon^3/64` and
    :math:`1 + \varepsilon - \varepsilon^2/8 - \varepsilon^3/64`.
    """
    osc = oscillator
    if isinstance(n, bool) or not isinstance(n, int) or n < 0:
        raise ParameterError(f"n = {n!r}: expected an integer >= 0")
    if isinstance(order, bool) or not isinstance(order, int) or order < 1:
        raise ParameterError(f"order = {order!r}: expected an integer >= 1")
    free, delta, named, stiffness = _transition_model(osc, parameter, epsilon)
    if n == 0:
        return _transition_n0(free, delta, named, order)
    p, q = 2, n
    g = math.gcd(p, q)
    mod = _derive(free, order, (p // g, q // g), epsilon, "stiffness", None)
    eps = mod.epsilon
    M = sp.Matrix(mod.cartesian).jacobian([mod.u, mod.v])
    if M.has(mod.u, mod.v):
        raise PerturbError("internal: the slow flow of a linear model is not linear")
    ds = sp.symbols(f"d_1:{order + 1}")
    series = sp.Add(*(eps**j * ds[j] for j in range(order)))
    branches = _transition_branches(M.xreplace({mod.sigma: series}), eps, ds, order)
    rhs = mod.nu**2 - eps * series
    curves = []
    for br in branches:
        poly = sp.Poly(sp.expand(stiffness - rhs.xreplace(br)), delta)
        if poly.degree() != 1:
            raise PerturbError(f"cannot solve {stiffness} = {rhs} for {delta}: not linear")
        c1, c0 = poly.all_coeffs()
        expr = sp.expand(-c0 / c1)
        if named is None:
            expr = sp.expand(expr.xreplace({eps: 1}))
        curves.append(expr)
    return _sorted_curves(curves, named or eps)


def _transition_model(
    osc: Oscillator, parameter: str | None, epsilon: str | None
) -> tuple[Oscillator, sp.Symbol, sp.Symbol | None, sp.Expr]:
    """Check the model is linear, unforced and parametric; return it with the stiffness
    parameter delta (and the named epsilon) left free, delta, the named epsilon and the
    stiffness at epsilon = 0."""
    nonlinear = [
        (label, val)
        for label, val in (
            ("polynomial", osc.polynomial),
            ("nonsmooth", osc.nonsmooth),
            ("smooth", osc.smooth),
            ("velocity", osc.velocity),
        )
        if val != 0
    ]
    if nonlinear or not osc.forcing.is_zero or osc.parametric == 0:
        raise ModelError(
            f"transition curves need a linear, unforced model with a parametric term; model "
            f"{osc.name!r} has "
            + (
                ", ".join(f"{lab} terms {val}" for lab, val in nonlinear)
                or ("forcing" if not osc.forcing.is_zero else "no parametric term")
            )
        )
    stiffness = osc.linear_stiffness
    named = real_symbol(epsilon) if epsilon is not None else None
    if named is not None:
        if epsilon not in osc.params:
            raise ParameterError(f"epsilon = {epsilon!r} is not a parameter of model {osc.name!r}")
        stiffness = stiffness.subs(named, 0)
    if parameter is None:
        if not isinstance(stiffness, sp.Symbol):
            raise ParameterError(
                f"the linear stiffness {stiffness} of model {osc.name!r} is not a single "
                "parameter: name the parameter to solve for"
            )
        delta = stiffness
    else:
        if parameter not in osc.params:
            raise ParameterError(
                f"parameter {parameter!r} is not a parameter of model {osc.name!r}"
            )
        delta = real_symbol(parameter)
    free = osc.with_params({name: None for name in (delta.name, epsilon) if name})
    return free, delta, named, stiffness


def _transition_branches(
    sub: sp.Matrix, eps: sp.Symbol, ds: Sequence[sp.Symbol], order: int
) -> list[dict[sp.Symbol, sp.Expr]]:
    """Solve det M(Delta = d_1 + eps d_2 + ...) = 0 power by power of eps: the lowest
    non-vanishing coefficient fixes the next d_j on each branch (a double root defers the
    split to a higher power; an inconsistent branch is dropped)."""
    num = sp.expand(sub[0, 0] * sub[1, 1] - sub[0, 1] * sub[1, 0])
    top = 2 * order + 3
    coeffs = [sp.expand(num.coeff(eps, k)) for k in range(top + 1)]
    branches: list[dict[sp.Symbol, sp.Expr]] = [{}]
    for j in range(order):
        new: list[dict[sp.Symbol, sp.Expr]] = []
        for br in branches:
            for ck in coeffs:
                ck = sp.expand(ck.xreplace(br))
                if ck == 0:
                    continue
                unknown = sorted(ck.free_symbols & set(ds), key=lambda s: s.name)
                if not unknown:
                    break  # inconsistent: this branch is not a transition curve
                if unknown != [ds[j]]:
                    raise PerturbError(
                        f"transition curve: the coefficient {ck} involves {unknown}; the "
                        "order-by-order solution is ambiguous here"
                    )
                for root in sp.roots(sp.Poly(ck, ds[j])):
                    if root.is_real is not False:
                        new.append({**br, ds[j]: sp.nsimplify(root)})
                break
        branches = new
    return branches


def _sorted_curves(curves: list[sp.Expr], eps: sp.Symbol) -> tuple[sp.Expr, ...]:
    unique = []
    for c in curves:
        if not any(sp.expand(c - u) == 0 for u in unique):
            unique.append(c)

    def key(c: sp.Expr) -> tuple:
        poly = sp.Poly(c, eps) if c.is_polynomial(eps) else None
        if poly is None:
            return (0,)
        out = []
        for k in range(poly.degree() + 1):
            val = poly.coeff_monomial(eps**k)
            out.append(float(val) if val.is_number else 0.0)
        return tuple(out)

    return tuple(sorted(unique, key=key))


def _transition_n0(
    osc: Oscillator, delta: sp.Symbol, named: sp.Symbol | None, order: int
) -> tuple[sp.Expr, ...]:
    """``n = 0``: periodic expansion about the constant solution (see transition_curves)."""
    from perturb.fourier.trig import harmonics

    x, t = osc.x, osc.t
    eps = named if named is not None else sp.Symbol("epsilon", positive=True)
    if osc.damping != 0:
        raise ModelError("the n = 0 transition curve is provided for undamped models only")
    stiffness = sp.expand(osc.linear_stiffness - delta)
    if named is not None:
        stiffness = stiffness.subs(named, 0)
    if stiffness != 0:
        raise ModelError(
            f"n = 0 needs the linear stiffness to be exactly {delta} (plus eps terms); model "
            f"{osc.name!r} has {osc.linear_stiffness}"
        )
    parametric = _eps_split(-osc.parametric / x, named, "parametric")
    extra = _eps_split(sp.expand(-(osc.linear_stiffness - delta)), named, "linear stiffness")
    for k, c in extra.items():
        parametric[k] = parametric.get(k, 0) + c
    if 0 in parametric:
        raise ModelError("the parametric term must be of order epsilon")
    if parametric and any(sp.expand(c).has(x, osc.v) for c in parametric.values()):
        raise ModelError("the parametric term must be linear in x and free of x'")
    freqs = [
        _split_arg(f.args[0], t)[0]
        for c in parametric.values()
        for f in sp.sympify(c).atoms(sp.cos, sp.sin)
    ]
    base = _base_frequency(freqs)
    psi = sp.Dummy("psi", real=True)
    P = {k: sp.expand(sp.sympify(c).subs(t, psi / base)) for k, c in parametric.items()}
    d = sp.Symbol("d", real=True)  # real: the harmonic split takes real parts
    found: list[sp.Expr] = []
    xs: list[sp.Expr] = [sp.Integer(1)]
    for k in range(1, order + 1):
        # x_k'' = -sum_j d_j x_{k-j} + sum_m P_m x_{k-m}  (d_k unknown, the others known)
        ds = [*found, d]
        rhs = -sp.Add(*(ds[j - 1] * xs[k - j] for j in range(1, k + 1)))
        rhs += sp.Add(*(P[m] * xs[k - m] for m in P if m <= k))
        parts = harmonics(sp.expand(rhs), psi)
        mean = parts.get(0, (sp.Integer(0), 0))[0]
        sol = sp.solve(mean, d)
        if len(sol) != 1:
            raise PerturbError(f"n = 0 transition curve: cannot solve {mean} = 0 for d_{k}")
        found.append(sol[0])
        xs.append(
            sp.Add(
                *(
                    -(c.subs(d, sol[0]) * sp.cos(m * psi) + s_.subs(d, sol[0]) * sp.sin(m * psi))
                    / (m * base) ** 2
                    for m, (c, s_) in parts.items()
                    if m
                )
            )
        )
    ds = found
    curve = sp.expand(sp.Add(*(eps ** (j + 1) * ds[j] for j in range(order))))
    if named is None:
        curve = sp.expand(curve.xreplace({eps: 1}))
    return (curve,)
