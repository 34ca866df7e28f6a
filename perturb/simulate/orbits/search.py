"""All periodic orbits at one forcing frequency, found from many seeds.

:func:`periodic_orbits` collects candidate initial states from

- the attractors reached from a grid of initial conditions (stable orbits),
- a single-harmonic balance approximation at that frequency, when it applies (stable and
  unstable orbits alike: its unstable solutions seed multiple shooting),
- the closed-form steady state of every linear segment of a piecewise-linear force that
  stays inside its segment (exact orbits, e.g. the saddle orbit of ``nsd`` inside ``|x| < 1``),
- multi-start harmonic balance (``H = 9`` or ``ceil(3 omega_max / Omega)`` up to 21; the exact
  Galerkin projection for PWL forces): Newton from each linear segment's forced steady state
  (as if the segment extended everywhere) and from a grid of guesses
  ``c + A cos(j theta - phi)`` in amplitude, mean and phase, for the forcing harmonic
  ``j = 1`` and the superharmonics ``j`` nearest the segments' natural frequencies over
  ``Omega``; then deflated Newton (known solutions deflated) from small perturbations of
  each solution, for the partner of a solution near a fold. Each start is capped at a few
  Newton steps and the whole search at a fixed number of residual evaluations (about 0.5 s
  CPU at Omega = 0.6); every distinct solution seeds multiple shooting. This finds the
  strongly unstable, asymmetric and superharmonic orbits that neither attractors nor the
  single-harmonic approximation reach (nsd, k = -3, Omega = 0.6: 9 orbits, 3 before),
- the caller's own guesses,

corrects each by shooting (multiple shooting for the strongly unstable ones), removes
duplicates and, for a system symmetric under ``(x, t) -> (-x, t + T/2)``, adds the mirror image
of every orbit found.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from perturb.errors import ParameterError, PerturbError
from perturb.model.oscillator import Oscillator
from perturb.simulate.flows.base import Flow, FlowFamily
from perturb.simulate.orbits.shooting import (
    PeriodicOrbit,
    ShootingError,
    multiple_shooting,
    periodic_orbit,
)

__all__ = ["periodic_orbits", "linear_segment_orbits"]

_NODES = 16
#: growth of a perturbation per multiple-shooting sub-interval of a closed-form segment orbit
_NODE_GROWTH = 100.0
#: beyond this many nodes (a multiplier above 100**160 = 1e320) the monodromy overflows anyway
_MAX_SEGMENT_NODES = 160


def linear_segment_orbits(flow: Flow) -> list[np.ndarray]:
    """Initial states ``(x0, v0)`` of the closed-form steady states of each linear segment of
    a PWL flow with one forcing harmonic that stay strictly inside their segment.

    In segment ``i`` the force is ``s_i x + o_i``; the steady state of
    ``x'' + mu x' + s_i x + o_i = c + F cos(w t + p)`` is
    ``x = (c - o_i)/s_i + Re(F e^{i(w t + p)} / (s_i - w^2 + i mu w))`` — an orbit of the
    whole system when it never leaves the segment.
    """
    return [nodes[0] for nodes in _linear_segment_nodes(flow, 1)]


def _linear_segment_nodes(flow: Flow, max_nodes: int) -> list[np.ndarray]:
    """The orbits of :func:`linear_segment_orbits` sampled at ``N`` equally spaced times of
    one forcing period, ``N`` (at most ``max_nodes``) chosen so that a perturbation grows by
    at most ``_NODE_GROWTH`` per sub-interval: the saddle orbit of a negative-stiffness
    segment grows like ``exp(lambda T)``, beyond what single shooting can correct (a factor
    1e76 at Omega = 0.05 for nsd, k = -2), while its nodes are known in closed form."""
    system = getattr(flow, "system", None)
    if system is None or len(system.forcing) != 1:
        return []
    (F, w, ph), mu = system.forcing[0], system.damping
    T = 2.0 * np.pi / w
    edges = np.concatenate([[-np.inf], system.breakpoints, [np.inf]])
    out = []
    for i, (s, o) in enumerate(zip(system.slopes, system.offsets, strict=True)):
        if s == 0:
            continue
        Z = F / complex(s - w * w, mu * w)
        xc = (system.static_force - o) / s
        if edges[i] < xc - abs(Z) and xc + abs(Z) < edges[i + 1]:
            rate = -0.5 * mu + np.sqrt(complex(0.25 * mu * mu - s)).real
            n = int(np.clip(np.ceil(rate * T / np.log(_NODE_GROWTH)), 1, max_nodes))
            phase = Z * np.exp(1j * (w * T * np.arange(n) / n + ph))
            out.append(np.column_stack([xc + phase.real, (1j * w * phase).real]))
    return out


def _approximation_guesses(osc: Oscillator, Omega: float) -> list[np.ndarray]:
    """Node guesses (``_NODES`` states over one period) from single-harmonic balance."""
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
    guesses = []
    tau = np.linspace(0, 2 * np.pi, _NODES, endpoint=False)
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

    R = system.residual(u, Omega)
    m, g = deflation(u)
    norm = m * float(np.linalg.norm(R))
    evaluations = 1
    for _ in range(_SEARCH_ITERATIONS):
        if not np.isfinite(norm):
            return None, evaluations
        J, _ = system.jacobian(u, Omega)
        try:
            du = np.linalg.solve(J, -R)
        except np.linalg.LinAlgError:
            return None, evaluations
        if not np.all(np.isfinite(du)):
            return None, evaluations
        if np.max(np.abs(du)) <= 1e-8 * scale:
            return u + du, evaluations
        if known:
            denom = 1.0 - float(g @ du)
            if abs(denom) > 1e-12:
                du = du / denom
        alpha = 1.0
        for _ in range(_SEARCH_HALVINGS + 1):
            trial = u + alpha * du
            Rt = system.residual(trial, Omega)
            evaluations += 1
            mt, gt = deflation(trial)
            nt = mt * float(np.linalg.norm(Rt))
            if np.isfinite(nt) and nt < (1.0 - 1e-4 * alpha) * norm:
                break
            alpha *= 0.5
        else:
            return None, evaluations
        u, R, norm, g = trial, Rt, nt, gt
    return None, evaluations


def _harmonic_balance_guesses(
    osc: Oscillator, Omega: float, extent: float, symmetric: bool, flow: Flow
) -> list[np.ndarray]:
    """Node guesses (``_NODES`` states over one period) from harmonic-balance solutions
    found by Newton from a grid of starts (module docstring): ``c + A cos(j theta - phi)``
    for the forcing harmonic ``j = 1`` and, below the natural frequencies ``omega_i`` of the
    linear segments, for the superharmonics ``j`` nearest ``omega_i / Omega``."""
    system = getattr(flow, "system", None)
    slopes = np.asarray(getattr(system, "slopes", [1.0]), float)
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
        (F, wf, ph), mu = system.forcing[0], system.damping
        for sl, off in zip(system.slopes, system.offsets, strict=True):
            if sl == 0.0 or abs(wf - Omega) > 1e-12 * Omega:
                continue
            Z = F * np.exp(1j * ph) / complex(sl - wf * wf, mu * wf)
            u = np.zeros(basis.size)
            u[0] = (system.static_force - off) / sl
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
    theta = np.linspace(0.0, 2.0 * np.pi, _NODES, endpoint=False)
    w = Omega / hb.m
    return [
        np.column_stack([basis.evaluate(u, theta), w * basis.evaluate(u, theta, 1)])
        for u in solutions
    ]


def _odd_symmetric(flow: Flow, T: float, extent: float) -> bool:
    """Whether the vector field is invariant under ``(x, v, t) -> (-x, -v, t + T/2)`` (checked
    at a few fixed points, to rounding)."""
    rng = np.random.default_rng(1)
    for _ in range(8):
        t = float(rng.uniform(0.0, T))
        y = rng.uniform(-extent, extent, 2)
        try:
            a = np.asarray(flow.vector_field(t, y), float)
            b = np.asarray(flow.vector_field(t + 0.5 * T, -y), float)
        except (PerturbError, ValueError, ArithmeticError):
            return False
        if not np.all(np.abs(a + b) <= 1e-9 * (1.0 + np.abs(a))):
            return False
    return True


def _mirror(flow: Flow, orbit: PeriodicOrbit) -> PeriodicOrbit | None:
    """The image ``-x(t + T/2)`` of a period-1 orbit, polished by multiple shooting."""
    try:
        _, x, v = orbit.sample(_NODES)
        nodes = -np.roll(np.column_stack([x, v]), -_NODES // 2, axis=0)
        return multiple_shooting(flow, nodes, m=1)
    except (ShootingError, PerturbError):
        return None


def _same(a: PeriodicOrbit, b: PeriodicOrbit) -> bool:
    if a.m != b.m:
        return False
    scale = max(1.0, float(np.max(np.abs(a.y0))))
    if np.max(np.abs(a.y0 - b.y0)) < 1e-6 * scale:
        return True
    # a period-m orbit started at another of its m stroboscopic points is the same orbit
    if a.m > 1:
        t, x, v = b.sample(64 * b.m)
        idx = (np.arange(b.m) * 64).astype(int)
        pts = np.column_stack([x[idx], v[idx]])
        return bool(np.min(np.max(np.abs(pts - a.y0), axis=1)) < 1e-6 * scale)
    return False


def periodic_orbits(
    oscillator: Oscillator,
    Omega: float | None = None,
    *,
    m: int = 1,
    guesses: Sequence[Sequence[float]] = (),
    grid: int = 3,
    transient_periods: int = 100,
    extent: float | None = None,
) -> tuple[PeriodicOrbit, ...]:
    """Every period-``m`` orbit found at forcing frequency ``Omega``.

    Parameters
    ----------
    oscillator
        A forced oscillator; parameters need values (``Omega`` overrides the frequency).
    m
        Forcing periods per orbit.
    guesses
        Extra initial states ``(x0, v0)`` to shoot from.
    grid
        ``grid x grid`` initial conditions over ``[-extent, extent]^2`` are simulated for
        ``transient_periods`` to find attractors (``extent`` defaults to three times the
        largest breakpoint, or 3).

    Returns
    -------
    tuple of PeriodicOrbit
        Sorted by amplitude.
    """
    family = FlowFamily(oscillator)
    name = family.parameter
    if Omega is None:
        Omega = oscillator.params.get(name)
        if Omega is None:
            raise ParameterError(f"no value for the forcing frequency {name!r}: pass Omega=")
    flow = family.at(float(Omega))
    osc = oscillator.with_params({name: float(Omega)})
    if extent is None:
        bps = getattr(getattr(flow, "system", None), "breakpoints", np.array([]))
        extent = 3.0 * max(1.0, float(np.max(np.abs(bps)))) if len(bps) else 3.0
    T = flow.period
    if T is None:  # e.g. F = 0: the harmonic load vanishes and the flow is autonomous
        raise ParameterError(
            f"the flow of {oscillator.name!r} at {name} = {Omega!r} has no forcing period (a "
            "zero forcing amplitude?): periodic_orbits needs a periodic forcing; use "
            "perturb.simulate.orbits.shooting.limit_cycle for autonomous systems"
        )
    candidates: list[tuple[str, np.ndarray]] = []
    for x0 in np.linspace(-extent, extent, grid):
        for v0 in np.linspace(-extent, extent, grid):
            try:
                y = flow([x0, v0], 0.0, transient_periods * T).y
            except PerturbError:
                continue
            candidates.append(("single", y))
    if m == 1:
        candidates += [
            ("single", nodes[0]) if len(nodes) == 1 else ("multiple", nodes)
            for nodes in _linear_segment_nodes(flow, _MAX_SEGMENT_NODES)
        ]
        candidates += [("multiple", g) for g in _approximation_guesses(osc, float(Omega))]
        symmetric = _odd_symmetric(flow, T, extent)
        candidates += [
            ("multiple", g)
            for g in _harmonic_balance_guesses(osc, float(Omega), extent, symmetric, flow)
        ]
    else:
        symmetric = False
    candidates += [("single", np.asarray(g, float)) for g in guesses]
    found: list[PeriodicOrbit] = []
    for how, guess in candidates:
        try:
            if how == "single":
                orbit = periodic_orbit(flow, guess, m=m)
            else:
                orbit = multiple_shooting(flow, guess, m=m)
        except (ShootingError, PerturbError):
            continue
        if not any(_same(orbit, other) for other in found):
            found.append(orbit)
    if symmetric:
        for orbit in list(found):
            image = _mirror(flow, orbit)
            if image is not None and not any(_same(image, other) for other in found):
                found.append(image)
    return tuple(sorted(found, key=lambda o: o.amplitude))
