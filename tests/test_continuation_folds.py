"""Folds of traced branches are refined, not interpolated.

Near a fold the parameter is extreme, :math:`p(s) \\approx p^* - c(s - s^*)^2`: a fold
interpolated linearly between two sampled points lies *inside* the sampled range (the first
version reported the Duffing jump-down fold at 2.21168 while its own points reached
2.21191).  The oracle here is independent of the continuation code: the extended system
``phi_T(y0) = y0, det(M - I) = 0`` for ``(x0, v0, Omega)``, integrated with ``solve_ivp``
(DOP853, variational equations) and solved by ``scipy.optimize.root``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import root

from perturb.model.builtins import builtin_model
from perturb.simulate.exact_response import continue_orbits

DUFFING = {"mu": 0.1, "omega0": 1.0, "alpha": 1.0, "F": 0.5}


def _duffing_monodromy(y0: np.ndarray, Om: float) -> tuple[np.ndarray, np.ndarray]:
    """``(phi_T(y0), M)`` of x'' + 0.1 x' + x + x^3 = 0.5 cos(Om t), T = 2 pi / Om."""

    def rhs(t, z):
        x, v = z[0], z[1]
        dfdx = -1.0 - 3.0 * x * x
        Phi = z[2:].reshape(2, 2)
        A = np.array([[0.0, 1.0], [dfdx, -0.1]])
        dv = 0.5 * math.cos(Om * t) - 0.1 * v - x - x**3
        return np.concatenate(([v, dv], (A @ Phi).ravel()))

    z0 = np.concatenate((y0, np.eye(2).ravel()))
    sol = solve_ivp(rhs, (0.0, 2 * math.pi / Om), z0, method="DOP853", rtol=1e-12, atol=1e-12)
    assert sol.success
    return sol.y[:2, -1], sol.y[2:, -1].reshape(2, 2)


def _duffing_fold_oracle(guess: np.ndarray) -> np.ndarray:
    """``(x0, v0, Omega)`` of the saddle-node of period-1 orbits nearest ``guess``."""

    def g(u):
        yT, M = _duffing_monodromy(u[:2], u[2])
        return np.append(yT - u[:2], np.linalg.det(M - np.eye(2)))

    sol = root(g, guess, method="hybr", options={"xtol": 1e-13})
    assert sol.success, sol.message
    assert np.max(np.abs(g(sol.x))) < 1e-9
    return sol.x


@pytest.fixture(scope="module")
def duffing_branch():
    osc = builtin_model("duffing", **DUFFING)
    return continue_orbits(osc, 0.5, [0.0, 0.0], (0.5, 2.5), ds_max=0.05)


def test_duffing_folds_lie_beyond_the_sampled_points(duffing_branch):
    br = duffing_branch
    p = br.parameters
    hi, lo = sorted(br.folds, key=lambda s: -s.parameter)
    assert hi.index < lo.index
    # the jump-down fold is the largest frequency up to the jump-up fold, and that one the
    # smallest beyond it: a fold is never inside the sampled range of its side
    assert hi.parameter >= p[: lo.index + 1].max()
    assert lo.parameter <= p[hi.index :].min()
    # the refined fold is a point of the branch polyline, with a multiplier at +1
    for f in (hi, lo):
        q = br.points[f.index]
        assert q.parameter == f.parameter and q.amplitude == f.amplitude
        assert abs(q.multipliers[0] - 1.0) < 1e-6
        assert abs(q.tangent[2]) < 1e-8


def test_duffing_folds_match_the_extended_system_oracle(duffing_branch):
    br = duffing_branch
    for f in br.folds:
        # the oracle starts from the sampled point nearest the fold, not the fold itself
        j = f.index - 1 if f.index > 0 else f.index + 1
        q = br.points[j]
        x0, v0, Om = _duffing_fold_oracle(np.array([q.y0[0], q.y0[1], q.parameter]))
        assert f.parameter == pytest.approx(Om, abs=1e-6)
        assert np.allclose(f.y0, (x0, v0), atol=1e-5)
    # the jump-down fold the issue reported short of the sampled points
    hi = max(f.parameter for f in br.folds)
    assert hi == pytest.approx(2.2119353, abs=1e-6)


def test_nsd_detached_fold_is_not_inside_the_sampled_range():
    """The resonance peak of the detached nsd branch (k = -3): exact PWL flow, same rule."""
    osc = builtin_model("nsd", k=-3.0, mu=0.05, F=2.0)
    br = continue_orbits(osc, 0.6, [11.43532506, 1.58868563], (0.6, 1.0))
    (f,) = br.folds
    assert f.parameter >= br.parameters.max() - 1e-15
    assert br.points[f.index].parameter == f.parameter
    assert abs(br.points[f.index].multipliers[0] - 1.0) < 1e-6
