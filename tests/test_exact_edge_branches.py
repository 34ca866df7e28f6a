"""The exact frequency response finds the branches that lie in the window only near its low
edge and are stable only on short stretches (nsd, k = -3, window (0.2, 2.5)).

Three mirror pairs of branches there used to be missed by the exact solver (the numeric HB
found them): Omega 0.2-0.2144 (mean +-0.81), 0.2-0.2784 (mean +-2.0) and 0.2-0.4834
(amplitude 6.3-11.3, mean +-(1.6..3.96), stable only on 0.4757-0.4834).  The oracle is
written here, independently of perturb: the oscillator integrated by ``solve_ivp`` (DOP853,
rtol = atol = 1e-12) one linear segment at a time (a terminal event where the orbit leaves
its segment, so every integration is smooth), settled from a fixed start state in the
orbit's basin, then Newton on the period map with a finite-difference Jacobian.  The test
asks that the exact response has a branch with a point at the oracle's frequency whose
amplitude, mean and initial state are the oracle's; and, the oscillator being odd, the
mirror image (same amplitude, opposite mean).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from perturb import ParameterError, builtin_model
from perturb.model.system_builtins import builtin_system
from perturb.simulate.exact_response import exact_branches

K, MU, F = -3.0, 0.05, 2.0
WINDOW = (0.2, 2.5)


def _force_segment(x: float, v: float) -> int:
    """Segment of f(x) = k x + (1 - k)[(x - 1)H(x - 1) + (x + 1)H(-x - 1)] holding the
    state (on a breakpoint: the one the velocity enters)."""
    if x > 1.0 or (x == 1.0 and v > 0.0):
        return 1
    if x < -1.0 or (x == -1.0 and v < 0.0):
        return -1
    return 0


def _rhs(seg: int, Om: float):
    # the force of the segment, extended linearly past its ends (smooth integrand)
    def f(t, y):
        x, v, _ = y
        if seg == 0:
            fx = K * x
        else:
            fx = x - (1.0 - K) * seg  # x -/+ 4 for k = -3
        return [v, F * math.cos(Om * t) - MU * v - fx, x]

    return f


def _leave(seg: int):
    """Terminal events where the orbit leaves segment ``seg``."""
    evs = []
    for b, d in ((1.0, 1.0), (-1.0, -1.0)) if seg == 0 else ((float(seg), -float(seg)),):

        def ev(t, y, b=b):
            return y[0] - b

        ev.terminal = True
        ev.direction = d
        evs.append(ev)
    return evs


def _turn(t, y):
    return y[1]


def period_map(y0: np.ndarray, Om: float) -> tuple[np.ndarray, float, float]:
    """(state after one forcing period, max |x| over it, mean of x) from ``y0`` at t = 0."""
    T = 2.0 * math.pi / Om
    t, y = 0.0, np.array([y0[0], y0[1], 0.0])
    amp = abs(y[0])
    for _ in range(10_000):
        seg = _force_segment(y[0], y[1])
        sol = solve_ivp(
            _rhs(seg, Om),
            (t, T),
            y,
            method="DOP853",
            rtol=1e-12,
            atol=1e-12,
            events=[*_leave(seg), _turn],
        )
        assert sol.status >= 0, sol.message
        turns = sol.y_events[-1]
        if len(turns):
            amp = max(amp, float(np.max(np.abs(turns[:, 0]))))
        t, y = float(sol.t[-1]), sol.y[:, -1].copy()
        amp = max(amp, abs(y[0]))
        if sol.status == 0:
            return y[:2], amp, y[2] / T
        # on the breakpoint exactly (the event's root), so the next segment is unambiguous
        y[0] = round(y[0])
    raise AssertionError("too many segment changes in one period")


def oracle_orbit(start: tuple[float, float], Om: float) -> tuple[np.ndarray, float, float]:
    """The stable periodic orbit reached from ``start``: 12 periods of settling, then Newton
    on the period map (central differences); (y0, amplitude, mean)."""
    y = np.asarray(start, dtype=float)
    for _ in range(12):
        y = period_map(y, Om)[0]
    for _ in range(12):
        r = period_map(y, Om)[0] - y
        J = np.empty((2, 2))
        for j in range(2):
            h = 1e-6 * max(1.0, abs(y[j]))
            e = np.zeros(2)
            e[j] = h
            J[:, j] = (period_map(y + e, Om)[0] - period_map(y - e, Om)[0]) / (2 * h)
        dy = np.linalg.solve(J - np.eye(2), -r)
        y = y + dy
        if np.max(np.abs(dy)) < 1e-11 * max(1.0, np.max(np.abs(y))):
            break
    y1, amp, mean = period_map(y, Om)
    assert np.max(np.abs(y1 - y)) < 1e-8 * max(1.0, np.max(np.abs(y)))
    return y, amp, mean


@pytest.fixture(scope="module")
def response():
    osc = builtin_model("nsd", k=K, mu=MU, F=F)
    return exact_branches(osc, WINDOW, progress=False, workers=1)


# (frequency, start state in the stable orbit's basin, expected mean): one of each pair
CASES = [
    (0.205, (5.0, 3.2), 0.806),  # branch on 0.2-0.2144
    (0.27, (6.1, 3.1), 2.06),  # branch on 0.2-0.2784
    (0.48, (-2.7, 1.3), -3.90),  # branch on 0.2-0.4834, stable on 0.4757-0.4834
]


def _nearest_stable_point(response, Om: float, mean: float):
    """The stable point nearest ``Om`` (within 0.01) of the branches whose mean is within
    0.05 of ``mean`` there, or None."""
    best = None
    for br in response.branches:
        for q in br.points:
            if not q.stable or q.max_multiplier > 0.95 or abs(q.parameter - Om) > 0.01:
                continue
            if abs(q.mean - mean) > 0.05:
                continue
            if best is None or abs(q.parameter - Om) < abs(best.parameter - Om):
                best = q
    return best


@pytest.mark.parametrize(("Om", "start", "mean"), CASES)
def test_branch_through_each_pair(response, Om, start, mean):
    q = _nearest_stable_point(response, Om, mean)
    assert q is not None, f"no exact branch with mean {mean} near Omega = {Om}"
    y0, amp, m = oracle_orbit(start, q.parameter)
    assert m == pytest.approx(mean, abs=0.05)  # the start reached the intended orbit
    tol = 1e-7 * amp
    assert abs(q.amplitude - amp) <= tol
    assert abs(q.mean - m) <= tol
    assert np.max(np.abs(np.asarray(q.y0) - y0)) <= 1e-6 * amp
    # odd oscillator: the mirror image (x, t) -> (-x, t + T/2) is on a branch too
    image = _nearest_stable_point(response, q.parameter, -m)
    assert image is not None and image.parameter == q.parameter
    assert abs(image.amplitude - amp) <= tol
    assert abs(image.mean + m) <= tol


@pytest.mark.parametrize("bad", ["yes", 1, None])
def test_attractors_option_must_be_a_flag(bad):
    with pytest.raises(ParameterError, match="attractors"):
        exact_branches(builtin_model("nsd", k=-0.5), (0.9, 1.0), attractors=bad, progress=False)


# ---------------------------------------------------------------------------------------------
# nsd2 over (1.2, 1.3): a branch that enters and leaves the window through Omega = 1.2
# ---------------------------------------------------------------------------------------------
# Its fold is at Omega ~ 1.2147 (amplitude of x1 1.70-2.20 in the window); at the edge its
# orbits are unstable, stable only on ~1.2033-1.2147, so no attractor at a scan frequency
# reaches it.  The oracle: the two-storey structure with the device written here, integrated
# one linear segment of the device at a time (DOP853, rtol = atol = 1e-12), settled from a
# state in the stable orbit's basin at Omega = 1.21 and polished by Newton on the period map
# (forward differences).  The start state is the end of a 400-period DOP853 (rtol 1e-7)
# simulation of this ODE at Omega = 1.21 from (x1, x2, x1', x2') = (0, -3, 0, 0).
NSD2 = {"k": -0.5, "mu1": 0.05, "mu2": 0.02, "k2": 1.0, "m2": 1.0, "F": 2.0}
NSD2_START = (-0.42, -3.16, 0.11, -0.13)


def _nsd2_rhs(seg: int, Om: float):
    k, mu1, mu2, k2, m2, f = (NSD2[s] for s in ("k", "mu1", "mu2", "k2", "m2", "F"))

    def rhs(t, y):
        x1, x2, v1, v2, _ = y
        device = k * x1 + (1.0 - k) * (x1 - seg) * abs(seg)  # the segment's force, extended
        a1 = f * math.cos(Om * t) - mu1 * v1 - mu2 * (v1 - v2) - device - k2 * (x1 - x2)
        a2 = (-mu2 * (v2 - v1) - k2 * (x2 - x1)) / m2
        return [v1, v2, a1, a2, x1]

    return rhs


def nsd2_period_map(y0: np.ndarray, Om: float) -> tuple[np.ndarray, float, float]:
    """(state (x1, x2, x1', x2') after one forcing period, max |x1| over it, mean of x1)."""
    T = 2.0 * math.pi / Om
    t, y = 0.0, np.array([*y0, 0.0])
    amp = abs(y[0])

    def turn(t, y):
        return y[2]

    for _ in range(10_000):
        seg = _force_segment(y[0], y[2])
        sol = solve_ivp(
            _nsd2_rhs(seg, Om),
            (t, T),
            y,
            method="DOP853",
            rtol=1e-12,
            atol=1e-12,
            events=[*_leave(seg), turn],
        )
        assert sol.status >= 0, sol.message
        turns = sol.y_events[-1]
        if len(turns):
            amp = max(amp, float(np.max(np.abs(turns[:, 0]))))
        t, y = float(sol.t[-1]), sol.y[:, -1].copy()
        amp = max(amp, abs(y[0]))
        if sol.status == 0:
            return y[:4], amp, y[4] / T
        y[0] = round(y[0])  # on the breakpoint exactly: the next segment is unambiguous
    raise AssertionError("too many segment changes in one period")


def nsd2_oracle(Om: float) -> tuple[np.ndarray, float, float]:
    """The stable orbit reached from ``NSD2_START`` at ``Om``: (y0, amplitude, mean)."""
    y = np.asarray(NSD2_START, dtype=float)
    for _ in range(5):
        y = nsd2_period_map(y, Om)[0]
    for _ in range(12):
        y1 = nsd2_period_map(y, Om)[0]
        r = y1 - y
        J = np.empty((4, 4))
        for j in range(4):
            h = 1e-7 * max(1.0, abs(y[j]))
            e = np.zeros(4)
            e[j] = h
            J[:, j] = (nsd2_period_map(y + e, Om)[0] - y1) / h
        dy = np.linalg.solve(J - np.eye(4), -r)
        y = y + dy
        if np.max(np.abs(dy)) < 1e-10 * max(1.0, np.max(np.abs(y))):
            break
    y1, amp, mean = nsd2_period_map(y, Om)
    assert np.max(np.abs(y1 - y)) < 1e-8 * max(1.0, np.max(np.abs(y)))
    return y, amp, mean


def test_nsd2_branch_through_the_fold_beyond_the_low_edge():
    system = builtin_system("nsd2")
    assert {k: system.params[k] for k in NSD2} == NSD2
    response = exact_branches(system, (1.2, 1.3), progress=False, workers=1)
    y0, amp, mean = nsd2_oracle(1.21)
    assert 2.0 < amp < 2.3  # the start reached the fold-tip orbit (not the main branch, ~1.4)
    q = _nearest_stable_point(response, 1.21, mean)
    assert q is not None, f"no exact branch with mean {mean:.4f} near Omega = 1.21"
    y0, amp, mean = nsd2_oracle(q.parameter)
    tol = 1e-7 * amp
    assert abs(q.amplitude - amp) <= tol
    assert abs(q.mean - mean) <= tol
    assert np.max(np.abs(np.asarray(q.y0) - y0)) <= 1e-6 * amp
    # the branch reaches the window only through its low edge
    br = next(b for b in response.branches if any(p is q for p in b.points))
    omegas = [p.parameter for p in br.points]
    assert min(omegas) == pytest.approx(1.2, abs=1e-9) and max(omegas) < 1.22
    # the device is odd: the mirror image (x, t) -> (-x, t + T/2) is on a branch too
    image = _nearest_stable_point(response, q.parameter, -mean)
    assert image is not None and image.parameter == q.parameter
    assert abs(image.amplitude - amp) <= tol
    assert abs(image.mean + mean) <= tol
