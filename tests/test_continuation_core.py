"""The numeric continuation package: options object, step control and event objects.

Oracles are closed forms: the curve ``u^2 + lam^2 = 1`` (folds at ``lam = +-1``, ``u = 0``)
and the pitchfork ``u (lam - u^2) = 0`` (branch point at the origin, where the trivial curve
``u = 0`` meets the parabola ``lam = u^2``).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from perturb.errors import ParameterError
from perturb.numeric.continuation import (
    ContinuationOptions,
    Corrector,
    Evaluation,
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
    with pytest.raises(ParameterError, match="ds_maximum"):
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


def _circle_evaluation(with_column: bool, D=None):
    """Evaluations of the circle, counted; without F_lam when ``with_column`` is False; the
    iterate is scaled by ``D`` when given (the unscaled Jacobians are returned)."""
    calls = []

    def evaluate(x):
        calls.append(x.copy())
        x = x if D is None else x * D
        ju, jl = circle_jac(x[:1], float(x[1]))
        return Evaluation(circle(x[:1], float(x[1])), ju, jl if with_column else None, "tag")

    return evaluate, calls


@pytest.mark.parametrize("with_column", [True, False])
@pytest.mark.parametrize("scaled", [True, False])
def test_corrector_lands_on_the_circle_on_the_bordering_line(with_column, scaled):
    # from (0.9, 0.6) along the row (1, 1): the corrected point is the intersection of the
    # circle with the line u + lam = 1.5 (both coordinates scaled by D = (2, 1))
    D = np.array([2.0, 1.0])
    evaluate, calls = _circle_evaluation(with_column, D if scaled else None)
    fd_calls = []

    def fd_column(x, r):
        fd_calls.append(1)
        x = x * D if scaled else x
        h = 1e-7
        return (circle(x[:1], float(x[1]) + h) - r) / h

    x0 = np.array([0.9, 0.6])
    row = np.array([1.0, 1.0]) / math.sqrt(2.0)
    newton = Corrector(evaluate, scaled=scaled, tangent=scaled, fd_column=fd_column)

    def accept(k, size, prev, ev):
        assert ev.payload == "tag"
        return size <= 1e-9  # the accepted iterate is then within ~1e-18 (quadratic)

    if scaled:
        c = newton.correct(x0 / D, D, row, max_iter=30, accept=accept, target=float(row @ (x0 / D)))
        u, lam = c.x * D
    else:
        c = newton.correct(x0, D, row, max_iter=30, accept=accept, anchor=x0 / D)
        u, lam = c.x
    # the line in unscaled coordinates: u/2 + lam = 0.45 + 0.6; with the circle
    c_line = 0.45 + 0.6
    # 5 lam^2 - 8 c lam + 4 c^2 - 1 = 0, the root near the start (lam ~ 0.69, u ~ 0.73)
    lam_ref = (8.0 * c_line - math.sqrt(64.0 * c_line**2 - 20.0 * (4.0 * c_line**2 - 1.0))) / 10.0
    u_ref = 2.0 * (c_line - lam_ref)
    assert u**2 + lam**2 == pytest.approx(1.0, abs=1e-12)
    assert (u, lam) == pytest.approx((u_ref, lam_ref), abs=1e-10)
    assert c.evaluations == len(calls) + len(fd_calls)
    assert len(fd_calls) == (0 if with_column else 1)  # Broyden after the first difference
    if scaled:
        # the tangent of the circle at the point, from the same factorisation
        t = c.z * D / np.linalg.norm(c.z * D)
        assert abs(t @ np.array([u, lam])) < 1e-6


def test_corrector_refuses_a_far_predictor_and_an_unevaluable_iterate():
    evaluate, calls = _circle_evaluation(True)
    newton = Corrector(evaluate, scaled=False)
    D = np.ones(2)
    row = np.array([0.0, 1.0])

    def accept(k, size, prev, ev):
        return size <= 1e-9

    # the first correction from (3, 0) to the circle at lam = 0 is larger than the cap
    x0 = np.array([3.0, 0.0])
    assert newton.correct(x0, D, row, max_iter=30, accept=accept, anchor=x0, cap=0.5) is None
    assert newton.evaluations == 1
    ok = newton.correct(x0, D, row, max_iter=30, accept=accept, anchor=x0)
    assert ok is not None and ok.x == pytest.approx([1.0, 0.0], abs=1e-12)
    # no evaluation possible: a failure, not counted
    none = Corrector(lambda x: None, scaled=False)
    assert none.correct(x0, D, row, max_iter=5, accept=accept, anchor=x0) is None
    assert none.evaluations == 0
    # lam = 2 on the row e_lam: no real point on the circle, Newton does not converge
    x2 = np.array([0.5, 2.0])
    assert newton.correct(x2, D, row, max_iter=30, accept=accept, anchor=x2) is None
