"""All periodic orbits at one forcing frequency, found from many seeds.

:func:`periodic_orbits` collects candidate initial states from

- the attractors reached from a grid of initial conditions (stable orbits),
- a single-harmonic balance approximation at that frequency, when it applies (stable and
  unstable orbits alike: its unstable solutions seed multiple shooting),
- the closed-form steady state of every linear segment of a piecewise-linear force that
  stays inside its segment (exact orbits, e.g. the saddle orbit of ``nsd`` inside ``|x| < 1``),
- the caller's own guesses,

corrects each by shooting (multiple shooting for the strongly unstable ones) and removes
duplicates.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..errors import ParameterError, PerturbError
from ..model import Oscillator
from .flow import Flow, FlowFamily
from .shooting import PeriodicOrbit, ShootingError, multiple_shooting, periodic_orbit

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
        from ..methods.harmonic_balance import single_harmonic_balance
        from ..numeric.compile import bind_parameters, lambdify
        from ..numeric.frequency_response import solutions_at

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
            "perturb.simulate.shooting.limit_cycle for autonomous systems"
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
    return tuple(sorted(found, key=lambda o: o.amplitude))
