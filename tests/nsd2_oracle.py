"""An oracle for the 2-DOF nsd structure (``builtin_system('nsd2')`` at its defaults), written
independently of perturb and shared by the tests of the system front doors
(``test_auto_nd``, ``test_bench_nd``, ``test_front_nd_hb``): the equations by hand, DOP853 at
rtol = atol = 1e-12 and a shooting Newton (``fsolve``) on the period map.
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import fsolve

P = {"k": -0.5, "mu1": 0.05, "mu2": 0.02, "k2": 1.0, "m2": 1.0, "F": 2.0}


def g(x):
    """The nsd restoring force of the first mass (hand copy of the builtin's equation)."""
    k = P["k"]
    return k * x + (1 - k) * (np.maximum(x - 1, 0.0) + np.minimum(x + 1, 0.0))


def rhs(t, y, W):
    x1, x2, v1, v2 = y
    a1 = P["F"] * np.cos(W * t) - P["mu1"] * v1 - P["mu2"] * (v1 - v2) - g(x1) - P["k2"] * (x1 - x2)
    a2 = (-P["mu2"] * (v2 - v1) - P["k2"] * (x2 - x1)) / P["m2"]
    return [v1, v2, a1, a2]


def exact_orbit_max(W, y0, samples=20000):
    """max |x1|, max |x2| of the exact periodic orbit shot from ``y0`` at frequency ``W``."""
    T = 2 * np.pi / W

    def flow(y):
        sol = solve_ivp(rhs, (0, T), y, args=(W,), method="DOP853", rtol=1e-12, atol=1e-12)
        return sol.y[:, -1]

    y = fsolve(lambda y: flow(y) - y, np.asarray(y0, float), xtol=1e-12)
    # accepted on the shooting residual (fsolve may stop short of xtol once it stalls at
    # rounding level)
    assert np.abs(flow(y) - y).max() <= 1e-9 * (1 + np.abs(y).max())
    t = np.linspace(0, T, samples, endpoint=False)
    sol = solve_ivp(rhs, (0, T), y, args=(W,), method="DOP853", rtol=1e-12, atol=1e-12, t_eval=t)
    return np.abs(sol.y[:2]).max(axis=1)
