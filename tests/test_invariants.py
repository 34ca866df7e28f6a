"""Conserved linear combinations (``System.invariants``) and the orbits pinned on them.

The first-order linear mount ``mount_linear`` conserves ``C1 p1 + C2 p2 - A_r x``: its
periodic orbits form a family, one per value of that combination. ``periodic_orbits`` and
``perturb frc --omega 50,60`` must return exactly one orbit per frequency: the one whose
period-mean of ``C1 p1 + C2 p2`` is 0 (the rest state's value), which is the closed-form
harmonic response ``y = Re(Y e^{i W t})``, ``(i W I - A) Y = -i beta`` of the equations
written out by hand here (a sinusoid: zero mean, ``max |y_k| = |Y_k|``), to 1e-10 relative;
its Floquet multipliers are ``exp(lambda T)`` of the hand-written matrix, the eigenvalue 0 of
the invariant giving the trivial multiplier 1.
"""

from __future__ import annotations

import contextlib
import csv
import io
import math

import numpy as np
import pytest

from perturb.apps.cli import main
from perturb.errors import ModelError, ParameterError
from perturb.model.system import System
from perturb.model.system_builtins import builtin_system
from perturb.solve import orbit_columns, periodic_orbits

#: the builtin's parameter values (data only: the equations are written out below)
P = dict(builtin_system("mount_linear").params)
STATES = ("p1", "p2", "q_i", "q_d")


def mount_matrix(p: dict) -> tuple[np.ndarray, np.ndarray]:
    """C1 p1' = -q_i - q_d - A_r Xa W sin(W t), C2 p2' = q_i + q_d,
    I_i q_i' = p1 - p2 - R_i q_i, I_d q_d' = p1 - p2 - R_d q_d: (A, beta / W), the forcing
    being beta sin(W t)."""
    C1, C2, Ii, Id, Ri, Rd = (p[k] for k in ("C1", "C2", "I_i", "I_d", "R_i", "R_d"))
    A = np.array(
        [
            [0.0, 0.0, -1 / C1, -1 / C1],
            [0.0, 0.0, 1 / C2, 1 / C2],
            [1 / Ii, -1 / Ii, -Ri / Ii, 0.0],
            [1 / Id, -1 / Id, 0.0, -Rd / Id],
        ]
    )
    return A, np.array([-p["A_r"] * p["Xa"] / C1, 0.0, 0.0, 0.0])


def closed_form(p: dict, W: float) -> np.ndarray:
    """The complex amplitude Y of the zero-mean harmonic response at W."""
    A, beta = mount_matrix(p)
    return np.linalg.solve(1j * W * np.eye(4) - A, -1j * W * beta)


