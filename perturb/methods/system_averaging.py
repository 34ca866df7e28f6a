r"""First-order multiple scales for two-coordinate systems with a 1:1 or 1:3 internal resonance.

The system (:class:`~perturb.model.system.System`, two second-order coordinates, no
first-order states)

.. math::

    M q'' + C q' + K q + \sum_e w_e\, f_e(c_e\cdot y) = F_c \cos\Omega t + F_s \sin\Omega t

is taken as weakly damped, weakly forced and weakly nonlinear: ``C``, ``F`` and the elements
are the small terms (order :math:`\varepsilon`, a bookkeeping parameter set to 1 in the
results), ``M`` and ``K`` are the order-one linear part. The steps:

1. **Modal coordinates.** :math:`K\phi = \omega^2 M\phi`, ``Phi`` the M-orthonormal
   eigenvectors (columns, :math:`\Phi^T M\Phi = I`, :math:`\Phi^T K\Phi =
   \mathrm{diag}(\omega_1^2, \omega_2^2)`, :math:`\omega_1 \le \omega_2`), :math:`q = \Phi\eta`:

   .. math:: \eta_k'' + \omega_k^2\eta_k = N_k, \qquad
       N = \Phi^T\big(F(t) - C\Phi\eta' - \textstyle\sum_e w_e f_e\big).

2. **Internal resonance.** ``"1:1"``: :math:`\omega_2 = \omega_1 + \sigma_1`; ``"1:3"``:
   :math:`\omega_2 = 3\omega_1 + \sigma_1`, with the internal detuning :math:`\sigma_1` small
   (checked: :math:`|\omega_2/(R\omega_1) - 1|` at most ``tolerance``). The forcing is near
   mode ``near``: :math:`\Omega = \omega_{near} + \sigma`. Both modes then oscillate at
   multiples of one base frequency :math:`\omega_b` (:math:`\Omega` or :math:`\Omega/3`):
   :math:`\nu_1 = \omega_b`, :math:`\nu_2 = R\,\omega_b`.

3. **Solvability.** With :math:`\eta_k = A_k(t)\,e^{i\nu_k t} + \bar A_k e^{-i\nu_k t}` and
   :math:`A_k` slowly varying (multiple scales written in the frame that rotates with the
   forcing, so that the slow flow is autonomous), removing the secular terms of the first-order
   problem gives

   .. math:: 2 i\omega_k\big(A_k' + i(\nu_k - \omega_k) A_k\big) = [N_k]_{\nu_k},

   where :math:`[N_k]_{\nu_k}` is the coefficient of :math:`e^{i\nu_k t}` in :math:`N_k`
   evaluated on the ansatz (velocities :math:`\eta_k' = i\omega_k A_k e^{i\nu_k t} + c.c.`).
   For a 1:3 resonance this brings the terms :math:`\bar A_1^{\,2}A_2` into mode 1 and
   :math:`A_1^3` into mode 2 of a cubic nonlinearity; for 1:1 every cubic term
   :math:`A_j A_l \bar A_m` is resonant.

4. **Real forms.** Cartesian (van der Pol) amplitudes :math:`A_k = (p_k - i q_k)/2`, so that
   :math:`\eta_k = p_k\cos\nu_k t + q_k\sin\nu_k t`; polar ones
   :math:`A_k = \tfrac12 a_k e^{-i\gamma_k}`, :math:`\eta_k = a_k\cos(\nu_k t - \gamma_k)`:

   .. math:: p_k' = -(\nu_k-\omega_k) q_k + \frac{\operatorname{Im} c_k}{\omega_k},\quad
       q_k' = (\nu_k-\omega_k) p_k + \frac{\operatorname{Re} c_k}{\omega_k},\quad
       a_k' = \frac{\operatorname{Im}(c_k e^{i\gamma_k})}{\omega_k},\quad
       a_k\gamma_k' = (\nu_k-\omega_k)a_k + \frac{\operatorname{Re}(c_k e^{i\gamma_k})}{\omega_k}.

   Fixed points of the Cartesian flow are the periodic responses (period :math:`2\pi/\omega_b`);
   the eigenvalues :math:`\lambda` of its Jacobian give their stability (Floquet multipliers
   :math:`\approx e^{\lambda T}`).

This is the same slow flow as first-order averaging in the rotating frame (they agree to first
order); it is named multiple scales because the detuning enters as :math:`\nu_k - \omega_k`
and the velocities as :math:`i\omega_k A_k`, Nayfeh and Mook's convention.

Elements: polynomial functions of a combination ``s = c.y`` (positions and velocities) or of
the states; quadratic terms give no resonant first-order term for 1:1 and 1:3 (they are dropped,
with a note). A piecewise-linear odd element is taken through its closed-form describing
function (:func:`perturb.fourier.symbols.series_coefficient`, as in
:mod:`perturb.methods.system_harmonic_balance`) for a **1:1** resonance only, where its signal
is one harmonic :math:`s = \hat S e^{i\omega_b t} + c.c.` and its resonant part is
:math:`N(2|\hat S|)\,\hat S`; under 1:3 the signal holds two harmonics and the averaged
force has no simple closed form, so it is refused.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

import sympy as sp

from perturb.approximation import Step
from perturb.errors import FourierError, ModelError, NonsmoothError, ParameterError
from perturb.fourier.symbols import series_coefficient
from perturb.methods.applicability import is_odd
from perturb.model.parsing import real_symbol
from perturb.model.system import S as ELEMENT_SYMBOL
from perturb.model.system import System

__all__ = ["InternalResonanceSlowFlow", "internal_resonance_slow_flow", "RESONANCES"]

#: The internal resonances this module derives, with their frequency ratio omega_2/omega_1.
RESONANCES: Mapping[str, int] = MappingProxyType({"1:1": 1, "1:3": 3})

_METHOD = "multiple scales, first order (internal resonance)"
_MAX_DEGREE = 7  # polynomial elements beyond this make the expansion slow and the text long


@dataclass(frozen=True)
class InternalResonanceSlowFlow:
    """The first-order slow flow of a two-coordinate system near an internal resonance.

    Attributes
    ----------
    system
        The system derived.
    method
        ``"multiple scales, first order (internal resonance)"``.
    resonance
        ``"1:1"`` or ``"1:3"``; ``ratio`` is 1 or 3.
    near
        The mode the forcing frequency is near (1 or 2).
    frequency
        ``Omega``: the forcing frequency (for an unforced system, the frequency of the frame).
    modal_matrix
        ``Phi`` (2x2, columns the M-orthonormal eigenvectors of ``K``), exact where SymPy
        keeps it short, else 15-digit floats.
    natural_frequencies
        ``(omega_1, omega_2)``, ascending.
    internal_detuning
        ``sigma_1 = omega_2 - ratio * omega_1``.
    frame_frequencies
        ``(nu_1, nu_2)`` in ``Omega``: the frequencies the modes oscillate at.
    modal_damping, modal_forcing
        ``Phi^T C Phi`` and ``Phi^T F``.
    modal_equations
        ``eta_k'' + omega_k^2 eta_k - N_k(eta, eta', t)`` (= 0), in the symbols ``modal``
        (``eta_1, eta_2``) and ``modal_velocities``.
    complex_amplitudes
        ``A_1, A_2`` (complex symbols; their conjugates appear as ``conjugate(A_k)``).
    secular_terms
        ``c_k = [N_k]_{nu_k}``, the resonant coefficients in ``A`` and its conjugate.
    complex_slow_flow
        ``A_k'`` in ``A``.
    cartesian
        ``(p_1, q_1, p_2, q_2)``; ``slow_flow`` their time derivatives (real expressions).
    polar
        ``(a_1, gamma_1, a_2, gamma_2)``; ``polar_slow_flow`` is ``(a_1', a_1 gamma_1', a_2',
        a_2 gamma_2')``.
    steady_state
        The fixed-point equations ``slow_flow == 0`` (``sympy.Eq``, Cartesian);
        ``polar_steady_state`` the polar ones (``a_k' = 0``, ``a_k gamma_k' = 0``).
    jacobian
        ``d slow_flow / d cartesian`` (4x4): its eigenvalues at a fixed point decide stability.
    waveforms
        ``q(t)`` per coordinate in the Cartesian amplitudes.
    parameters, values
        The other symbols of the slow flow and their values (``None`` for a free one).
    steps, notes
        The derivation (title, mathematics, sentence) and caveats.
    """

    system: System
    method: str
    resonance: str
    ratio: int
    near: int
    frequency: sp.Symbol
    time: sp.Symbol
    modal_matrix: sp.ImmutableMatrix
    natural_frequencies: tuple[sp.Expr, sp.Expr]
    internal_detuning: sp.Expr
    frame_frequencies: tuple[sp.Expr, sp.Expr]
    modal_damping: sp.ImmutableMatrix
    modal_forcing: tuple[sp.Expr, sp.Expr]
    modal: tuple[sp.Symbol, sp.Symbol]
    modal_velocities: tuple[sp.Symbol, sp.Symbol]
    modal_equations: tuple[sp.Expr, sp.Expr]
    complex_amplitudes: tuple[sp.Symbol, sp.Symbol]
    secular_terms: tuple[sp.Expr, sp.Expr]
    complex_slow_flow: tuple[sp.Expr, sp.Expr]
    cartesian: tuple[sp.Symbol, ...]
    slow_flow: tuple[sp.Expr, ...]
    polar: tuple[sp.Symbol, ...]
    polar_slow_flow: tuple[sp.Expr, ...]
    steady_state: tuple[sp.Equality, ...]
    polar_steady_state: tuple[sp.Equality, ...]
    jacobian: sp.ImmutableMatrix
    waveforms: tuple[sp.Expr, sp.Expr]
    parameters: tuple[sp.Symbol, ...]
    values: Mapping[str, float | None]
    steps: tuple[Step, ...] = ()
    notes: tuple[str, ...] = ()

    @property
    def arguments(self) -> tuple[sp.Symbol, ...]:
        """``cartesian + (frequency,) + parameters``: the order a numeric layer passes the
        symbols of ``slow_flow`` and ``jacobian`` to ``sympy.lambdify`` (with
        :data:`perturb.fourier.symbols.NUMERIC_IMPLEMENTATIONS` first among its modules when
        an element is piecewise linear)."""
        return self.cartesian + (self.frequency,) + self.parameters

    @property
    def period(self) -> sp.Expr:
        """The period of the responses the fixed points stand for: ``2 pi / omega_b``."""
        return 2 * sp.pi / self.frame_frequencies[0]

    def __str__(self) -> str:
        w1, w2 = self.natural_frequencies
        lines = [
            f"{self.method} of system {self.system.name!r}: {self.resonance} internal "
            f"resonance, forcing near mode {self.near}",
            f"  modal matrix Phi = {sp.sstr(self.modal_matrix.tolist())}",
            f"  omega_1 = {sp.sstr(w1)}, omega_2 = {sp.sstr(w2)}, "
            f"sigma_1 = omega_2 - {self.ratio}*omega_1 = {sp.sstr(self.internal_detuning)}",
            f"  frame: nu_1 = {sp.sstr(self.frame_frequencies[0])}, "
            f"nu_2 = {sp.sstr(self.frame_frequencies[1])}",
        ]
        for k, c in enumerate(self.secular_terms, 1):
            lines.append(f"  secular term of mode {k}: c_{k} = {_clip(c)}")
        for x, rhs in zip(self.cartesian, self.slow_flow, strict=True):
            lines.append(f"  {x}' = {_clip(rhs)}")
        lines += [f"  note: {n}" for n in self.notes]
        return "\n".join(lines)


class _Primed(sp.Symbol):
    """A real symbol named ``eta_1''`` that LaTeX prints as its base with primes
    (``\\eta_{1}''``; SymPy would put the primes in the subscript)."""

    def __new__(cls, name: str) -> _Primed:
        return super().__new__(cls, name, real=True)

    def _latex(self, printer: Any) -> str:
        base = self.name.rstrip("'")
        return printer._print(real_symbol(base)) + "'" * (len(self.name) - len(base))


def _clip(expr: sp.Basic, width: int = 240) -> str:
    text = sp.sstr(expr)
    return text if len(text) <= width else text[: width - 3] + "..."


# ----------------------------------------------------------------------------- checks --
def _numeric_matrix(system: System, mat: sp.MatrixBase, label: str) -> sp.Matrix:
    """``mat`` with the parameter values in, exact rationals where the values are."""
    vals = {real_symbol(k): v for k, v in system.params.items() if v is not None}
    out = sp.Matrix(mat).xreplace(vals)
    free = sorted({str(s) for s in out.free_symbols})
    if free:
        raise ParameterError(
            f"{label} of system {system.name!r} holds the parameters {', '.join(free)} without "
            "values: the internal resonance is checked on the natural frequencies, so M and K "
            "need numbers (set them with System.with_params)"
        )
    return out.applyfunc(lambda v: sp.nsimplify(v, rational=True) if v.is_Float else v)


def _short(expr: sp.Expr) -> bool:
    """Short enough to print exactly: a few operations and no nested radicals (which
    multiply through every secular term)."""
    nested = any(
        p.exp.q == 2 and p.base.has(sp.Pow) for p in expr.atoms(sp.Pow) if p.exp.is_Rational
    )
    return sp.count_ops(expr) <= 8 and not nested


def _modal(M: sp.Matrix, K: sp.Matrix, name: str) -> tuple[sp.Matrix, list[sp.Expr]]:
    """M-orthonormal eigenvectors of the 2x2 pencil ``(K, M)``, frequencies ascending."""
    if M != M.T or K != K.T:
        raise ModelError(
            f"system {name!r}: M = {M.tolist()} and K = {K.tolist()} must be symmetric for "
            "real M-orthonormal modes (expected a conservative linear part)"
        )
    if not (M[0, 0] > 0 and M.det() > 0):
        raise ModelError(f"system {name!r}: M = {M.tolist()} is not positive definite")
    lam = sp.Symbol("lambda")
    poly = sp.Poly((K - lam * M).det(), lam)
    a, b, c = poly.all_coeffs()
    disc = sp.nsimplify(sp.expand(b**2 - 4 * a * c))
    exact = True
    if disc == 0:
        lams = [-b / (2 * a)] * 2
    else:
        root = sp.sqrt(disc)
        lams = [sp.radsimp((-b - root) / (2 * a)), sp.radsimp((-b + root) / (2 * a))]
    if any(float(v) <= 0 for v in lams):
        raise ModelError(
            f"system {name!r}: K = {K.tolist()} has eigenvalues {[float(v) for v in lams]} "
            "relative to M: expected positive ones (a stable linear part with two natural "
            "frequencies)"
        )
    vecs: list[sp.Matrix] = []
    if disc == 0:  # K = lambda M: any M-orthonormal basis is modal
        e1 = sp.Matrix([1, 0])
        e2 = sp.Matrix([0, 1])
        v1 = e1
        v2 = e2 - (e2.T * M * v1)[0] / (v1.T * M * v1)[0] * v1
        vecs = [v1, v2]
    else:
        for lv in lams:
            A = K - lv * M
            row = A.row(0) if any(sp.simplify(x) != 0 for x in A.row(0)) else A.row(1)
            vecs.append(sp.Matrix([row[1], -row[0]]))
    cols = []
    for v in vecs:
        v = v.applyfunc(sp.radsimp)
        norm = sp.sqrt(sp.radsimp(sp.expand((v.T * M * v)[0])))
        v = (v / norm).applyfunc(lambda x: sp.radsimp(sp.nsimplify(x)))
        first = next(x for x in v if x != 0)
        if float(first) < 0:
            v = -v
        cols.append(v)
    Phi = sp.Matrix.hstack(*cols)
    omegas = [sp.sqrt(v) for v in lams]
    omegas = [sp.radsimp(sp.sqrtdenest(w)) for w in omegas]
    exact = all(_short(x) for x in (*Phi, *omegas))
    if not exact:  # long radicals would drown the derivation: 15 digits are plenty
        Phi = Phi.evalf(15)
        omegas = [sp.Float(w.evalf(15), 15) for w in omegas]
    return Phi, omegas


def _forcing(system: System) -> tuple[sp.Symbol | None, list[tuple[sp.Expr, sp.Expr]]]:
    """The forcing frequency symbol (None when unforced) and ``(F_c, F_s)`` per equation."""
    t = system.t
    rates: set[sp.Expr] = set()
    parts: list[tuple[sp.Expr, sp.Expr]] = []
    for i, entry in enumerate(system.F):
        fc, fs = sp.S.Zero, sp.S.Zero
        for term in sp.Add.make_args(sp.expand(sp.sympify(entry))):
            if term == 0:
                continue
            trig = [f for f in term.atoms(sp.cos, sp.sin) if f.has(t)]
            coeff = term / trig[0] if len(trig) == 1 else None
            if coeff is None or coeff.has(t) or not sp.expand(trig[0].args[0]).is_Mul:
                raise ModelError(
                    f"forcing term {term} in equation {i + 1} of system {system.name!r}: "
                    "expected F cos(Omega*t) or F sin(Omega*t) (no static load, one harmonic "
                    "of one frequency)"
                )
            rates.add(sp.expand(trig[0].args[0]).coeff(t))
            if isinstance(trig[0], sp.cos):
                fc += coeff
            else:
                fs += coeff
        parts.append((fc, fs))
    if len(rates) > 1:
        raise ModelError(
            f"the forcing of system {system.name!r} has the frequencies "
            f"{sorted(map(str, rates))}: expected one forcing frequency"
        )
    if not rates:
        return None, parts
    (Omega,) = rates
    if not isinstance(Omega, sp.Symbol):
        raise ModelError(
            f"the forcing frequency of system {system.name!r} is {Omega}: expected a parameter "
            "symbol (e.g. Omega) that the slow flow keeps as the frequency to sweep"
        )
    return Omega, parts


def _check_ratio(resonance: Any, omegas: list[sp.Expr], tolerance: float, name: str) -> str:
    w1, w2 = (float(w) for w in omegas)
    ratio = w2 / w1
    declared = "declared"
    if resonance is None:
        resonance = min(RESONANCES, key=lambda r: abs(ratio / RESONANCES[r] - 1))
        declared = "nearer"
    if resonance not in RESONANCES:
        raise ParameterError(
            f"resonance = {resonance!r}: expected one of {', '.join(map(repr, RESONANCES))} "
            "(or None to pick the nearer)"
        )
    R = RESONANCES[resonance]
    off = ratio / R - 1
    if abs(off) > tolerance:
        raise ModelError(
            f"system {name!r}: omega_2/omega_1 = {w2:.6g}/{w1:.6g} = {ratio:.6g}, "
            f"{100 * off:+.3g}% from the {declared} {resonance} ratio {R} (tolerance "
            f"{100 * tolerance:.3g}%): not near a {resonance} internal resonance; the internal "
            f"detuning omega_2 - {R}*omega_1 = {w2 - R * w1:.6g} must be small"
        )
    return resonance


# --------------------------------------------------------------------- the expansions --
def _harmonic_terms(expr: sp.Expr, E: sp.Symbol) -> dict[int, sp.Expr]:
    """``expr`` (a Laurent polynomial in ``E``) as {power: coefficient}."""
    out: dict[int, sp.Expr] = {}
    for term in sp.Add.make_args(sp.expand(expr)):
        coeff, power = term.as_coeff_exponent(E)
        if coeff.has(E) or not power.is_Integer:
            raise ModelError(
                f"term {term}: not a harmonic of the base frequency"
            )  # pragma: no cover
        out[int(power)] = out.get(int(power), sp.S.Zero) + coeff
    return {k: v for k, v in out.items() if v != 0}


def _real_imag(expr: sp.Expr) -> tuple[sp.Expr, sp.Expr]:
    """Real and imaginary parts of an expression that is polynomial in ``I`` over real
    symbols (cheap: no ``as_real_imag`` walk)."""
    e = sp.expand(expr)
    im = e.coeff(sp.I)
    return sp.expand(e - sp.I * im), sp.expand(im)


def _exp_to_trig(expr: sp.Expr) -> sp.Expr:
    """``e^{i phi}`` factors as ``cos phi + i sin phi``, after merging the exponentials of
    each term (so that ``a_1^2 a_2`` terms come out with ``cos(gamma_2 - 3 gamma_1)``)."""
    expr = sp.Add(*(sp.powsimp(x, combine="exp") for x in sp.Add.make_args(sp.expand(expr))))
    return sp.expand(
        expr.replace(
            lambda x: isinstance(x, sp.exp),
            lambda x: (
                sp.cos(sp.expand(x.args[0] / sp.I)) + sp.I * sp.sin(sp.expand(x.args[0] / sp.I))
            ),
        )
    )


def internal_resonance_slow_flow(
    system: System,
    resonance: str | None = None,
    *,
    near: int = 1,
    tolerance: float = 0.15,
) -> InternalResonanceSlowFlow:
    r"""Derive the first-order multiple-scales slow flow of a two-coordinate system near an
    internal resonance.

    Parameters
    ----------
    system
        Two second-order coordinates, no first-order states; ``M`` and ``K`` numeric (their
        parameters given values), symmetric, ``M`` positive definite. Forcing
        ``F_c cos(Omega t) + F_s sin(Omega t)`` with ``Omega`` a parameter, or none.
        Damping, forcing and elements are the small terms.
    resonance
        ``"1:1"`` (:math:`\omega_2 \approx \omega_1`) or ``"1:3"``
        (:math:`\omega_2 \approx 3\omega_1`); ``None`` (default) picks the nearer of the
        two, relative to the ratio.
    near
        The mode the forcing frequency is near: ``Omega ~ omega_near`` (1 or 2).
    tolerance
        Largest relative internal mistuning :math:`|\omega_2/(R\omega_1) - 1|` accepted.

    Returns
    -------
    InternalResonanceSlowFlow

    Raises
    ------
    ModelError
        Not two second-order coordinates, first-order states, frequencies not near the
        declared ratio (the message gives the ratio and how far it is), a static load or
        several forcing frequencies, a stop or friction element, a non-polynomial element
        under 1:3 or a piecewise-linear element that is not odd.
    ParameterError
        A resonance other than ``"1:1"``/``"1:3"``, ``near`` not 1 or 2, a bad ``tolerance``,
        ``M``/``K`` parameters without values.
    """
    if not isinstance(system, System):
        raise ModelError(
            f"system = {system!r}: expected a perturb.model.system.System of two coordinates"
        )
    if system.first_order:
        raise ModelError(
            f"system {system.name!r} has the first-order states {', '.join(system.first_order)}: "
            "the internal-resonance slow flow takes two second-order coordinates and no "
            "first-order states"
        )
    if len(system.coordinates) != 2:
        raise ModelError(
            f"system {system.name!r} has {len(system.coordinates)} coordinate(s) "
            f"({', '.join(system.coordinates)}): expected exactly 2 for a 1:1 or 1:3 internal "
            "resonance"
        )
    if resonance is not None and (not isinstance(resonance, str) or resonance not in RESONANCES):
        raise ParameterError(
            f"resonance = {resonance!r}: expected one of {', '.join(map(repr, RESONANCES))} "
            "(or None to pick the nearer)"
        )
    if isinstance(near, bool) or not isinstance(near, (int, float)) or near not in (1, 2):
        raise ParameterError(f"near = {near!r}: expected the mode 1 or 2 the forcing is near")
    near = int(near)  # 2.0 indexes the frame tuples below
    if (
        isinstance(tolerance, bool)
        or not isinstance(tolerance, (int, float))
        or not math.isfinite(tolerance)
        or not 0 < tolerance < 1
    ):
        raise ParameterError(f"tolerance = {tolerance!r}: expected a number in (0, 1)")

    name = system.name
    M = _numeric_matrix(system, system.M, "M")
    K = _numeric_matrix(system, system.K, "K")
    Phi, omegas = _modal(M, K, name)
    resonance = _check_ratio(resonance, omegas, tolerance, name)
    R = RESONANCES[resonance]
    Omega_found, fparts = _forcing(system)
    notes: list[str] = []
    if Omega_found is None:
        Omega = real_symbol("Omega")
        if Omega in _all_symbols(system):
            raise ModelError(
                f"system {name!r} is unforced but has a parameter Omega: rename it (the slow "
                "flow uses Omega as the frequency of its rotating frame)"
            )
        notes.append(
            "unforced: Omega is the frequency of the rotating frame; a fixed point is a free "
            "periodic orbit at that frequency (undamped case)"
        )
    else:
        Omega = Omega_found

    # ---- symbols
    t = system.t
    eta = (real_symbol("eta_1"), real_symbol("eta_2"))
    etad = (_Primed("eta_1'"), _Primed("eta_2'"))
    A = (sp.Symbol("A_1"), sp.Symbol("A_2"))
    Ab = tuple(sp.conjugate(x) for x in A)
    p = (real_symbol("p_1"), real_symbol("p_2"))
    q = (real_symbol("q_1"), real_symbol("q_2"))
    amp = (sp.Symbol("a_1", nonnegative=True), sp.Symbol("a_2", nonnegative=True))
    gam = (real_symbol("gamma_1"), real_symbol("gamma_2"))
    used = {s.name for s in _all_symbols(system)}
    clash = sorted(used & {s.name for s in (*eta, *p, *q, *amp, *gam)} | (used & {"A_1", "A_2"}))
    if clash:
        raise ModelError(
            f"system {name!r} uses the names {clash}, which the slow flow reserves for its "
            "modal coordinates and amplitudes: rename them"
        )
    E = sp.Dummy("E")  # e^{i omega_b t}
    theta = real_symbol("theta")  # omega_b t, for display

    r = (1, R)
    m_force = r[near - 1]  # Omega = m_force * omega_b
    omega_b = Omega / m_force
    nu = (r[0] * omega_b, r[1] * omega_b)
    w = omegas

    # ---- modal form
    Ct = sp.Matrix(system.C).xreplace({})
    Cm = (Phi.T * Ct * Phi).applyfunc(
        lambda x: sp.nsimplify(sp.expand(x)) if not x.free_symbols else sp.expand(x)
    )
    Fc = sp.Matrix([fc for fc, _ in fparts])
    Fs = sp.Matrix([fs for _, fs in fparts])
    Fm_c = (Phi.T * Fc).applyfunc(sp.expand)
    Fm_s = (Phi.T * Fs).applyfunc(sp.expand)
    qvec = Phi * sp.Matrix(eta)
    qdvec = Phi * sp.Matrix(etad)
    states = system.states  # (x1, x2, x1', x2')
    on_modal = dict(zip(states, (*qvec, *qdvec), strict=True))

    # ansatz in E
    eta_E = [A[j] * E ** r[j] + Ab[j] * E ** (-r[j]) for j in range(2)]
    etad_E = [sp.I * w[j] * (A[j] * E ** r[j] - Ab[j] * E ** (-r[j])) for j in range(2)]
    to_E = dict(zip((*eta, *etad), (*eta_E, *etad_E), strict=True))

    poly_force = [sp.S.Zero, sp.S.Zero]  # modal polynomial element force (eta form)
    pwl: list[tuple[str, sp.Expr, sp.Expr, tuple[sp.Expr, sp.Expr], sp.Expr]] = []
    vals = {real_symbol(k): v for k, v in system.params.items() if v is not None}
    dropped_even = False
    for e in system.elements:
        if e.kind == "stop":
            raise ModelError(
                f"element {e.name!r} of system {name!r} is a rigid stop: impacts are not a weak "
                "force, so the slow flow does not apply; use the exact solvers (perturb.simulate)"
            )
        wvec = sp.Matrix([sp.sympify(x) for x in e.distribution])
        wm = (Phi.T * wvec).applyfunc(sp.expand)
        if e.combination is None:
            f_modal = sp.expand(sp.sympify(e.function).xreplace(on_modal))
            if not f_modal.is_polynomial(*eta, *etad):
                raise ModelError(
                    f"element {e.name!r} of system {name!r}: {e.function} is not polynomial in "
                    "the states: expected polynomial (cubic) terms or a piecewise-linear "
                    "element of one combination"
                )
            deg = sp.Poly(f_modal, *eta, *etad).total_degree()
            _check_degree(e.name, name, deg)
            for k in range(2):
                poly_force[k] += wm[k] * f_modal
            continue
        c = [sp.sympify(x) for x in e.combination]
        s_modal = sp.expand(sp.Add(*(ci * on_modal[y] for ci, y in zip(c, states, strict=True))))
        if s_modal == 0:
            raise ModelError(
                f"element {e.name!r} of system {name!r}: its combination is identically zero"
            )
        f = sp.sympify(e.function)
        if f.is_polynomial(ELEMENT_SYMBOL):
            deg = sp.Poly(f, ELEMENT_SYMBOL).degree() if f.has(ELEMENT_SYMBOL) else 0
            _check_degree(e.name, name, deg)
            fm = sp.expand(f.xreplace({ELEMENT_SYMBOL: s_modal}))
            for k in range(2):
                poly_force[k] += wm[k] * fm
            continue
        if e.kind == "friction" or resonance != "1:1":
            why = (
                "a friction law (sticking is not a weak force)"
                if e.kind == "friction"
                else "piecewise linear, and under a 1:3 resonance its signal s = "
                f"{s_modal} holds the harmonics omega_b and 3 omega_b, whose averaged force has "
                "no simple closed form"
            )
            raise ModelError(
                f"element {e.name!r} of system {name!r} is {why}: the internal-resonance slow "
                "flow takes polynomial elements (and odd piecewise-linear ones under 1:1); use "
                "numeric harmonic balance (perturb.numeric.system_balance) or the exact solvers"
            )
        if not is_odd(f, (ELEMENT_SYMBOL,), vals):
            raise ModelError(
                f"element {e.name!r} of system {name!r}: f(s) = {f} is not odd, so its force has "
                "a mean that shifts the equilibrium; the slow flow assumes none (use the "
                "single-harmonic balance with bias, perturb.methods.system_harmonic_balance)"
            )
        S_sym = sp.Symbol(f"S_{len(pwl) + 1}", positive=True)
        try:
            a1 = series_coefficient(
                f,
                ELEMENT_SYMBOL,
                1,
                S_sym,
                0,
                values={k: v for k, v in system.params.items() if v is not None},
            )
        except (FourierError, NonsmoothError) as exc:
            raise ModelError(
                f"element {e.name!r} of system {name!r}: f(s) = {f} has no closed-form "
                f"describing function ({exc})"
            ) from None
        s_hat = sp.expand(s_modal.xreplace(to_E)).coeff(E, 1)
        pwl.append((e.name, S_sym, sp.expand(a1 / S_sym), (wm[0], wm[1]), s_hat))

    for k in range(2):
        poly_force[k] = sp.expand(poly_force[k])
    # even (quadratic) parts never reach the resonant harmonics at 1:1 or 1:3
    for k in range(2):
        if poly_force[k] != 0:
            even = sp.expand(
                (
                    poly_force[k]
                    + poly_force[k].xreplace({**{x: -x for x in eta}, **{x: -x for x in etad}})
                )
                / 2
            )
            if even != 0:
                dropped_even = True

    # ---- secular terms: the e^{i nu_k t} coefficient of N_k
    N_parts: list[dict[int, sp.Expr]] = []
    secular: list[sp.Expr] = []
    for k in range(2):
        damp = -sp.Add(*(Cm[k, j] * etad[j] for j in range(2)))
        N_E = (damp - poly_force[k]).xreplace(to_E)
        harm = _harmonic_terms(N_E, E)
        fc_k, fs_k = Fm_c[k], Fm_s[k]
        if fc_k != 0 or fs_k != 0:
            # F_c cos + F_s sin = (F_c - i F_s)/2 E^m + c.c.
            harm[m_force] = harm.get(m_force, sp.S.Zero) + (fc_k - sp.I * fs_k) / 2
            harm[-m_force] = harm.get(-m_force, sp.S.Zero) + (fc_k + sp.I * fs_k) / 2
        N_parts.append(harm)
        ck = harm.get(r[k], sp.S.Zero)
        for _, S_sym, _gain, wm, s_hat in pwl:
            ck += -wm[k] * sp.Function(f"N_{S_sym.name[2:]}")(S_sym) * s_hat
        secular.append(sp.expand(ck))

    # describing-function gains: N_e(S) with S = 2|s_hat|
    gain_subs_cart: dict[sp.Basic, sp.Expr] = {}
    cart_A = {A[j]: (p[j] - sp.I * q[j]) / 2 for j in range(2)}
    cart_A.update({Ab[j]: (p[j] + sp.I * q[j]) / 2 for j in range(2)})
    polar_A = {A[j]: amp[j] / 2 * sp.exp(-sp.I * gam[j]) for j in range(2)}
    polar_A.update({Ab[j]: amp[j] / 2 * sp.exp(sp.I * gam[j]) for j in range(2)})
    gain_subs_polar: dict[sp.Basic, sp.Expr] = {}
    amp_defs_cart: list[sp.Equality] = []
    amp_defs_polar: list[sp.Equality] = []
    for _, S_sym, gain, _, s_hat in pwl:
        sr, si = _real_imag(s_hat.xreplace(cart_A))
        S_cart = 2 * sp.sqrt(sr**2 + si**2)
        fn = sp.Function(f"N_{S_sym.name[2:]}")(S_sym)
        gain_subs_cart[fn] = gain.xreplace({S_sym: S_cart})
        amp_defs_cart.append(sp.Eq(S_sym, S_cart, evaluate=False))
        s_pol = _exp_to_trig(s_hat.xreplace(polar_A))
        pr, pi_ = _real_imag(s_pol)
        S_pol = 2 * sp.sqrt(sp.trigsimp(sp.expand(pr**2 + pi_**2)))
        gain_subs_polar[fn] = gain.xreplace({S_sym: S_pol})
        amp_defs_polar.append(sp.Eq(S_sym, S_pol, evaluate=False))

    # ---- slow flows
    complex_flow = tuple(
        sp.expand(-sp.I * (nu[k] - w[k]) * A[k] - sp.I * secular[k] / (2 * w[k])) for k in range(2)
    )
    cart_rhs: list[sp.Expr] = []
    polar_rhs: list[sp.Expr] = []
    # the derivation prints N_e(S_e) by name, with S_e defined beside the flow
    cart_shown: list[sp.Expr] = []
    polar_shown: list[sp.Expr] = []
    for k in range(2):
        fns = {f for f in secular[k].atoms(sp.Function) if f.func.__name__.startswith("N_")}
        c_cart = secular[k].xreplace(cart_A)
        re_c, im_c = _real_imag(c_cart)
        det = nu[k] - w[k]
        pk = -det * q[k] + im_c / w[k]
        qk = det * p[k] + re_c / w[k]
        cart_shown += [sp.expand(pk), sp.expand(qk)]
        cart_rhs += [x.xreplace(gain_subs_cart) for x in cart_shown[-2:]]
        c_pol = _exp_to_trig(secular[k].xreplace(polar_A) * sp.exp(sp.I * gam[k]))
        re_p, im_p = _real_imag(c_pol)
        polar_shown += [sp.expand(im_p / w[k]), sp.expand(det * amp[k] + re_p / w[k])]
        polar_rhs += [x.xreplace(gain_subs_polar) for x in polar_shown[-2:]]
        del fns
    cart = (p[0], q[0], p[1], q[1])
    polar = (amp[0], gam[0], amp[1], gam[1])
    jac = sp.ImmutableMatrix(4, 4, lambda i, j: sp.diff(cart_rhs[i], cart[j]))
    steady = tuple(sp.Eq(x, 0) for x in cart_rhs)
    polar_steady = tuple(sp.Eq(x, 0) for x in polar_rhs)

    waves = tuple(
        sp.expand(
            sp.Add(
                *(
                    Phi[i, j] * (p[j] * sp.cos(nu[j] * t) + q[j] * sp.sin(nu[j] * t))
                    for j in range(2)
                )
            )
        )
        for i in range(2)
    )
    params: set[sp.Symbol] = set()
    for x in (*cart_rhs, *jac):
        params |= x.free_symbols
    params -= {*cart, Omega}
    parameters = tuple(sorted(params, key=str))
    values = MappingProxyType({s.name: system.params.get(s.name) for s in parameters})

    if dropped_even:
        notes.append(
            "even (quadratic) terms of the elements give no resonant first-order term at a 1:1 "
            "or 1:3 resonance; they enter at second order and are dropped"
        )
    notes.append(
        "first order: the fixed points approximate the periodic responses with a relative "
        "error of the order of the small terms (damping, forcing, nonlinearity, detunings)"
    )
    if pwl:
        notes.append(
            "piecewise-linear elements enter through their describing functions N(S), "
            "S = 2|s_hat|; lambdify with perturb.fourier.symbols.NUMERIC_IMPLEMENTATIONS"
        )

    modal_eqs = tuple(
        sp.expand(
            _Primed(f"eta_{k + 1}''")
            + w[k] ** 2 * eta[k]
            + sp.Add(*(Cm[k, j] * etad[j] for j in range(2)))
            + poly_force[k]
            - Fm_c[k] * sp.cos(Omega * t)
            - Fm_s[k] * sp.sin(Omega * t)
        )
        for k in range(2)
    )
    result_args = dict(
        system=system,
        method=_METHOD,
        resonance=resonance,
        ratio=R,
        near=near,
        frequency=Omega,
        time=t,
        modal_matrix=sp.ImmutableMatrix(Phi),
        natural_frequencies=(w[0], w[1]),
        internal_detuning=sp.nsimplify(w[1] - R * w[0]) if not w[0].is_Float else w[1] - R * w[0],
        frame_frequencies=nu,
        modal_damping=sp.ImmutableMatrix(Cm),
        modal_forcing=(
            Fm_c[0] * sp.cos(Omega * t) + Fm_s[0] * sp.sin(Omega * t),
            Fm_c[1] * sp.cos(Omega * t) + Fm_s[1] * sp.sin(Omega * t),
        ),
        modal=eta,
        modal_velocities=etad,
        modal_equations=modal_eqs,
        complex_amplitudes=A,
        secular_terms=tuple(secular),
        complex_slow_flow=complex_flow,
        cartesian=cart,
        slow_flow=tuple(cart_rhs),
        polar=polar,
        polar_slow_flow=tuple(polar_rhs),
        steady_state=steady,
        polar_steady_state=polar_steady,
        jacobian=jac,
        waveforms=waves,
        parameters=parameters,
        values=values,
        notes=tuple(notes),
    )
    shown = {
        "cartesian": (tuple(cart_shown), tuple(amp_defs_cart)),
        "polar": (tuple(polar_shown), tuple(amp_defs_polar)),
    }
    steps = _steps(system, result_args, M, K, pwl, N_parts, theta, omega_b, shown)
    return InternalResonanceSlowFlow(**result_args, steps=steps)


def _check_degree(element: str, name: str, deg: int) -> None:
    if deg > _MAX_DEGREE:
        raise ModelError(
            f"element {element!r} of system {name!r} has degree {deg}: expected at most "
            f"{_MAX_DEGREE} (the expansion of higher powers is too long to print)"
        )


def _all_symbols(system: System) -> set[sp.Symbol]:
    return {real_symbol(k) for k in system.params}


# ------------------------------------------------------------------------- derivation --
def _steps(system, res, M, K, pwl, N_parts, theta, omega_b, shown) -> tuple[Step, ...]:
    """The derivation as (title, mathematics, sentence) steps, in the order a paper writes
    them; equations are SymPy ``Eq`` (unevaluated where a side is a matrix)."""
    Omega = res["frequency"]
    Phi = res["modal_matrix"]
    w1, w2 = res["natural_frequencies"]
    R = res["ratio"]
    near = res["near"]
    eta, A = res["modal"], res["complex_amplitudes"]
    q = sp.Matrix([real_symbol(c) for c in system.coordinates])
    eq = lambda lhs, rhs: sp.Eq(lhs, rhs, evaluate=False)  # noqa: E731
    steps: list[Step] = []
    Ms, Ks, Cs, Phis = (sp.Symbol(n) for n in ("M", "K", "C", "Phi"))
    steps.append(
        Step(
            "The system",
            (
                eq(Ms, sp.ImmutableMatrix(M)),
                eq(Ks, sp.ImmutableMatrix(K)),
                eq(Cs, sp.ImmutableMatrix(system.C)),
                eq(sp.Symbol("F"), sp.ImmutableMatrix(system.F)),
            ),
            text=(
                f"The system {system.name} has the coordinates "
                + ", ".join(f"${sp.latex(real_symbol(c))}$" for c in system.coordinates)
                + " and obeys $M q'' + C q' + K q + f(q, q') = F$. Damping, forcing and the "
                "nonlinear elements are taken as small (of order $\\varepsilon$, set to 1 in "
                "the results)."
            ),
        )
    )
    steps.append(
        Step(
            "Modal coordinates",
            (
                eq(Phis, Phi),
                eq(sp.Symbol("omega_1"), w1),
                eq(sp.Symbol("omega_2"), w2),
                eq(
                    sp.MatrixSymbol("Phi", 2, 2).T
                    * sp.MatrixSymbol("C", 2, 2)
                    * sp.MatrixSymbol("Phi", 2, 2),
                    res["modal_damping"],
                ),
            ),
            text=(
                "The columns of $\\Phi$ are the eigenvectors of $K\\phi = \\omega^2 M\\phi$, "
                "normalised so that $\\Phi^T M \\Phi = I$ and $\\Phi^T K\\Phi = "
                "\\mathrm{diag}(\\omega_1^2, \\omega_2^2)$. With $q = \\Phi\\eta$ the modal "
                "equations read:"
            ),
        )
    )
    steps.append(
        Step(
            "Modal equations",
            tuple(sp.Eq(x, 0) for x in res["modal_equations"]) + (eq(q, Phi * sp.Matrix(eta)),),
        )
    )
    sigma, sigma1 = sp.Symbol("sigma"), sp.Symbol("sigma_1")
    nu = res["frame_frequencies"]
    detune = []
    for k, (nk, wk) in enumerate(zip(nu, (w1, w2), strict=True), 1):
        detune.append(eq(sp.Symbol(f"nu_{k}") - sp.Symbol(f"omega_{k}"), sp.expand(nk - wk)))
    steps.append(
        Step(
            f"The {res['resonance']} internal resonance",
            (
                eq(sigma1, res["internal_detuning"]),
                eq(sigma, sp.expand(Omega - (w1, w2)[near - 1])),
                eq(sp.Symbol("nu_1"), nu[0]),
                eq(sp.Symbol("nu_2"), nu[1]),
                *detune,
            ),
            text=(
                f"Here $\\omega_2 = {R if R != 1 else ''}\\omega_1 + \\sigma_1$ and the forcing "
                f"frequency is near mode {near}, $\\Omega = \\omega_{near} + \\sigma$. Mode $k$ "
                "oscillates at $\\nu_k$, so that "
                "$\\eta_k = A_k(t)\\, e^{i\\nu_k t} + \\bar A_k e^{-i\\nu_k t}$ with slowly "
                "varying $A_k$; the detunings $\\nu_k - \\omega_k$ are small."
            ),
        )
    )
    harm_math = []
    for k, parts in enumerate(N_parts, 1):
        positive = sorted(n for n in parts if n > 0)
        terms = [sp.Mul(parts[n], sp.exp(sp.I * n * theta), evaluate=False) for n in positive]
        if 0 in parts:
            terms.insert(0, parts[0])
        rhs = sp.Add(*terms, evaluate=False) if terms else sp.S.Zero
        harm_math.append(eq(sp.Symbol(f"N_{k}"), rhs))
    steps.append(
        Step(
            "Forces on the ansatz, collected by harmonic",
            tuple(harm_math),
            text=(
                f"With $\\theta = {sp.latex(omega_b)}\\, t$ and $\\eta_k' = i\\omega_k A_k "
                "e^{i\\nu_k t} + \\mathrm{c.c.}$ the modal forces (damping, polynomial elements, "
                "forcing) are sums of harmonics of $\\theta$ (shown: the positive ones and the "
                "mean; the negative ones are their complex conjugates); mode $k$ is resonant with "
                f"$e^{{i\\nu_k t}}$, i.e. the harmonic $e^{{i\\theta}}$ for mode 1 and "
                f"$e^{{{R if R != 1 else ''}i\\theta}}$ for mode 2."
            ),
        )
    )
    if pwl:
        pw = []
        for _name, S_sym, gain, _, s_hat in pwl:
            idx = S_sym.name[2:]
            pw.append(eq(sp.Symbol(f"hat{{S}}_{idx}"), s_hat))
            pw.append(eq(sp.Function(f"N_{idx}")(S_sym), gain))
        steps.append(
            Step(
                "Piecewise-linear elements: describing functions",
                tuple(pw),
                text=(
                    "Under a 1:1 resonance the signal of each piecewise-linear element is one "
                    "harmonic, $s = \\hat S e^{i\\theta} + \\mathrm{c.c.}$, and the resonant part "
                    "of its force is $N(S)\\hat S$ with $S = 2|\\hat S|$ and $N$ its describing "
                    "function (closed-form Fourier coefficients)."
                ),
            )
        )
    steps.append(
        Step(
            "Solvability conditions",
            tuple(
                eq(
                    2 * sp.I * wk * (_Primed(f"A_{k}'") + sp.I * sp.expand(nk - wk) * A[k - 1]),
                    c,
                )
                for k, (wk, nk, c) in enumerate(
                    zip((w1, w2), nu, res["secular_terms"], strict=True), 1
                )
            ),
            text=(
                "Removing the terms of the first-order problem that resonate with "
                "$e^{i\\nu_k t}$ gives the complex slow flow:"
            ),
        )
    )
    p1, q1, p2, q2 = res["cartesian"]
    steps.append(
        Step(
            "Cartesian slow flow",
            tuple(
                sp.Eq(_Primed(f"{x.name}'"), rhs)
                for x, rhs in zip(res["cartesian"], shown["cartesian"][0], strict=True)
            )
            + shown["cartesian"][1],
            text=(
                "With $A_k = (p_k - i q_k)/2$, i.e. $\\eta_k = p_k\\cos\\nu_k t + q_k\\sin\\nu_k "
                "t$:"
            ),
        )
    )
    a1, g1, a2, g2 = res["polar"]
    steps.append(
        Step(
            "Polar slow flow",
            (
                sp.Eq(_Primed("a_1'"), shown["polar"][0][0]),
                sp.Eq(a1 * _Primed("gamma_1'"), shown["polar"][0][1]),
                sp.Eq(_Primed("a_2'"), shown["polar"][0][2]),
                sp.Eq(a2 * _Primed("gamma_2'"), shown["polar"][0][3]),
            )
            + shown["polar"][1],
            text=(
                "With $A_k = \\tfrac12 a_k e^{-i\\gamma_k}$, i.e. $\\eta_k = a_k\\cos(\\nu_k t - "
                "\\gamma_k)$:"
            ),
        )
    )
    steps.append(
        Step(
            "Steady states and their stability",
            (eq(sp.Symbol("J"), res["jacobian"]),) if _jacobian_printable(res["jacobian"]) else (),
            text=(
                "The periodic responses are the fixed points of the Cartesian slow flow "
                "(all four right-hand sides zero; in polar form $a_k' = 0$, "
                "$a_k\\gamma_k' = 0$). A fixed point is stable when every eigenvalue "
                "$\\lambda$ of the Jacobian $J$ of the Cartesian slow flow has a negative real "
                "part; the Floquet multipliers of the response are close to "
                "$e^{\\lambda T}$, $T = 2\\pi/\\nu_1$."
                + (
                    ""
                    if _jacobian_printable(res["jacobian"])
                    else " (The Jacobian is too long to print here.)"
                )
            ),
        )
    )
    return tuple(steps)


def _jacobian_printable(J: sp.MatrixBase) -> bool:
    return all(sp.count_ops(x) <= 12 for x in J)
