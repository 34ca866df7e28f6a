r"""Lindstedt–Poincaré (``lp``) and modified Lindstedt–Poincaré (``mlp``) expansions of a
nonlinear normal mode (NNM) of a conservative system of two coordinates: its backbone.

The system (:class:`~perturb.model.system.System`, no damping, no forcing)

.. math::

    M q'' + K q + \sum_e w_e f_e(c_e\cdot q) = 0

is split about a reference linear stiffness: the linear part of each polynomial element, the
mean of the two outer slopes of each piecewise-linear one (as the SDOF engines do), so that

.. math::

    M q'' + \bar K q + \varepsilon\, g(q) = 0, \qquad
    g(q) = \sum_e w_e\, g_e(c_e\cdot q),

with the bookkeeping parameter :math:`\varepsilon` set to one at the end. The M-orthonormal
eigenvectors of :math:`\bar K` (:math:`\Phi^T M\Phi = I`, :math:`\Phi^T\bar K\Phi =
\mathrm{diag}(\omega_1^2, \omega_2^2)`) give the modal equations, :math:`q = \Phi u`,

.. math::

    u'' + \Lambda u + \varepsilon\, n(u) = 0, \qquad n(u) = \Phi^T g(\Phi u).

The NNM continuing linear mode :math:`j` (the other one is :math:`k`) is periodic with an
unknown frequency; with :math:`\tau = \omega t` and :math:`u_j = A\cos\tau + \dots`,
:math:`u_k = O(\varepsilon)`:

``lp``
    :math:`\omega = \omega_j + \varepsilon\omega_1 + \varepsilon^2\omega_2 + \dots`,
    :math:`u = u_0 + \varepsilon u_1 + \dots`, :math:`u_0 = A\cos\tau\, e_j`. At order
    :math:`\varepsilon^n`, :math:`\omega_j^2 u_n'' + \Lambda u_n = -\sum_{i\ge1} W_i
    u_{n-i}'' - [\varepsilon^{n-1}]\, n(u)`, :math:`W_i = \sum_{p+q=i}\omega_p\omega_q`. The
    coefficient of :math:`\cos\tau` in mode :math:`j`'s equation must vanish (no secular
    term), which gives :math:`\omega_n`; mode :math:`k`'s harmonic :math:`m` is divided by
    :math:`\omega_k^2 - m^2\omega_j^2`.
``mlp``
    Cheung, Chen & Lau's :math:`\alpha`-transformation as in
    :mod:`perturb.methods.modified_lindstedt`: :math:`\omega^2 = \omega_j^2(1 +
    \delta_2\alpha^2 + \dots)/(1 - \alpha)`, :math:`\alpha = \nu/(\omega_j^2 + \nu)`, and the
    modal equations divided by :math:`\omega^2` are linear in :math:`\alpha` apart from the
    :math:`\delta_n`,

    .. math::

        (1 + \delta_2\alpha^2 + \dots)\, u'' + R u + \alpha\Big[-R u + \frac{n(u)}{\nu}\Big] = 0,
        \qquad R = \Lambda/\omega_j^2,

    solved with :math:`u = \sum\alpha^n u_n`; order 1 gives :math:`\nu = \hat n_{j,1}/A` (the
    first harmonic of mode :math:`j`'s force along :math:`u_0`), order :math:`n \ge 2` gives
    :math:`\delta_n`; mode :math:`k`'s harmonic :math:`m` is divided by :math:`r^2 - m^2`,
    :math:`r = \omega_k/\omega_j`.

Both keep :math:`A` the amplitude of the first harmonic of :math:`u_j` (every correction of
:math:`u_j` is free of :math:`\cos\tau`). Polynomial elements: any order up to
:data:`MAX_ORDER`. Piecewise-linear elements (Heaviside, Max, Min, Abs: the ``nsd2`` device)
enter at first order only, through the closed-form Fourier coefficients of
:mod:`perturb.fourier.symbols` of :math:`g_e(S\cos\tau)`, :math:`S = (c_e\cdot\varphi_j) A`
(ramp coefficients :math:`a^R_n` and step coefficients :math:`a^H_n = 2\sin n\theta/(n\pi)`
with :math:`\theta = \arccos(d/S)` for a switching point :math:`d`; for the ``nsd`` device
:math:`g_e = (k - 1)\,\mathrm{sat}(s)`, odd, so only odd harmonics enter; the derivation
prints the first harmonic in its :math:`\theta`-form). Switching points and reference slopes
take the parameter values. The second order would need products of the truncated series and
Dirac coefficients at the switches, and is refused.

Internal resonance: when :math:`\omega_k = m\,\omega_j` for a harmonic :math:`m` that the
nonlinear force of mode :math:`k` contains, the correction of mode :math:`k` has a vanishing
denominator and the NNM is not a continuation of one linear mode; the engine refuses with
:class:`InternalResonanceError` naming :math:`m` and the frequencies. Near such a ratio the
expansion holds only while the frequency shift is small compared with the detuning, which
the result's ``notes`` state.

Why not :class:`~perturb.approximation.Approximation`: that contract holds one oscillator and
one scalar waveform; an NNM needs the system, the modal matrix and one waveform per
coordinate. :class:`NNMBackbone` holds those, with ``steps`` in the same ``(title, math,
text)`` form, so that :func:`perturb.report.latex.derivation_body` writes the derivation.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import numpy as np
import sympy as sp

from perturb.approximation import Step
from perturb.errors import ModelError, NonsmoothError, ParameterError, PerturbError
from perturb.fourier.symbols import (
    NUMERIC_IMPLEMENTATIONS,
    DiracCoefficient,
    RampCoefficient,
    StepCoefficient,
    series_coefficient,
)
from perturb.methods.series import closed_form_step, equation
from perturb.methods.series import derivation_step as _series_step
from perturb.model.parsing import real_symbol
from perturb.model.pwl import to_pwl
from perturb.model.system import S as ELEMENT_SYMBOL
from perturb.model.system import System

__all__ = [
    "METHODS",
    "MAX_ORDER",
    "PWL_ORDER",
    "InternalResonanceError",
    "NNMBackbone",
    "nnm_backbone",
]

#: The expansions offered.
METHODS = ("lp", "mlp")
#: Highest order for polynomial elements (each order multiplies the size of the expressions;
#: order 4 of the cubic spring to ground takes 0.4 s (L-P) and 1.3 s (mLP) of CPU).
MAX_ORDER = 4
#: Highest order for piecewise-linear elements (first order: the closed-form coefficients).
PWL_ORDER = 1
#: Highest harmonic kept in the waveform of a piecewise-linear element (its force has every odd
#: harmonic; the backbone at first order needs the first only).
DEFAULT_HARMONICS = 7
#: |omega_k**2 - m**2 omega_j**2| below this fraction of omega_k**2 is a resonance (refused);
#: below NEAR_RESONANCE a small divisor (stated in the notes).
RESONANCE_TOL = 1e-9
NEAR_RESONANCE = 0.1
#: Exact modal data longer than this (SymPy operation count per entry) is written in floating
#: point with DIGITS significant digits.
EXACT_OPS = 8
DIGITS = 15

_COEFFS = (StepCoefficient, RampCoefficient, DiracCoefficient)

Trig = dict[int, sp.Expr]  # {m: coefficient of cos(m tau)}, m >= 0 (m = 0: the mean)


class InternalResonanceError(ModelError):
    """The two linear frequencies are commensurate, ``omega_k = m omega_j``, with a harmonic
    ``m`` that the nonlinear force of mode ``k`` contains: the NNM does not continue one
    linear mode and a denominator of the expansion vanishes."""


# ----------------------------------------------------------------------------- the result --
@dataclass(frozen=True)
class NNMBackbone:
    """The L-P or mLP expansion of one nonlinear normal mode of a conservative 2-coordinate
    system (immutable, printable).

    Attributes
    ----------
    system
        The system expanded (parameter values as given).
    method
        ``"lp"`` or ``"mlp"``.
    mode
        1 or 2: the linear mode the NNM continues (modes numbered by increasing frequency).
    order
        Highest power of the expansion parameter kept.
    coordinates
        Names of the two coordinates.
    reference_stiffness
        :math:`\\bar K`: ``K`` plus the reference slopes of the elements.
    mass
        ``M`` (values substituted).
    natural_frequencies
        :math:`(\\omega_1, \\omega_2)` of :math:`(M, \\bar K)`, increasing.
    modal_matrix
        :math:`\\Phi`: M-orthonormal eigenvectors as columns (first nonzero entry positive).
    amplitude, tau, frequency
        ``A`` (first-harmonic amplitude of the modal coordinate ``u_mode``), ``tau = omega t``
        and ``omega``.
    corrections
        ``lp``: ``omega_0 .. omega_N`` (``omega = sum``); ``mlp``: ``nu``, ``alpha`` and
        ``delta_2 .. delta_N`` in ``A`` (``omega**2 = (omega_j**2 + nu)(1 + sum delta_n
        alpha**n)``).
    backbone
        :math:`\\omega(A)` in closed form (the bookkeeping parameter set to one).
    modal_waveforms
        :math:`u_1(\\tau), u_2(\\tau)`.
    waveforms
        :math:`q_i(\\tau) = (\\Phi u)_i` per coordinate.
    parameters
        The symbols besides ``A`` and ``tau`` in the expressions (kept symbolic: they appear
        only in the nonlinear elements); ``values`` their values from the system (or None).
    resonance_denominators
        ``(m, omega_k**2 - m**2 omega_j**2)`` for every harmonic ``m`` the other mode meets.
    steps, notes
        The derivation (title, mathematics, sentence) and caveats, including where the
        expansion is invalid.
    """

    system: System
    method: str
    mode: int
    order: int
    options: Mapping[str, Any]
    coordinates: tuple[str, ...]
    mass: sp.ImmutableMatrix
    reference_stiffness: sp.ImmutableMatrix
    natural_frequencies: tuple[sp.Expr, sp.Expr]
    modal_matrix: sp.ImmutableMatrix
    amplitude: sp.Symbol
    tau: sp.Symbol
    frequency: sp.Symbol
    corrections: Mapping[str, sp.Expr]
    backbone: sp.Expr
    modal_waveforms: tuple[sp.Expr, sp.Expr]
    waveforms: tuple[sp.Expr, sp.Expr]
    parameters: tuple[sp.Symbol, ...]
    values: Mapping[str, float | None]
    resonance_denominators: tuple[tuple[int, sp.Expr], ...] = ()
    steps: tuple[Step, ...] = ()
    notes: tuple[str, ...] = ()
    _numeric: dict = field(default_factory=dict, compare=False, repr=False, hash=False)

    @property
    def label(self) -> str:
        return f"{self.method}(mode={self.mode}, order={self.order})"

    def _compiled(self, what: str, expr: sp.Expr):
        if what not in self._numeric:
            missing = [p.name for p in self.parameters if self.values.get(p.name) is None]
            if missing:
                raise ParameterError(
                    f"system {self.system.name!r} needs values for {', '.join(missing)} to "
                    "evaluate the backbone numerically: pass them with with_params(...)"
                )
            reps = {p: sp.Float(self.values[p.name]) for p in self.parameters}
            self._numeric[what] = sp.lambdify(
                (self.amplitude, self.tau),
                expr.xreplace(reps),
                modules=[NUMERIC_IMPLEMENTATIONS, "numpy"],
            )
        return self._numeric[what]

    def frequency_at(self, A: Any, *, invalid: str = "raise") -> np.ndarray:
        """:math:`\\omega(A)` in numbers (parameters at the system's values); ``A`` the modal
        first-harmonic amplitude, scalar or array.

        Where the expansion gives no real positive frequency (an mLP :math:`\\omega^2 < 0`,
        an L-P :math:`\\omega \\le 0`: e.g. the negative-stiffness device at small
        amplitude, whose equilibrium at rest is unstable), ``invalid="raise"`` raises
        :class:`~perturb.errors.ParameterError` naming the first such amplitude and
        ``invalid="nan"`` returns NaN there.
        """
        if invalid not in ("raise", "nan"):
            raise ParameterError(f"invalid = {invalid!r}: expected 'raise' or 'nan'")
        A = _finite_array(A, "A", nonnegative=True)
        f = self._compiled("omega", self.backbone)
        with np.errstate(invalid="ignore"):
            out = np.broadcast_to(np.asarray(f(A, 0.0), dtype=float), A.shape).copy()
        bad = ~np.isfinite(out) | (out <= 0)
        if np.any(bad):
            if invalid == "raise":
                first = float(np.ravel(A)[np.argmax(np.ravel(bad))])
                raise ParameterError(
                    f"the {self.method} backbone of mode {self.mode} has no real positive "
                    f"frequency at A = {first:g} (the expansion does not hold there; pass "
                    "invalid='nan' to get NaN)"
                )
            out[bad] = np.nan
        return out

    def displacement_at(self, A: Any, tau: Any = 0.0) -> np.ndarray:
        """``q(tau)`` in numbers, shape ``(2,) + broadcast(A, tau).shape``; at ``tau = 0`` the
        turning point (all velocities vanish there). ``A >= 0`` and ``tau`` finite numbers
        (ParameterError otherwise)."""
        A = _finite_array(A, "A", nonnegative=True)
        tau = _finite_array(tau, "tau")
        try:
            A, tau = np.broadcast_arrays(A, tau)
        except ValueError:
            raise ParameterError(
                f"A of shape {A.shape} and tau of shape {tau.shape}: expected shapes that "
                "broadcast together"
            ) from None
        rows = []
        for i, w in enumerate(self.waveforms):
            f = self._compiled(f"q{i}", w)
            rows.append(np.broadcast_to(np.asarray(f(A, tau), dtype=float), A.shape))
        return np.array(rows)

    def __str__(self) -> str:
        om = [sp.sstr(w) for w in self.natural_frequencies]
        lines = [
            f"NNM backbone by {self.label} of system {self.system.name!r}",
            f"  linear frequencies: omega_1 = {om[0]}, omega_2 = {om[1]}",
            f"  modal matrix: {sp.sstr(self.modal_matrix.tolist())}",
        ]
        for k, v in self.corrections.items():
            lines.append(f"  {k} = {_clip(v)}")
        lines.append(f"  {self.frequency}(A) = {_clip(self.backbone)}")
        for name, w in zip(self.coordinates, self.waveforms, strict=True):
            lines.append(f"  {name}({self.tau}) = {_clip(w)}")
        lines += [f"  note: {n}" for n in self.notes]
        return "\n".join(lines)


def _finite_array(value: Any, what: str, nonnegative: bool = False) -> np.ndarray:
    """``value`` (numbers, not text) as a float array of finite entries (``>= 0`` with
    ``nonnegative``).

    Raises
    ------
    ParameterError
        Naming ``what`` and the value given.
    """
    expected = "finite numbers" + (" >= 0" if nonnegative else "")
    arr = None
    if not isinstance(value, str | bytes | bool) and value is not None:
        try:
            arr = np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            arr = None
        if arr is not None and arr.dtype.kind != "f":  # pragma: no cover - defensive
            arr = None
    if arr is None or not np.all(np.isfinite(arr)) or (nonnegative and np.any(arr < 0)):
        raise ParameterError(f"{what} = {value!r}: expected {expected}")
    return arr


def _clip(expr: Any, width: int = 240) -> str:
    text = sp.sstr(expr)
    return text if len(text) <= width else text[: width - 3] + "..."


#: Significant digits of floating-point numbers in the derivation text.
TEXT_DIGITS = 6


def derivation_step(title: str, math=(), text: str = "") -> Step:
    """A derivation step whose floating-point numbers are written to :data:`TEXT_DIGITS`
    significant digits (the result's fields keep full precision)."""
    rounded = []
    for m in math:
        floats = m.atoms(sp.Float) if isinstance(m, sp.Basic) else set()
        if floats:
            reps = {f: sp.Float(f, TEXT_DIGITS) for f in floats}
            # an Equality rebuilt by xreplace would be evaluated (a matrix side gives False)
            if isinstance(m, sp.Equality):
                m = equation(m.lhs.xreplace(reps), m.rhs.xreplace(reps))
            else:
                m = m.xreplace(reps)
        rounded.append(m)
    return _series_step(title, rounded, text)


# -------------------------------------------------------------------- trigonometric series --
def _chop(expr: sp.Expr) -> sp.Expr:
    """Rounding residue of floating-point modal data (terms that cancel exactly) removed."""
    small = {f: sp.S.Zero for f in expr.atoms(sp.Float) if abs(f) < 1e-12}
    return expr.xreplace(small) if small else expr


def _canon(expr: sp.Expr) -> sp.Expr:
    """One form for a number built from the modal matrix (so that equal coefficient-function
    arguments are equal expressions)."""
    expr = sp.expand(expr)
    return expr if expr.has(sp.Float) else sp.radsimp(sp.simplify(expr))


def _factor(expr: sp.Expr) -> sp.Expr:
    """Factored for the text when exact (SymPy's factor of floating-point coefficients
    writes spurious rational approximations)."""
    if expr.has(sp.Float):
        return expr
    return sp.factor(expr)


def _t_add(*terms: tuple[Any, Trig]) -> Trig:
    out: dict[int, sp.Expr] = {}
    for c, ser in terms:
        for m, v in ser.items():
            out[m] = out.get(m, sp.S.Zero) + c * v
    return {m: v for m, v in out.items() if v != 0}


def _t_mul(a: Trig, b: Trig) -> Trig:
    """cos(p) cos(q) = (cos(p + q) + cos(p - q))/2 (also right for the mean, p = 0)."""
    out: dict[int, sp.Expr] = {}
    for p, ca in a.items():
        for q, cb in b.items():
            half = ca * cb / 2
            out[p + q] = out.get(p + q, sp.S.Zero) + half
            out[abs(p - q)] = out.get(abs(p - q), sp.S.Zero) + half
    out = {m: _chop(sp.expand(v)) for m, v in out.items()}
    return {m: v for m, v in out.items() if v != 0}


def _t_dd(a: Trig) -> Trig:
    """Second derivative in tau."""
    return {m: -(m**2) * v for m, v in a.items() if m}


def _t_expr(a: Trig, tau: sp.Symbol, tidy: bool = True) -> sp.Expr:
    """The series as an expression, one term per harmonic with its coefficient factored."""
    terms = []
    for m in sorted(a):
        c = _factor(a[m]) if tidy and not a[m].has(*_COEFFS) else a[m]
        # the printer writes each coefficient before its harmonic and groups by harmonic
        terms.append(c if m == 0 else c * sp.cos(m * tau))
    return sp.Add(*terms) if terms else sp.S.Zero


_EpsSeries = list[Trig]  # index: power of the expansion parameter


def _e_mul(a: _EpsSeries, b: _EpsSeries, P: int) -> _EpsSeries:
    out: _EpsSeries = [{} for _ in range(P)]
    for i, ai in enumerate(a[:P]):
        for k, bk in enumerate(b[: P - i]):
            if ai and bk:
                out[i + k] = _t_add((1, out[i + k]), (1, _t_mul(ai, bk)))
    return out


# ------------------------------------------------------------------------------- the model --
@dataclass
class _Element:
    """One element after the split: ``w g(c.q)`` with ``g`` polynomial or piecewise linear."""

    name: str
    c: tuple[sp.Expr, sp.Expr]
    w: tuple[sp.Expr, sp.Expr]
    g: sp.Expr  # in ELEMENT_SYMBOL
    pwl: bool
    slope: sp.Expr


@dataclass
class _Model:
    system: System
    names: tuple[str, str]
    q: tuple[sp.Symbol, sp.Symbol]
    M: sp.Matrix
    Kbar: sp.Matrix
    K: sp.Matrix
    elements: list[_Element]
    smooth: sp.Matrix  # polynomial forces of several coordinates (combination None)
    reps: dict[sp.Symbol, sp.Expr]  # parameter values substituted (those of M, K)
    pwl: bool


def _vanishes(expr: sp.Expr, values: Mapping[sp.Symbol, Any]) -> bool:
    e = sp.sympify(expr).xreplace(values)
    # Float(0.0) == 0 is False in SymPy >= 1.13: ask is_zero
    return bool(e.is_zero) or bool(sp.simplify(e).is_zero)


def _exact(value: float) -> sp.Expr:
    return sp.nsimplify(value, rational=True)


def _model(system: System) -> _Model:
    """Check that ``system`` is conservative with two coordinates and elements the engine
    expands, and split its stiffness about the reference slopes of the elements."""
    if not isinstance(system, System):
        raise ModelError(
            f"system = {system!r}: expected a perturb.model.system.System (two coordinates)"
        )
    if len(system.coordinates) != 2 or system.first_order:
        raise ModelError(
            f"system {system.name!r} has {len(system.coordinates)} second-order coordinate(s) "
            f"({', '.join(system.coordinates)}) and {len(system.first_order)} first-order "
            "state(s): the NNM backbone engine expects exactly 2 second-order coordinates"
        )
    given = {real_symbol(k): v for k, v in system.params.items() if v is not None}
    num = {s: sp.Float(v) for s, v in given.items()}
    for i in range(2):
        for jj in range(2):
            if not _vanishes(system.C[i, jj], num):
                raise ModelError(
                    f"system {system.name!r} has damping C[{i + 1},{jj + 1}] = "
                    f"{system.C[i, jj]}: an NNM backbone needs a conservative system (give the "
                    "damping parameters the value 0)"
                )
    for i, f in enumerate(system.F):
        if not _vanishes(f, num):
            raise ModelError(
                f"system {system.name!r} is forced: F[{i + 1}] = {f} (expected no forcing for "
                "a free conservative NNM; give the forcing amplitude the value 0)"
            )
    # the values of the parameters of the linear part are substituted (exactly) so that the
    # modal matrix is readable; parameters only in the elements stay symbolic
    linear_syms = (system.M.free_symbols | system.K.free_symbols) - {system.t}
    free = sorted(s.name for s in linear_syms if s not in given)
    if free:
        # a symbolic eigenproblem gives nested radicals SymPy cannot simplify in bounded time
        raise ParameterError(
            f"system {system.name!r}: the linear part (M, K) has parameters without values "
            f"({', '.join(free)}): give them values (with_params); parameters that appear only "
            "in the nonlinear elements may stay symbolic"
        )
    reps = {s: _exact(given[s]) for s in linear_syms}
    M = sp.Matrix(system.M.xreplace(reps))
    K = sp.Matrix(system.K.xreplace(reps))
    if M != M.T or sp.simplify(K - K.T) != sp.zeros(2, 2):
        raise ModelError(
            f"system {system.name!r}: M = {M.tolist()} and K = {K.tolist()} must be symmetric "
            "for a conservative system"
        )
    q = (real_symbol(system.coordinates[0]), real_symbol(system.coordinates[1]))
    # the reference stiffness takes the elements' reference slopes: their parameters (a
    # contact stiffness r of a gap) join the substituted ones, and the elements are split again
    for _ in range(2):
        Kbar, elements, smooth = _split_elements(system, K, q, reps)
        extra = Kbar.free_symbols - set(reps)
        if not extra:
            break
        free = sorted(x.name for x in extra if x not in given)
        if free:
            raise ParameterError(
                f"system {system.name!r}: the reference stiffness {Kbar.tolist()} has "
                f"parameters without values ({', '.join(free)}): give them values"
            )
        reps.update({x: _exact(given[x]) for x in extra})
    Kbar = sp.Matrix(Kbar.applyfunc(sp.nsimplify))
    if smooth != sp.zeros(2, 1):
        jac = smooth.jacobian(sp.Matrix(q))
        if sp.simplify(jac - jac.T) != sp.zeros(2, 2):
            raise ModelError(
                f"the smooth forces {list(smooth)} of system {system.name!r} are not the "
                "gradient of a potential (their Jacobian is not symmetric): not conservative"
            )
    return _Model(
        system=system,
        names=(system.coordinates[0], system.coordinates[1]),
        q=q,
        M=M,
        Kbar=Kbar,
        K=K,
        elements=elements,
        smooth=smooth,
        reps=reps,
        pwl=any(el.pwl for el in elements),
    )


def _split_elements(system: System, K: sp.Matrix, q, reps):
    """``(Kbar, elements, smooth)``: the elements split at the parameter values ``reps``."""
    Kbar = sp.Matrix(K)
    elements: list[_Element] = []
    smooth = sp.zeros(2, 1)
    for e in system.elements:
        split = _element(system, e, q, reps)
        if isinstance(split, _Element):
            Kbar += split.slope * sp.Matrix(split.w) * sp.Matrix(split.c).T
            elements.append(split)
        else:
            lin, rest = split
            Kbar += lin
            smooth += rest
    return Kbar, elements, smooth


def _element(system: System, e, q, reps):
    """An element split into its reference slope and remainder (``_Element``), or a smooth
    force of several coordinates as ``(linear part matrix, remainder vector)``."""
    n = len(system.coordinates)
    if e.kind in ("stop", "friction"):
        raise ModelError(
            f"element {e.name!r} of system {system.name!r} is a {e.kind}: the NNM backbone "
            "engine expands smooth polynomial and piecewise-linear springs only (impacts and "
            "friction are not conservative forces of the position)"
        )
    w = tuple(sp.sympify(v).xreplace(reps) for v in e.distribution)
    if e.combination is None:
        vec = sp.Matrix([w[i] * e.function.xreplace(reps) for i in range(2)])
        bad = vec.free_symbols & {real_symbol(s) for s in system.state_names[n:]}
        if bad:
            raise ModelError(
                f"element {e.name!r} of system {system.name!r} depends on the velocities "
                f"{sorted(map(str, bad))}: not a conservative force of the position"
            )
        return _polynomial_force(system, e, vec, q)
    comb = tuple(sp.sympify(v).xreplace(reps) for v in e.combination)
    if any(not _vanishes(v, {}) for v in comb[n:]):
        raise ModelError(
            f"element {e.name!r} of system {system.name!r} acts on a velocity "
            f"({e.describe(system.state_names)}): not a conservative force"
        )
    c = (comb[0], comb[1])
    f = e.function.xreplace(reps)
    s = ELEMENT_SYMBOL
    # conservative alone: the force is distributed along its own combination (w parallel to
    # c). A polynomial force that is not (x1**2/2 in the second equation of a pair with
    # x1*x2 in the first) may still be one part of a potential: it joins the smooth forces
    # of several coordinates, whose sum _model checks for a symmetric Jacobian.
    if sp.simplify(w[0] * c[1] - w[1] * c[0]) != 0:
        if f.is_polynomial(s):
            along = f.xreplace({s: c[0] * q[0] + c[1] * q[1]})
            return _polynomial_force(system, e, sp.Matrix([w[i] * along for i in range(2)]), q)
        raise ModelError(
            f"element {e.name!r} of system {system.name!r}: its force w = {list(w)} is not "
            f"along its combination c = {list(c)}, so it derives from no potential (not "
            "conservative)"
        )
    if e.kind == "smooth" or not f.has(sp.Heaviside, sp.Max, sp.Min, sp.Abs, sp.sign, sp.Piecewise):
        if not f.is_polynomial(s):
            raise ModelError(
                f"element {e.name!r} of system {system.name!r}: f(s) = {f} is not a polynomial: "
                "expected polynomial or piecewise-linear elements"
            )
        poly = sp.Poly(sp.expand(f), s)
        f0 = poly.coeff_monomial(1)
        if f0 != 0:
            raise ModelError(
                f"element {e.name!r} has the static load f(0) = {f0}: expected f(0) = 0 (the "
                "NNM is expanded about q = 0)"
            )
        slope = poly.coeff_monomial(s)
        return _Element(e.name, c, w, sp.expand(f - slope * s), False, slope)
    # symbolic switching points (d and -d of a gap) cannot be ordered: the values of the
    # parameters inside the switches are substituted (those in front may stay symbolic)
    inside = set().union(
        *(a.free_symbols for a in f.atoms(sp.Heaviside, sp.Max, sp.Min, sp.Abs, sp.sign))
    ) - {s}
    given = {real_symbol(k): v for k, v in system.params.items() if v is not None}
    f = f.xreplace({x: _exact(given[x]) for x in inside if x in given})
    try:
        pwl = to_pwl(f, s)
    except (NonsmoothError, TypeError, ValueError) as exc:
        raise ModelError(
            f"element {e.name!r} of system {system.name!r}: f(s) = {f} is not piecewise "
            f"linear with ordered breakpoints ({exc}); give its parameters values"
        ) from None
    # oddness: the switching points mirror and every slope with its mirror
    odd = sp.simplify(f.xreplace({s: -s}) + f)
    if odd != 0:
        pts = np.linspace(-7.3, 7.3, 41) * float(
            max([1.0] + [abs(float(b)) for b in pwl.breakpoints if b.is_number])
        )
        fn = sp.lambdify(s, f, "math") if not (f.free_symbols - {s}) else None
        if fn is None or max(abs(fn(x) + fn(-x)) for x in pts) > 1e-12:
            raise ModelError(
                f"element {e.name!r} of system {system.name!r}: f(s) = {f} is not odd: the NNM "
                "would have a mean of order one; expected an odd piecewise-linear force"
            )
    slope = sp.nsimplify((pwl.slopes[0] + pwl.slopes[-1]) / 2)
    if f.subs(s, 0) != 0:
        raise ModelError(f"element {e.name!r}: f(0) = {f.subs(s, 0)}, expected 0")
    return _Element(e.name, c, w, f - slope * s, True, slope)


def _polynomial_force(system: System, e, vec: sp.Matrix, q):
    """``(linear part matrix, remainder vector)`` of a polynomial force ``vec`` of the
    coordinates ``q``.

    Raises
    ------
    ModelError
        ``vec`` is no polynomial in ``q``, or has a nonzero constant (a static load).
    """
    if not all(sp.sympify(v).is_polynomial(*q) for v in vec):
        raise ModelError(
            f"element {e.name!r} of system {system.name!r}: {e.function} is not a "
            "polynomial in the coordinates: expected polynomial or piecewise-linear forces"
        )
    lin = sp.zeros(2, 2)
    rest = sp.zeros(2, 1)
    for i in range(2):
        poly = sp.Poly(sp.expand(vec[i]), *q)
        for (a, b), coeff in poly.terms():
            if coeff == 0:  # Poly(0).terms() is ((0, 0), 0): no force in this equation
                continue
            if a + b == 0:
                raise ModelError(
                    f"element {e.name!r} has a static load {coeff} in equation {i + 1}: "
                    "expected forces that vanish at rest (the NNM is expanded about q = 0)"
                )
            if a + b == 1:
                lin[i, 0 if a else 1] += coeff
            else:
                rest[i] += coeff * q[0] ** a * q[1] ** b
    return lin, rest


# ------------------------------------------------------------------------------ modal part --
def _modes(model: _Model, name: str):
    """Eigenvalues (increasing) and M-orthonormal eigenvectors of ``(M, Kbar)``."""
    lam = sp.Symbol("lambda")
    M, K = model.M, model.Kbar
    char = sp.expand((K - lam * M).det())
    roots = sp.solve(char, lam)
    if len(roots) == 1 or (len(roots) == 2 and sp.simplify(roots[0] - roots[1]) == 0):
        raise InternalResonanceError(
            f"system {name!r}: the two linear frequencies are equal (omega_1**2 = omega_2**2 = "
            f"{roots[0]}): a 1:1 internal resonance; expected distinct frequencies"
        )
    try:
        roots = sorted(roots, key=lambda r: float(r))
        numeric = True
    except TypeError:
        numeric = False
    for r in roots:
        if numeric and float(r) <= 0:
            raise ModelError(
                f"system {name!r}: the reference stiffness {model.Kbar.tolist()} has the "
                f"eigenvalue omega**2 = {r} <= 0: expected a stable equilibrium at rest (both "
                "omega**2 > 0)"
            )
    cols = []
    for r in roots:
        null = (K - r * M).applyfunc(sp.simplify).nullspace(simplify=True)
        if len(null) != 1:
            raise ModelError(f"system {name!r}: no single mode shape for omega**2 = {r}")
        v = null[0]
        norm = sp.sqrt(sp.simplify((v.T * M * v)[0]))
        v = (v / norm).applyfunc(sp.radsimp)
        first = next(x for x in v if x != 0)
        if numeric and float(first) < 0:
            v = -v
        cols.append(v.applyfunc(sp.simplify))
    Phi = sp.Matrix.hstack(*cols)
    if numeric and (
        max(sp.count_ops(x) for x in Phi) > EXACT_OPS
        or max(sp.count_ops(r) for r in roots) > EXACT_OPS
    ):
        # nested radicals (the golden ratio of nsd2) make every later expression unreadable:
        # the modal data in floating point (the notes say so)
        roots = [sp.Float(float(r), DIGITS) for r in roots]
        Phi = Phi.applyfunc(lambda x: sp.Float(float(x), DIGITS))
        omegas = tuple(sp.Float(float(sp.sqrt(r)), DIGITS) for r in roots)
        return tuple(roots), omegas, Phi, True, True
    omegas = tuple(sp.sqrt(r) for r in roots)
    return tuple(roots), omegas, Phi, numeric, False


# ------------------------------------------------------------------------------ expansions --
class _Forces:
    """The modal forces :math:`n(u) = \\Phi^T g(\\Phi u)` composed with the expansion
    :math:`u = \\sum p^q u_q` (``p`` = epsilon or alpha), by order."""

    def __init__(self, model: _Model, Phi: sp.Matrix, j: int, A: sp.Symbol, harmonics: int):
        self.model, self.Phi, self.j, self.A, self.harmonics = model, Phi, j, A, harmonics
        self.u = (sp.Symbol("u_1"), sp.Symbol("u_2"))
        if not model.pwl:
            q = sp.Matrix(model.q)
            g = sp.Matrix(model.smooth)
            for el in model.elements:
                s = el.c[0] * q[0] + el.c[1] * q[1]
                g += sp.Matrix(el.w) * el.g.xreplace({ELEMENT_SYMBOL: s})
            sub = dict(zip(model.q, list(Phi * sp.Matrix(self.u)), strict=True))
            self.poly = [
                sp.Poly(sp.expand(v), *self.u)
                for v in (Phi.T * g.xreplace(sub)).applyfunc(sp.expand)
            ]
        self._pow: dict[tuple[int, int], _EpsSeries] = {}

    def modal_expression(self) -> sp.Matrix:
        """n(u) for the text."""
        if not self.model.pwl:
            return sp.Matrix([p.as_expr() for p in self.poly])
        out = sp.zeros(2, 1)
        u = sp.Matrix(self.u)
        for el in self.model.elements:
            kappa = sp.Matrix(el.c).T * self.Phi  # c . phi_i
            s = (kappa * u)[0]
            gf = sp.Function(f"g_{{{el.name}}}" if len(self.model.elements) > 1 else "g")
            out += (self.Phi.T * sp.Matrix(el.w)).applyfunc(_canon) * gf(_canon(s))
        return out

    def order(self, U: list[list[Trig]], p: int) -> list[Trig]:
        """``[p^p] n(sum p^q U[q])`` for both modes (``U`` known to order ``p``)."""
        if self.model.pwl:
            if p > 0:  # pragma: no cover - refused in nnm_backbone
                raise ParameterError("piecewise-linear elements: first order only")
            return self._pwl_first()
        P = p + 1
        series = [[U[q][i] for q in range(P)] for i in range(2)]
        out: list[Trig] = [{}, {}]
        for i in range(2):
            for (a, b), coeff in self.poly[i].terms():
                prod = self._power(series, 0, a, P, len(U))
                prod = _e_mul(prod, self._power(series, 1, b, P, len(U)), P)
                if len(prod) > p and prod[p]:
                    out[i] = _t_add((1, out[i]), (coeff, prod[p]))
        out = [{m: _chop(sp.expand(v)) for m, v in o.items()} for o in out]
        return [{m: v for m, v in o.items() if v != 0} for o in out]

    def _power(self, series, i, k, P, known) -> _EpsSeries:
        key = (i, k, P, known)
        if key not in self._pow:
            if k == 0:
                val: _EpsSeries = [{0: sp.S.One}] + [{} for _ in range(P - 1)]
            else:
                val = _e_mul(self._power(series, i, k - 1, P, known), series[i], P)
            self._pow[key] = val
        return self._pow[key]

    def _pwl_first(self) -> list[Trig]:
        """Harmonics of n(A cos(tau) e_j): per element, the closed-form coefficients of
        g(S cos tau), S = |c . phi_j| A (odd g: a sign for c . phi_j < 0)."""
        out: list[Trig] = [{}, {}]
        for el in self.model.elements:
            kappa = _canon(el.c[0] * self.Phi[0, self.j] + el.c[1] * self.Phi[1, self.j])
            if kappa == 0:
                continue
            sign = sp.sign(kappa)
            S = sp.Abs(kappa) * self.A
            proj = [_canon((self.Phi[:, i].T * sp.Matrix(el.w))[0]) for i in range(2)]
            # g is odd (checked): its even harmonics and mean vanish, though the ramp form
            # writes them as differences of coefficient functions that SymPy cannot cancel
            for m in range(1, self.harmonics + 1, 2):
                a_m = series_coefficient(el.g, ELEMENT_SYMBOL, m, S)
                if a_m == 0:
                    continue
                a_m = a_m * sign
                for i in range(2):
                    if proj[i] != 0:
                        out[i][m] = out[i].get(m, sp.S.Zero) + sp.expand(proj[i] * a_m)
        return [{m: v for m, v in o.items() if v != 0} for o in out]


def _check_resonance(
    name: str, mode: int, m: int, denominator: sp.Expr, omegas, numerator: sp.Expr, notes: list
) -> None:
    k = 2 if mode == 1 else 1
    d = sp.simplify(denominator)
    lam_k = omegas[k - 1] ** 2
    what = (
        f"omega_{k} = {m}*omega_{mode} (omega_{mode} = {omegas[mode - 1]}, omega_{k} = "
        f"{omegas[k - 1]})"
    )
    if d == 0 or (d.is_number and abs(float(d)) <= RESONANCE_TOL * abs(float(lam_k))):
        raise InternalResonanceError(
            f"system {name!r}, mode {mode}: internal resonance {what}: harmonic {m} of the "
            f"nonlinear force on mode {k} ({_clip(numerator, 80)}) drives it at its natural "
            f"frequency, so the denominator omega_{k}**2 - {m**2}*omega_{mode}**2 vanishes; "
            "expected a non-resonant pair (a 1:m internal resonance needs averaging or "
            "multiple scales on both modes)"
        )
    if d.is_number:
        rel = abs(float(d)) / abs(float(lam_k))
        if rel < NEAR_RESONANCE:
            notes.append(
                f"near internal resonance {what.replace(' = ', ' ~ ', 1)}: the divisor "
                f"omega_{k}**2 - {m**2}*omega_{mode}**2 = {float(d):.3g} is small; the "
                "expansion holds only while the frequency shift is small compared with it"
            )
    else:
        notes.append(
            f"valid away from omega_{k} = {m}*omega_{mode} (the divisor {d} must not vanish)"
        )


# ---------------------------------------------------------------------------- entry point --
def nnm_backbone(
    system: System,
    mode: int = 1,
    order: int = 2,
    *,
    method: str = "lp",
    harmonics: int = DEFAULT_HARMONICS,
) -> NNMBackbone:
    r"""Backbone :math:`\omega(A)` of the nonlinear normal mode continuing linear ``mode`` of a
    conservative two-coordinate system, by Lindstedt–Poincaré or modified L-P.

    Parameters
    ----------
    system
        ``M q'' + K q + sum_e w_e f_e(c_e . q) = 0``: exactly two second-order coordinates, no
        first-order states; damping and forcing absent or with the value 0; elements
        polynomial (any order up to :data:`MAX_ORDER`) or odd piecewise linear (order 1).
        Parameters of ``M`` and ``K`` are replaced by their values (exactly, as rationals);
        parameters only in the elements stay symbolic.
    mode
        1 or 2: the linear mode continued (modes in increasing frequency).
    order
        Highest power of :math:`\varepsilon` (``lp``) or :math:`\alpha` (``mlp``), >= 1.
    method
        ``"lp"`` or ``"mlp"``.
    harmonics
        Highest harmonic kept in the waveform when an element is piecewise linear.

    Returns
    -------
    NNMBackbone

    Raises
    ------
    ModelError
        Not a system of two coordinates, damping or forcing present, elements that are not
        conservative springs (friction, stops, velocity-dependent, non-polynomial smooth),
        non-odd piecewise-linear elements, a reference stiffness that is not positive.
    InternalResonanceError
        Equal linear frequencies (1:1) or :math:`\omega_k = m\omega_j` with a harmonic ``m``
        present in mode ``k``'s force (a :class:`ModelError`).
    ParameterError
        ``mode`` not 1 or 2, ``method`` unknown, ``order`` not an integer in range (for
        piecewise-linear elements: 1), ``harmonics`` not an integer in 1..63.
    """
    real = isinstance(mode, int | float | np.number) and not isinstance(mode, bool)
    if not real or mode not in (1, 2):
        raise ParameterError(f"mode = {mode!r}: expected 1 or 2 (the linear mode continued)")
    mode = int(mode)  # 2.0 indexes the modes
    if method not in METHODS:
        raise ParameterError(f"method = {method!r}: expected one of {', '.join(METHODS)}")
    if (
        isinstance(order, bool)
        or not isinstance(order, int | np.integer)
        or not (1 <= order <= MAX_ORDER)
    ):
        raise ParameterError(f"order = {order!r}: expected an integer from 1 to {MAX_ORDER}")
    if (
        isinstance(harmonics, bool)
        or not isinstance(harmonics, int | np.integer)
        or not (1 <= harmonics <= 63)
    ):
        raise ParameterError(f"harmonics = {harmonics!r}: expected an integer from 1 to 63")
    order, harmonics = int(order), int(harmonics)
    try:
        model = _model(system)
    except PerturbError:
        raise
    except (TypeError, ValueError, NotImplementedError) as exc:  # pragma: no cover - defensive
        raise ModelError(
            f"system {getattr(system, 'name', system)!r}: its linear part or elements could "
            f"not be split for the NNM expansion ({exc})"
        ) from None
    if model.pwl and order > PWL_ORDER:
        names = ", ".join(el.name for el in model.elements if el.pwl)
        raise ParameterError(
            f"order = {order} for the piecewise-linear element(s) {names} of system "
            f"{system.name!r}: expected order = {PWL_ORDER} (the closed-form Fourier "
            "coefficients hold at first order; the second would need products of truncated "
            "series and Dirac coefficients at the switches — use numeric harmonic balance)"
        )
    try:
        return _derive(model, mode, order, method, harmonics)
    except PerturbError:
        raise
    except (
        TypeError,
        ValueError,
        ZeroDivisionError,
        NotImplementedError,
    ) as exc:  # pragma: no cover
        raise ModelError(
            f"system {system.name!r}: the {method} expansion of mode {mode} failed ({exc})"
        ) from None


@dataclass
class _Run:
    """What the orders share: the modes, the symbols, the expansion ``U[n][i]`` (order ``n``,
    mode ``i``) as it grows, the frequency corrections found so far and the divisors met."""

    model: _Model
    mode: int
    order: int
    method: str
    harmonics: int
    lams: tuple[sp.Expr, sp.Expr]
    omegas: tuple[sp.Expr, sp.Expr]
    Phi: sp.Matrix
    rounded: bool
    A: sp.Symbol
    tau: sp.Symbol
    omega: sp.Symbol
    forces: _Forces
    U: list[list[Trig]] = field(default_factory=list)
    w: list[sp.Expr] = field(default_factory=list)  # lp: omega_0 .. omega_n
    nu_value: sp.Expr = sp.S.Zero  # mlp
    delta_val: dict[int, sp.Expr] = field(default_factory=dict)  # mlp
    denominators: dict[int, sp.Expr] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    @property
    def j(self) -> int:
        return self.mode - 1

    @property
    def k(self) -> int:
        return 2 - self.mode

    @property
    def ratio2(self) -> list[sp.Expr]:
        """``r_i^2 = omega_i^2/omega_j^2`` (exactly 1 for the mode itself)."""
        return [
            _canon(self.lams[i] / self.lams[self.j]) if i != self.j else sp.S.One for i in (0, 1)
        ]


NU = sp.Symbol("nu")


def _derive(model: _Model, mode: int, order: int, method: str, harmonics: int) -> NNMBackbone:
    system = model.system
    lams, omegas, Phi, _, rounded = _modes(model, system.name)
    A = sp.Symbol("A", positive=True)
    taken = set(system.params) | set(system.coordinates)
    wname = "omega"
    while wname in taken:
        wname += "_r"
    run = _Run(
        model,
        mode,
        order,
        method,
        harmonics,
        lams,
        omegas,
        Phi,
        rounded,
        A,
        real_symbol("tau"),
        real_symbol(wname),
        _Forces(model, Phi, mode - 1, A, harmonics),
    )
    run.U = [[{}, {}]]
    run.U[0][run.j] = {1: A}
    run.w = [omegas[run.j]]
    steps = _opening_steps(
        model, lams, omegas, Phi, run.forces, mode, method, order, run.tau, run.omega
    )
    steps.append(_order_zero_step(run))
    for n in range(1, order + 1):
        N = run.forces.order(run.U, n - 1)
        if n == 1 and model.pwl:
            cf = closed_form_step(
                sp.Function(f"nhat_{mode}")(A),
                N[run.j].get(1, sp.S.Zero),
                f"First harmonic of the force on mode {mode} in closed form",
            )
            if cf is not None:
                steps.append(derivation_step(cf.title, cf.math, cf.text))
        rhs, cond, secular = (_order_lp if method == "lp" else _order_mlp)(run, n, N)
        run.U.append(_solve_modes(run, rhs))
        steps.append(_order_step(run, n, rhs, cond, secular))
    return _result(run, steps)


def _order_zero_step(run: _Run) -> Step:
    ufun = [sp.Function(f"u_{i + 1}") for i in range(2)]
    return derivation_step(
        "Order zero in $" + ("\\varepsilon" if run.method == "lp" else "\\alpha") + "$",
        (
            equation(ufun[run.j](run.tau), run.A * sp.cos(run.tau)),
            equation(ufun[run.k](run.tau), 0),
        ),
        f"The NNM continues linear mode {run.mode}: at order zero only $u_{run.mode}$ moves, "
        "with the amplitude $A$ of its first harmonic (kept so at every order); the phase is "
        "set by starting at a turning point, so every term is a cosine.",
    )


def _order_lp(run: _Run, n: int, N: list[Trig]):
    """L-P order ``n``: the right-hand sides of ``omega_j^2 u_n'' + Lambda u_n = ...`` without
    the unknown ``omega_n``, which the secular condition gives (appended to ``run.w``)."""
    w, U, j = run.w, run.U, run.j

    def W(i: int) -> sp.Expr:  # sum_{p+q=i} omega_p omega_q, omega_n left out
        return sum((w[p] * w[i - p] for p in range(i + 1) if p != n and i - p != n), sp.S.Zero)

    rhs = [
        _t_add(*((-W(ii), _t_dd(U[n - ii][i])) for ii in range(1, n + 1)), (-1, N[i]))
        for i in range(2)
    ]
    # omega_n enters as -2 omega_j omega_n u_0'' = 2 omega_j omega_n A cos(tau)
    wn = sp.simplify(-sp.expand(rhs[j].get(1, sp.S.Zero)) / (2 * run.omegas[j] * run.A))
    w.append(wn)
    w_n = sp.Symbol(f"omega_{n}")
    return rhs, equation(w_n, _tidy(wn)), 2 * run.omegas[j] * w_n * run.A


def _order_mlp(run: _Run, n: int, N: list[Trig]):
    """mLP order ``n``: ``u_n'' + R u_n = -sum delta_i u_{n-i}'' + R u_{n-1} - N_{n-1}/nu``;
    order 1 gives ``nu``, order ``n >= 2`` gives ``delta_n``."""
    U, j, r2 = run.U, run.j, run.ratio2
    rhs = []
    for i in range(2):
        terms = [(-run.delta_val[ii], _t_dd(U[n - ii][i])) for ii in range(2, n)]
        rhs.append(_t_add(*terms, (r2[i], U[n - 1][i]), (-1 / NU, N[i])))
    if n == 1:  # A - nhat_j1/nu = 0
        run.nu_value = sp.simplify(N[j].get(1, sp.S.Zero) / run.A)
        if run.nu_value == 0:
            # alpha = nu/(omega_j**2 + nu) would be 0 and every later order divides by nu
            # (delta_n = zoo): mLP needs a first-order frequency correction
            raise ModelError(
                f"system {run.model.system.name!r}, mode {run.mode}: the first-harmonic "
                "force of the mode vanishes at first order (nu = 0, e.g. only quadratic "
                "terms), so mLP's alpha = nu/(omega**2 + nu) is 0 and its corrections divide "
                "by zero: use method='lp'"
            )
        return rhs, equation(NU, _tidy(run.nu_value)), sp.S.Zero
    # delta_n enters as -delta_n u_0'' = delta_n A cos(tau)
    run.delta_val[n] = sp.simplify(-sp.expand(rhs[j].get(1, sp.S.Zero)) / run.A)
    d_n = sp.Symbol(f"delta_{n}")
    return rhs, equation(d_n, _tidy(run.delta_val[n])), d_n * run.A


def _solve_modes(run: _Run, rhs: list[Trig]) -> list[Trig]:
    """Harmonic ``m`` of mode ``i``: divided by ``lambda_i - m^2 lambda_j`` (lp) or
    ``r_i^2 - m^2`` (mlp); the secular harmonic of mode ``j`` is zero; every divisor of the
    other mode is checked for an internal resonance."""
    j, k, lams = run.j, run.k, run.lams
    if run.method == "lp":
        denom, scale = list(lams), lams[j]
    else:
        denom, scale = run.ratio2, sp.S.One
    out: list[Trig] = [{}, {}]
    for i in range(2):
        for m, v in rhs[i].items():
            if i == j and m == 1:
                continue  # the secular term, removed by the condition
            if i == k and m not in run.denominators:
                d_lin = lams[k] - m**2 * lams[j]
                _check_resonance(
                    run.model.system.name, run.mode, m, d_lin, run.omegas, v, run.notes
                )
                run.denominators[m] = sp.simplify(d_lin)
            out[i][m] = _chop(sp.expand(v / (denom[i] - m**2 * scale)))
    return out


def _order_step(run: _Run, n: int, rhs: list[Trig], cond: sp.Equality, secular) -> Step:
    """The equations of order ``n`` collected by harmonic, the condition and the solution."""
    tau, j, k, mode = run.tau, run.j, run.k, run.mode
    ufun = [sp.Function(f"u_{i + 1}") for i in range(2)]
    if run.method == "lp":
        scale, diag = run.lams[j], run.lams
    else:
        scale, diag = sp.S.One, run.ratio2
    shown = []
    for i in range(2):
        lhs = scale * sp.Derivative(ufun[i](tau), tau, 2) + diag[i] * ufun[i](tau)
        shown_i = dict(rhs[i])
        if i == j and secular != 0:  # the unknown correction joins the first harmonic
            shown_i[1] = sp.expand(shown_i.get(1, sp.S.Zero) + secular)
        shown.append(equation(lhs, _t_expr(shown_i, tau)))
    sym = "\\varepsilon" if run.method == "lp" else "\\alpha"
    if run.method == "lp":
        gives = f"the frequency correction $\\omega_{n}$"
        divisor = f"$\\omega_{k + 1}^2 - m^2\\omega_{mode}^2$)."
    else:
        gives = "$\\nu$" if n == 1 else f"$\\delta_{n}$"
        divisor = f"$r^2 - m^2$, $r = \\omega_{k + 1}/\\omega_{mode}$)."
    return derivation_step(
        f"Order {n} in ${sym}$",
        (
            *shown,
            cond,
            *(equation(ufun[i](tau), _t_expr(run.U[n][i], tau)) for i in range(2)),
        ),
        f"Collected by harmonic. No secular term in mode {mode}: the coefficient of "
        f"$\\cos\\tau$ vanishes, which gives {gives}; mode {k + 1} is solved harmonic by "
        f"harmonic (harmonic $m$ divided by {divisor}",
    )


def _assemble_lp(run: _Run):
    """Backbone ``sum omega_n``, modal waveforms ``sum u_n`` and the result's equations."""
    corrections = {f"omega_{n}": wn for n, wn in enumerate(run.w)}
    modal = [
        sp.Add(*(_t_expr(run.U[n][i], run.tau, tidy=False) for n in range(run.order + 1)))
        for i in range(2)
    ]
    shown = [equation(run.omega, sp.Add(*(_tidy(x) for x in run.w), evaluate=False))]
    return sp.Add(*run.w), corrections, modal, shown


def _assemble_mlp(run: _Run):
    """``omega^2 = (omega_j^2 + nu)(1 + sum delta_n alpha^n)``, ``alpha = nu/(omega_j^2 +
    nu)``; each ``alpha^n u_n`` written as ``beta^n (nu^n u_n)``, ``beta = 1/(omega_j^2 + nu)``,
    so that nothing is singular where ``nu`` vanishes; then ``nu`` replaced by its value."""
    lam, nu_val, dv, alpha = run.lams[run.j], run.nu_value, run.delta_val, sp.Symbol("alpha")
    factor = 1 + sp.Add(*(dv[n] * NU**n / (lam + NU) ** n for n in dv))
    backbone = sp.sqrt(((lam + NU) * factor).xreplace({NU: nu_val}))
    corrections = {"nu": nu_val, "alpha": sp.simplify(nu_val / (lam + nu_val))}
    for n, d in dv.items():
        corrections[f"delta_{n}"] = _simplify(d.xreplace({NU: nu_val}))
    beta = 1 / (lam + NU)
    modal = []
    for i in range(2):
        total = sp.S.Zero
        for n in range(run.order + 1):
            scaled = {m: sp.expand(v * NU**n) for m, v in run.U[n][i].items()}
            total += beta**n * _t_expr(scaled, run.tau, tidy=False)
        modal.append(total.xreplace({NU: nu_val}))
    deltas = [sp.Symbol(f"delta_{n}") for n in dv]
    shown = [
        equation(NU, _tidy(nu_val)),
        equation(alpha, NU / (lam + NU)),
        *(equation(sp.Symbol(f"delta_{n}"), corrections[f"delta_{n}"]) for n in dv),
        equation(
            run.omega,
            sp.sqrt(
                (lam + NU) * (1 + sp.Add(*(d * alpha**n for n, d in zip(dv, deltas, strict=True))))
            ),
        ),
        equation(run.omega, _simplify(backbone)),
    ]
    return backbone, corrections, modal, shown


def _result(run: _Run, steps: list[Step]) -> NNMBackbone:
    """The result with the expansion parameter set to one: backbone, waveforms ``q = Phi u``,
    the result and validity steps, and the :class:`NNMBackbone`."""
    model, tau = run.model, run.tau
    backbone, corrections, modal, shown = (
        _assemble_lp(run) if run.method == "lp" else _assemble_mlp(run)
    )
    backbone = _simplify(backbone)
    modal = [_simplify_wave(m, tau) for m in modal]
    waves = tuple(_simplify_wave(sp.expand(v), tau) for v in run.Phi * sp.Matrix(modal))
    params = sorted(
        (backbone.free_symbols | set().union(*(wv.free_symbols for wv in waves))) - {run.A, tau},
        key=lambda s: s.name,
    )
    steps.append(
        derivation_step(
            "Result with $\\varepsilon = 1$" if run.method == "lp" else "Result",
            (
                *shown,
                *(
                    equation(sp.Function(nm)(tau), _wave_shown(v, tau))
                    for nm, v in zip(model.names, waves, strict=True)
                ),
            ),
            "The backbone (frequency-amplitude relation) of the NNM and its waveform in the "
            "physical coordinates, $q = \\Phi u$"
            + (
                f"; harmonics above {run.harmonics} of the piecewise-linear force are dropped."
                if model.pwl
                else "."
            ),
        )
    )
    notes = list(run.notes)
    if run.rounded:
        notes.append(
            "the exact modal data are nested radicals: frequencies and mode shapes are used in "
            f"floating point ({DIGITS} digits; the derivation prints {TEXT_DIGITS})"
        )
    notes += _validity_notes(model, run.method, run.mode, run.omegas)
    steps.append(
        _validity_step(model, run.method, run.mode, run.omegas, run.denominators, run.rounded)
    )
    options: dict[str, Any] = {"mode": run.mode, "order": run.order, "method": run.method}
    if model.pwl:
        options["harmonics"] = run.harmonics
    return NNMBackbone(
        system=model.system,
        method=run.method,
        mode=run.mode,
        order=run.order,
        options=MappingProxyType(options),
        coordinates=model.names,
        mass=sp.ImmutableMatrix(model.M),
        reference_stiffness=sp.ImmutableMatrix(model.Kbar),
        natural_frequencies=(run.omegas[0], run.omegas[1]),
        modal_matrix=sp.ImmutableMatrix(run.Phi),
        amplitude=run.A,
        tau=tau,
        frequency=run.omega,
        corrections=MappingProxyType(corrections),
        backbone=backbone,
        modal_waveforms=(modal[0], modal[1]),
        waveforms=waves,
        parameters=tuple(params),
        values=MappingProxyType({p.name: model.system.params.get(p.name) for p in params}),
        resonance_denominators=tuple(sorted(run.denominators.items())),
        steps=tuple(steps),
        notes=tuple(notes),
    )


def _tidy(expr: sp.Expr) -> sp.Expr:
    if expr.has(*_COEFFS):
        calls = sorted(expr.atoms(*_COEFFS), key=sp.default_sort_key)
        return sp.collect(sp.expand(expr), calls)
    return _factor(expr)


def _simplify(expr: sp.Expr) -> sp.Expr:
    if expr.has(*_COEFFS) or expr.has(sp.Float):
        return expr
    return sp.simplify(expr)


def _simplify_wave(expr: sp.Expr, tau: sp.Symbol) -> sp.Expr:
    """Collected by harmonic, each coefficient simplified."""
    expr = sp.expand(expr)
    cos_terms = sorted(expr.atoms(sp.cos), key=sp.default_sort_key)
    collected = sp.collect(expr, cos_terms, evaluate=False)
    out = sp.S.Zero
    for key, c in collected.items():
        c = c if c.has(*_COEFFS) or c.has(sp.Float) else sp.factor(sp.cancel(c))
        out += c * key
    return out


def _harmonic_key(c: sp.Expr, tau: sp.Symbol) -> int:
    """m of cos(m tau) (0 for the mean)."""
    if isinstance(c, sp.cos):
        m = sp.simplify(c.args[0] / tau)
        return int(m) if m.is_Integer else 10**6
    return 0


def _wave_shown(expr: sp.Expr, tau: sp.Symbol) -> sp.Expr:
    expr = sp.expand(expr)
    cos_terms = sorted(expr.atoms(sp.cos), key=lambda c: sp.default_sort_key(c.args[0]))
    collected = sp.collect(expr, cos_terms, evaluate=False)
    terms = []
    for key in sorted(collected, key=lambda c: _harmonic_key(c, tau)):
        c = _tidy(collected[key])
        terms.append(c if key == 1 else sp.Mul(c, key, evaluate=False))
    return sp.Add(*terms, evaluate=False)


def _validity_step(model, method, mode, omegas, denominators, rounded) -> Step:
    """The derivation's closing paragraph: where the expansion holds, in words."""
    j, k = mode, 3 - mode
    parts = []
    if method == "lp":
        parts.append(
            "The L-P series is a power series in the ratio of the nonlinear to the linear "
            f"restoring force: it holds while the frequency correction is small against "
            f"$\\omega_{j}$ (for a cubic element, while $\\varepsilon A^2 \\ll \\omega_{j}^2$); "
            "for a softening force it fails before the backbone reaches zero frequency."
        )
    else:
        parts.append(
            "The mLP parameter $\\alpha = \\nu/(\\omega_j^2 + \\nu)$ stays below one at any "
            "amplitude of a hardening force, so the expansion remains usable where L-P "
            "diverges; for a softening force it fails where $\\omega_j^2 + \\nu$ approaches "
            "zero (no real frequency)."
        )
    if denominators:
        ms = ", ".join(str(m) for m in sorted(denominators))
        parts.append(
            f"Mode {k} is driven at the harmonics $m = {ms}$ of the frequency; each is divided "
            f"by $\\omega_{k}^2 - m^2\\omega_{j}^2$, so the expansion excludes the internal "
            f"resonances $\\omega_{k} = m\\,\\omega_{j}$ (refused when exact), and holds "
            f"only while the backbone stays away from $\\omega_{k}/m$."
        )
    if model.pwl:
        parts.append(
            "The piecewise-linear element enters at first order through its closed-form Fourier "
            "coefficients; the reference stiffness is the mean of its outer slopes, so the "
            "correction is small only at amplitudes well beyond the switching points, and the "
            "backbone is qualitative near them (for a negative-stiffness device the equilibrium "
            "at rest is unstable and small amplitudes have no real frequency)."
        )
    if rounded:
        parts.append(
            f"The modal data are nested radicals and are written to {TEXT_DIGITS} digits "
            f"(computed with {DIGITS})."
        )
    return derivation_step("Where the expansion holds", (), " ".join(parts))


def _validity_notes(model: _Model, method: str, mode: int, omegas) -> list[str]:
    j = mode - 1
    out = []
    if method == "lp":
        out.append(
            "L-P is a power series in the nonlinear force relative to the linear one: "
            f"valid while the frequency correction is small against omega_{mode} = {omegas[j]} "
            "(for a cubic element, eps*A**2 small against omega**2); for softening forces it "
            "fails before omega(A) reaches zero"
        )
    else:
        out.append(
            "mLP expands in alpha = nu/(omega_j**2 + nu), below one for any amplitude of a "
            "hardening force, so it stays usable at large amplitude where L-P diverges; for a "
            "softening force it fails where omega_j**2 + nu approaches zero"
        )
    if model.pwl:
        out.append(
            "piecewise-linear elements: first order, reference stiffness the mean of the outer "
            "slopes; the correction is not small near the switching amplitude when the slopes "
            "differ much (e.g. the negative-stiffness device), so the backbone is qualitative "
            "there"
        )
    out.append(
        "the NNM is followed as long as omega(A) stays away from omega_k/m for the other mode "
        "k (a resonance tongue the expansion does not see)"
    )
    return out


def _opening_steps(model, lams, omegas, Phi, forces, mode, method, order, tau, omega) -> list[Step]:
    """Equations of motion in matrices, the reference stiffness, the linear modes and the
    modal equations; then the expansion (strained time for lp, the alpha-transformation for
    mlp)."""
    t = model.system.t
    xf = [sp.Function(nm) for nm in model.names]
    qv = sp.Matrix([f(t) for f in xf])
    Msym, Ksym, Kb, gsym = sp.Symbol("M"), sp.Symbol("K"), sp.Symbol("Kbar"), sp.Symbol("g")
    qs, qpp = sp.Symbol("q"), sp.Symbol("q''")
    eps = sp.Symbol("varepsilon")
    # the nonlinear forces as written: each element's g_e(c.q) along w_e
    g_shown = sp.Matrix(model.smooth)
    for el in model.elements:
        s = el.c[0] * qv[0] + el.c[1] * qv[1]
        g_shown += sp.Matrix(el.w) * el.g.xreplace({ELEMENT_SYMBOL: s})
    g_shown = g_shown.xreplace(dict(zip(qv, model.q, strict=True)))
    lam = sp.Symbol("omega")
    j = mode - 1
    steps = [
        derivation_step(
            "Equations of motion",
            (
                equation(sp.Add(Msym * qpp, Ksym * qs, sp.Symbol("f(q)"), evaluate=False), 0),
                equation(Msym, sp.ImmutableMatrix(model.M)),
                equation(Ksym, sp.ImmutableMatrix(model.K)),
                equation(qs, sp.ImmutableMatrix(list(model.q))),
            ),
            "The system has no damping and no forcing: a conservative system of two "
            "coordinates, whose nonlinear forces $f(q)$ are the elements"
            + (" (parameter values of the linear part substituted)." if model.reps else "."),
        ),
        derivation_step(
            "Bookkeeping",
            (
                equation(sp.Add(Msym * qpp, Kb * qs, eps * gsym, evaluate=False), 0),
                equation(Kb, sp.ImmutableMatrix(model.Kbar)),
                equation(gsym, sp.ImmutableMatrix(g_shown)),
            ),
            "Each element is split into a linear reference spring"
            + (
                " (for a piecewise-linear element the mean of its outer slopes)"
                if model.pwl
                else " (its linear part)"
            )
            + " and a remainder, ordered by the bookkeeping parameter $\\varepsilon$ (set to "
            "one at the end).",
        ),
        derivation_step(
            "Linear modes",
            (
                equation(sp.factor(sp.expand((model.Kbar - lam**2 * model.M).det())), 0),
                equation(sp.Symbol("omega_1"), omegas[0]),
                equation(sp.Symbol("omega_2"), omegas[1]),
                equation(sp.Symbol("Phi"), sp.ImmutableMatrix(Phi)),
            ),
            "The characteristic equation $\\det(\\bar K - \\omega^2 M) = 0$ gives the natural "
            "frequencies; the mode shapes are the columns of $\\Phi$, normalised so that "
            "$\\Phi^T M\\Phi = I$ and $\\Phi^T\\bar K\\Phi = \\mathrm{diag}(\\omega_1^2, "
            "\\omega_2^2)$.",
        ),
    ]
    u = sp.Function("u_1"), sp.Function("u_2")
    nvec = forces.modal_expression()
    steps.append(
        derivation_step(
            "Modal equations",
            (
                equation(qs, sp.MatMul(sp.Symbol("Phi"), sp.Symbol("u"), evaluate=False)),
                *(
                    equation(
                        sp.Add(
                            sp.Derivative(u[i](t), t, 2),
                            lams[i] * u[i](t),
                            eps * sp.Function(f"n_{i + 1}")(sp.Symbol("u")),
                            evaluate=False,
                        ),
                        0,
                    )
                    for i in range(2)
                ),
                *(
                    equation(
                        sp.Function(f"n_{i + 1}")(sp.Symbol("u")), _collect_u(nvec[i], forces.u)
                    )
                    for i in range(2)
                ),
            ),
            "In modal coordinates the linear part decouples; the nonlinear forces "
            "$n(u) = \\Phi^T g(\\Phi u)$ couple the modes"
            + (
                " ($g$ the remainder of the piecewise-linear element, a function of one "
                "combination of the coordinates)."
                if model.pwl
                else "."
            ),
        )
    )
    if method == "lp":
        steps.append(
            derivation_step(
                "Strained time and expansions",
                (
                    equation(tau, omega * t),
                    equation(
                        omega,
                        omegas[j]
                        + sp.Add(*(eps**n * sp.Symbol(f"omega_{n}") for n in range(1, order + 1))),
                    ),
                    equation(
                        sp.Symbol("u"),
                        sp.Add(*(eps**n * sp.Symbol(f"u_{{({n})}}") for n in range(order + 1))),
                    ),
                    *(
                        equation(
                            sp.Add(
                                omega**2 * sp.Derivative(u[i](tau), tau, 2),
                                lams[i] * u[i](tau),
                                eps * sp.Function(f"n_{i + 1}")(sp.Symbol("u")),
                                evaluate=False,
                            ),
                            0,
                        )
                        for i in range(2)
                    ),
                ),
                f"Time is strained by the unknown frequency of the NNM continuing mode {mode}, "
                "expanded with the response; primes are derivatives with respect to $\\tau$ and "
                "powers of $\\varepsilon$ are collected.",
            )
        )
    else:
        alpha, nu = sp.Symbol("alpha"), sp.Symbol("nu")
        deltas = sp.Add(*(sp.Symbol(f"delta_{n}") * alpha**n for n in range(2, order + 1)))
        r2 = [_canon(lams[i] / lams[j]) if i != j else sp.S.One for i in range(2)]
        steps.append(
            derivation_step(
                "Alpha-transformation",
                (
                    equation(tau, omega * t),
                    equation(
                        omega**2,
                        lams[j]
                        + eps * sp.Symbol("omega_1")
                        + eps**2 * sp.Symbol("omega_2")
                        + sp.Symbol("..."),
                    ),
                    equation(nu, eps * sp.Symbol("omega_1")),
                    equation(alpha, nu / (lams[j] + nu)),
                    equation(omega**2, lams[j] * (1 + deltas) / (1 - alpha)),
                ),
                "Time is scaled by the frequency of the NNM continuing mode "
                f"{mode}, whose square is expanded in $\\varepsilon$. The first-order shift "
                "$\\nu$ defines Cheung, Chen and Lau's parameter $\\alpha$, which stays below "
                "one however strong a hardening nonlinearity; the higher shifts become the "
                "coefficients $\\delta_n$.",
            )
        )
        steps.append(
            derivation_step(
                "Transformed equation and expansion",
                (
                    *(
                        equation(
                            sp.Add(
                                (1 + deltas) * sp.Derivative(u[i](tau), tau, 2),
                                r2[i] * u[i](tau),
                                alpha
                                * (
                                    -r2[i] * u[i](tau)
                                    + sp.Function(f"n_{i + 1}")(sp.Symbol("u")) / nu
                                ),
                                evaluate=False,
                            ),
                            0,
                        )
                        for i in range(2)
                    ),
                    equation(
                        sp.Symbol("u"),
                        sp.Add(*(alpha**n * sp.Symbol(f"u_{{({n})}}") for n in range(order + 1))),
                    ),
                ),
                "Dividing the modal equations by $\\omega^2 = \\omega_j^2/(1 - \\alpha)$ "
                "(times the $\\delta_n$ factor) leaves them linear in $\\alpha$ apart from the "
                "$\\delta_n$, with $\\varepsilon$ set to one and the ratios "
                "$r_i^2 = \\omega_i^2/\\omega_j^2$; $u$ is expanded in powers of $\\alpha$.",
            )
        )
    return steps


def _collect_u(expr: sp.Expr, u) -> sp.Expr:
    if expr.has(sp.Function) and not expr.is_polynomial(*u):
        return expr
    return sp.collect(sp.expand(expr), list(u))
