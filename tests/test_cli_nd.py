"""The command line on systems of several coordinates (issue 15, item 6).

``perturb simulate``, ``perturb periodic`` and ``perturb frc`` are run in-process
(:func:`perturb.apps.cli.main`) on the builtin ``nsd2`` and ``impact_pair`` systems and on a
linear 2-DOF system given as two equations separated by ``;``. Their CSV columns are checked
against references that share no code with the package:

* the equations of motion written out by hand here, integrated by ``solve_ivp`` (DOP853,
  rtol = atol = 1e-12) with a terminal event on every switching surface and a restart (the
  region held fixed between crossings); ``max |c . y|`` over a period located as the root of
  its rate on the dense output, the mean by quadrature of the dense output;
* the closed-form harmonic response ``(K - W^2 M + i W C) Q = F`` of the linear system, and its
  Floquet multipliers ``exp(lambda_i T)`` from the eigenvalues of the first-order matrix;
* a settled long run from rest (the attractor), which the orbit search must find.

The SDOF formats are checked to be unchanged (headers, ``--output x`` accepted).
"""

from __future__ import annotations

import csv
import io
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from perturb.apps.cli import main

RTOL = ATOL = 1e-12


# ------------------------------------------------------------------------------------------
# references written out by hand; state (x1, x2, x1', x2')
# ------------------------------------------------------------------------------------------
def nsd2(k=-0.5, mu1=0.05, mu2=0.02, k2=1.0, m2=1.0, F=2.0, W=1.0):
    """x1'' + mu1 x1' + mu2 (x1' - x2') + k x1 + (1 - k) h(x1) + k2 (x1 - x2) = F cos W t,
    m2 x2'' + mu2 (x2' - x1') + k2 (x2 - x1) = 0, h(s) = (s - 1)^+ - (-1 - s)^+."""

    def rhs(t, y, pat):
        x1, x2, v1, v2 = y
        h = x1 - 1.0 if pat[0] > 0 else (x1 + 1.0 if pat[1] < 0 else 0.0)
        a1 = -mu1 * v1 - mu2 * (v1 - v2) - k * x1 - (1 - k) * h - k2 * (x1 - x2)
        a2 = (-mu2 * (v2 - v1) - k2 * (x2 - x1)) / m2
        return np.array([v1, v2, a1 + F * math.cos(W * t), a2])

    return rhs, [(np.array([1.0, 0, 0, 0]), 1.0), (np.array([1.0, 0, 0, 0]), -1.0)]


def impact_pair(mu=0.05, mu2=0.01, r=20.0, d=0.5, m2=0.2, F=0.5, W=1.0):
    """x1'' + mu x1' + x1 + r b = F cos W t, m2 x2'' + mu2 (x2' - x1') - r b = 0,
    b = (s - d)^+ - (-d - s)^+, s = x1 - x2."""

    def rhs(t, y, pat):
        x1, x2, v1, v2 = y
        s = x1 - x2
        b = s - d if pat[0] > 0 else (s + d if pat[1] < 0 else 0.0)
        a1 = -mu * v1 - x1 - r * b + F * math.cos(W * t)
        a2 = (-mu2 * (v2 - v1) + r * b) / m2
        return np.array([v1, v2, a1, a2])

    c = np.array([1.0, -1.0, 0, 0])
    return rhs, [(c, d), (c, -d)]


def run(model, y0, t0, t1):
    """DOP853 with a terminal event on each surface and a restart in the region entered.
    Returns the final state and the dense pieces ``[(ta, tb, sol, pattern), ...]``."""
    rhs, surfaces = model
    y = np.array(y0, dtype=float)
    pat = [1 if c @ y - d >= 0 else -1 for c, d in surfaces]
    t, pieces = t0, []
    for _ in range(100_000):
        events = []
        for j, (c, d) in enumerate(surfaces):

            def ev(tt, yy, c=c, d=d):
                return c @ yy - d

            ev.terminal = True
            ev.direction = -pat[j]  # only a crossing out of the current side
            events.append(ev)
        p = tuple(pat)
        sol = solve_ivp(
            lambda tt, yy, p=p: rhs(tt, yy, p),
            (t, t1),
            y,
            method="DOP853",
            rtol=RTOL,
            atol=ATOL,
            events=events,
            dense_output=True,
        )
        assert sol.status >= 0
        pieces.append((t, float(sol.t[-1]), sol.sol, p))
        y, t = sol.y[:, -1].copy(), float(sol.t[-1])
        if sol.status == 0:
            return y, pieces
        for j, te in enumerate(sol.t_events):
            if te.size:
                pat[j] = -pat[j]
    raise AssertionError("too many events")


