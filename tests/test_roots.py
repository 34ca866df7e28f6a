"""Tests of perturb.numeric.roots against independent oracles (closed forms, scipy brentq)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.sparse as sps
from scipy.optimize import brentq

from perturb.errors import ParameterError
from perturb.numeric.roots import (
    NewtonOptions,
    damped_newton,
    illinois,
    illinois_vectorized,
    lu_or_lstsq,
    newton_direction,
)


# ---------------------------------------------------------------------------------------------
# regula falsi (Illinois)
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("f", "a", "b", "exact"),
    [
        (lambda x: x * x - 2.0, 0.0, 2.0, math.sqrt(2.0)),
        (lambda x: math.cos(x) - x, 0.0, 1.0, None),
        (lambda x: math.exp(x) - 10.0, 0.0, 5.0, math.log(10.0)),
        (lambda x: x**3 - x - 1.0, 1.0, 2.0, None),
    ],
)
def test_illinois_matches_closed_forms_and_brentq(f, a, b, exact):
    res = illinois(f, a, b)
    oracle = exact if exact is not None else brentq(f, a, b, xtol=1e-15, rtol=1e-15)
    assert res.converged
    assert res.root == pytest.approx(oracle, abs=1e-13)
    assert res.iterations < 30  # superlinear: far below the cap


def _plain_regula_falsi(f, a, b, n):
    fa, fb = f(a), f(b)
    for _ in range(n):
        c = b - fb * (b - a) / (fb - fa)
        fc = f(c)
        if fc * fa > 0:
            a, fa = c, fc
        else:
            b, fb = c, fc
    return a, b


def test_illinois_fixes_the_stalling_of_plain_regula_falsi():
    # x^10 - 1 on [0, 1.3]: convex, plain regula falsi keeps b = 1.3 for ever and creeps up
    # on the root from the left
    f = lambda x: x**10 - 1.0  # noqa: E731
    a, b = _plain_regula_falsi(f, 0.0, 1.3, 25)
    assert b == 1.3  # the stalled end: the bracket does not shrink to 0
    assert abs(a - 1.0) > 1e-3  # after 25 evaluations still 3 digits off
    res = illinois(f, 0.0, 1.3, max_iter=25)
    assert res.converged
    assert res.root == pytest.approx(1.0, abs=1e-14)
    assert res.iterations < 25
    lo, hi = res.bracket
    assert lo <= 1.0 <= hi


def test_illinois_cap_and_failure_and_payload():
    f = lambda x: math.tanh(50 * (x - 0.3))  # noqa: E731
    capped = illinois(f, 0.0, 1.0, max_iter=2)
    assert capped.iterations == 2 and not capped.converged
    # f fails at the first iterate: stops, reports failure, keeps the better end
    failing = illinois(lambda x: None, 0.0, 1.0, fa=-1.0, fb=2.0)
    assert failing.failed and not failing.converged and failing.root == 0.0
    assert math.isnan(illinois(lambda x: None, 0.0, 1.0, -1, 2, include_ends=False).root)
    # payload of the best iterate
    res = illinois(lambda x: (x - 0.25, f"at {x}"), 0.0, 1.0)
    assert res.root == pytest.approx(0.25) and res.payload == f"at {res.root}"
    # ftol: stop early
    loose = illinois(lambda x: x - 0.25, 0.0, 1.0, fa=-0.25, fb=0.75, ftol=1.0)
    assert loose.converged and loose.iterations == 1


def test_illinois_rejects_bad_brackets():
    with pytest.raises(ParameterError):
        illinois(lambda x: x * x + 1, -1.0, 1.0)
    with pytest.raises(ParameterError):
        illinois(lambda x: x, 1.0, -1.0)
    with pytest.raises(ParameterError):
        illinois(lambda x: x, 0.0, math.inf)


def test_illinois_vectorized_against_brentq():
    c = np.linspace(0.5, 30.0, 40)

    def f(x):
        return x**3 - c

    lo, hi = np.zeros_like(c), np.full_like(c, 4.0)
    res = illinois_vectorized(f, lo, hi, f(lo))
    oracle = np.array([brentq(lambda x, ci=ci: x**3 - ci, 0.0, 4.0, xtol=1e-15) for ci in c])
    np.testing.assert_allclose(res.root, oracle, rtol=1e-14)
    np.testing.assert_allclose(res.root, np.cbrt(c), rtol=1e-14)
    assert res.converged.all() and res.iterations < 60


def test_illinois_vectorized_cap():
    res = illinois_vectorized(
        lambda x: x**10 - 1.0, np.array([0.0]), np.array([1.3]), np.array([-1.0]), max_iter=3
    )
    assert res.iterations == 3 and not res.converged[0]


# ---------------------------------------------------------------------------------------------
# damped Newton
# ---------------------------------------------------------------------------------------------
def _arctan(z):
    return np.array([math.atan(z[0] - 1.0)]), np.array([[1.0 / (1.0 + (z[0] - 1.0) ** 2)]]), None


def test_damped_newton_arctan_needs_damping():
    # undamped Newton on atan(x - 1) from x = 4 diverges (|x_k - 1| grows): check that first
    z = 4.0
    for _ in range(5):
        z = z - math.atan(z - 1.0) * (1.0 + (z - 1.0) ** 2)
    assert abs(z - 1.0) > 1e3 or not math.isfinite(z)
    res = damped_newton(_arctan, np.array([4.0]), tol=1e-14, max_iter=50)
    assert res.converged and res.status == "residual"
    assert res.z[0] == pytest.approx(1.0, abs=1e-13)
    res_undamped = damped_newton(_arctan, np.array([4.0]), tol=1e-14, max_halvings=0)
    assert not res_undamped.converged and res_undamped.status == "no_decrease"


def test_damped_newton_system_with_separate_jacobian():
    # intersection of the circle x^2 + y^2 = 4 with y = e^x - 1 ... oracle via brentq in x
    def r(z):
        return np.array([z[0] ** 2 + z[1] ** 2 - 4.0, z[1] - math.exp(z[0]) + 1.0])

    def J(z):
        return np.array([[2 * z[0], 2 * z[1]], [-math.exp(z[0]), 1.0]])

    res = damped_newton(r, np.array([1.0, 1.0]), jac=J, tol=1e-13, scale=1.0)
    x = brentq(lambda x: x**2 + (math.exp(x) - 1) ** 2 - 4, 0.0, 2.0, xtol=1e-15)
    assert res.converged
    np.testing.assert_allclose(res.z, [x, math.exp(x) - 1], atol=1e-12)
    assert res.evaluations >= res.iterations + 1


def test_damped_newton_no_root_terminates():
    # x^2 + 1 has no real root: every cap must stop it
    calls = []

    def fun(z):
        calls.append(1)
        return np.array([z[0] ** 2 + 1.0]), np.array([[2 * z[0]]]), None

    res = damped_newton(fun, np.array([0.5]), tol=1e-12, max_iter=30, max_halvings=8)
    assert not res.converged and res.status in {"no_decrease", "max_iter", "singular"}
    assert len(calls) <= 1 + 30 * 9
    assert res.rnorm >= 1.0


def test_damped_newton_caps_steps_bounds_and_errors():
    class Outside(Exception):
        pass

    def fun(z):
        if z[0] < 0:
            raise Outside
        return np.array([z[0] - 2.0]), np.array([[1.0]]), "data"

    # the first full step from 100 lands on the root; max_step = 1 forces many capped steps
    res = damped_newton(fun, np.array([100.0]), tol=1e-12, max_step=1.0, max_iter=200)
    assert res.converged and res.iterations >= 98 and res.data == "data"
    # iteration cap reached
    res = damped_newton(fun, np.array([100.0]), tol=1e-12, max_step=1.0, max_iter=5)
    assert res.status == "max_iter" and res.z[0] == pytest.approx(95.0)
    # initial error reported, not raised
    res = damped_newton(fun, np.array([-1.0]), catch=(Outside,))
    assert res.status == "initial_error" and isinstance(res.error, Outside)
    with pytest.raises(Outside):
        damped_newton(fun, np.array([-1.0]))

    # bounds: the iterate never leaves [1.5, 3]; root of (x - 1) is outside, so no decrease
    def g(z):
        return np.array([z[0] - 1.0]), np.array([[1.0]]), None

    res = damped_newton(g, np.array([2.5]), tol=1e-12, bounds=(1.5, 3.0))
    assert not res.converged and 1.5 <= res.z[0] <= 3.0


def test_damped_newton_step_test_and_final_step():
    def fun(z):
        return np.array([z[0] - 1.0]), np.array([[1.0]]), None

    res = damped_newton(fun, np.array([1.0 + 1e-10]), tol=0.0, step_tol=1e-8)
    assert res.status == "step" and res.z[0] == 1.0 + 1e-10  # correction not taken
    res = damped_newton(fun, np.array([1.0 + 1e-10]), step_tol=1e-8, take_final_step=True)
    assert res.z[0] == pytest.approx(1.0, abs=1e-16)


def test_newton_direction_paths():
    rng = np.random.default_rng(0)
    for n in (2, 5):
        A = rng.normal(size=(n, n)) + n * np.eye(n)
        x = rng.normal(size=n)
        np.testing.assert_allclose(newton_direction(A, A @ x), x, rtol=1e-12)
        np.testing.assert_allclose(newton_direction(sps.csr_matrix(A), A @ x), x, rtol=1e-12)
    # singular: minimum-norm least squares
    S = np.array([[1.0, 1.0], [1.0, 1.0]])
    np.testing.assert_allclose(newton_direction(S, np.array([2.0, 2.0])), [1.0, 1.0])


def test_newton_options_object_equals_keywords():
    """``options=`` and the keywords of the same names are one call; keywords override."""

    def fun(z):
        return np.array([math.atan(z[0])]), np.array([[1.0 / (1.0 + z[0] ** 2)]]), None

    kw = damped_newton(fun, np.array([4.0]), tol=1e-14, max_iter=50, max_halvings=8)
    opt = damped_newton(
        fun, np.array([4.0]), options=NewtonOptions(tol=1e-14, max_iter=50, max_halvings=8)
    )
    assert kw.status == opt.status == "residual"
    assert np.array_equal(kw.z, opt.z) and kw.iterations == opt.iterations
    assert abs(opt.z[0]) <= 1e-14  # the root of atan, independently known
    # a keyword replaces the field: no halvings means the undamped Newton diverging from 4
    over = damped_newton(fun, np.array([4.0]), options=NewtonOptions(tol=1e-14), max_halvings=0)
    assert not over.converged and over.status == "no_decrease"
    assert NewtonOptions().max_halvings == 12  # the object itself is not changed


def test_newton_options_rejects_unknown_keyword_and_bad_object():
    def fun(z):
        return z, np.eye(1), None

    with pytest.raises(ParameterError, match="max_iters"):
        damped_newton(fun, np.array([1.0]), max_iters=3)
    with pytest.raises(ParameterError, match="NewtonOptions"):
        damped_newton(fun, np.array([1.0]), options={"tol": 1e-3})
    with pytest.raises(ParameterError, match="max_iter"):
        damped_newton(fun, np.array([1.0]), options=NewtonOptions(max_iter=-1))


def test_damped_newton_scale_per_unknown():
    """An array ``scale`` measures the correction componentwise (step cap, step test) and the
    residual in its own units; equal entries behave like the scalar scale."""

    def lin(target):
        target = np.asarray(target, float)
        return lambda z: (z - target, np.eye(z.size), None)

    # step cap: max |d_i / s_i| <= max_step; d = (10, 1000) with s = (1, 1000) is cut by 0.05
    res = damped_newton(
        lin([10.0, 1000.0]), np.zeros(2), scale=[1.0, 1000.0], max_step=0.5, max_iter=1
    )
    assert res.status == "max_iter"
    np.testing.assert_allclose(res.z, [0.5, 50.0], rtol=1e-15)
    # (a scalar scale 1000 would not cut it at all: |d| = 1000 <= 0.5 * 1000)
    res = damped_newton(lin([10.0, 1000.0]), np.zeros(2), scale=1000.0, max_step=1.0, max_iter=1)
    np.testing.assert_allclose(res.z, [10.0, 1000.0], rtol=1e-15)

    # residual test in the residual's own units: |r| = 1e-7 passes tol 1e-6, not tol 1e-8
    z0 = np.array([1.0 + 1e-7])
    res = damped_newton(lin([1.0]), z0, scale=[1e3], tol=1e-6)
    assert res.status == "residual" and res.iterations == 0
    res = damped_newton(lin([1.0]), z0, scale=[1e3], tol=1e-8)
    assert res.status == "residual" and res.iterations == 1

    # step test per unknown: x ~ 2e6 and y ~ 3e-6 (roots of x^2 = 4e12, y^2 = 9e-12); the
    # correction of the small unknown is judged on its own scale, so it is resolved too
    def f(z):
        x, y = z
        return np.array([x * x - 4e12, 1e12 * (y * y - 9e-12)]), np.diag([2 * x, 2e12 * y]), None

    res = damped_newton(
        f, np.array([3e6, 5e-6]), scale=[1e6, 1e-6], step_tol=1e-10, take_final_step=True
    )
    assert res.status == "step"
    assert abs(res.z[0] - 2e6) <= 1e-12 * 2e6 and abs(res.z[1] - 3e-6) <= 1e-12 * 3e-6

    # equal entries: the same iterates as the scalar scale (tol = 0: no residual test)
    g = lambda z: (np.arctan(z - 0.3), np.diag(1.0 / (1.0 + (z - 0.3) ** 2)), None)  # noqa: E731
    for kw in ({"step_tol": 1e-9}, {"max_step": 0.7, "step_tol": 1e-12}):
        a = damped_newton(g, np.array([4.0, -3.0]), scale=2.0, **kw)
        b = damped_newton(g, np.array([4.0, -3.0]), scale=[2.0, 2.0], **kw)
        assert a.status == b.status and a.iterations == b.iterations
        assert np.array_equal(a.z, b.z)


def test_illinois_bisection_safeguard():
    """f = x**21 - 1e-21 (root 0.1) on [0, 1] varies by 21 orders of magnitude inside the
    bracket: plain Illinois creeps from the end; the safeguard halves the bracket at least
    every other iterate, and its first iterate is the midpoint."""
    root = 0.1

    def f(x):
        return x**21 - root**21, x

    plain = illinois(f, 0.0, 1.0, xtol=1e-12, max_iter=300)
    safe = illinois(f, 0.0, 1.0, xtol=1e-12, max_iter=300, bisect=True)
    assert safe.converged and abs(safe.root - root) <= 1e-12
    # bisection alone needs log2(1 / 1e-12) = 40 halvings: at most twice that many iterates;
    # here far fewer than the plain iteration's
    assert safe.iterations <= 2 * 40 + 2
    assert plain.converged and 2 * safe.iterations < plain.iterations
    first = []
    illinois(lambda x: first.append(x) or f(x), 0.0, 1.0, -1.0, 1.0, max_iter=1, bisect=True)
    assert first == [0.5]


def test_illinois_secant_forms_and_final_iterate():
    exact = 0.3 ** (1 / 3)

    def f(x):
        return x**3 - 0.3

    # the two forms of the secant point: the same root (different rounding)
    a = illinois(f, 0.0, 1.0)
    b = illinois(f, 0.0, 1.0, secant="mean")
    assert abs(a.root - exact) <= 4e-16 and abs(b.root - exact) <= 4e-16
    with pytest.raises(ParameterError):
        illinois(f, 0.0, 1.0, secant="midpoint")
    # final_iterate: one more iterate, taken inside the bracket that met xtol
    d = illinois(f, 0.0, 1.0, xtol=1e-4)
    e = illinois(f, 0.0, 1.0, xtol=1e-4, final_iterate=True)
    lo, hi = d.bracket
    assert hi - lo < 1e-4 and lo <= exact <= hi
    assert e.iterations == d.iterations + 1 and lo <= e.root <= hi


def test_illinois_retry_beside_a_failure():
    """f cannot be evaluated within 1e-7 of its root (a corrector singular at the root):
    without retry the iteration stops there; with it, the points beside the failure bracket
    the root."""
    root = 0.123456789

    def f(x):
        return None if abs(x - root) < 1e-7 else math.tanh(x - root)

    # the midpoint of [root - 1, root + 1] is the root itself: the first iterate fails
    plain = illinois(f, root - 1.0, root + 1.0, bisect=True)
    assert plain.failed and plain.iterations == 1
    res = illinois(f, root - 1.0, root + 1.0, bisect=True, retry=1e-4, xtol=1e-9)
    lo, hi = res.bracket
    # retried at root -+ 2e-4 (both evaluable): the bracket shrinks to [root -+ 2e-4]; the
    # next midpoint is the root again and its neighbours at -+4e-8 fail too: it stops there
    assert res.failed and res.iterations == 6
    assert lo < root < hi and hi - lo <= 4e-4 * (1 + 1e-12)
    assert abs(res.root - root) <= 2e-4 * (1 + 1e-12)


def test_lu_or_lstsq():
    """Regular: the exact solution (Cramer by hand); exactly singular: the minimum-norm
    least-squares solution (the pseudo-inverse)."""
    J = np.array([[2.0, 1.0], [1.0, 3.0]])
    d = lu_or_lstsq(J, np.array([3.0, 5.0]))
    np.testing.assert_allclose(d, [(9 - 5) / 5, (10 - 3) / 5], rtol=1e-15)
    S = np.array([[1.0, 2.0], [2.0, 4.0]])
    rhs = np.array([1.0, 1.0])
    np.testing.assert_allclose(lu_or_lstsq(S, rhs), np.linalg.pinv(S) @ rhs, rtol=1e-12)
