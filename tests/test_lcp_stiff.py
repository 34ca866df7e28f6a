"""LCP time-stepping on a stiff contact (issue 18, item 17).

``perturb simulate MODEL --method lcp`` on a stop of stiffness ratio 1e6 took the default step
T/200, 31 times the period of the contact oscillation: the trapezoidal step jumped across whole
contacts, each crossing added energy, and the orbit grew to max|x| ~ 100 where the exact
solution stays below 1.8. The step is now refined to resolve the stiffest segment (with a
warning naming the stiffness ratio and both steps), or refused on request.

Oracle: the exact piecewise-analytic propagator (closed-form segments, crossings to rounding),
itself checked here against solve_ivp (DOP853, rtol 1e-11) with contact events.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from perturb import Oscillator
from perturb.errors import PerturbError
from perturb.simulate.flows.lcp import MAX_STEP_PHASE, simulate_lcp
from perturb.simulate.flows.piecewise_exact import propagate
from perturb.simulate.flows.system import to_pwl_system
from perturb.simulate.time_history import time_history

EQ = "x'' + 0.1*x' + x + 1e6*(x-0.5)*Heaviside(x-0.5) = cos(Omega*t)"
W, T_END = 1.0, 60.0


@pytest.fixture(scope="module")
def stop():
    osc = Oscillator.parse(EQ, {"Omega": W})
    t = np.linspace(0.0, T_END, 1201)
    exact = propagate(to_pwl_system(osc, W), (0.0, 0.0), (0.0, T_END), t_eval=t)
    return osc, t, np.asarray(exact.x)


def _ivp_reference(t_eval, max_segments=2000):
    """solve_ivp with the contact as a terminal event, restarted in the other piece."""

    def rhs(t, y, inside):
        x, v = y
        return [v, np.cos(W * t) - 0.1 * v - x - (1e6 * (x - 0.5) if inside else 0.0)]

    def enter(t, y, inside):
        return y[0] - 0.5

    def leave(t, y, inside):
        return y[0] - 0.5

    enter.terminal = leave.terminal = True
    enter.direction, leave.direction = 1.0, -1.0
    ts, xs = [], []
    t, y = 0.0, np.array([0.0, 0.0])
    inside = False
    for _ in range(max_segments):
        sol = solve_ivp(
            rhs,
            (t, T_END),
            y,
            method="DOP853",
            rtol=1e-11,
            atol=1e-13,
            events=leave if inside else enter,
            args=(inside,),
            dense_output=True,
        )
        sel = (t_eval >= t) & (t_eval <= sol.t[-1])
        if np.any(sel):
            ts.append(t_eval[sel])
            xs.append(sol.sol(t_eval[sel])[0])
        if sol.status == 0:
            break
        t, y = sol.t[-1], sol.y[:, -1].copy()
        y[0] = 0.5
        inside = y[1] > 0
    else:
        raise AssertionError("oracle: too many contacts")
    tt, xx = np.concatenate(ts), np.concatenate(xs)
    _, first = np.unique(tt, return_index=True)
    return xx[first]


def test_exact_oracle_agrees_with_solve_ivp(stop):
    osc, t, x = stop
    ref = _ivp_reference(t)
    assert np.max(np.abs(ref - x)) < 1e-6
    assert np.max(np.abs(x)) < 1.8  # the stop holds: x <= 0.5 + O(1e-3) on the contact side
    assert np.max(x) < 0.51


def test_default_cli_step_is_refined_and_right(stop):
    osc, t, x = stop
    with pytest.warns(RuntimeWarning, match=r"stiffness ratio 1e\+06.*refined to h"):
        hist = time_history(osc, [0.0, 0.0], (0.0, T_END), method="lcp", samples=t.size)
    np.testing.assert_allclose(hist.t, t)
    assert np.max(hist.x) < 0.51
    assert abs(np.max(np.abs(hist.x)) - np.max(np.abs(x))) < 5e-3
    # the first two forcing periods, before phase errors accumulate, agree pointwise
    early = t < 4 * np.pi
    assert np.max(np.abs(hist.x[early] - x[early])) < 2e-2


def test_refined_lcp_converges_to_exact(stop):
    osc, t, x = stop
    errs = []
    for h in (5e-4, 1.25e-4):  # h * omega = 0.5 and 0.125: no refinement, no warning
        tr = simulate_lcp(osc, (0.0, 0.0), (0.0, 15.0), h, Omega=W)
        sel = t <= 15.0
        errs.append(np.max(np.abs(np.interp(t[sel], tr.t, tr.x) - x[sel])))
    assert errs[1] < errs[0] / 4 and errs[1] < 5e-3, errs


def test_coarse_step_refused_on_request_or_when_too_many_steps(stop):
    osc = stop[0]
    h = 2 * np.pi / W / 200
    with pytest.raises(PerturbError, match=r"stiffness ratio 1e\+06.*h \* omega = 31.*exact"):
        simulate_lcp(osc, (0.0, 0.0), (0.0, T_END), h, Omega=W, stiff="error")
    with pytest.raises(PerturbError, match=r"max_steps = 1000"):
        simulate_lcp(osc, (0.0, 0.0), (0.0, T_END), h, Omega=W, max_steps=1000)
    # what the guard prevents: the requested step taken as given gains energy
    bad = simulate_lcp(osc, (0.0, 0.0), (0.0, T_END), h, Omega=W, stiff="ignore")
    assert np.max(np.abs(bad.x)) > 4 * np.max(np.abs(stop[2]))


def test_soft_systems_untouched():
    """nsd (largest positive slope 1) keeps every step up to h = MAX_STEP_PHASE."""
    osc = Oscillator.parse(
        "x'' + 0.05*x' - 2*x + 3*((x-1)*Heaviside(x-1) + (x+1)*Heaviside(-x-1)) = 2*cos(0.6*t)"
    )
    tr = simulate_lcp(osc, (0.0, 0.0), (0.0, 10.0), MAX_STEP_PHASE)
    assert tr.n_steps == 10
