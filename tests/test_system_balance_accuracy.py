"""Accuracy of the multi-harmonic balance of systems (perturb.numeric.system_balance) at fixed
frequency, against the exact periodic orbit (issue 16: the HB error of each coordinate's
max|.| within 2x of the truncation floor, AFT with 4H + 1 samples beside it).

Oracle, computed here: the exact periodic orbit of the piecewise-affine system (closed-form
propagation between the switches, ``make_flow``; shooting, ``periodic_orbit``), sampled at
2^14 points; ``max|x_j|`` refined by the parabola through the largest sample and its
neighbours; the truncation floor at H is the error of ``max|x_j|`` of the samples' Fourier
series cut at H (FFT). The HB orbit at each H is Newton's from the exact series cut at H (the
guess only starts Newton: the HB solution near it does not depend on it).

Measured (benchmarks/bench_system_balance_accuracy.py, H = 1..63, the full tables in
benchmarks/results/bench_system_balance_accuracy.md), ratio HB error / the orbit's floor (the
largest over its coordinates):

* nsd2, Omega = 1.2: <= 1.03 for H = 1, 3, 7, 15, 31, 63; the PWL coordinate x1 against its
  own floor <= 1.03; Omega = 0.7: <= 1.35 (x1 own floor <= 1.35). The smooth coordinate x2
  against its own (much smaller) floor is 1-82x: its error is inherited from x1.
* impact_pair (mu2 = 0.2: a stable impacting orbit), Omega = 1.2: 1.16, 2.44, 6.72, 1.07,
  1.00 at H = 3, 7, 15, 31, 63 -- the contact (r = 20 on m2 = 0.2, ~8x the forcing
  frequency) is resolved from H ~ 31 on; below it the Galerkin solution is not the best
  approximation the floor measures. H = 1 and 2 have no HB solution near the exact orbit
  (least squares from its series stops at |R|^2 = 0.013).
* AFT with 4H + 1 samples (``projection="aft"``) at H = 3, 7, 15, 31, 63: 11-1160x the floor
  on nsd2 x1; on the impact pair x1 86-2570x at H = 7..63 (no AFT solution at H = 3). Over all
  H = 3..63 it is sometimes accurate by chance (down to 0.09x the floor on nsd2 at one H).

Tolerances: 2x the floor where the issue's criterion holds (measured <= 1.35), 1.5x for x1
against its own floor (measured <= 1.35); the impact pair's H = 3, 7, 15 at 1.5x their
measured ratios (the criterion does not hold there; a regression beyond would show).
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

from perturb.model.system_builtins import builtin_system
from perturb.numeric.system_balance import SystemBalance, system_balance_orbit
from perturb.simulate.flows.factory import make_flow
from perturb.simulate.orbits.shooting import periodic_orbit

N_SAMPLES = 2**14
HS = (1, 3, 7, 15, 31, 63)


def _peak(x: np.ndarray) -> float:
    """max |x| of a densely sampled periodic signal, refined by the parabola through the
    largest sample and its neighbours (the orbits are C^2: continuous forces)."""
    i = int(np.argmax(np.abs(x)))
    n = x.size
    a, b, c = x[(i - 1) % n], x[i], x[(i + 1) % n]
    den = a - 2 * b + c
    d = 0.5 * (a - c) / den if den != 0 else 0.0
    return abs(b - 0.25 * (a - c) * d)


def _series_cut(Q: np.ndarray, H: int) -> np.ndarray:
    """Rows ``[a0, a1, b1, ...]`` of the sampled coordinates (columns of ``Q``), cut at H."""
    X = np.fft.rfft(Q, axis=0) / Q.shape[0]
    U = np.zeros((Q.shape[1], 2 * H + 1))
    U[:, 0] = X[0].real
    U[:, 1::2] = 2 * X[1 : H + 1].real.T
    U[:, 2::2] = -2 * X[1 : H + 1].imag.T
    return U


def _floor(x: np.ndarray, H: int) -> float:
    """Error of max|x| of the exact orbit's Fourier series cut at H."""
    X = np.fft.rfft(x)
    X[H + 1 :] = 0.0
    return abs(_peak(np.fft.irfft(X, n=x.size)) - _peak(x))


def _exact(system, W: float, y_guess: np.ndarray):
    """The exact orbit's coordinates sampled over one period, and its shooting result."""
    flow = make_flow(system.with_params(Omega=W), W)
    orb = periodic_orbit(flow, y_guess)
    T = 2 * np.pi / W
    Y = np.asarray(flow(orb.y0, 0.0, T, t_eval=np.arange(N_SAMPLES) * T / N_SAMPLES).ys)
    return orb, Y[:, : len(system.coordinates)]


@functools.cache
def _nsd2(W: float):
    system = builtin_system("nsd2")
    y0 = system_balance_orbit(system, W, harmonics=15, stability=False).state(0.0)
    return (system, *_exact(system, W, y0))


@functools.cache
def _pair():
    system = builtin_system("impact_pair").with_params(mu2=0.2)
    W = 1.2
    flow = make_flow(system.with_params(Omega=W), W)
    y0 = flow(np.zeros(system.n), 0.0, 300 * 2 * np.pi / W).y  # settle on the stable orbit
    return (system, *_exact(system, W, y0))


def _errors(system, W, Q, H, projection):
    """Per coordinate, |max|x_j|_HB - max|x_j|_exact|."""
    sb = SystemBalance(
        system, H, projection=projection, samples=4 * H + 1 if projection == "aft" else None
    )
    u = sb.solve(W, _series_cut(Q, H).reshape(-1))
    return np.array(
        [abs(sb.max_abs(u, W, c) - _peak(Q[:, j])) for j, c in enumerate(system.coordinates)]
    )


@pytest.mark.parametrize("W", [1.2, 0.7])
def test_nsd2_within_twice_the_truncation_floor(W):
    system, orb, Q = _nsd2(W)
    assert orb.residual < 1e-10  # the shooting orbit closes
    for H in HS:
        err = _errors(system, W, Q, H, "exact")
        floors = np.array([_floor(Q[:, j], H) for j in range(Q.shape[1])])
        assert err.max() <= 2.0 * floors.max(), (H, err, floors)
        # the coordinate carrying the PWL force, against its own floor
        assert err[0] <= 1.5 * floors[0], (H, err, floors)
        # AFT with 4H + 1 samples beside it: measured 11-1160x the floor on x1
        aft = _errors(system, W, Q, H, "aft")
        assert aft[0] >= 5.0 * err[0], (H, aft, err)
    # the floor itself falls by five decades over H = 1..63: the test measures something
    assert _floor(Q[:, 0], 63) < 1e-4 * _floor(Q[:, 0], 1)


def test_impact_pair_against_the_truncation_floor():
    system, orb, Q = _pair()
    W = 1.2
    assert orb.stability == "stable"
    bound = {3: 1.8, 7: 3.7, 15: 8.0, 31: 2.0, 63: 2.0}  # measured 1.16, 2.44, 6.72, 1.07, 1.00
    errs = {}
    for H, factor in bound.items():
        err = _errors(system, W, Q, H, "exact")
        floors = np.array([_floor(Q[:, j], H) for j in range(Q.shape[1])])
        assert err.max() <= factor * floors.max(), (H, err, floors)
        errs[H] = err.max()
        if H >= 7:
            aft = _errors(system, W, Q, H, "aft")
            assert aft.max() >= 2.0 * err.max(), (H, aft, err)  # measured 2.4-32x
    assert errs[63] < 1e-3 * errs[3]
