"""``perturb periodic`` / ``perturb frc`` on autonomous systems (issue 15, front doors).

``perturb periodic belt``, ``perturb periodic drill_string`` and a van der Pol-like system of
two coordinates given as ``;``-separated equations return their limit cycles (period,
``omega = 2 pi / period``, multipliers with the trivial 1). Each is checked against a
reference written here that shares no code with the package:

* belt: one stick-slip cycle built from its phases, the slip by ``solve_ivp`` (DOP853,
  rtol = atol = 1e-12) with the return to the belt's speed located as an event, the sticking
  phase in closed form ``x = x_s + v_b t`` up to the static-friction limit;
* drill string: a long DOP853 run (rtol = atol = 1e-12) from rest, bit sticking and release
  located as events, the period as the mean spacing of the last ten stick onsets;
* van der Pol-like pair: a long DOP853 run, successive maxima of ``x1`` located as events.

A linear damped system has no cycle: its stable equilibrium is a row of its own, with the
eigenvalues of the hand-written matrix. ``--omega`` and ``--m`` on an autonomous system and
``frc`` on one are refused with one line naming the problem.
"""

from __future__ import annotations

import contextlib
import csv
import io
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from perturb.apps.cli import main
from perturb.errors import PerturbError

RTOL = ATOL = 1e-12


