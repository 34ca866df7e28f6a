"""All periodic orbits at one forcing frequency, found from many seeds.

:func:`periodic_orbits` collects candidate initial states from

- the attractors reached from a grid of initial conditions (stable orbits),
- the closed-form steady state of every linear segment of a piecewise-linear force that
  stays inside its segment (exact orbits, e.g. the saddle orbit of ``nsd`` inside ``|x| < 1``;
  multiple shooting from closed-form nodes for a strongly unstable one),
- the caller's node guesses (whole orbits, corrected by multiple shooting): the front door
  :func:`perturb.solve.periodic_orbits` passes those of
  :func:`perturb.seeds.periodic_orbit_guesses` — single-harmonic balance and a multi-start
  numeric harmonic-balance search, which find the strongly unstable, asymmetric and
  superharmonic orbits that attractors do not reach (nsd, k = -3, Omega = 0.6: 9 orbits),
- the caller's own initial states,

corrects each by shooting (multiple shooting for the strongly unstable ones), removes
duplicates and, for a system symmetric under ``(x, t) -> (-x, t + T/2)``
(:mod:`perturb.model.symmetry`), adds the mirror image of every orbit found.  This module
never imports an approximation (contract ``independent-references``): every seed only starts
Newton on the exact flow, and an orbit is accepted on the exact flow's residual.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from perturb.errors import ParameterError, PerturbError
from perturb.model.oscillator import Oscillator
from perturb.model.segments import segment_steady_states
from perturb.model.symmetry import is_odd_symmetric, mirror_nodes
from perturb.simulate.flows.base import Flow, as_flow
from perturb.simulate.flows.factory import FlowFamily
from perturb.simulate.orbits.shooting import (
    PeriodicOrbit,
    ShootingError,
    multiple_shooting,
    periodic_orbit,
)

__all__ = ["periodic_orbits", "linear_segment_orbits", "default_extent", "odd_symmetric", "NODES"]

#: states per forcing period of the node guesses (multiple shooting) made here and by
#: :func:`perturb.seeds.periodic_orbit_guesses`
NODES = 16
_NODES = NODES
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
    whole system when it never leaves the segment
    (:func:`perturb.model.segments.segment_steady_states`).
    """
    return [nodes[0] for nodes in _linear_segment_nodes(as_flow(flow), 1)]


def _linear_segment_nodes(flow: Flow, max_nodes: int) -> list[np.ndarray]:
    """The orbits of :func:`linear_segment_orbits` sampled at ``N`` equally spaced times of
    one forcing period, ``N`` (at most ``max_nodes``) chosen so that a perturbation grows by
    at most ``_NODE_GROWTH`` per sub-interval: the saddle orbit of a negative-stiffness
    segment grows like ``exp(lambda T)``, beyond what single shooting can correct (a factor
    1e76 at Omega = 0.05 for nsd, k = -2), while its nodes are known in closed form."""
    system = flow.system
    if system is None or len(system.forcing) != 1:
        return []
    (_, w, ph), mu = system.forcing[0], system.damping
    T = 2.0 * np.pi / w
    out = []
    for st in segment_steady_states(
        system.breakpoints,
        system.slopes,
        system.offsets,
        system.damping,
        system.forcing,
        system.static_force,
    ):
        if st is not None and st.inside:
            rate = -0.5 * mu + np.sqrt(complex(0.25 * mu * mu - st.slope)).real
            n = int(np.clip(np.ceil(rate * T / np.log(_NODE_GROWTH)), 1, max_nodes))
            # the forcing angle w t_k as w T k / n (not w (T k / n)): the nodes of earlier
            # versions, to the bit
            phase = st.responses[0] * np.exp(1j * (w * T * np.arange(n) / n + ph))
            out.append(np.column_stack([st.centre + phase.real, (1j * w * phase).real]))
    return out


def default_extent(flow: Flow) -> float:
    """Half-width of the box of initial conditions and the scale of guesses: three times the
    largest breakpoint of a PWL flow (at least 3), else 3."""
    flow = as_flow(flow)
    bps = flow.system.breakpoints if flow.system is not None else np.array([])
    return 3.0 * max(1.0, float(np.max(np.abs(bps)))) if len(bps) else 3.0


def odd_symmetric(flow: Flow, T: float, extent: float) -> bool:
    """Whether the flow's vector field is invariant under ``(x, v, t) -> (-x, -v, t + T/2)``:
    :func:`perturb.model.symmetry.is_odd_symmetric` (checked at a few fixed points of the box
    ``[-extent, extent]^2``, to rounding) on ``flow.vector_field``."""
    return is_odd_symmetric(flow.vector_field, T, extent)


def _mirror(flow: Flow, orbit: PeriodicOrbit) -> PeriodicOrbit | None:
    """The image ``-x(t + T/2)`` of a period-1 orbit
    (:func:`perturb.model.symmetry.mirror_nodes` of its samples), polished by multiple
    shooting."""
    try:
        _, x, v = orbit.sample(_NODES)
        return multiple_shooting(flow, mirror_nodes(np.column_stack([x, v])), m=1)
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
    node_guesses: Sequence[np.ndarray] = (),
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
    node_guesses
        Extra guesses of whole orbits, each an array of ``N`` states ``(x, v)`` at equally
        spaced times of one forcing period from ``t = 0``, corrected by multiple shooting
        (e.g. :func:`perturb.seeds.periodic_orbit_guesses`, approximations' solutions, as
        the front door :func:`perturb.solve.periodic_orbits` passes them).  Like every seed
        they only start Newton: an orbit is accepted on the exact flow's residual.
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
    if extent is None:
        extent = default_extent(flow)
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
        symmetric = odd_symmetric(flow, T, extent)
    else:
        symmetric = False
    # after the closed-form orbits, before the caller's single states: the order in which
    # candidates are shot decides which of two equal orbits is kept
    candidates += [("multiple", np.asarray(g, float)) for g in node_guesses]
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