def cli(*argv: str) -> tuple[int, list[dict[str, str]], str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(list(argv))
    text = out.getvalue()
    return code, (list(csv.DictReader(io.StringIO(text))) if text.strip() else []), err.getvalue()


def test_mount_invariant_is_the_chambers_volume():
    s = builtin_system("mount_linear")
    C = s.invariants()
    assert C.shape == (1, 4)
    expected = np.array([P["C1"], P["C2"], 0.0, 0.0]) / P["C1"]
    assert np.allclose(C[0], expected, rtol=1e-12, atol=0.0)
    A, _ = mount_matrix(P)
    assert float(np.abs(C[0] @ A).max()) <= 1e-12 * float(np.abs(C[0]).max() * np.abs(A).max())


def test_invariants_of_other_systems():
    for name in ("nsd2", "impact_pair", "belt", "drill_string", "mount"):
        assert builtin_system(name).invariants().shape == (0, builtin_system(name).n), name
    free = System.parse(
        ["x1'' + c*(x1' - x2') + k*(x1 - x2) = 0", "x2'' + c*(x2' - x1') + k*(x2 - x1) = 0"],
        {"c": 0.1, "k": 2.0},
    )
    # two free masses: the momentum x1' + x2'
    assert np.allclose(free.invariants(), [[0.0, 0.0, 1.0, 1.0]], atol=1e-14)
    # a spring to the ground breaks it
    grounded = System.parse(["x1'' + x1 + k*(x1 - x2) = 0", "x2'' + k*(x2 - x1) = 0"], {"k": 2.0})
    assert grounded.invariants().shape == (0, 4)


@pytest.mark.parametrize("W", [50.0, 60.0])
def test_one_orbit_per_frequency_equal_to_the_closed_form(W):
    s = builtin_system("mount_linear")
    orbits = periodic_orbits(s, W)
    assert len(orbits) == 1
    o = orbits[0]
    Y = closed_form(P, W)
    for k in range(4):  # each state relative to its own amplitude
        assert abs(o.y0[k] - Y[k].real) <= 1e-10 * abs(Y[k]), STATES[k]
    num = orbit_columns(s.with_params(Omega=W), o)
    for k, name in enumerate(STATES):
        assert num[f"amplitude_{name}"] == pytest.approx(abs(Y[k]), rel=1e-10)
        assert abs(num[f"mean_{name}"]) <= 1e-10 * abs(Y[k])
    # multipliers: exp(lambda T) of the hand-written matrix; lambda = 0 (the invariant) -> 1
    A, _ = mount_matrix(P)
    expected = np.exp(np.linalg.eigvals(A) * 2 * math.pi / W)
    got = np.asarray(o.multipliers)
    assert np.sum(got == 1.0) == 1  # the trivial one, reported exactly
    assert np.allclose(np.sort_complex(got), np.sort_complex(expected), rtol=0, atol=1e-10)
    nontrivial = np.delete(expected, np.argmin(np.abs(expected - 1.0)))
    assert o.max_multiplier == pytest.approx(float(np.abs(nontrivial).max()), abs=1e-10)
    assert o.stability == "stable"


def test_other_invariant_values_shift_the_pressures():
    s = builtin_system("mount_linear")
    W, v = 50.0, 30.0
    (o,) = periodic_orbits(s, W, invariants=[v])
    c = np.array([1.0, P["C2"] / P["C1"], 0.0, 0.0])
    # the family's direction: equal pressures (A r = 0), scaled to mean c . y = v
    r = np.array([1.0, 1.0, 0.0, 0.0])
    y0 = closed_form(P, W).real + v / float(c @ r) * r
    Y = closed_form(P, W)
    for k in range(4):
        assert abs(o.y0[k] - y0[k]) <= 1e-10 * abs(Y[k]), STATES[k]
    with pytest.raises(ParameterError, match="expected 1 number.*p1 \\+ 100\\*p2"):
        periodic_orbits(s, W, invariants=[1.0, 2.0])
    with pytest.raises(ParameterError, match="invariants"):
        periodic_orbits(builtin_system("nsd2"), 1.0, invariants=[0.0])


def test_frc_at_listed_frequencies_gives_one_orbit_each():
    code, rows, err = cli("frc", "mount_linear", "--omega", "50,60", "--output", "p1")
    assert code == 0, err
    assert sorted(float(r["omega"]) for r in rows) == [50.0, 60.0]
    for row in rows:
        Y = closed_form(P, float(row["omega"]))
        assert float(row["amplitude"]) == pytest.approx(abs(Y[0]), rel=1e-10)
        for k, name in enumerate(STATES):
            assert float(row[f"amplitude_{name}"]) == pytest.approx(abs(Y[k]), rel=1e-10)
    assert "p1 + 100*p2" in err and "mean" in err


def test_periodic_cli_one_orbit_and_the_note():
    code, rows, err = cli("periodic", "mount_linear", "--omega", "60")
    assert code == 0, err
    assert len(rows) == 1
    Y = closed_form(P, 60.0)
    assert float(rows[0]["amplitude_p2"]) == pytest.approx(abs(Y[1]), rel=1e-10)
    assert "conserved combination" in err and "trivial" in err


def test_traced_window_is_refused_naming_the_invariant(capsys):
    assert main(["frc", "mount_linear", "--omega", "50:60"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("perturb: error: ") and "\n" not in err
    assert "p1 + 100*p2" in err and "perturb periodic mount_linear" in err


def test_a_drifting_invariant_has_no_periodic_orbit():
    s = System.parse(
        ["x1'' + k*(x1 - x2) = a + F*cos(Omega*t)", "x2'' + k*(x2 - x1) = 0"],
        {"k": 1.0, "a": 0.5, "F": 1.0, "Omega": 1.3},
    )
    with pytest.raises(ModelError, match="constant rate.*no periodic orbit"):
        periodic_orbits(s, 1.3)


def test_a_free_translation_without_a_pinning_invariant_is_refused():
    # two masses coupled to each other only: every orbit comes with all its translates
    # x1 + s, x2 + s (the momentum invariant x1' + x2' does not fix s)
    s = System.parse(
        [
            "x1'' + c*(x1' - x2') + k*(x1 - x2) = F*cos(Omega*t)",
            "x2'' + c*(x2' - x1') + k*(x2 - x1) = 0",
        ],
        {"c": 0.1, "k": 2.0, "F": 1.0, "Omega": 1.3},
    )
    with pytest.raises(ModelError, match="shift of its state along d = x1 \\+ x2.*not isolated"):
        periodic_orbits(s, 1.3)