def stats(model, pieces, c):
    """``max |c . y|`` (extrema at the roots of the rate on each piece's dense output) and the
    mean of ``c . y`` (Gauss-Legendre on each piece) over the pieces' span."""
    rhs = model[0]
    best, integral, span = 0.0, 0.0, 0.0
    nodes, weights = np.polynomial.legendre.leggauss(20)
    for ta, tb, sol, p in pieces:
        if tb <= ta:
            continue
        tt = np.linspace(ta, tb, 400)
        z = c @ sol(tt)
        best = max(best, float(np.abs(z).max()))

        def rate(s, sol=sol, p=p):
            return float(c @ rhs(s, sol(s), p))

        rates = [rate(s) for s in tt]
        for i in range(len(tt) - 1):
            if rates[i] * rates[i + 1] < 0:
                s = brentq(rate, tt[i], tt[i + 1], xtol=1e-15)
                best = max(best, abs(float(c @ sol(s))))
        # the piece's mean by Gauss-Legendre on sub-intervals of the dense output
        edges = np.linspace(ta, tb, 9)
        for a, b in zip(edges[:-1], edges[1:], strict=True):
            s = 0.5 * (b - a) * nodes + 0.5 * (a + b)
            integral += 0.5 * (b - a) * float(weights @ (c @ sol(s)))
        span += tb - ta
    return best, integral / span


def cli(*argv: str) -> tuple[int, list[dict[str, str]], str]:
    """Run ``perturb argv`` in-process; (exit status, CSV rows of standard output, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    import contextlib

    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(list(argv))
    text = out.getvalue()
    rows = list(csv.DictReader(io.StringIO(text))) if code == 0 and "," in text else []
    return code, rows, err.getvalue()


def header(*argv: str) -> list[str]:
    out = io.StringIO()
    import contextlib

    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        assert main(list(argv)) == 0
    return out.getvalue().splitlines()[0].split(",")


E = np.eye(4)
STATES = ("x1", "x2", "x1'", "x2'")


def check_orbit_rows(model, rows, W, output):
    """Every row is a periodic orbit of the reference equations, and its columns are the
    reference's numbers over one period from its y0."""
    T = 2 * math.pi / W
    for row in rows:
        y0 = np.array([float(row[f"y0_{s}"]) for s in STATES])
        y1, pieces = run(model, y0, 0.0, T)
        scale = max(1.0, float(np.abs(y0).max()))
        mu = float(row["max_multiplier"])
        # the reference period map returns y0 (its rounding amplified by the multiplier)
        assert np.abs(y1 - y0).max() <= 1e-9 * scale * max(1.0, mu)
        amp, mean = stats(model, pieces, output)
        assert float(row["amplitude"]) == pytest.approx(amp, rel=1e-8, abs=1e-10)
        assert float(row["mean"]) == pytest.approx(mean, abs=1e-8 * scale)
        for i, name in enumerate(("x1", "x2")):
            amp_i, mean_i = stats(model, pieces, E[i])
            assert float(row[f"amplitude_{name}"]) == pytest.approx(amp_i, rel=1e-8, abs=1e-10)
            assert float(row[f"mean_{name}"]) == pytest.approx(mean_i, abs=1e-8 * scale)
        assert row["stable"] == str(int(mu < 1))


def settled(model, W, y0, max_periods=3000):
    """The state at phase 0 after a long run, once the stroboscopic map has settled."""
    T = 2 * math.pi / W
    y = np.array(y0, dtype=float)
    for k in range(max_periods):
        y_next, _ = run(model, y, k * T, (k + 1) * T)
        if np.abs(y_next - y).max() <= 1e-10 * max(1.0, float(np.abs(y).max())):
            return y_next
        y = y_next
    raise AssertionError("the run did not settle")


# ------------------------------------------------------------------------------------------
# perturb periodic
# ------------------------------------------------------------------------------------------
def test_periodic_nsd2_rows_are_orbits_of_the_reference_and_include_the_attractor():
    code, rows, err = cli("periodic", "nsd2", "--omega", "1.0", "--output", "x2")
    assert code == 0, err
    assert rows
    cols = list(rows[0])
    assert cols[:8] == [
        "omega",
        "m",
        "amplitude",
        "first_harmonic_amplitude",
        "mean",
        "stable",
        "max_multiplier",
        "stability",
    ]
    assert cols[8:] == [
        "amplitude_x1",
        "amplitude_x2",
        "mean_x1",
        "mean_x2",
        "multipliers",
        *(f"y0_{s}" for s in STATES),
    ]
    model = nsd2(W=1.0)
    check_orbit_rows(model, rows, 1.0, E[1])
    # the attractor reached from rest is one of the stable rows
    y = settled(model, 1.0, [0.0, 0.0, 0.0, 0.0])
    _, pieces = run(model, y, 0.0, 2 * math.pi)
    amp, mean = stats(model, pieces, E[1])
    stable = [r for r in rows if r["stable"] == "1"]
    assert any(
        abs(float(r["amplitude"]) - amp) <= 1e-7 * amp and abs(float(r["mean"]) - mean) <= 1e-6
        for r in stable
    ), (amp, mean, [(r["amplitude"], r["mean"]) for r in stable])


