"""Scenes of systems of several coordinates (issue 15, item 6).

``[model] system = "nsd2"`` (or ``name`` of a builtin system, or ``equations = [...]``) with
``output = "x1 - x2"``; kinds ``frequency_response`` (exact), ``time_history`` and
``step_response``. The written CSVs are checked against references computed here without the
package: the equations written out by hand and integrated by DOP853 (rtol = atol = 1e-12, an
event and a restart at every switching surface), the closed-form harmonic response of a linear
system, and the closed-form step response of a linear system (the matrix exponential of the
augmented first-order matrix). Bad scenes are refused with messages naming the key and value.
"""

from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest
import scipy.linalg
from scipy.integrate import solve_ivp

from perturb.apps.scene import parse_scene, run_scene
from perturb.errors import PerturbError

STATES = ("x1", "x2", "x1'", "x2'")


def nsd2_rhs(W, k=-0.5, mu1=0.05, mu2=0.02, k2=1.0, m2=1.0, F=2.0):
    def rhs(t, y, pat):
        x1, x2, v1, v2 = y
        h = x1 - 1.0 if pat[0] > 0 else (x1 + 1.0 if pat[1] < 0 else 0.0)
        a1 = -mu1 * v1 - mu2 * (v1 - v2) - k * x1 - (1 - k) * h - k2 * (x1 - x2)
        return np.array(
            [v1, v2, a1 + F * math.cos(W * t), (-mu2 * (v2 - v1) - k2 * (x2 - x1)) / m2]
        )

    return rhs


def reference(rhs, y0, t0, t1):
    """DOP853 with a terminal event on x1 = +-1 and a restart in the region entered."""
    y, t = np.array(y0, dtype=float), t0
    pat = [1 if y[0] >= 1 else -1, 1 if y[0] >= -1 else -1]
    for _ in range(10_000):
        events = []
        for j, off in enumerate((1.0, -1.0)):

            def ev(tt, yy, off=off):
                return yy[0] - off

            ev.terminal, ev.direction = True, -pat[j]
            events.append(ev)
        p = tuple(pat)
        sol = solve_ivp(
            lambda tt, yy, p=p: rhs(tt, yy, p),
            (t, t1),
            y,
            method="DOP853",
            rtol=1e-12,
            atol=1e-12,
            events=events,
        )
        y, t = sol.y[:, -1].copy(), float(sol.t[-1])
        if sol.status == 0:
            return y
        for j, te in enumerate(sol.t_events):
            if te.size:
                pat[j] = -pat[j]
    raise AssertionError("too many events")


def rows_of(path):
    return list(csv.DictReader(open(path)))


def test_time_history_scene_of_nsd2(tmp_path):
    scene = parse_scene(
        """
[model]
system = "nsd2"
output = "x1 - x2"
[params]
Omega = 0.8
[ask]
kind = "time_history"
y0 = {x1 = 0.3, "x2'" = 0.1}
t = [0.0, 30.0]
samples = 31
""",
        "th.toml",
    )
    paths = run_scene(scene, tmp_path, log=open("/dev/null", "w"))
    rows = rows_of(paths["csv"])
    assert list(rows[0]) == ["t", *STATES, "output"]
    Y = np.array([[float(r[s]) for s in STATES] for r in rows])
    assert np.array_equal(Y[0], [0.3, 0.0, 0.0, 0.1])
    rhs = nsd2_rhs(0.8)
    y = Y[0]
    for j in range(1, len(rows)):
        y = reference(rhs, y, float(rows[j - 1]["t"]), float(rows[j]["t"]))
        assert np.abs(Y[j] - y).max() <= 1e-8 * max(1.0, float(np.abs(y).max()))
    assert np.allclose([float(r["output"]) for r in rows], Y[:, 0] - Y[:, 1], atol=1e-13)
    report = json.loads(paths["report"].read_text())
    assert report["integrator"] == "exact" and report["output"] == "x1 - x2"
    assert paths["png"].stat().st_size > 0


LINEAR = [
    "x1'' + 0.1*x1' + 2*x1 - x2 = F*cos(Omega*t)",
    "x2'' + 0.05*x2' + x2 - x1 = 0",
]


