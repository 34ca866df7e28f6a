r"""Harmonic-balance solutions at a window edge that the seeds there miss.

A branch of a frequency response that enters and leaves the window through the same edge
(both ends on the edge, a fold inside) is found by :func:`~perturb.numeric.system_balance.
system_balance_response` only if a seed converges onto it. At the edge the seeds are Newton
runs from linear, describing-function and scaled guesses; an unstable multi-impact orbit is
far from all of them (the impact pair, ``mu2 = 0.01``, ``Omega = 0.8``, H = 15: no seed
converges at all, ``SystemBalance.solve(0.8)`` stops at ``|R| = 0.243``), and the attractor
stage cannot see an unstable orbit. Such a branch is, however, connected to the branches that
are found: :func:`edge_solutions` follows that connection from the solutions already known at
the edge, by two bounded continuations of THE continuation core
(:func:`perturb.numeric.continuation.continue_curve`; the final corrections by
:meth:`SystemBalance.solve`, its damped Newton):

1. **Outward** (``outward = -1`` at the low edge, ``+1`` at the high edge, ``margin > 0``):
   each known solution is continued in the frequency out of the window, at most ``margin``
   beyond the edge. A run that turns at folds outside and comes back to the edge ends on a
   solution there, which is returned (a new branch end inside the window). This is the
   frequency response itself, traced a little past the edge: whatever the response reaches
   in that margin it reaches here.
2. **Forcing homotopy** at the fixed edge frequency (``homotopy_points > 0``): each known
   solution is continued in a scale :math:`\lambda` of the forcing, :math:`R(u) + (1 -
   \lambda)\hat F = 0` (``R`` the balance residual, :math:`\hat F` the forcing coefficients,
   so :math:`\lambda = 1` is the problem), both ways over ``lam_range``; every crossing of
   :math:`\lambda = 1` is a solution of the problem at the edge frequency. The curve passes
   the folds in :math:`\lambda` where fixed-frequency Newton from any guess stalls, and it
   starts on a solution, never on the singular zero-amplitude orbit of a clearance without
   stiffness. Solutions already found (by either stage) are not started again.

Neither stage needs anything but the balance and the known solutions (no simulation, no
exact solver). Both are bounded: at most ``max_runs`` continuations, at most
``homotopy_points`` points in all homotopy runs, ``max_points`` per outward run, and
``max_new`` solutions returned.

Measured (H = 15, CPU, load ~2 on 2 cores; the response with the call after its seeding
stage, ``outward`` at both edges, ``margin`` 10 % of the width, no homotopy): impact pair
(defaults) over (0.8, 1.3): 0.23 s in 3 calls; the outward runs from the branch ends the
response has on the low edge come back to it on the unstable mirror pair that the exact
solver has on 0.8000-0.8652 (multipliers 8-15, 8-10 switches), which the response then
traces (all 22 sampled exact points of the pair on a traced branch, none before; the other
12 exact branches as before); over (0.6, 1.4) 0.007 s, nothing new; nsd2 over (0.5, 2) 0.018 s
for both edges, the same 4 branches. The forcing homotopy at 0.8 from one known solution
(1500 points) takes 1.3 s and returns 8-10 solutions: every HB solution of the exact
branches there and 4 more (3.3-21 % from the nearest of them, relative max norm; DOP853
shooting from their states at t = 0 fails or lands on a known orbit: no exact orbit found
for them), so the response does not call it by default.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from perturb.errors import ParameterError, PerturbError
from perturb.numeric.continuation import ContinuationError, continue_curve

if TYPE_CHECKING:  # system_balance imports this module: no import at run time
    from perturb.numeric.system_balance import SystemBalance

__all__ = ["edge_solutions"]

#: Relative distance (max norm over max(1, |u|)) below which two solutions are one.
_SAME = 1e-6


def _same(u: np.ndarray, v: np.ndarray) -> bool:
    return float(np.abs(u - v).max()) <= _SAME * max(1.0, float(np.abs(v).max()))


def _polish(sb: SystemBalance, Omega: float, guess: np.ndarray) -> np.ndarray | None:
    """Damped Newton of the balance at ``Omega`` from ``guess`` (None when it fails)."""
    try:
        u = sb.solve(Omega, guess, tol=1e-10, max_iterations=20)
    except (PerturbError, ValueError, np.linalg.LinAlgError):
        return None
    return u if np.all(np.isfinite(u)) else None


def edge_solutions(
    sb: SystemBalance,
    Omega: float,
    *,
    known: Sequence[np.ndarray],
    outward: int = 0,
    margin: float = 0.0,
    homotopy_points: int = 1500,
    lam_range: tuple[float, float] = (0.2, 5.0),
    max_runs: int = 8,
    max_points: int = 400,
    max_new: int = 16,
    lam_scale: float | None = None,
    ds_max: float = 0.05,
    tol: float = 1e-9,
) -> list[np.ndarray]:
    """HB solutions at ``Omega`` reached from the ``known`` ones (module docstring).

    Parameters
    ----------
    sb : SystemBalance
        The balance (its ``residual``, ``jacobian``, ``forcing`` and ``solve``).
    Omega : float
        The frequency (a window edge).
    known : sequence of arrays
        Solutions at ``Omega`` already found (flat coefficients): the starts, and the
        solutions not returned.
    outward : -1, 0 or 1
        Direction out of the window for stage 1 (0: no outward tracing).
    margin : float
        How far past ``Omega`` stage 1 traces (absolute, > 0 for stage 1).
    homotopy_points : int
        Points in all forcing-homotopy runs together (0: no homotopy).
    lam_range : (float, float)
        Range of the forcing scale, ``low < 1 < high``.
    max_runs : int
        Continuation runs in all (both stages).
    max_points : int
        Points per outward run.
    max_new : int
        Solutions returned at most.
    lam_scale : float, optional
        Frequency scale of the outward runs (default ``10 * margin``: the window's width
        when the margin is 10 % of it, the scale of the response's own runs).
    ds_max, tol
        Continuation step and tolerance.

    Returns
    -------
    list of numpy.ndarray
        Converged solutions at ``Omega`` (flat coefficients), none within ``1e-6`` (relative,
        max norm) of a known one or of each other, in the order found.
    """
    W = float(Omega)
    if not (math.isfinite(W) and W > 0):
        raise ParameterError(f"Omega = {Omega!r}: expected a finite positive number")
    if outward not in (-1, 0, 1):
        raise ParameterError(f"outward = {outward!r}: expected -1, 0 or 1")
    lam_lo, lam_hi = (float(v) for v in lam_range)
    if not 0.0 <= lam_lo < 1.0 < lam_hi:
        raise ParameterError(f"lam_range = {lam_range!r}: expected 0 <= low < 1 < high")
    seen = [np.asarray(u, dtype=float).reshape(-1) for u in known]
    new: list[np.ndarray] = []
    runs = 0

    def accept(u: np.ndarray | None) -> bool:
        if u is None or len(new) >= max_new or any(_same(u, v) for v in seen):
            return False
        seen.append(u)
        new.append(u)
        return True

    # stage 1: each known solution traced out of the window, at most ``margin`` past it
    if outward and margin > 0.0:
        window = (W - margin, W) if outward < 0 else (W, W + margin)
        for u0 in list(seen):
            if runs >= max_runs or len(new) >= max_new:
                break
            runs += 1
            try:
                curve = continue_curve(
                    sb.residual,
                    sb.jacobian,
                    u0,
                    W,
                    window,
                    direction=int(outward),
                    u_scale=1e-2 * max(1e-10, float(np.abs(u0).max())),
                    lam_scale=float(lam_scale) if lam_scale else 10.0 * margin,
                    adaptive_scale=True,
                    ds_max=ds_max,
                    tol=tol,
                    max_points=max_points,
                    predictor="hermite",
                    early_accept=True,
                )
            except (ContinuationError, ParameterError):
                continue
            lam = np.asarray(curve.lam, dtype=float)
            if lam.size > 1 and curve.stop_reason == "window" and abs(lam[-1] - W) <= 1e-12 * W:
                # back on the edge (placed there by Newton at fixed frequency): polished
                # once more to the balance's own tolerance
                accept(_polish(sb, W, np.asarray(curve.u[-1], dtype=float)))

    # stage 2: the forcing homotopy at fixed frequency from each solution not yet on a
    # homotopy curve; every crossing of lam = 1 is a solution
    budget = int(homotopy_points)
    if budget > 0:
        F, _ = sb.forcing(W)
        Fv = F.reshape(-1)
        dF = -Fv

        def residual(u, lam):
            return sb.residual(u, W) + (1.0 - lam) * Fv

        def jacobian(u, lam):
            J, _ = sb.jacobian(u, W)
            return J, dF

        on_curve: list[np.ndarray] = []
        for u0 in list(seen):
            if runs >= max_runs or budget <= 0 or len(new) >= max_new:
                break
            if any(_same(u0, v) for v in on_curve):
                continue
            on_curve.append(u0)
            for direction in (-1, 1):
                if budget <= 1 or runs >= max_runs:
                    break
                runs += 1
                try:
                    curve = continue_curve(
                        residual,
                        jacobian,
                        u0,
                        1.0,
                        (lam_lo, lam_hi),
                        direction=direction,
                        u_scale=1e-2 * max(1e-10, float(np.abs(u0).max())),
                        lam_scale=1.0,
                        adaptive_scale=True,
                        ds_max=ds_max,
                        tol=tol,
                        max_points=budget,
                        predictor="hermite",
                        early_accept=True,
                    )
                except (ContinuationError, ParameterError):
                    continue
                lam = np.asarray(curve.lam, dtype=float)
                U = np.asarray(curve.u, dtype=float)
                budget -= lam.size
                closed = curve.stop_reason == "closed"
                g = lam - 1.0
                for j in np.nonzero(g[1:-1] == 0.0)[0] + 1:
                    u = _polish(sb, W, U[j])
                    if u is not None:
                        on_curve.append(u)
                        accept(u)
                for j in np.nonzero(g[:-1] * g[1:] < 0.0)[0]:
                    a = g[j] / (g[j] - g[j + 1])
                    u = _polish(sb, W, U[j] + a * (U[j + 1] - U[j]))
                    if u is not None:
                        on_curve.append(u)
                        accept(u)
                if closed:
                    break  # a closed curve: the other direction retraces it
    return new
