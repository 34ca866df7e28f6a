"""An exact-orbit oracle for the builtin ``impact_pair`` system, written independently of
perturb (no perturb.simulate / perturb.numeric / perturb.fourier) and shared by
``test_edge_solutions``, ``test_exact_impact_pair_gap`` and ``test_impact_pair_galerkin``.

The equations are typed here from the builtin's docstring::

    x1'' + mu x1' + x1 + r b(x1 - x2) = F cos(W t),
    m2 x2'' + mu2 (x2' - x1') - r b(x1 - x2) = 0,   b(s) = (s-d)H(s-d) + (s+d)H(-s-d),

state ``(x1, x2, x1', x2')`` (perturb's order). The flow is integrated by ``solve_ivp``
(DOP853, rtol = atol = 1e-12) one contact state at a time: free (``|s| <= d``, b = 0) or in
contact on side +1 (b = s - d) or -1 (b = s + d), each with its own smooth field, stopped by a
terminal event at the switch ``|x1 - x2| = d`` with a direction (entering from free, leaving
from contact), so the restart at the event state does not fire the same event again.
``max_step`` is T/2000 by default: a contact shallower than one step would otherwise go
unseen, and the free field would then leave its force out altogether. Periodic orbits by
Newton on the period map with a central-difference Jacobian, at most ``max_iterations``
steps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.integrate import solve_ivp

#: The builtin's defaults (perturb/model/system_builtins.py), typed here; Omega is an argument.
P_DEFAULT = {"mu": 0.05, "mu2": 0.01, "r": 20.0, "d": 0.5, "m2": 0.2, "F": 0.5}
RTOL = ATOL = 1e-12
STEPS_PER_PERIOD = 2000  # max_step = T / STEPS_PER_PERIOD
MAX_SWITCHES = 200  # per flow; a period of these orbits has 4-10


def _rhs(side: int, W: float, p: dict):
    """The smooth field of one contact state (0 free, +1 / -1 in contact on that side)."""
    F, mu, mu2, r, d, m2 = p["F"], p["mu"], p["mu2"], p["r"], p["d"], p["m2"]
    off = d if side == 1 else -d

    def f(t, y):
        x1, x2, v1, v2 = y
        b = (x1 - x2 - off) if side else 0.0
        a1 = F * math.cos(W * t) - mu * v1 - x1 - r * b
        a2 = (r * b - mu2 * (v2 - v1)) / m2
        return [v1, v2, a1, a2]

    return f


def _events(side: int, d: float):
    """Terminal events of a contact state: entering a contact from free (s - d rising through
    0, s + d falling through 0), leaving it (the other way)."""

    def upper(t, y):
        return y[0] - y[1] - d

    def lower(t, y):
        return y[0] - y[1] + d

    if side == 0:
        upper.direction, lower.direction = 1, -1
        evs = [upper, lower]
    elif side == 1:
        upper.direction = -1
        evs = [upper]
    else:
        lower.direction = 1
        evs = [lower]
    for e in evs:
        e.terminal = True
    return evs


def side_of(y, d: float) -> int:
    s = y[0] - y[1]
    return 1 if s > d else (-1 if s < -d else 0)


@dataclass
class Flight:
    """One integration: the end state, the number of contact switches and, with
    ``dense=True``, the pieces ``(t0, t1, side, dense output)`` between them."""

    y: np.ndarray
    switches: int
    segments: list = field(default_factory=list)

    def sample(self, t) -> np.ndarray:
        """The state (4, len(t)) at times within the flight (needs ``dense=True``)."""
        assert self.segments, "sample() needs flow(..., dense=True)"
        t = np.asarray(t, float)
        starts = np.array([s[0] for s in self.segments])
        idx = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(starts) - 1)
        out = np.empty((4, t.size))
        for i in np.unique(idx):
            m = idx == i
            out[:, m] = self.segments[i][3](t[m])
        return out


def flow(
    W: float,
    y0,
    p: dict = P_DEFAULT,
    *,
    t1: float | None = None,
    max_step: float | None = None,
    dense: bool = False,
) -> Flight:
    """The flow from ``y0`` at t = 0 to ``t1`` (default one forcing period 2 pi / W)."""
    T = 2.0 * math.pi / W
    t1 = T if t1 is None else float(t1)
    max_step = T / STEPS_PER_PERIOD if max_step is None else max_step
    t, y = 0.0, np.array(y0, dtype=float)
    side = side_of(y, p["d"])
    segments = []
    for switches in range(MAX_SWITCHES + 1):
        sol = solve_ivp(
            _rhs(side, W, p),
            (t, t1),
            y,
            method="DOP853",
            rtol=RTOL,
            atol=ATOL,
            max_step=max_step,
            events=_events(side, p["d"]),
            dense_output=dense,
        )
        if sol.status < 0:
            raise AssertionError(f"oracle integration failed: {sol.message}")
        if dense:
            segments.append((t, float(sol.t[-1]), side, sol.sol))
        t, y = float(sol.t[-1]), sol.y[:, -1].copy()
        if sol.status != 1 or t >= t1:
            return Flight(y, switches, segments)
        # at s = +-d: from free into the contact on that side, from a contact back to free
        side = (1 if y[0] - y[1] > 0 else -1) if side == 0 else 0
    raise AssertionError(f"oracle: more than {MAX_SWITCHES} contact switches before t = {t1}")


def monodromy(W: float, y, p: dict = P_DEFAULT, *, rel_step: float = 1e-6, **flow_kw) -> np.ndarray:
    """Jacobian of the period map by central differences (step rel_step max(1, |y_k|))."""
    y = np.asarray(y, float)
    J = np.zeros((4, 4))
    for k in range(4):
        e = np.zeros(4)
        e[k] = rel_step * max(1.0, abs(y[k]))
        J[:, k] = (flow(W, y + e, p, **flow_kw).y - flow(W, y - e, p, **flow_kw).y) / (2 * e[k])
    return J


def periodic_orbit(
    W: float,
    y0,
    p: dict = P_DEFAULT,
    *,
    tol: float = 1e-11,
    accept: float = 1e-9,
    max_iterations: int = 20,
    **flow_kw,
) -> np.ndarray:
    """The state at t = 0 of the period-T orbit near ``y0``: Newton on the period map until
    |y(T) - y| < tol max(1, |y|) (2-norms), at most ``max_iterations`` steps; fails unless the
    last residual is below ``accept``."""
    y = np.array(y0, dtype=float)
    for it in range(max_iterations + 1):
        G = flow(W, y, p, **flow_kw).y - y
        if np.linalg.norm(G) < tol * max(1.0, float(np.linalg.norm(y))) or it == max_iterations:
            break
        y = y + np.linalg.solve(monodromy(W, y, p, **flow_kw) - np.eye(4), -G)
    res = float(np.linalg.norm(G))
    assert res < accept, f"oracle Newton did not converge at Omega = {W}: |y(T) - y| = {res:.1e}"
    return y