def test_frequency_response_scene_of_a_linear_system_equals_the_closed_form(tmp_path):
    scene = parse_scene(
        f"""
[model]
equations = {json.dumps(LINEAR)}
name = "two_masses"
output = "x2"
[params]
F = 1.0
[ask]
kind = "frequency_response"
omega = [0.3, 0.5]
""",
        "frc.toml",
    )
    paths = run_scene(scene, tmp_path, log=open("/dev/null", "w"))
    assert "latex" not in paths
    rows = rows_of(paths["csv"])
    cols = list(rows[0])
    assert cols[:8] == [
        "branch",
        "omega",
        "amplitude",
        "first_harmonic_amplitude",
        "mean",
        "stable",
        "max_multiplier",
        "method",
    ]
    assert cols[8:] == ["amplitude_x1", "amplitude_x2", "mean_x1", "mean_x2"]
    K = np.array([[2.0, -1.0], [-1.0, 1.0]])
    C = np.diag([0.1, 0.05])
    for row in rows:
        W = float(row["omega"])
        Q = np.linalg.solve(K - W**2 * np.eye(2) + 1j * W * C, [1.0, 0.0])
        # away from the resonance (0.606) the traced points are within ~1e-9
        assert float(row["amplitude"]) == pytest.approx(abs(Q[1]), rel=1e-7)
        assert float(row["amplitude_x1"]) == pytest.approx(abs(Q[0]), rel=1e-7)
        assert abs(float(row["mean_x2"])) <= 1e-8
    report = json.loads(paths["report"].read_text())
    assert report["output"] == "x2" and report["branches"] >= 1
    assert report["columns"] == ["amplitude_x1", "amplitude_x2", "mean_x1", "mean_x2"]


def test_step_response_scene_of_a_linear_system_equals_the_closed_form(tmp_path):
    scene = parse_scene(
        f"""
[model]
equations = {json.dumps(["x1'' + 0.4*x1' + 2*x1 - x2 = P", "x2'' + 0.2*x2' + x2 - x1 = 0"])}
output = "x1 - x2"
[params]
P = 1.5
[ask]
kind = "step_response"
times = [0.0, 12.0]
points = 25
outputs = {{ spring = "x1 - x2", rate = "x2'" }}
crossings = ["rate"]
""",
        "step.toml",
    )
    paths = run_scene(scene, tmp_path, log=open("/dev/null", "w"))
    rows = rows_of(paths["csv"])
    assert list(rows[0]) == ["t", *STATES, "spring", "rate", "output"]
    # y' = A y + b from rest: (y, 1)(t) = expm([[A, b], [0, 0]] t) (0, 1)
    A = np.array(
        [[0, 0, 1, 0], [0, 0, 0, 1], [-2.0, 1.0, -0.4, 0.0], [1.0, -1.0, 0.0, -0.2]], dtype=float
    )
    aug = np.zeros((5, 5))
    aug[:4, :4] = A
    aug[2, 4] = 1.5
    for row in rows:
        t = float(row["t"])
        y = (scipy.linalg.expm(aug * t) @ np.array([0, 0, 0, 0, 1.0]))[:4]
        got = np.array([float(row[s]) for s in STATES])
        assert np.abs(got - y).max() <= 1e-10
        assert float(row["spring"]) == pytest.approx(y[0] - y[1], abs=1e-10)
        assert float(row["output"]) == float(row["spring"])
        assert float(row["rate"]) == pytest.approx(y[3], abs=1e-10)
    report = json.loads(paths["report"].read_text())
    assert report["solver"] == "closed_form"
    # the zeros of x2' are the turning points of x2: check them on the closed form
    assert len(report["crossings"]["rate"]) >= 1  # a loop over nothing would check nothing
    for tz in report["crossings"]["rate"]:
        y = scipy.linalg.expm(aug * tz) @ np.array([0, 0, 0, 0, 1.0])
        assert abs(y[3]) <= 1e-9


