r"""The odd (half-period) symmetry of a forced oscillator: the one place it is written.

A forced oscillator :math:`\ddot x + g(x, \dot x) = f(t)` with an odd restoring and damping
force, :math:`g(-x, -v) = -g(x, v)`, and a forcing that the half-period shift negates,
:math:`f(t + T/2) = -f(t)` (no static load, only odd multiples of the base frequency), is
invariant under

.. math:: \sigma:\ (x, v, t) \mapsto (-x, -v, t + T/2),

i.e. its vector field satisfies :math:`F(t + T/2, -y) = -F(t, y)`.  Then the *mirror image*
:math:`-y(t + T/2)` of every orbit is an orbit too: same multipliers and amplitude, opposite
mean.  An orbit can be its own image (the symmetric orbits of the single-harmonic seeds);
the asymmetric ones, born at symmetry-breaking pitchforks, come in mirror pairs.  The solvers
find one orbit of a pair and add the other as its image instead of searching for it.

This module holds what is the same in all of them:

* :func:`is_odd_symmetric` — whether a vector field is invariant under :math:`\sigma`
  (checked at sample states, to rounding; it works for any flow, PWL or smooth, so it needs
  no symbolic analysis of the model);
* :func:`mirror_nodes` — the image of an orbit given by ``N`` states at equally spaced times
  (multiple-shooting nodes): a shift by ``N / (2m)`` nodes and a sign;
* :func:`mirror_harmonic` — the image of an orbit given by its Fourier coefficients: the
  ``2 x 2`` block that turns harmonic ``k`` of the orbit frequency by half a forcing period
  and negates it (the bias changes sign).

What stays with its representation: numeric harmonic balance checks the symmetry on its own
discretised residual (:func:`perturb.numeric.harmonic_balance.odd_symmetry`, which decides
whether the *truncated* system commutes with the mirror) and maps whole branches
(``mirror_branch``: tangents, folds, branch points); the exact continuation maps its
continuation points (signatures, closed-form segment orbits).  Those are computations on
their own data structures, built on the maps here.

Pure numpy; this module belongs to the model layer (it imports only :mod:`perturb.errors`).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike

from perturb.errors import ParameterError, PerturbError

__all__ = ["is_odd_symmetric", "mirror_nodes", "mirror_harmonic"]

#: default number of sample states of :func:`is_odd_symmetric`
SAMPLES = 8


def is_odd_symmetric(
    vector_field: Callable[[float, np.ndarray], ArrayLike],
    period: float,
    extent: float,
    *,
    samples: int = SAMPLES,
    seed: int = 1,
    rtol: float = 1e-9,
) -> bool:
    r"""Whether ``vector_field`` is invariant under :math:`(x, v, t) \to (-x, -v, t + T/2)`.

    Checks :math:`|F(t, y) + F(t + T/2, -y)| \le \text{rtol}\,(1 + |F(t, y)|)` (elementwise)
    at ``samples`` pseudo-random times in :math:`[0, T)` and states in the box
    :math:`[-\text{extent}, \text{extent}]^2` (a fixed ``seed``: the answer is reproducible).
    A sample test, not a proof: a vector field that breaks the symmetry only outside the box
    (a breakpoint beyond ``extent``) passes, which is why callers take the box from the
    model's breakpoints.

    Parameters
    ----------
    vector_field : callable
        ``vector_field(t, y) -> (dx/dt, dv/dt)``.
    period : float
        The forcing period :math:`T`.
    extent : float
        Half-width of the box of sample states.
    samples : int
        Number of sample points.
    seed : int
        Seed of the sample points.
    rtol : float
        Tolerance relative to ``1 + |F|`` (rounding of the vector field).

    Returns
    -------
    bool
        False as well when the vector field raises a :class:`~perturb.errors.PerturbError`,
        ``ValueError`` or ``ArithmeticError`` at a sample (outside its domain).
    """
    if not (math.isfinite(period) and period > 0.0):
        raise ParameterError(f"period = {period!r}: expected a positive finite number")
    if not (math.isfinite(extent) and extent >= 0.0):
        raise ParameterError(f"extent = {extent!r}: expected a finite number >= 0")
    rng = np.random.default_rng(seed)
    for _ in range(samples):
        # draws in this order (t, then y): the sample points of the orbit search since it
        # first checked the symmetry
        t = float(rng.uniform(0.0, period))
        y = rng.uniform(-extent, extent, 2)
        try:
            a = np.asarray(vector_field(t, y), float)
            b = np.asarray(vector_field(t + 0.5 * period, -y), float)
        except (PerturbError, ValueError, ArithmeticError):
            return False
        if not np.all(np.abs(a + b) <= rtol * (1.0 + np.abs(a))):
            return False
    return True


def mirror_nodes(nodes: ArrayLike, m: int = 1) -> np.ndarray:
    r"""The mirror image :math:`-y(t + T/2)` of an orbit sampled at equally spaced times.

    Parameters
    ----------
    nodes : array_like, shape (N, d)
        States :math:`y(t_0 + iP/N)`, :math:`i = 0 .. N-1`, over one orbit period
        :math:`P = mT`.
    m : int
        Forcing periods per orbit period.

    Returns
    -------
    ndarray, shape (N, d)
        The image's states at the same times: node :math:`i` is :math:`-y_{(i + N/(2m))
        \bmod N}` (exact: a shift and a sign, no interpolation).

    Raises
    ------
    ParameterError
        When ``N`` is not a multiple of ``2 m`` (half a forcing period is then not a whole
        number of nodes: the image needs the flow between nodes).
    """
    Z = np.asarray(nodes, dtype=float)
    if isinstance(m, bool) or not isinstance(m, int | np.integer) or m < 1:
        raise ParameterError(f"m = {m!r}: expected an integer >= 1")
    if Z.ndim != 2 or Z.shape[0] % (2 * m):
        raise ParameterError(
            f"nodes of shape {Z.shape}: expected (N, d) with N a multiple of 2 m = {2 * m}"
        )
    return -np.roll(Z, -Z.shape[0] // (2 * m), axis=0)


def mirror_harmonic(k: int, m: int = 1) -> np.ndarray:
    r"""The mirror map on harmonic ``k`` of the orbit frequency :math:`\Omega/m`.

    With :math:`x(\theta) = a_0 + \sum_k a_k \cos k\theta + b_k \sin k\theta`,
    :math:`\theta = \Omega t/m`, the image :math:`-x(\theta + \delta)`, :math:`\delta = \pi/m`
    (half a forcing period), has

    .. math:: (a_k, b_k) \mapsto -(a_k \cos k\delta + b_k \sin k\delta,\
              b_k \cos k\delta - a_k \sin k\delta),\qquad a_0 \mapsto -a_0 .

    For ``m = 1`` odd harmonics are unchanged and even ones change sign.

    Returns
    -------
    ndarray, shape (2, 2)
        The matrix acting on ``(a_k, b_k)`` (the bias block is ``-1``).
    """
    delta = math.pi / m
    c, sn = math.cos(k * delta), math.sin(k * delta)
    return np.array([[-c, -sn], [sn, -c]])