def test_periodic_nsd2_strongly_unstable_orbits_are_right():
    # k = -3: the in-well orbit's multiplier is ~1e4 (solved again on shooting nodes)
    argv = ("periodic", "nsd2", "--param", "k=-3", "--omega", "1.0", "--output", "x1 - x2")
    code, rows, err = cli(*argv)
    assert code == 0, err
    assert max(float(r["max_multiplier"]) for r in rows) > 1e3
    check_orbit_rows(nsd2(k=-3.0, W=1.0), rows, 1.0, np.array([1.0, -1.0, 0, 0]))


def test_periodic_nsd2_multipliers_match_finite_differences_of_the_reference_map():
    code, rows, err = cli("periodic", "nsd2", "--omega", "1.0")
    assert code == 0, err
    model = nsd2(W=1.0)
    T = 2 * math.pi
    row = next(r for r in rows if r["stable"] == "1")
    y0 = np.array([float(row[f"y0_{s}"]) for s in STATES])
    h = 1e-5
    M = np.column_stack(
        [(run(model, y0 + h * e, 0, T)[0] - run(model, y0 - h * e, 0, T)[0]) / (2 * h) for e in E]
    )
    ref = sorted(np.linalg.eigvals(M), key=lambda z: (-abs(z), z.imag))
    got = sorted((complex(z) for z in row["multipliers"].split()), key=lambda z: (-abs(z), z.imag))
    assert len(got) == 4
    assert np.allclose(got, ref, atol=1e-6)
    assert float(row["max_multiplier"]) == pytest.approx(abs(ref[0]), abs=1e-6)
    assert row["stability"] == "stable"


def test_periodic_impact_pair_relative_displacement():
    code, rows, err = cli("periodic", "impact_pair", "--omega", "1.2", "--output", "x1 - x2")
    assert code == 0, err
    assert rows
    check_orbit_rows(impact_pair(W=1.2), rows, 1.2, np.array([1.0, -1.0, 0, 0]))


# a linear 2-DOF system as two equations separated by ';'
LINEAR = "x1'' + 0.1*x1' + 2*x1 - x2 = F*cos(Omega*t); x2'' + 0.05*x2' + x2 - x1 = 0"


def linear_response(W, F=1.0):
    """(Q1, Q2) of (K - W^2 M + i W C) Q = (F, 0) and the first-order matrix."""
    K = np.array([[2.0, -1.0], [-1.0, 1.0]])
    C = np.diag([0.1, 0.05])
    Q = np.linalg.solve(K - W**2 * np.eye(2) + 1j * W * C, np.array([F, 0.0]))
    A = np.block([[np.zeros((2, 2)), np.eye(2)], [-K, -C]])
    return Q, A


def test_periodic_linear_system_equals_the_closed_form():
    code, rows, err = cli(
        "periodic", LINEAR, "--param", "F=1", "--omega", "0.7", "--output", "x1 - x2"
    )
    assert code == 0, err
    assert len(rows) == 1
    (row,) = rows
    Q, A = linear_response(0.7)
    assert float(row["amplitude"]) == pytest.approx(abs(Q[0] - Q[1]), rel=1e-10)
    assert float(row["first_harmonic_amplitude"]) == pytest.approx(abs(Q[0] - Q[1]), rel=1e-10)
    assert float(row["amplitude_x1"]) == pytest.approx(abs(Q[0]), rel=1e-10)
    assert float(row["amplitude_x2"]) == pytest.approx(abs(Q[1]), rel=1e-10)
    for key in ("mean", "mean_x1", "mean_x2"):
        assert abs(float(row[key])) <= 1e-10
    # the orbit's initial state is Re Q (x at t = 0) and Re(i W Q) (velocities)
    y0 = [float(row[f"y0_{s}"]) for s in STATES]
    expected = [Q[0].real, Q[1].real, (1j * 0.7 * Q[0]).real, (1j * 0.7 * Q[1]).real]
    assert np.allclose(y0, expected, atol=1e-10)
    mu = np.exp(np.linalg.eigvals(A) * 2 * math.pi / 0.7)
    got = np.array([complex(z) for z in row["multipliers"].split()])
    assert np.allclose(sorted(np.abs(got)), sorted(np.abs(mu)), rtol=1e-8)
    assert row["stability"] == "stable"