def test_mount_step_scene_runs_with_the_builtin_outputs(tmp_path):
    scene = parse_scene(
        """
[model]
name = "mount"
[params]
X = -2.4e-3
[ask]
kind = "step_response"
times = [0.0, 0.3]
points = 31
outputs = ["p1", "p2"]
crossings = ["flow"]
[output]
csv = "mount_step.csv"
png = "mount_step.png"
""",
        "mount.toml",
    )
    paths = run_scene(scene, tmp_path, log=open("/dev/null", "w"))
    rows = rows_of(paths["csv"])
    assert list(rows[0]) == ["t", "V_i", "V_d", "V_i'", "V_d'", "p1", "p2", "flow"]
    # the chamber pressures written out from the He-Singh model (hydraulic_mount.py values)
    A_r, C1, C2, C1v, p_vac, X, V_gap = 3.0e-3, 4.0e-11, 4.0e-9, 2.0e-9, 9.0e4, -2.4e-3, 7.5e-7
    for row in rows:
        Vi, Vd = float(row["V_i"]), float(row["V_d"])
        assert -1e-15 <= Vd <= 2 * V_gap + 1e-15  # the decoupler stays between its stops
        u = A_r * X - Vi - Vd
        uk = -p_vac * C1
        p1 = u / C1 + (1 / C1v - 1 / C1) * (u - uk) * (uk - u > 0)
        assert float(row["p1"]) == pytest.approx(p1, rel=1e-9, abs=1e-6)
        assert float(row["p2"]) == pytest.approx((Vi + Vd) / C2, rel=1e-9, abs=1e-6)
    report = json.loads(paths["report"].read_text())
    assert report["solver"] == "events" and report["events"] > 0
    assert "flow" in report["crossings"]


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ('[model]\nname = "nsd"\noutput = "x2"', "output.*systems"),
        ('[model]\nsystem = "nsd3"', "nsd3.*nsd2"),
        ('[model]\nsystem = "nsd2"\nequations = ["x1\'\' = 0"]', "not both"),
        ('[model]\nsystem = "nsd2"\nequation = "x\'\' = 0"', "equations"),
        ("[model]\nequations = \"x1'' = 0\"", "list of"),
        ('[model]\nsystem = "nsd2"\n[ask]\nkind = "backbone"', "one coordinate"),
        ('[model]\nsystem = "nsd2"\n[method]\nname = "mlp"', "mlp.*one coordinate"),
        ('[model]\nsystem = "nsd2"\n[method]\nname = "exact"\nharmonics = 3', "harmonics"),
        ('[model]\nsystem = "nsd2"\n[compare]\nreference = "exact"', r"\[compare\]"),
        ('[model]\nsystem = "nsd2"\n[ask]\nkind = "time_history"\nsamples = 1', "samples"),
        ('[model]\nsystem = "nsd2"\n[ask]\nkind = "time_history"\ny0 = "a"', "y0"),
        ('[model]\nsystem = "nsd2"\n[ask]\nkind = "time_history"\nactive = {a = 1}', "active"),
        ('[model]\nname = "mount"\n[ask]\nkind = "step_response"\nactive = {decoupler = 2}', "-1"),
        ('[model]\nname = "mount"\n[ask]\nkind = "step_response"\nmethod = "lcp"', "closed_form"),
        ('[model]\nsystem = "nsd2"\n[output]\nlatex = "d.tex"', "derivation"),
        ('[model]\nsystem = "nsd2"\noutput = 3', "output = 3"),
    ],
)
def test_bad_system_scenes_name_the_key(text, match):
    with pytest.raises(PerturbError, match=match):
        parse_scene(text, "bad.toml")


@pytest.mark.parametrize(
    ("ask", "match"),
    [
        ('kind = "time_history"\ny0 = [1.0, 2.0]', "4 numbers"),
        ('kind = "time_history"\ny0 = {x3 = 1.0}', "x3.*x1, x2"),
    ],
)
def test_initial_states_are_checked_against_the_model(tmp_path, ask, match):
    scene = parse_scene(f'[model]\nsystem = "nsd2"\n[ask]\n{ask}', "y0.toml")
    with pytest.raises(PerturbError, match=match):
        run_scene(scene, tmp_path, log=open("/dev/null", "w"))


def test_bad_output_is_refused_when_the_scene_runs(tmp_path):
    scene = parse_scene(
        '[model]\nsystem = "nsd2"\noutput = "x1 + z"\n[ask]\nkind = "time_history"', "o.toml"
    )
    with pytest.raises(PerturbError, match="x1 \\+ z.*x1, x2"):
        run_scene(scene, tmp_path, log=open("/dev/null", "w"))


def test_oscillator_scenes_are_unchanged():
    scene = parse_scene('[model]\nname = "nsd"\n[ask]\nkind = "time_history"', "sdof.toml")
    assert not scene.is_system and scene.y0 == (0.0, 0.0) and scene.method == "auto"
    assert scene.model_object().name == "nsd"
