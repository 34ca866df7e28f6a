"""Starting guesses from cheap approximations: the only bridge from methods/numeric to simulate.

The reference solvers of :mod:`perturb.simulate` never import the approximations they judge
(contract ``independent-references`` in ``pyproject.toml``).  They still profit from a good
start: an approximation's solutions lie near most exact orbits, including the unstable ones
that no simulation reaches.  This module computes such starts from the approximations, and
the front doors (:mod:`perturb.solve`) pass them to the solvers as arguments.  A seed only
starts a Newton iteration on the exact flow: every orbit is accepted on the exact flow's
residual, so a bad seed costs time (or finds nothing), never a wrong orbit.

Three kinds of seed:

:func:`approximation_seeds`
    ``(Omega, (x0, v0))`` pairs along every branch of an amplitude-parametrised
    approximation, for :func:`perturb.simulate.exact_response.exact_branches` (``seeds=``).
:func:`periodic_orbit_guesses`
    Node arrays (states over one forcing period) at one frequency from single-harmonic
    balance and from a multi-start numeric harmonic-balance search, for
    :func:`perturb.simulate.orbits.search.periodic_orbits` (``node_guesses=``).
:func:`single_harmonic_seeds`
    Single-harmonic balance points as coefficient vectors of numeric harmonic balance,
    for :func:`perturb.numeric.harmonic_balance.harmonic_balance_branches` (``seeds=``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from perturb.errors import ParameterError, PerturbError
from perturb.model.oscillator import Oscillator
from perturb.model.segments import segment_steady_states
from perturb.numeric.harmonic_balance import HarmonicBalanceSystem
from perturb.numeric.roots import damped_newton

if TYPE_CHECKING:
    from perturb.simulate.flows.base import Flow

# the reference flows (and scipy.integrate with them, ~0.3 s of CPU per cold process) are
# imported by the periodic-orbit guesses that use them, not by single_harmonic_seeds

__all__ = [
    "approximation_seeds",
    "periodic_orbit_guesses",
    "harmonic_balance_guesses",
    "single_harmonic_guesses",
    "single_harmonic_seeds",
]


# =============================================================================================
# exact continuation: (Omega, (x0, v0)) along an approximation's branches
# =============================================================================================
def approximation_seeds(
    approximation: Any, window: Sequence[float], per_branch: int = 16
) -> list[tuple[float, np.ndarray]]:
    """``(Omega, (x0, v0))`` along every branch of an amplitude-parametrised approximation.

    The approximation has a waveform ``x(tau)``, ``tau = Omega t``, and unknowns
    ``(A, phase)``; the amplitude unknown is taken as the branch's first-harmonic amplitude
    (exact for single-harmonic balance).  ``per_branch`` points are spread evenly in arc
    length (frequency over the window, amplitude over the branch's largest) along each
    branch, detached loops included.

    Parameters
    ----------
    approximation
        An :class:`~perturb.approximation.Approximation`, e.g. ``single_harmonic_balance(osc)``.
    window
        ``(low, high)`` forcing frequencies.
    per_branch
        Seeds per branch.

    Raises
    ------
    ParameterError
        Not an approximation, or one without an amplitude parametrisation.
    """
    import sympy as sp

    from perturb.approximation import Approximation
    from perturb.numeric.amplitude import approximation_response
    from perturb.numeric.compile import bind_parameters, lambdify

    if not isinstance(approximation, Approximation):
        raise ParameterError(
            f"approximation = {approximation!r}: expected an Approximation (e.g. "
            "single_harmonic_balance(osc)); pass states as seeds= instead"
        )
    ap = approximation
    if ap.amplitude is None or ap.phase_from is None or len(ap.unknowns) != 2:
        raise ParameterError(
            f"{ap.label}: seeds need an amplitude-parametrised approximation with unknowns "
            "(A, phase) and phase_from"
        )
    window = (float(window[0]), float(window[1]))
    resp = approximation_response(ap, window, points=400, stability="slow_flow")
    A, Om, ph, tau = ap.amplitude, ap.frequency, ap.unknowns[1], ap.tau
    keep = (A, Om, ph, tau)
    wave, dwave, pc, ps = bind_parameters(
        ap, [ap.waveform, sp.diff(ap.waveform, tau), *ap.phase_from], keep
    )
    fx = lambdify((tau, A, ph, Om), [wave, dwave])
    fphi = lambdify((A, Om), [pc, ps])
    Sp = window[1] - window[0]
    out = []
    for br in resp.branches:
        w, a = br.omega, br.first_harmonic_amplitude
        if w.size == 0:
            continue
        s = np.r_[0.0, np.cumsum(np.hypot(np.diff(w) / Sp, np.diff(a) / max(1.0, a.max())))]
        targets = np.linspace(0.0, s[-1], per_branch + 2)[1:-1] if s[-1] > 0 else [0.0]
        idx = np.unique(np.searchsorted(s, targets).clip(0, w.size - 1))
        c, sn = fphi(a[idx], w[idx])
        phi = np.arctan2(sn, c)
        x0, dx = fx(np.zeros(idx.size), a[idx], phi, w[idx])
        for wi, xi, vi in zip(w[idx], x0, w[idx] * dx, strict=True):
            if np.isfinite(xi) and np.isfinite(vi):
                out.append((float(wi), np.array([xi, vi], dtype=float)))
    return out


# =============================================================================================
# periodic orbits at one frequency: node guesses for multiple shooting
# =============================================================================================
def periodic_orbit_guesses(
    oscillator: Oscillator, Omega: float | None = None, *, extent: float | None = None
) -> list[np.ndarray]:
    """Node guesses at forcing frequency ``Omega`` for
    :func:`perturb.simulate.orbits.search.periodic_orbits` (``node_guesses=``): those of
    :func:`single_harmonic_guesses`, then those of :func:`harmonic_balance_guesses`.

    Parameters
    ----------
    oscillator
        A forced oscillator; parameters need values (``Omega`` overrides the frequency).
    Omega
        Forcing frequency (default: the oscillator's value).
    extent
        Scale of the search's starts (default that of ``periodic_orbits``).

    Returns
    -------
    list of numpy.ndarray
        Arrays of ``NODES`` states ``(x, v)`` over one forcing period from ``t = 0``.
    """
    from perturb.simulate.flows.factory import FlowFamily
    from perturb.simulate.orbits.search import default_extent, odd_symmetric

    family = FlowFamily(oscillator)
    name = family.parameter
    if Omega is None:
        Omega = oscillator.params.get(name)
        if Omega is None:
            raise ParameterError(f"no value for the forcing frequency {name!r}: pass Omega=")
    flow = family.at(float(Omega))
    T = flow.period
    if T is None:
        return []  # no forcing period: periodic_orbits refuses it with its own message
    osc = oscillator.with_params({name: float(Omega)})
    if extent is None:
        extent = default_extent(flow)
    symmetric = odd_symmetric(flow, T, extent)
    out = single_harmonic_guesses(osc, float(Omega))
    out += harmonic_balance_guesses(osc, float(Omega), extent, symmetric, flow)
    return out


def single_harmonic_guesses(osc: Oscillator, Omega: float) -> list[np.ndarray]:
    """Node guesses (:data:`~perturb.simulate.orbits.search.NODES` states over one period)
    from every single-harmonic balance solution at ``Omega``, stable and unstable alike
    (none when the method does not apply)."""
    try:
        from perturb.methods.harmonic_balance import single_harmonic_balance
        from perturb.numeric.amplitude import solutions_at
        from perturb.numeric.compile import bind_parameters, lambdify

        approx = single_harmonic_balance(osc)
        resp = solutions_at(approx, [Omega], stability="slow_flow")
        A_sym, W_sym = approx.amplitude, approx.frequency
        parts = bind_parameters(approx, list(approx.phase_from or (1, 0)), (A_sym, W_sym))
        phase_parts = lambdify((A_sym, W_sym), parts)
    except PerturbError:
        return []
    from perturb.simulate.orbits.search import NODES

    guesses = []
    tau = np.linspace(0, 2 * np.pi, NODES, endpoint=False)
    for br in resp.branches:
        for A in br.first_harmonic_amplitude:
            c, s_ = phase_parts(float(A), float(Omega))
            phi = float(np.arctan2(s_, c))
            # x = A cos(tau - phi) with tau = Omega t
            guesses.append(np.column_stack([A * np.cos(tau - phi), -Omega * A * np.sin(tau - phi)]))
    return guesses


#: harmonics of the multi-start harmonic-balance search (orbits are polished by shooting)
_SEARCH_HARMONICS = 9
#: and at least this many times the largest natural frequency over Omega (up to 21)
_HARMONICS_PER_RATIO = 3.0
#: Newton steps per start, step halvings per Newton step, and residual evaluations for the
#: whole multi-start search (a bound on its work)
_SEARCH_ITERATIONS = 12
_SEARCH_HALVINGS = 4
_SEARCH_BUDGET = 6000
_DEFLATION_BUDGET = 1500


def _search_newton(
    system, u, Omega: float, scale: float, known: Sequence[np.ndarray] = ()
) -> tuple[np.ndarray | None, int]:
    """Damped, deflated Newton on the HB residual from one start, cheap to abandon: at most
    ``_SEARCH_ITERATIONS`` steps of at most ``_SEARCH_HALVINGS`` halvings each (a start that
    needs more is dropped: the grid has others). The solutions ``known`` already are deflated
    (Farrell, Birkisson & Funke 2015): Newton runs on ``m(u) R(u)`` with
    ``m = prod(1 + |(u - u_i)/s|^-2)``, whose step is the Newton step ``d`` of ``R`` times
    ``1 / (1 - grad(log m) . d)``, so a start in the basin of a known solution is pushed on
    to another one instead of converging again. Returns the solution (None when it failed)
    and the number of residual evaluations spent."""
    known = [np.asarray(k) for k in known]

    def deflation(v: np.ndarray) -> tuple[float, np.ndarray]:
        m, g = 1.0, np.zeros_like(v)
        for k in known:
            e = (v - k) / scale
            r2 = max(float(e @ e), 1e-300)
            m_i = 1.0 + 1.0 / r2
            m *= m_i
            g += (-2.0 / (r2 * r2) / m_i / scale) * e
        return m, g

    R0 = system.residual(u, Omega)
    if not np.isfinite(deflation(u)[0] * float(np.linalg.norm(R0))):
        return None, 1
    # damped_newton evaluates the start first: hand it the residual already computed (the
    # finiteness test above needs the deflated norm, which damped_newton does not check)
    pending = [R0]

    def residual(v: np.ndarray) -> np.ndarray:
        return pending.pop() if pending else system.residual(v, Omega)

    def merit(v: np.ndarray, r: np.ndarray) -> float:
        # the deflated norm m(u) |R(u)| of the line search
        return deflation(v)[0] * float(np.linalg.norm(r))

    def deflate(v: np.ndarray, d: np.ndarray) -> np.ndarray:
        # the Newton step of m R: d / (1 - grad(log m) . d), left alone near a pole
        if not known:
            return d
        denom = 1.0 - float(deflation(v)[1] @ d)
        return d / denom if abs(denom) > 1e-12 else d

    res = damped_newton(
        residual,
        u,
        jac=lambda v: system.jacobian(v, Omega)[0],
        merit=merit,
        modify_step=deflate,
        solve=np.linalg.solve,
        max_iter=_SEARCH_ITERATIONS,
        max_halvings=_SEARCH_HALVINGS,
        scale=scale,
        step_tol=1e-8,
        take_final_step=True,
    )
    return (res.z if res.converged else None), res.evaluations


def harmonic_balance_guesses(
    osc: Oscillator, Omega: float, extent: float, symmetric: bool, flow: Flow
) -> list[np.ndarray]:
    """Node guesses (``NODES`` states over one period) from harmonic-balance solutions
    found by Newton from a grid of starts (module docstring): ``c + A cos(j theta - phi)``
    for the forcing harmonic ``j = 1`` and, below the natural frequencies ``omega_i`` of the
    linear segments, for the superharmonics ``j`` nearest ``omega_i / Omega``."""
    from perturb.simulate.flows.base import as_flow
    from perturb.simulate.orbits.search import NODES

    system = as_flow(flow).system
    slopes = np.asarray(system.slopes if system is not None else [1.0], float)
    naturals = np.sqrt(slopes[slopes > 0.0]) if np.any(slopes > 0.0) else np.array([1.0])
    harmonics = int(
        np.clip(np.ceil(_HARMONICS_PER_RATIO * naturals.max() / Omega), _SEARCH_HARMONICS, 21)
    )
    try:
        from perturb.numeric.harmonic_balance import HarmonicBalanceSystem

        hb = HarmonicBalanceSystem(osc, harmonics=harmonics)
    except PerturbError:
        return []
    basis = hb.basis
    if not basis.bias:
        return []
    means = extent * np.array([0.0, 1 / 6, 0.5, 1.0])
    if not symmetric:  # otherwise mirror images supply the negative means
        means = np.concatenate([means, -means[1:]])
    phases = np.arange(4) * (np.pi / 2)
    supers = sorted(
        {
            j
            for r in naturals / Omega
            for j in (math.floor(r), math.ceil(r))
            if 2 <= j <= harmonics // 2
        }
    )
    # superharmonic starts first: the forcing harmonic's large orbits also have hb1 seeds
    starts = [(j, A) for j in supers for A in np.geomspace(0.3 * extent, 5.0 * extent, 5)]
    starts += [(1, A) for A in np.geomspace(0.03 * extent, 7.0 * extent, 12)]
    budget = _SEARCH_BUDGET
    solutions: list[np.ndarray] = []
    # each linear segment's forced steady state, as if the segment extended everywhere
    pos1 = basis.index_of(1)
    if system is not None and len(system.forcing) == 1 and pos1 is not None:
        wf = system.forcing[0][1]
        steady = segment_steady_states(
            system.breakpoints,
            system.slopes,
            system.offsets,
            system.damping,
            system.forcing,
            system.static_force,
        )
        for st in steady:
            if st is None or abs(wf - Omega) > 1e-12 * Omega:
                continue
            Z = st.amplitude
            u = np.zeros(basis.size)
            u[0] = st.centre
            u[pos1], u[pos1 + 1] = Z.real, -Z.imag
            if abs(u[0]) + abs(Z) > 1e3 * extent:
                continue
            u, evaluations = _search_newton(hb, u, Omega, max(1.0, abs(Z), abs(u[0])))
            budget -= evaluations
            if u is not None and np.all(np.isfinite(u)) and np.max(np.abs(u)) < 1e3 * extent:
                scale = max(1.0, float(np.max(np.abs(u))))
                if not any(np.max(np.abs(u - v)) < 1e-5 * scale for v in solutions):
                    solutions.append(u)
    for j, A in starts:
        pos = basis.index_of(j)
        if pos is None:
            continue
        for c in means:
            for phi in phases:
                if budget <= 0:
                    break
                u = np.zeros(basis.size)
                u[0], u[pos], u[pos + 1] = c, A * np.cos(phi), A * np.sin(phi)
                u, evaluations = _search_newton(hb, u, Omega, max(1.0, A))
                budget -= evaluations
                if u is None:
                    continue
                if not np.all(np.isfinite(u)) or np.max(np.abs(u)) > 1e3 * extent:
                    continue
                scale = max(1.0, float(np.max(np.abs(u))))
                if not any(np.max(np.abs(u - v)) < 1e-5 * scale for v in solutions):
                    solutions.append(u)
    # second pass: a solution near a fold has a partner close by, in the basin of the first;
    # deflated Newton from small perturbations of each solution finds it
    budget = _DEFLATION_BUDGET
    for u0 in list(solutions):
        scale = max(1.0, float(np.max(np.abs(u0))))
        for factor, shift in ((0.95, 0.0), (1.05, 0.0), (1.0, 0.1), (1.0, -0.1)):
            if budget <= 0:
                break
            u = factor * u0
            u[0] = u0[0] + shift * extent
            u, evaluations = _search_newton(hb, u, Omega, scale, solutions)
            budget -= evaluations
            if u is not None and np.all(np.isfinite(u)) and np.max(np.abs(u)) < 1e3 * extent:
                if not any(np.max(np.abs(u - v)) < 1e-5 * scale for v in solutions):
                    solutions.append(u)
    theta = np.linspace(0.0, 2.0 * np.pi, NODES, endpoint=False)
    w = Omega / hb.m
    return [
        np.column_stack([basis.evaluate(u, theta), w * basis.evaluate(u, theta, 1)])
        for u in solutions
    ]


# =============================================================================================
# numeric harmonic balance: coefficient vectors on single-harmonic branches
# =============================================================================================
def single_harmonic_seeds(
    system: HarmonicBalanceSystem, window: tuple[float, float], per_branch: int
) -> list[tuple[float, np.ndarray]]:
    """Starting guesses ``(Omega, u)`` for numeric harmonic balance
    (:func:`perturb.numeric.harmonic_balance.harmonic_balance_branches`, ``seeds=``) on
    every branch of the single-harmonic balance response (amplitude parametrisation:
    detached loops included, no continuation), at ``per_branch`` points spread along each
    branch. Empty when the method does not apply.

    Only the response's public columns are used: the mean ``a0`` and the first-harmonic
    amplitude ``A``. The phase follows from this system's own residual: the equation of
    motion is time-invariant, so shifting ``x = a0 + A cos theta`` in time turns the
    first-harmonic part ``Z = R_a1 - i R_b1`` of its unforced residual by the same angle,
    and the shift that turns ``Z`` onto the forcing's ``F_a1 - i F_b1`` balances it."""
    from perturb.methods import single_harmonic_balance
    from perturb.numeric.amplitude import approximation_response

    basis = system.basis
    pos = basis.index_of(system.m)
    if pos is None:
        return []
    try:
        resp = approximation_response(
            single_harmonic_balance(system.oscillator), window, points=400, stability="slow_flow"
        )
    except PerturbError:
        return []
    seeds = []
    for br in resp.branches:
        n = br.omega.size
        idx = np.unique(np.linspace(0, n - 1, per_branch + 2).round().astype(int)[1:-1])
        for j in idx:
            W, A = float(br.omega[j]), float(br.first_harmonic_amplitude[j])
            if not (math.isfinite(W) and math.isfinite(A) and A > 0):
                continue
            u = np.zeros(basis.size)
            if basis.bias:
                u[0] = float(br.mean[j])
            u[pos] = A
            fh, fs, _ = system.forcing_vector(W)
            R = system.evaluate(u, W, jacobian=False)[0] + fh
            Z = complex(R[pos], -R[pos + 1])
            target = complex(fh[pos], -fh[pos + 1])
            if Z == 0 or target == 0:
                continue
            turn = (target / Z) / abs(target / Z)
            u[pos], u[pos + 1] = (A * turn).real, -(A * turn).imag
            seeds.append((W, u))
    return seeds