# ------------------------------------------------------------------------------------------
# perturb frc
# ------------------------------------------------------------------------------------------
def test_frc_linear_system_range_and_list_equal_the_closed_form():
    code, rows, err = cli("frc", LINEAR, "--param", "F=1", "--omega", "0.5:0.9", "--output", "x2")
    assert code == 0, err
    assert rows and list(rows[0])[:8] == [
        "branch",
        "omega",
        "amplitude",
        "first_harmonic_amplitude",
        "mean",
        "stable",
        "max_multiplier",
        "method",
    ]
    assert list(rows[0])[8:] == ["amplitude_x1", "amplitude_x2", "mean_x1", "mean_x2"]
    errors = []
    for row in rows:
        Q, _ = linear_response(float(row["omega"]))
        # a traced point is corrected to the continuation's tolerance in scaled (orbit,
        # frequency) coordinates: at the resonance peak (Omega 0.606, amplitude 10.8) that
        # left 1.3e-7 relative, elsewhere ~1e-10 (median 1.6e-10, measured 2026-11-27)
        assert float(row["amplitude"]) == pytest.approx(abs(Q[1]), rel=5e-7)
        assert float(row["amplitude_x2"]) == float(row["amplitude"])
        assert float(row["amplitude_x1"]) == pytest.approx(abs(Q[0]), rel=5e-7)
        assert abs(float(row["mean_x1"])) <= 1e-8
        assert row["stable"] == "1"
        errors.append(abs(float(row["amplitude"]) - abs(Q[1])) / abs(Q[1]))
    assert float(np.median(errors)) <= 1e-8
    code, rows, err = cli("frc", LINEAR, "--param", "F=1", "--omega", "0.6,0.8")
    assert code == 0, err
    assert [float(r["omega"]) for r in rows] == [0.6, 0.8]
    for row in rows:
        Q, _ = linear_response(float(row["omega"]))
        assert float(row["amplitude"]) == pytest.approx(abs(Q[0]), rel=1e-9)  # default: x1
        assert float(row["amplitude_x2"]) == pytest.approx(abs(Q[1]), rel=1e-9)


def test_frc_nsd2_at_one_frequency_finds_the_attractor():
    code, rows, err = cli("frc", "nsd2", "--omega", "1.0", "--output", "x1 - x2")
    assert code == 0, err
    model = nsd2(W=1.0)
    y = settled(model, 1.0, [0.0, 0.0, 0.0, 0.0])
    _, pieces = run(model, y, 0.0, 2 * math.pi)
    amp, _ = stats(model, pieces, np.array([1.0, -1.0, 0, 0]))
    amp2, mean2 = stats(model, pieces, E[1])
    assert any(
        abs(float(r["amplitude"]) - amp) <= 1e-7 * amp
        and abs(float(r["amplitude_x2"]) - amp2) <= 1e-7 * amp2
        and abs(float(r["mean_x2"]) - mean2) <= 1e-6
        and r["stable"] == "1"
        for r in rows
    ), (amp, amp2, mean2, rows)


# ------------------------------------------------------------------------------------------
# perturb simulate
# ------------------------------------------------------------------------------------------
def test_simulate_nsd2_states_and_output_match_the_reference(tmp_path):
    out = tmp_path / "h.csv"
    png = tmp_path / "h.png"
    argv = ["simulate", "nsd2", "--param", "Omega=0.8", "--y0", "0.3,0,0,0.1", "--t", "0:40"]
    argv += ["--samples", "41", "--output", "x1 - x2", "--out", str(out), "--plot", str(png)]
    code, _, err = cli(*argv)
    assert code == 0, err
    assert png.stat().st_size > 0
    rows = list(csv.DictReader(out.open()))
    assert list(rows[0]) == ["t", *STATES, "output"]
    assert len(rows) == 41
    model = nsd2(W=0.8)
    Y = np.array([[float(r[s]) for s in STATES] for r in rows])
    assert np.array_equal(Y[0], [0.3, 0.0, 0.0, 0.1])
    y = Y[0]
    for j in range(1, 41):  # the reference, restarted at every sample time
        y, _ = run(model, y, float(rows[j - 1]["t"]), float(rows[j]["t"]))
        assert np.abs(Y[j] - y).max() <= 1e-8 * max(1.0, float(np.abs(y).max()))
    out_col = np.array([float(r["output"]) for r in rows])
    assert np.allclose(out_col, Y[:, 0] - Y[:, 1], rtol=0, atol=1e-13)


