"""The numeric continuation package: options object, step control and event objects.

Oracles are closed forms: the curve ``u^2 + lam^2 = 1`` (folds at ``lam = +-1``, ``u = 0``)
and the pitchfork ``u (lam - u^2) = 0`` (branch point at the origin, where the trivial curve
``u = 0`` meets the parabola ``lam = u^2``).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from perturb.numeric.continuation import (
    ContinuationOptions,
    FloquetCrossings,
    StepControl,
    branch_off,
    continue_curve,
    hermite_extrapolate,
)


def circle(u, lam):
    return np.array([u[0] ** 2 + lam**2 - 1.0])


def circle_jac(u, lam):
    return np.array([[2.0 * u[0]]]), np.array([2.0 * lam])


def test_options_object_and_keywords_trace_the_same_curve():
    kw = {"ds_max": 0.03, "predictor": "hermite", "tol": 1e-12}
    a = continue_curve(circle, circle_jac, [math.sqrt(0.75)], -0.5, (-2.0, 2.0), **kw)
    b = continue_curve(
        circle, circle_jac, [math.sqrt(0.75)], -0.5, (-2.0, 2.0), ContinuationOptions(**kw)
    )
    # a keyword overrides the options object's field
    c = continue_curve(
        circle,
        circle_jac,
        [math.sqrt(0.75)],
        -0.5,
        (-2.0, 2.0),
        ContinuationOptions(ds_max=0.5, predictor="hermite", tol=1e-12),
        ds_max=0.03,
    )
    for other in (b, c):
        assert np.array_equal(a.u, other.u) and np.array_equal(a.lam, other.lam)
    # the circle is closed: both folds on the way round, each on the curve (u = 0, lam = +-1)
    assert a.stop_reason == "closed"
    lams = sorted(f.lam for f in a.folds)
    assert lams == pytest.approx([-1.0, 1.0], abs=1e-12)
    assert all(abs(f.u[0]) < 1e-5 for f in a.folds)
    assert np.max(np.abs(a.u[:, 0] ** 2 + a.lam**2 - 1.0)) < 1e-9


def test_unknown_keyword_and_bad_options_are_refused():
    with pytest.raises(TypeError, match="ds_maximum"):
        continue_curve(circle, circle_jac, [1.0], 0.0, (-2.0, 2.0), ds_maximum=0.1)
    with pytest.raises(Exception, match="ContinuationOptions"):
        continue_curve(circle, circle_jac, [1.0], 0.0, (-2.0, 2.0), {"ds_max": 0.1})


def test_step_control_paces_by_iterations_and_underflows():
    ctl = StepControl.growing(0.01, 1e-4, 0.05, growth=2.0)
    assert ctl.accepted(1) == pytest.approx(0.02)
    assert ctl.accepted(3) == pytest.approx(0.02)  # three iterations: kept
    assert ctl.accepted(2) == pytest.approx(0.04)
    assert ctl.accepted(2) == pytest.approx(0.05)  # capped at ds_max
    assert ctl.accepted(6) == pytest.approx(0.035)  # hard correction: x0.7
    assert ctl.accepted(1, limit=0.036) == pytest.approx(0.036)  # a caller's tighter cap
    steps = 0
    while ctl.failed():
        steps += 1
        assert steps < 100
    assert ctl.step < 1e-4 and steps == int(math.log2(0.036 / 1e-4))


def test_hermite_predictor_is_exact_on_a_cubic_arc():
    # points of the straight line: the cubic through two points with their (equal) unit
    # tangents is the line itself, whatever the extrapolation
    t = np.array([0.6, 0.8])
    w0, w1 = np.zeros(2), 0.1 * t
    assert np.allclose(hermite_extrapolate(w0, t, w1, t, 0.25), 0.35 * t, atol=1e-15)
    assert hermite_extrapolate(w0, t, w0, t, 0.1) is None


def pitchfork(u, lam):
    return np.array([u[0] * (lam - u[0] ** 2)])


def pitchfork_jac(u, lam):
    return np.array([[lam - 3.0 * u[0] ** 2]]), np.array([u[0]])


def test_branch_point_of_a_pitchfork_and_switching_onto_the_parabola():
    curve = continue_curve(
        pitchfork,
        pitchfork_jac,
        [0.0],
        -1.0,
        (-1.0, 1.0),
        ds_max=0.05,
        detect_branch_points=True,
    )
    assert len(curve.branch_points) == 1
    bp = curve.branch_points[0]
    assert abs(bp.lam) < 1e-6 and abs(bp.u[0]) < 1e-6
    sides = branch_off(pitchfork, pitchfork_jac, bp, step=0.05)
    assert len(sides) == 2
    for u, lam in sides:
        # on the parabola lam = u^2, off the trivial curve
        assert abs(lam - u[0] ** 2) < 1e-9 and abs(u[0]) > 1e-3


def test_floquet_crossings_name_the_multiplier_that_crossed():
    # a real multiplier through +1 (0.9 -> 1.2), the other inside: a branch point at 1/3
    got = FloquetCrossings.crossings(np.array([0.9, 0.1 + 0j]), np.array([1.2, 0.1 + 0j]))
    assert [k for k, _ in got] == ["branch_point"]
    assert got[0][1] == pytest.approx(1.0 / 3.0, rel=1e-12)  # (1 - 0.9) / (0.3)
    # through -1: a period doubling
    got = FloquetCrossings.crossings(np.array([-0.8, 0.2 + 0j]), np.array([-1.1, 0.2 + 0j]))
    assert [k for k, _ in got] == ["period_doubling"]
    # a complex pair leaving the unit circle: Neimark-Sacker (torus)
    inside = 0.95 * np.exp(1j * np.array([0.7, -0.7]))
    outside = 1.05 * np.exp(1j * np.array([0.7, -0.7]))
    got = FloquetCrossings.crossings(inside, outside)
    assert [k for k, _ in got] == ["torus"] and got[0][1] == pytest.approx(0.5)
    # no crossing
    assert FloquetCrossings.crossings(np.array([0.5, 0.2 + 0j]), np.array([0.6, 0.3 + 0j])) == []
