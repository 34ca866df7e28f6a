"""limit_cycle on flows of several states: the belt stick-slip cycle on SystemEventFlow against
an independent stick-slip reference written here (solve_ivp DOP853 rtol = atol = 1e-12 in the
slip phases with event-located stick entry, the sticking phase in closed form x = x_s + v_b t),
a sticking phase lasting most of the period, a smooth 4-state cycle on SystemODEFlow against a
long DOP853 run, the monodromy against finite differences, and the drill string (its angles grow
without bound: a clear error, in bounded time)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from perturb.errors import ParameterError, PerturbError
from perturb.model.system import System
from perturb.model.system_builtins import builtin_system
from perturb.simulate.flows.factory import make_flow
from perturb.simulate.flows.system_events import SystemEventFlow
from perturb.simulate.orbits.shooting import limit_cycle, multiple_shooting

TIGHT = {"method": "DOP853", "rtol": 1e-12, "atol": 1e-12}


def _belt_reference(p, x0, n_cycles=4):
    """Stick-slip of m x'' + c x' + k x + N mu(|x' - v_b|) sign(x' - v_b) = 0,
    mu(u) = mu_k + (mu_s - mu_k) exp(-u / v_s). Returns (period, max |x|, stick fraction) of
    the last cycle between two stick exits (the state there is always (x_e, v_b): the cycle
    is reached after the first sticking phase)."""
    m, c, k, N = p["m"], p["c"], p["k"], p["N"]
    mu_s, mu_k, v_s, vb = p["mu_s"], p["mu_k"], p["v_s"], p["v_b"]

    def rhs(sigma):
        def f(t, y):
            u = abs(y[1] - vb)
            fric = N * (mu_k + (mu_s - mu_k) * math.exp(-u / v_s)) * sigma
            return [y[1], -(c * y[1] + k * y[0] + fric) / m]

        return f

    def rel(t, y):
        return y[1] - vb

    def turn(t, y):
        return y[1]

    x_exit = (N * mu_s - c * vb) / k  # k x + c v_b = N mu_s ends sticking (x increases)
    t, y, sigma = 0.0, np.array([x0, 0.0]), -1
    exits, extremes, sticks = [], [], []
    for _ in range(50 * n_cycles):
        rel.terminal, rel.direction = True, -sigma
        sol = solve_ivp(rhs(sigma), (t, t + 200.0), y, events=[rel, turn], **TIGHT)
        assert sol.status == 1
        turns = zip(sol.t_events[1], sol.y_events[1], strict=True)
        extremes += [(float(te), float(ye[0])) for te, ye in turns]
        t = float(sol.t_events[0][0])
        y = np.array(sol.y_events[0][0])
        need = -(c * vb + k * y[0])  # friction force that keeps x'' = 0 at x' = v_b
        if abs(need) > N * mu_s:  # no sticking: slip on the other side
            sigma = -sigma
            y[1] = vb
            continue
        # sticking: x = x_s + v_b (t - t_s) until k x + c v_b = N mu_s
        t_exit = t + (x_exit - y[0]) / vb
        sticks.append((t, t_exit))
        extremes += [(t, y[0]), (t_exit, x_exit)]
        exits.append(t_exit)
        t, y, sigma = t_exit, np.array([x_exit, vb]), -1
        if len(exits) == n_cycles + 1:
            break
    a, b = exits[-2], exits[-1]
    amp = max(abs(x) for tt, x in extremes if a - 1e-12 <= tt <= b + 1e-12)
    stick = sum(min(e, b) - max(s, a) for s, e in sticks if e > a and s < b)
    return b - a, amp, stick / (b - a)


@pytest.mark.parametrize(
    ("params", "guess", "long_stick"),
    [({}, (0.6, 0.0, 6.5), False), ({"v_s": 0.05, "v_b": 0.02}, (0.45, 0.0, 17.0), True)],
    ids=["belt", "belt-long-stick"],
)
def test_belt_stick_slip_cycle_matches_reference(params, guess, long_stick):
    system = builtin_system("belt", **params)
    flow = SystemEventFlow(system, rtol=1e-12, atol=1e-12)
    orb = limit_cycle(flow, guess[:2], guess[2])
    p = {k: float(v) for k, v in system.params.items()}
    period, amp, stick = _belt_reference(p, 0.5)
    assert orb.period == pytest.approx(period, abs=1e-8)
    assert float(orb.max_abs(np.array([1.0, 0.0]))) == pytest.approx(amp, abs=1e-8)
    assert orb.amplitude == pytest.approx(amp, abs=1e-8)
    # sticking collapses the cycle onto the stick-exit point: the non-trivial multiplier is 0
    assert orb.stability == "stable" and orb.max_multiplier < 1e-8
    if long_stick:
        assert stick > 0.75  # the hard case: stuck most of the period
    else:
        assert 0.0 < stick < 0.5


def test_belt_cycle_monodromy_matches_finite_differences():
    flow = SystemEventFlow(builtin_system("belt"), rtol=1e-12, atol=1e-12)
    orb = limit_cycle(flow, [0.6, 0.0], 6.5)
    h = 1e-6
    J = np.zeros((2, 2))
    for i in range(2):
        e = np.zeros(2)
        e[i] = h
        J[:, i] = (flow(orb.y0 + e, 0.0, orb.period).y - flow(orb.y0 - e, 0.0, orb.period).y) / (
            2 * h
        )
    assert np.max(np.abs(orb.monodromy - J)) < 1e-7
    # the trivial multiplier: the field at y0 is mapped to itself
    f0 = flow.vector_field(0.0, orb.y0)
    assert np.max(np.abs(orb.monodromy @ f0 - f0)) < 1e-8


EPS, KC = 1.0, 0.3


def _vdp_pair():
    return System.parse(
        [
            "x1'' - eps*(1 - x1**2)*x1' + x1 + kc*(x1 - x2) = 0",
            "x2'' + 0.1*x2' + 1.5*x2 + kc*(x2 - x1) = 0",
        ],
        {"eps": EPS, "kc": KC},
    )


def _vdp_reference():
    """Period and max|x1|, max|x2| of the cycle after a long DOP853 transient: successive
    maxima of x1 (x1' crossing + to -), and the extrema of x2 over one cycle."""

    def rhs(t, y):
        x1, x2, v1, v2 = y
        return [
            v1,
            v2,
            EPS * (1 - x1 * x1) * v1 - x1 - KC * (x1 - x2),
            -0.1 * v2 - 1.5 * x2 - KC * (x2 - x1),
        ]

    settle = solve_ivp(rhs, (0.0, 400.0), [2.0, 0.0, 0.0, 0.0], **TIGHT).y[:, -1]

    def peak(t, y):
        return y[2]

    peak.direction = -1

    def turn2(t, y):
        return y[3]

    sol = solve_ivp(rhs, (0.0, 30.0), settle, events=[peak, turn2], **TIGHT)
    tp = sol.t_events[0]
    period = float(tp[-1] - tp[-2])
    a, b = tp[-2], tp[-1]
    highs = zip(sol.t_events[0], sol.y_events[0], strict=True)
    x1max = max(abs(float(y[0])) for t, y in highs if a <= t <= b)
    # x1 minima: x1' crossing - to +
    sol_min = solve_ivp(rhs, (0.0, 30.0), settle, events=[lambda t, y: y[2]], **TIGHT)
    lows = zip(sol_min.t_events[0], sol_min.y_events[0], strict=True)
    x1_ext = max(abs(float(y[0])) for t, y in lows if a <= t <= b)
    turns2 = zip(sol.t_events[1], sol.y_events[1], strict=True)
    x2_ext = max(abs(float(y[1])) for t, y in turns2 if a <= t <= b)
    return period, max(x1max, x1_ext), x2_ext


def test_smooth_four_state_cycle_on_ode_flow_matches_long_run():
    flow = make_flow(_vdp_pair(), method="ode", rtol=1e-12, atol=1e-12)
    orb = limit_cycle(flow, [2.0, 0.3, 0.0, 0.0], 6.5)
    period, x1, x2 = _vdp_reference()
    assert orb.period == pytest.approx(period, abs=1e-8)
    amps = orb.max_abs()
    assert amps[0] == pytest.approx(x1, abs=1e-8)
    assert amps[1] == pytest.approx(x2, abs=1e-8)
    assert orb.y0[2] == 0.0 or abs(orb.y0[2]) < 1e-12  # the phase condition x1' = 0
    assert orb.stability == "stable"
    assert abs(orb.multipliers[np.argmin(np.abs(orb.multipliers - 1))] - 1) < 1e-7


def test_drill_string_is_a_clear_error_or_a_cycle():
    # the rotary table and the bit turn on without bound (angles grow by about 20 rad per
    # cycle): no periodic orbit of the states exists, so plain shooting fails clearly and soon
    flow = SystemEventFlow(builtin_system("drill_string"), rtol=1e-10, atol=1e-10)
    y = flow([0.0, 0.0, 1.0, 0.0], 0.0, 100.0).y
    with pytest.raises(PerturbError):
        limit_cycle(flow, y, 10.0, max_iter=4)


def _drill_reference(p, y0, t_settle=150.0, cycles=3):
    """Stick-slip of the drill string's bit by solve_ivp DOP853 (1e-12) with events: slip
    phases (sign of phi_b' fixed) end where phi_b' = 0; the bit sticks while the torque it
    needs, c_t phi_r' + k_t (phi_r - phi_b), is within W_ob R_b mu_s, the table runs on.
    Returns the period between the last stick exits and max |phi_b'| over that cycle."""
    Jr, Jb, kt, ct, cr, cb = (p[k] for k in ("J_r", "J_b", "k_t", "c_t", "c_r", "c_b"))
    WR, mu_c, mu_s, gb, nu, Tm = (
        p["W_ob"] * p["R_b"],
        p["mu_c"],
        p["mu_s"],
        p["gamma_b"],
        p["nu_f"],
        p["T_m"],
    )

    def table(y):
        return (Tm - ct * (y[2] - y[3]) - kt * (y[0] - y[1]) - cr * y[2]) / Jr

    def bit_acc(y, sigma):
        fric = WR * (mu_c + (mu_s - mu_c) * math.exp(-gb * abs(y[3]) / nu)) * sigma
        return (ct * (y[2] - y[3]) + kt * (y[0] - y[1]) - cb * y[3] - fric) / Jb

    def need(y):
        return ct * y[2] + kt * (y[0] - y[1])

    t, y, sigma = 0.0, np.array(y0, float), 1
    exits, peaks = [], []
    for _ in range(2000):

        def slip(tt, z, sigma=sigma):
            return [z[2], z[3], table(z), bit_acc(z, sigma)]

        def stop(tt, z):
            return z[3]

        def top(tt, z, sigma=sigma):
            return bit_acc(z, sigma)

        stop.terminal, stop.direction = True, -sigma
        sol = solve_ivp(slip, (t, t + 100.0), y, events=[stop, top], **TIGHT)
        tops = zip(sol.t_events[1], sol.y_events[1], strict=True)
        peaks += [(float(a), abs(float(b[3]))) for a, b in tops]
        t, y = float(sol.t_events[0][0]), np.array(sol.y_events[0][0])
        y[3] = 0.0
        if abs(need(y)) > WR * mu_s:
            sigma = 1 if need(y) > 0 else -1
            continue

        def stuck(tt, z):
            return [z[2], 0.0, table(z), 0.0]

        def over(tt, z):
            return need(z) - WR * mu_s

        def under(tt, z):
            return need(z) + WR * mu_s

        over.terminal = under.terminal = True
        over.direction, under.direction = 1, -1
        sol = solve_ivp(stuck, (t, t + 100.0), y, events=[over, under], **TIGHT)
        which = 0 if sol.t_events[0].size else 1
        t, y = float(sol.t_events[which][0]), np.array(sol.y_events[which][0])
        sigma = 1 if which == 0 else -1
        if t > t_settle:
            exits.append(t)
            if len(exits) == cycles + 1:
                break
    a, b = exits[-2], exits[-1]
    return b - a, max(v for tt, v in peaks if a <= tt <= b)


def test_drill_string_stick_slip_cycle_with_drift_matches_reference():
    # periodic up to the rotation: drift d = (1, 1, 0, 0), the phase condition phi_b' = 1 (the
    # bit's speed passes 1 once accelerating; phi_b' = 0 holds over the whole sticking phase)
    system = builtin_system("drill_string")
    flow = SystemEventFlow(system, rtol=1e-12, atol=1e-12)
    y = flow([0.0, 0.0, 1.0, 0.0], 0.0, 100.0).y
    orb = limit_cycle(flow, y, 5.6, phase_state=3, phase_value=1.0, drift=[1, 1, 0, 0])
    period, peak = _drill_reference({k: float(v) for k, v in system.params.items()}, [0, 0, 1, 0])
    assert orb.period == pytest.approx(period, abs=1e-8)
    assert float(orb.max_abs([0, 0, 0, 1])) == pytest.approx(peak, abs=1e-8)
    flow(orb.y0, 0.0, orb.period)
    assert [e.kind for e in flow.events] == ["stick", "slip"]
    # modulo the drift the multipliers are 1 (time shift), the slip phase's and two zeros
    # (sticking fixes phi_b and phi_b'; the drift is projected out)
    mu = np.sort(np.abs(orb.multipliers))
    assert mu[3] == pytest.approx(1.0, abs=1e-7) and mu[1] < 1e-6 and orb.is_stable


def test_limit_cycle_bad_phase_state():
    flow = make_flow(_vdp_pair(), method="ode")
    with pytest.raises(ParameterError, match="phase_state"):
        limit_cycle(flow, [2.0, 0.3, 0.0, 0.0], 6.5, phase_state=4)


def test_autonomous_multiple_shooting_takes_n_states():
    # the belt cycle by 4-node multiple shooting on the event flow, and the 4-state smooth
    # cycle: the same periods as the independent references
    system = builtin_system("belt")
    flow = SystemEventFlow(system, rtol=1e-12, atol=1e-12)
    T = 6.5
    nodes = [flow([0.6, 0.0], 0.0, T * i / 4).y if i else np.array([0.6, 0.0]) for i in range(4)]
    orb = multiple_shooting(flow, nodes, period_guess=T)
    period, amp, _ = _belt_reference({k: float(v) for k, v in system.params.items()}, 0.5)
    assert orb.period == pytest.approx(period, abs=1e-8)
    assert orb.amplitude == pytest.approx(amp, abs=1e-8)
    ode = make_flow(_vdp_pair(), method="ode", rtol=1e-12, atol=1e-12)
    y = np.array([2.0, 0.3, 0.0, 0.0])
    nodes = [ode(y, 0.0, 6.5 * i / 3).y if i else y for i in range(3)]
    orb = multiple_shooting(ode, nodes, period_guess=6.5)
    assert orb.period == pytest.approx(_vdp_reference()[0], abs=1e-8)
    assert abs(orb.y0[2]) < 1e-12