def test_simulate_belt_uses_the_event_driven_flow():
    code, rows, err = cli("simulate", "belt", "--t", "0:10", "--samples", "5")
    assert code == 0, err
    assert list(rows[0]) == ["t", "x", "x'", "output"]
    assert "events" in err


def test_simulate_systems_with_stops_and_drift():
    # the mount's decoupler stays between its stops 0 <= V_d <= 2 V_gap (volumes of 1e-6 m^3:
    # the event tolerance is scaled to them)
    code, rows, err = cli("simulate", "mount", "--t", "0:0.3", "--samples", "31")
    assert code == 0, err
    vd = np.array([float(r["V_d"]) for r in rows])
    assert vd.min() >= -1e-15 and vd.max() <= 1.5e-6 + 1e-15 and vd.max() > 1e-7
    # the drill string turns without bound (no equilibrium to size a tolerance by)
    code, rows, err = cli("simulate", "drill_string", "--t", "0:10", "--samples", "3")
    assert code == 0, err
    assert float(rows[-1]["phi_r"]) > 1.0


# ------------------------------------------------------------------------------------------
# bad input, unchanged SDOF formats, models
# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("argv", "match"),
    [
        (("periodic", "nsd2", "--omega", "1", "--output", "x3"), "x3.*x1, x2"),
        (("simulate", "nsd2", "--output", "x1*x2", "--samples", "3"), "not linear"),
        (("frc", "nsd2", "--output", "x2 + 1"), "constant term"),
        (("simulate", "nsd", "--output", "x2"), "one coordinate 'x'"),
        (("periodic", "nsd", "--omega", "0.6", "--output", "x1"), "one coordinate 'x'"),
        (("frc", "nsd2", "--method", "mlp"), "mlp.*one coordinate.*--method exact"),
        (("frc", "nsd2", "--harmonics", "5"), "--harmonics.*one coordinate"),
        (("frc", "nsd2", "--param", "Omega=1"), "--omega"),
        (("derive", "mlp", "nsd2"), "several coordinates"),
        (("simulate", "nsd2", "--y0", "1,2"), "4 numbers.*x1, x2, x1', x2'"),
        (("simulate", "nsd2", "--method", "lcp"), "one coordinate"),
        (("periodic", "belt", "--omega", "1"), "Omega"),
        (("simulate", "x1'' + x1 = 0; x2'' + zz*x2 = 0", "--samples", "3"), "zz"),
        (("periodic", "nsd2", "--omega", "1", "--param", "kk=1"), "kk"),
        (("simulate", ";".join(f"x{i}'' + x{i} = 0" for i in range(70))), "70 equations"),
    ],
)
def test_bad_input_is_one_line_naming_the_value(argv, match, capsys):
    assert main(list(argv)) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("perturb: error: ") and "\n" not in err
    assert "internal error" not in err
    import re

    assert re.search(match, err), err


def test_sdof_formats_unchanged():
    assert header("simulate", "nsd", "--t", "0:1", "--samples", "3") == ["t", "x", "v"]
    with_x = cli("simulate", "nsd", "--t", "0:1", "--samples", "3", "--output", "x")
    without = cli("simulate", "nsd", "--t", "0:1", "--samples", "3")
    assert with_x[0] == without[0] == 0 and with_x[1] == without[1]
    assert header("frc", "duffing", "--omega", "0.5,0.6") == [
        "branch",
        "omega",
        "amplitude",
        "first_harmonic_amplitude",
        "mean",
        "stable",
        "max_multiplier",
        "method",
    ]


def test_models_lists_the_systems_with_their_states(capsys):
    assert main(["models"]) == 0
    text = capsys.readouterr().out
    from perturb.model.system_builtins import BUILTIN_SYSTEMS, builtin_system

    for name in ("nsd2", "impact_pair", "mount", "mount_linear", "belt", "drill_string"):
        assert f"\n{name}\n" in text
    for name in BUILTIN_SYSTEMS:  # the listed state order is the parsed system's
        block = text.split(f"\n{name}\n", 1)[1]
        states = block.split("states: ", 1)[1].split("\n", 1)[0]
        assert states == ", ".join(builtin_system(name).state_names)
    assert text.startswith("nsd\n")  # the oscillators first, as before