def cli(*argv: str) -> tuple[int, list[dict[str, str]], str]:
    """Run ``perturb argv`` in-process; (exit status, CSV rows of standard output, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(list(argv))
    text = out.getvalue()
    rows = list(csv.DictReader(io.StringIO(text))) if text.strip() else []
    return code, rows, err.getvalue()


def cycles(rows: list[dict[str, str]]) -> list[dict[str, str]]:
    return [r for r in rows if r["kind"] == "limit_cycle"]


def multipliers(field: str) -> np.ndarray:
    return np.array([complex(z) for z in field.split()])


# ------------------------------------------------------------------------------------------
# references
# ------------------------------------------------------------------------------------------
BELT = dict(m=1.0, c=0.0, k=1.0, N=1.0, mu_s=0.4, mu_k=0.25, v_s=0.5, v_b=0.2)


def belt_cycle(m, c, k, N, mu_s, mu_k, v_s, v_b) -> tuple[float, float]:
    """(period, max |x|) of the stick-slip cycle of
    m x'' + c x' + k x + N [mu_k + (mu_s - mu_k) exp(-|x' - v_b|/v_s)] sign(x' - v_b) = 0,
    from the end of a sticking phase: slip backwards (x' < v_b) until x' = v_b again, then
    stick (x = x_s + v_b t) until the spring and damper reach the static friction N mu_s."""
    x_end = (N * mu_s - c * v_b) / k

    def slip(t, y):  # x' < v_b: the friction pushes along +x
        mu = mu_k + (mu_s - mu_k) * math.exp(-abs(y[1] - v_b) / v_s)
        return [y[1], (-c * y[1] - k * y[0] + N * mu) / m]

    def restick(t, y):
        return y[1] - v_b

    restick.terminal, restick.direction = True, 1

    def turn(t, y):  # extrema of x
        return y[1]

    sol = solve_ivp(
        slip, (0.0, 100.0), [x_end, v_b], "DOP853", rtol=RTOL, atol=ATOL, events=[restick, turn]
    )
    assert sol.status == 1
    x_s = float(sol.y_events[0][0][0])
    assert abs(k * x_s + c * v_b) <= N * mu_s  # the mass sticks again
    period = float(sol.t_events[0][0]) + (x_end - x_s) / v_b
    extremes = [abs(x_end), abs(x_s), *(abs(float(y[0])) for y in sol.y_events[1])]
    return period, max(extremes)


DRILL = dict(
    J_r=2122.0,
    J_b=374.0,
    k_t=473.0,
    c_t=23.2,
    c_r=425.0,
    c_b=50.0,
    W_ob=5.0e4,
    R_b=0.155575,
    mu_c=0.5,
    mu_s=0.8,
    gamma_b=0.9,
    nu_f=1.0,
    T_m=6000.0,
)


def drill_period(p: dict, cycles_run: int = 40) -> float:
    """The stick-slip period of the drill string from a long run from rest: the state
    (phi_r, phi_b, w_r, w_b); the bit sticks (w_b = 0, phi_b held) while the torque on it,
    friction aside, stays within W_ob R_b mu_s; the mean spacing of the last ten stick
    onsets."""
    Ts = p["W_ob"] * p["R_b"] * p["mu_s"]

    def applied(y):
        return -p["c_t"] * (y[3] - y[2]) - p["k_t"] * (y[1] - y[0]) - p["c_b"] * y[3]

    def table(y):
        return (
            -p["c_t"] * (y[2] - y[3]) - p["k_t"] * (y[0] - y[1]) - p["c_r"] * y[2] + p["T_m"]
        ) / p["J_r"]

    def stick(t, y):
        return [y[2], 0.0, table(y), 0.0]

    def release(t, y):
        return abs(applied(y)) - Ts

    release.terminal, release.direction = True, 1
    y, t, onsets, sticking, sgn = np.zeros(4), 0.0, [], True, 1.0
    for _ in range(2 * cycles_run + 4):  # bounded: a stick and a slip phase per pass
        if sticking:
            s = solve_ivp(stick, (t, t + 1e3), y, "DOP853", rtol=RTOL, atol=ATOL, events=release)
            assert s.status == 1
            t, y = float(s.t_events[0][0]), s.y_events[0][0].copy()
            sgn = math.copysign(1.0, applied(y))  # the bit slips the way the torque pushes

        def slip(tt, z, sgn=sgn):
            sg = math.copysign(1.0, z[3]) if z[3] != 0.0 else sgn
            mu = p["mu_c"] + (p["mu_s"] - p["mu_c"]) * math.exp(
                -p["gamma_b"] * abs(z[3]) / p["nu_f"]
            )
            return [z[2], z[3], table(z), (applied(z) - p["W_ob"] * p["R_b"] * mu * sg) / p["J_b"]]

        def halt(tt, z):
            return z[3]

        halt.terminal, halt.direction = True, -sgn
        y[3] = 0.0
        s = solve_ivp(slip, (t, t + 1e3), y, "DOP853", rtol=RTOL, atol=ATOL, events=halt)
        assert s.status == 1
        t, y = float(s.t_events[0][0]), s.y_events[0][0].copy()
        y[3] = 0.0
        onsets.append(t)
        sticking = abs(applied(y)) <= Ts
        if not sticking:
            sgn = math.copysign(1.0, applied(y))
        if len(onsets) > cycles_run:
            break
    assert len(onsets) > 11
    return (onsets[-1] - onsets[-11]) / 10.0


VDP = "x1'' - eps*(1 - x1^2)*x1' + x1 + k*(x1 - x2) = 0; x2'' + c*x2' + x2 + k*(x2 - x1) = 0"
VDP_PARAMS = dict(eps=0.5, k=0.2, c=0.5)


def vdp_cycle(eps, k, c) -> tuple[float, float, float]:
    """(period, max |x1|, max |x2|) of the attracting cycle, from a DOP853 run from
    (2, 0, 0, 0): 60 time units of transient per decade of the cycle's contraction (its
    non-trivial multipliers are below 0.6), then ten successive maxima of x1."""

    def rhs(t, y):
        x1, x2, v1, v2 = y
        return [v1, v2, eps * (1 - x1**2) * v1 - x1 - k * (x1 - x2), -c * v2 - x2 - k * (x2 - x1)]

    def top(t, y):
        return y[2]

    top.direction = -1

    def ext2(t, y):
        return y[3]

    settle = solve_ivp(rhs, (0.0, 400.0), [2.0, 0.0, 0.0, 0.0], "DOP853", rtol=RTOL, atol=ATOL)
    s = solve_ivp(
        rhs, (0.0, 80.0), settle.y[:, -1], "DOP853", rtol=RTOL, atol=ATOL, events=[top, ext2]
    )
    tops = s.t_events[0]
    assert tops.size >= 11
    period = (tops[-1] - tops[-11]) / 10.0
    a1 = max(abs(float(y[0])) for y in s.y_events[0][-3:])
    a2 = max(abs(float(y[1])) for y in s.y_events[1][-6:])
    return period, a1, a2


# ------------------------------------------------------------------------------------------
# tests
# ------------------------------------------------------------------------------------------
def test_belt_cycle_equals_the_stick_slip_reference():
    code, rows, err = cli("periodic", "belt")
    assert code == 0, err
    found = cycles(rows)
    assert len(found) == 1, err
    row = found[0]
    period, amp = belt_cycle(**BELT)
    assert float(row["period"]) == pytest.approx(period, rel=0, abs=1e-8)
    assert float(row["omega"]) == pytest.approx(2 * math.pi / period, rel=1e-8)
    assert float(row["amplitude"]) == pytest.approx(amp, rel=0, abs=1e-8)
    assert float(row["amplitude_x"]) == pytest.approx(amp, rel=0, abs=1e-8)
    mu = multipliers(row["multipliers"])
    assert mu.size == 2 and abs(mu - 1.0).min() <= 1e-6  # the trivial multiplier
    # sticking collapses every neighbour onto one orbit: the other multiplier vanishes
    assert row["stability"] == "stable" and float(row["max_multiplier"]) < 1e-6
    # the unstable slipping equilibrium x = N mu(v_b)/k is a row too, eigenvalues 0.1 +- i
    eq = [r for r in rows if r["kind"] == "equilibrium"]
    assert len(eq) == 1 and eq[0]["stability"] == "unstable" and eq[0]["period"] == "inf"
    mu_b = BELT["mu_k"] + (BELT["mu_s"] - BELT["mu_k"]) * math.exp(-BELT["v_b"] / BELT["v_s"])
    assert float(eq[0]["y0_x"]) == pytest.approx(BELT["N"] * mu_b / BELT["k"], abs=1e-12)
    # x'' = -x + mu(v_b - x'): the slope of the friction law is the negative damping
    slope = (BELT["mu_s"] - BELT["mu_k"]) / BELT["v_s"] * math.exp(-BELT["v_b"] / BELT["v_s"])
    lam = np.roots([1.0, -slope, BELT["k"]])
    got = np.sort_complex(multipliers(eq[0]["eigenvalues"]))
    assert np.allclose(got, np.sort_complex(lam), atol=1e-9)
    assert "autonomous" in err and "limit cycle" in err


def test_drill_string_cycle_period_against_a_long_run():
    code, rows, err = cli("periodic", "drill_string")
    assert code == 0, err
    found = cycles(rows)
    assert len(found) == 1, err
    period = drill_period(DRILL)
    assert float(found[0]["period"]) == pytest.approx(period, rel=0, abs=1e-8)
    assert found[0]["stability"] == "stable"
    assert "drifts along d" in err  # the angles grow: periodic up to a shift
    # the coexisting steady rotations are reported as such
    drifts = [r for r in rows if r["kind"] == "steady_drift"]
    assert drifts and any(r["stability"] == "stable" for r in drifts)
    for r in drifts:  # w_r = w_b = rate, and the bit torque balances: a steady rotation
        assert float(r["y0_phi_r'"]) == pytest.approx(float(r["y0_phi_b'"]), rel=1e-10)


def test_smooth_two_coordinate_cycle_as_equations():
    argv = ["periodic", VDP]
    for name, value in VDP_PARAMS.items():
        argv += ["--param", f"{name}={value}"]
    code, rows, err = cli(*argv)
    assert code == 0, err
    found = cycles(rows)
    assert len(found) == 1, err
    period, a1, a2 = vdp_cycle(**VDP_PARAMS)
    assert float(found[0]["period"]) == pytest.approx(period, rel=0, abs=1e-8)
    assert float(found[0]["amplitude_x1"]) == pytest.approx(a1, rel=0, abs=1e-8)
    assert float(found[0]["amplitude_x2"]) == pytest.approx(a2, rel=0, abs=1e-8)
    mu = multipliers(found[0]["multipliers"])
    assert abs(mu - 1.0).min() <= 1e-6 and found[0]["stability"] == "stable"
    # the origin: unstable (van der Pol's negative damping), eigenvalues of the linear part
    eps, k, c = (VDP_PARAMS[n] for n in ("eps", "k", "c"))
    A = np.array([[0, 0, 1, 0], [0, 0, 0, 1], [-1 - k, k, eps, 0], [k, -1 - k, 0, -c]], float)
    eq = [r for r in rows if r["kind"] == "equilibrium"]
    assert len(eq) == 1 and eq[0]["stability"] == "unstable"
    got = np.sort_complex(multipliers(eq[0]["eigenvalues"]))
    assert np.allclose(got, np.sort_complex(np.linalg.eigvals(A)), atol=1e-9)


def test_no_cycle_reports_the_stable_equilibrium():
    code, rows, err = cli(
        "periodic", "x1'' + 0.1*x1' + 2*x1 - x2 = 0; x2'' + 0.1*x2' + 2*x2 - x1 = 0"
    )
    assert code == 0, err
    assert "no limit cycle" in err and "equilibrium (stable" in err
    assert len(rows) == 1 and rows[0]["kind"] == "equilibrium" and rows[0]["stable"] == "1"
    A = np.array([[0, 0, 1, 0], [0, 0, 0, 1], [-2, 1, -0.1, 0], [1, -2, 0, -0.1]], float)
    got = np.sort_complex(multipliers(rows[0]["eigenvalues"]))
    assert np.allclose(got, np.sort_complex(np.linalg.eigvals(A)), atol=1e-9)
    assert [float(rows[0][f"y0_{s}"]) for s in ("x1", "x2", "x1'", "x2'")] == [0.0] * 4


def test_python_api_returns_the_cycles():
    from perturb.model.system_builtins import builtin_system
    from perturb.solve import limit_cycles, periodic_orbits

    belt = builtin_system("belt")
    orbits = periodic_orbits(belt)
    period, amp = belt_cycle(**BELT)
    assert len(orbits) == 1 and orbits[0].autonomous
    assert orbits[0].period == pytest.approx(period, rel=0, abs=1e-8)
    assert float(orbits[0].max_abs(belt.output("x"))) == pytest.approx(amp, rel=0, abs=1e-8)
    found = limit_cycles(belt, grid=0)
    assert found.drift is None and len(found.cycles) == 1 and len(found.equilibria) == 1
    with pytest.raises(PerturbError, match="autonomous.*m = 1"):
        periodic_orbits(belt, m=2)


@pytest.mark.parametrize(
    ("argv", "match"),
    [
        (("periodic", "belt", "--omega", "1"), "autonomous.*Omega.*leave --omega out"),
        (("periodic", "belt", "--m", "2"), "--m 2.*autonomous"),
        (("periodic", "nsd"), "--omega: required"),
        (("periodic", "nsd2"), "--omega: required"),
        (("frc", "belt"), "autonomous.*no forcing frequency"),
        (("frc", "drill_string", "--omega", "1,2"), "autonomous.*no forcing frequency"),
    ],
)
def test_autonomous_misuse_is_one_clear_line(argv, match, capsys):
    assert main(list(argv)) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("perturb: error: ") and "\n" not in err
    assert "internal error" not in err
    import re

    assert re.search(match, err), err


def test_unforced_oscillator_equation_gives_its_limit_cycle():
    # one equation without forcing: the one-coordinate system's limit cycle (van der Pol)
    code, rows, err = cli("periodic", "x'' - 0.5*(1 - x^2)*x' + x = 0")
    assert code == 0, err
    found = cycles(rows)
    assert len(found) == 1, err

    def rhs(t, y):
        return [y[1], 0.5 * (1 - y[0] ** 2) * y[1] - y[0]]

    def top(t, y):
        return y[1]

    top.direction = -1
    settle = solve_ivp(rhs, (0.0, 300.0), [2.0, 0.0], "DOP853", rtol=RTOL, atol=ATOL)
    s = solve_ivp(rhs, (0.0, 80.0), settle.y[:, -1], "DOP853", rtol=RTOL, atol=ATOL, events=top)
    tops = s.t_events[0]
    assert float(found[0]["period"]) == pytest.approx((tops[-1] - tops[-11]) / 10, abs=1e-8)
    assert float(found[0]["amplitude_x"]) == pytest.approx(float(s.y_events[0][-1][0]), abs=1e-8)
