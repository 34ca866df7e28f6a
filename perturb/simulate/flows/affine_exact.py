r"""Exact propagation of piecewise-affine systems in ``n`` dimensions.

The system (:class:`~perturb.model.affine.PiecewiseAffineSystem`) is, in the region ``r``
fixed by the signs of the switching functions :math:`s_j(y) = c_j\cdot y - d_j`,

.. math::

    y' = A_r y + b_r + \sum_k \big(u_k\cos\omega_k t + v_k\sin\omega_k t\big),

so between two switches the solution is closed form.  This module evaluates that closed form,
finds the switching times on it with a bracketing that cannot miss a grazing crossing, and
returns the final state, the event log, a dense trajectory and (as a
:class:`~perturb.simulate.flows.base.Flow`) the exact sensitivity with saltation matrices.

Closed form in one region (the *modal* representation)
------------------------------------------------------
With :math:`A = V\Lambda V^{-1}` (eigenvectors well conditioned) the harmonic input is written
:math:`u\cos\omega t + v\sin\omega t = \operatorname{Re}\big((u - iv)e^{i\omega t}\big)`; every
source is then :math:`r_m e^{\sigma_m t}` with :math:`\sigma_0 = 0, r_0 = b` and
:math:`\sigma_k = i\omega_k, r_k = u_k - i v_k`, and the real solution is the real part of the
complex one (``A`` is real).  In modal coordinates :math:`\xi = V^{-1} y` each mode obeys
:math:`\xi_j' = \lambda_j\xi_j + \sum_m \beta_{jm} e^{\sigma_m t}`, :math:`\beta_m = V^{-1}r_m`.
A pair :math:`(j, m)` far from resonance contributes the particular solution
:math:`\beta_{jm}e^{\sigma_m t}/(\sigma_m - \lambda_j)`; summed over the modes this is

.. math::

    y_p(t) = -A^{-1} b + \operatorname{Re}\sum_k Z_k e^{i\omega_k t},\qquad
    (i\omega_k I - A) Z_k = u_k - i v_k ,

and :math:`y(t) = e^{A(t - t_0)}\big(y_0 - y_p(t_0)\big) + y_p(t)`.  A pair near resonance — a
zero eigenvalue (rigid-body mode, a first-order state without restoring term) under the
constant source, or :math:`|\lambda_j - i\omega_k| < \omega_k/100` (which includes the exact
resonance of an undamped mode) — is left out of :math:`y_p` and contributes instead its response
from zero initial data,

.. math::

    \operatorname{Re}\Big(V_j\beta_{jm}e^{\sigma_m t_0}\,E(\lambda_j, \sigma_m, t - t_0)\Big),
    \qquad E(\lambda, \sigma, \tau) = \int_0^\tau e^{\lambda(\tau - s)}e^{\sigma s}\,ds
    = e^{\lambda\tau}\,\tau\,\varphi_1\big((\sigma - \lambda)\tau\big),

with :math:`\varphi_1(z) = (e^z - 1)/z` (series for :math:`|z| < 1/2`, else
:math:`(e^{\sigma\tau} - e^{\lambda\tau})/(\sigma - \lambda)`): no :math:`1/(\sigma - \lambda)`
cancellation, the secular :math:`\tau e^{i\omega\tau}` at exact resonance and the drift
:math:`\tau` of a free mode under a constant load included.  Every component of the state, and
every switching function, is therefore an *exponential sum*

.. math::

    s_j(t_0 + \tau) = \operatorname{Re}\Big(\sum_q W_{jq} e^{\mu_q\tau}
    + \sum_r R_{jr} E_r(\tau)\Big),\qquad \mu = (\lambda_1, \dots, \lambda_n, 0,
    i\omega_1, \dots),

whose derivatives are as cheap as its value and whose derivatives are *rigorously* bounded on
an interval :math:`[\tau_a, \tau_b]` by
:math:`\sum_q |W_{jq}||\mu_q|^p\max(e^{\operatorname{Re}\mu_q\tau_a},
e^{\operatorname{Re}\mu_q\tau_b})` (plus the bounds of the :math:`E` terms).  The
eigen-decomposition, :math:`V^{-1}`, :math:`A^{-1}b` and :math:`Z_k` are computed once per
region; a piece (a visit of a region) only needs :math:`V^{-1}(y_0 - y_p(t_0))`.

Defective or ill-conditioned ``A`` (the *expm* representation)
--------------------------------------------------------------
When the eigenvectors are ill conditioned (:math:`\kappa(V) > 10^5`: a Jordan block such as an
undamped free body, a nearly repeated eigenvalue) the region uses the augmented (Van Loan)
matrix of the state :math:`z = (y, 1, \cos\omega_1 t, \sin\omega_1 t, \dots)`,

.. math::

    \tilde A = \begin{pmatrix} A & b & u_1 & v_1 & \cdots \\
    0 & 0 & & & \\ & & 0 & -\omega_1 & \\ & & \omega_1 & 0 & \\ & & & & \ddots\end{pmatrix},
    \qquad z(t_0 + \tau) = e^{\tilde A\tau}z(t_0),

evaluated with :func:`scipy.linalg.expm` (exact for every spectrum, resonance included; slower).
Its switching-function derivatives :math:`s_j^{(p)} = \tilde c_j^T\tilde A^p z` are bounded by
:math:`\|\tilde c_j^T\tilde A^p\|_2\,\|z(\tau_a)\|_2\,e^{\nu(\tau - \tau_a)}` with the
logarithmic norm :math:`\nu = \max(0, \lambda_{\max}((\tilde A + \tilde A^T)/2))`.

Units
-----
States of very different magnitudes (pressures ~1e4 Pa next to flows ~1e-5 m^3/s) make the
eigenvectors ill conditioned through the units alone.  The propagator then works on
:math:`z = D^{-1}y` with one power-of-two diagonal ``D`` for all regions (balancing of
:math:`\sum_r |A_r|`, applied only when it shrinks that matrix's norm by more than 16): same
eigenvalues, well-conditioned eigenvectors, exact conversion.  Results are returned in the
system's units.

Switching
---------
Inside region ``r`` the switching function ``j`` has a sign :math:`\sigma_j` and
:math:`g_j = \sigma_j s_j > 0`.  A piece is scanned on a grid of step :math:`h = 1/(8\rho)`
(:math:`\rho` the fastest rate :math:`|\mu_q|` of the terms that still matter), evaluated in
batches.  A grid interval of length :math:`L` is *clear* of surface ``j`` when
:math:`\min(g(\tau_a), g(\tau_b)) - M_2 L^2/8 > \text{tol}` (:math:`M_2` the rigorous bound of
:math:`|g''|`: the linear interpolant errs by at most :math:`M_2 L^2/8`), so neither a crossing
nor a tangency can hide in it.  (:math:`M_2` is also bounded by
:math:`(|g''(\tau_a)| + |g''(\tau_b)| + M_3 L)/2`, :math:`M_3` the bound of :math:`|g'''|`:
much tighter when a large particular solution and the homogeneous part cancel.)  An interval
that is not clear is examined: when :math:`g'` provably keeps its sign
(:math:`|g'(\tau_a)| + |g'(\tau_b)| > M_2 L`, same signs) :math:`g` is monotone and only the
end values matter; otherwise it is split in halves until :math:`g''` provably keeps one sign
(:math:`|g''(\tau_a)| + |g''(\tau_b)| > M_3 L`).  On such an interval :math:`g` is convex or
concave: concave with :math:`g > 0` at both ends, it has no root; convex, its minimum is the root of
:math:`g'` (when :math:`g'` changes sign) and the sign of :math:`g` there decides.  So a grazing
crossing (a dip of :math:`g` below zero between two grid points) is found, and a near miss is
correctly absent, whatever the grid.  Roots of :math:`g` and :math:`g'` are solved by a
safeguarded Newton–bisection on the closed form (exact derivatives), which never leaves its
bracket; a crossing on a monotone interval by safeguarded Halley–bisection from the root of the
cubic Hermite interpolant of the grid's :math:`g, g'` (two closed-form evaluations).  A
minimum with :math:`|g| \le` tol (a few rounding units of the terms of :math:`s`), or a
crossing whose penetration depth :math:`g'^2/(2g'')` is below tol, is a *tangency*: logged, and
the region is kept.  At a crossing the state is projected onto the surface
(:math:`y \leftarrow y - c\,(c\cdot y - d)/|c|^2`) and the region of the sign pattern on the
far side takes over.  When the field is discontinuous across the surface and the far side
pushes back into it (both sides point into the surface: sliding / sticking), the propagation
stops with a :class:`~perturb.errors.PerturbError`: the event-driven solver handles sliding.

Sensitivity
-----------
:math:`\partial y(t_1)/\partial y(t_0)` is the product of the region exponentials
:math:`e^{A_r h}` of the pieces and, at each crossing of surface ``j`` at state ``y``, of the
saltation matrix :math:`S = I + (f_+ - f_-)c_j^T/(c_j^T f_-)` (:math:`f_\mp` the fields
before/after; the identity where the field is continuous across the surface).

Limitations
-----------
* Sliding along a discontinuity is not integrated (see above).
* A tangency is resolved to the rounding level of the switching function: an orbit that grazes
  a surface *exactly* may be logged as a tangency or a pair of crossings of negligible depth.
* Two surfaces crossed at the same instant are switched one after the other (the second at a
  zero-length piece).
* The grid step follows the fastest rate of the region: a very stiff contact (rates 1e3 times
  the structure's) costs proportionally more grid intervals while in contact, and a contact
  that chatters on a gap of 1e-9 costs one piece per bounce (bounded by ``max_events`` and
  ``max_steps``, never a hang).
"""

from __future__ import annotations

import bisect
import cmath
import functools
import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike

from perturb.errors import ParameterError, PerturbError
from perturb.model.affine import PiecewiseAffineSystem
from perturb.simulate.flows import scan_kernel
from perturb.simulate.flows.base import Flow, FlowResult

__all__ = [
    "AffineEvent",
    "AffinePropagation",
    "AffineStats",
    "AffineTrajectory",
    "AffineExactFlow",
    "propagate",
]

_EPS = scan_kernel.EPS
#: eigenvector condition number above which a region uses the augmented-matrix exponential
_COND_MAX = 1.0e5
#: a harmonic source is resonant with a mode when |lambda - i omega| < this fraction of omega
#: (outside it the particular solution loses at most ~1/band rounding units to cancellation)
_RESONANCE_BAND = 0.01
#: the constant source is "resonant" with a mode when |lambda| < this fraction of the region's
#: fastest rate (a free mode, a first-order state without restoring term)
_ZERO_BAND = 1.0e-3
#: tangency tolerance, in rounding units of the magnitude of the terms of s_j
_TOL_ULPS = 64.0
#: grid steps per fastest time scale 1/rho
_STEPS_PER_SCALE = scan_kernel.STEPS_PER_SCALE
#: grid intervals per batch: first batch, largest batch
_BATCH_FIRST, _BATCH_MAX = scan_kernel.BATCH_FIRST, scan_kernel.BATCH_MAX
#: 0, 1, ..., _BATCH_MAX as floats (the batch grids: tau + h * k)
_ARANGE = np.arange(_BATCH_MAX + 1, dtype=float)
#: halvings of an interval before it is treated as one convex/concave piece
_MAX_DEPTH = scan_kernel.MAX_DEPTH
#: intervals examined by one search for a surface's first event before giving up
_MAX_NODES = scan_kernel.MAX_NODES
#: iterations of the Newton-bisection root solver (it stops at full precision long before)
_ROOT_ITER = scan_kernel.ROOT_ITER
#: a burst of this many crossings within a negligible time is Zeno behaviour / sliding
_ZENO_COUNT = 64

EVENT_DRIVEN_HINT = (
    "the event-driven solver for piecewise-smooth systems "
    "(perturb.simulate.flows.event_driven) handles sliding and sticking"
)


# --------------------------------------------------------------------------------------------
# public results
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class AffineEvent:
    """A crossing of a switching surface, or a tangency (touch and turn back, no switch).

    Attributes
    ----------
    time : float
        Event time.
    surface : int
        Index into ``system.surfaces``.
    direction : int
        ``+1`` when ``s`` increases through 0 (or touches 0 from below), ``-1`` otherwise.
    pattern_before, pattern_after : tuple of int
        Sign patterns of the regions before and after (equal for a tangency).
    y : ndarray
        The state at the event (on the surface, to rounding, for a crossing).
    tangency : bool
        True for a tangency.
    """

    time: float
    surface: int
    direction: int
    pattern_before: tuple[int, ...]
    pattern_after: tuple[int, ...]
    y: np.ndarray
    tangency: bool = False


@dataclass(frozen=True)
class AffineStats:
    """Work counters of one propagation: pieces, crossings, tangencies, grid intervals
    scanned, and pieces in the augmented-exponential (expm) representation."""

    n_pieces: int
    n_crossings: int
    n_tangencies: int
    n_grid: int
    n_expm_pieces: int


class AffineTrajectory:
    """The exact dense trajectory of one propagation: ``traj(t)`` anywhere in ``t_span``.

    Attributes
    ----------
    t_span : tuple of float
    events : tuple of AffineEvent
    starts : ndarray
        Start time of every closed-form piece.
    patterns : tuple of tuple of int
        The region (sign pattern) of every piece.
    """

    def __init__(self, system, pieces, events, t_span) -> None:
        self.system = system
        self._pieces = [p for _, _, p in pieces]
        self._starts = [float(t) for t, _, _ in pieces]
        self.starts = np.array(self._starts, dtype=float)
        self.patterns = tuple(p.region.key for _, _, p in pieces)
        self.events = tuple(events)
        self.t_span = (float(t_span[0]), float(t_span[1]))

    def __len__(self) -> int:
        return len(self._pieces)

    def modal_pieces(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, bool] | None:
        """The closed forms of every piece as arrays, for compiled evaluation: ``(starts,
        Y, mu, D, scaled)`` with the piece ``k`` state ``D * Re(Y[k] @ e^{mu[k] tau})``,
        ``tau = t - starts[k]`` (``Y`` of shape ``(pieces, n, nt)``, ``mu`` ``(pieces,
        nt)``; ``D`` only when ``scaled``); None when a piece has no such form (a resonant
        pair, the augmented-exponential representation, or regions with different numbers of
        terms)."""
        pieces = self._pieces
        first = pieces[0]
        if not all(getattr(p, "has_res", True) is False for p in pieces):
            return None
        nt = first.mu.size
        if any(p.mu.size != nt for p in pieces):
            return None
        if len(pieces) == 1:  # (no switch in the period: views, no copies)
            Y, mu = first.Y[None], first.mu[None]
        else:
            Y = np.stack([p.Y for p in pieces])
            mu = np.stack([p.mu for p in pieces])
        model = first.region.model
        return self.starts, Y, mu, model.D, bool(model.scaled)

    def transition(self, k: int, h: float) -> np.ndarray | None:
        """``e^{A h}`` of piece ``k`` over its duration ``h`` in the system's units, as the
        flow's sensitivity computed it (the modal product of the region's eigen-decomposition,
        ``((V e^{lambda h}) V^-1).real``), or None when it was not computed for that ``h``
        (no sensitivity asked, another ``h``, a scaled state or an augmented-exponential
        region)."""
        piece = self._pieces[k]
        got = getattr(piece, "trans", None)
        if got is None or got[0] != h or piece.region.model.scaled:
            return None
        return got[1]

    def _at(self, t: float) -> np.ndarray:
        """The state at one time (the fast path of ``traj(t)`` for a Python number: root
        solvers on the dense orbit call it once per iterate)."""
        t0, t1 = self.t_span
        slack = 1e-12 * max(t1 - t0, abs(t0), abs(t1))
        if not (t0 - slack <= t <= t1 + slack):
            raise ParameterError(
                f"t outside t_span = {self.t_span!r}: expected finite t0 <= t <= t1"
            )
        k = min(max(bisect.bisect_right(self._starts, t) - 1, 0), len(self._pieces) - 1)
        piece = self._pieces[k]
        z = piece.state1(t - self._starts[k])
        model = piece.region.model
        return z * model.D if model.scaled else z

    def __call__(self, t: ArrayLike) -> np.ndarray:
        """The exact state: shape ``(n,)`` for a scalar ``t``, ``(n, len(t))`` otherwise.

        Raises
        ------
        ParameterError
            A time outside ``t_span`` or not finite.
        """
        if isinstance(t, float | int) and not isinstance(t, bool):
            return self._at(float(t))
        ta = np.asarray(t, dtype=float)
        scalar = ta.ndim == 0
        ta = ta.reshape(-1)
        t0, t1 = self.t_span
        slack = 1e-12 * max(t1 - t0, abs(t0), abs(t1))
        if not np.all(np.isfinite(ta)) or np.any(ta < t0 - slack) or np.any(ta > t1 + slack):
            raise ParameterError(
                f"t outside t_span = {self.t_span!r}: expected finite t0 <= t <= t1"
            )
        n = self.system.n
        out = np.empty((n, ta.size))
        if ta.size > 1 and (ta[1:] >= ta[:-1]).all():
            # sorted times (samples of an orbit): each piece owns one slice
            cut = np.searchsorted(ta, self.starts[1:], side="left").tolist()
            lo = 0
            for k, hi in enumerate([*cut, ta.size]):
                if hi > lo:
                    out[:, lo:hi] = self._pieces[k].state(ta[lo:hi] - self._starts[k])
                lo = max(lo, hi)
        else:
            idx = np.searchsorted(self.starts, ta, side="right") - 1
            idx = np.clip(idx, 0, len(self.starts) - 1)
            for k in np.unique(idx):
                sel = idx == k
                out[:, sel] = self._pieces[int(k)].state(ta[sel] - self.starts[int(k)])
        model = self._pieces[0].region.model
        if model.scaled:
            out *= model.D[:, None]  # the pieces hold the scaled state z = y / D
        return out[:, 0] if scalar else out

    def state_and_rate(
        self, t: ArrayLike, *, trusted: bool = False
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """The exact state and its time derivative at sorted times ``t`` (1-d, inside
        ``t_span``): two arrays of shape ``(n, len(t))``, from the closed form of each piece
        (no field evaluation); None when a piece has no such form (a resonant pair or the
        augmented-exponential representation: use the vector field).  At a switch time the
        piece that starts there gives the rate (one-sided where the field jumps).
        ``trusted=True``: the caller guarantees a sorted float array inside ``t_span`` (the
        checks are skipped; orbit statistics sample every point of a branch).

        Raises
        ------
        ParameterError
            Times not finite, not sorted or outside ``t_span``.
        """
        ta = np.asarray(t, dtype=float).reshape(-1)
        t0, t1 = self.t_span
        slack = 1e-12 * max(t1 - t0, abs(t0), abs(t1))
        if not trusted and (
            not np.all(np.isfinite(ta))
            or np.any(ta < t0 - slack)
            or np.any(ta > t1 + slack)
            or np.any(ta[1:] < ta[:-1])
        ):
            raise ParameterError(
                f"t = {ta.tolist()!r}: expected sorted finite times in t_span = {self.t_span!r}"
            )
        n = self.system.n
        out = np.empty((2 * n, ta.size))
        cut = np.searchsorted(ta, self.starts[1:], side="right").tolist()
        lo = 0
        for k, hi in enumerate([*cut, ta.size]):
            if hi > lo:
                part = self._pieces[k].state_rate(ta[lo:hi] - self._starts[k])
                if part is None:
                    return None
                out[:, lo:hi] = part
            lo = max(lo, hi)
        model = self._pieces[0].region.model
        if model.scaled:
            out *= np.concatenate([model.D, model.D])[:, None]
        return out[:n], out[n:]

    def state_and_rate1(self, t: float) -> tuple[np.ndarray, np.ndarray] | None:
        """:meth:`state_and_rate` at one time (a Python float inside ``t_span``; root
        solvers on the dense orbit call it once per iterate): ``(y, y')`` of shape ``(n,)``
        each, or None."""
        t0, t1 = self.t_span
        slack = 1e-12 * max(t1 - t0, abs(t0), abs(t1))
        if not (t0 - slack <= t <= t1 + slack):
            raise ParameterError(
                f"t outside t_span = {self.t_span!r}: expected finite t0 <= t <= t1"
            )
        k = min(max(bisect.bisect_right(self._starts, t) - 1, 0), len(self._pieces) - 1)
        piece = self._pieces[k]
        one = getattr(piece, "state_rate1", None)  # (one time: no 2-d arrays)
        if one is not None:
            part = one(t - self._starts[k])
            if part is None:
                return None
        else:
            part = piece.state_rate(np.array([t - self._starts[k]]))
            if part is None:
                return None
            part = part[:, 0]
        n = self.system.n
        model = piece.region.model
        if model.scaled:
            return part[:n] * model.D, part[n:] * model.D
        return part[:n], part[n:]


class AffinePropagation(NamedTuple):
    """What :func:`propagate` returns (unpacks as ``y, events, trajectory, stats``).

    Attributes
    ----------
    y : ndarray
        State at ``t1``.
    events : tuple of AffineEvent
        Crossings and tangencies in time order.
    trajectory : AffineTrajectory or None
        The exact dense trajectory when ``dense=True``.
    stats : AffineStats
    """

    y: np.ndarray
    events: tuple[AffineEvent, ...]
    trajectory: AffineTrajectory | None
    stats: AffineStats


# --------------------------------------------------------------------------------------------
# the zero-initial-data response E(lambda, sigma, tau) of a resonant pair
# --------------------------------------------------------------------------------------------
_ONE = np.ones(1, dtype=complex)
_PHI1_TERMS = 20  # |z| < 1/2: the series error is below 0.5^20 / 21! ~ 1e-26


def _phi1_series(z: np.ndarray) -> np.ndarray:
    out = np.zeros_like(z)
    for k in range(_PHI1_TERMS, 0, -1):
        out = 1.0 + out * z / (k + 1)
    return out


def _E_all(lam: complex, sig: complex, tau: np.ndarray) -> tuple[np.ndarray, ...]:
    """``E`` and its first three derivatives in ``tau`` (arrays).

    ``E' = lam E + e^{sig tau}``, ``E'' = lam E' + sig e^{sig tau}``,
    ``E''' = lam E'' + sig^2 e^{sig tau}``.
    """
    tau = np.asarray(tau, dtype=float)
    d = sig - lam
    z = d * tau
    el = np.exp(lam * tau)
    es = np.exp(sig * tau)
    small = np.abs(z) < 0.5
    E = np.empty(tau.shape, dtype=complex)
    if np.any(small):
        E[small] = el[small] * tau[small] * _phi1_series(z[small].astype(complex))
    if np.any(~small):
        E[~small] = (es[~small] - el[~small]) / d
    E1 = lam * E + es
    E2 = lam * E1 + sig * es
    E3 = lam * E2 + sig * sig * es
    return E, E1, E2, E3


def _E_bounds(lam: complex, sig: complex, ta: np.ndarray, tb: np.ndarray) -> np.ndarray:
    """Rigorous bounds of ``|E^{(p)}|``, ``p = 0..3``, on ``[ta, tb]`` (``0 <= ta <= tb``),
    shape ``(4, len)``: ``|E| <= tau max(1, e^{Re lam tau})`` (the integral of moduli) and
    ``|E| <= (1 + e^{Re lam tau}) / |sig - lam|``; ``Re sig = 0``."""
    rl = lam.real
    ea = np.exp(rl * ta)
    eb = np.exp(rl * tb)
    emax = np.maximum(ea, eb)
    b0 = tb * np.maximum(1.0, emax)
    d = abs(sig - lam)
    if d > 0.0:
        b0 = np.minimum(b0, (1.0 + emax) / d)
    al, asg = abs(lam), abs(sig)
    b1 = al * b0 + 1.0
    b2 = al * b1 + asg
    b3 = al * b2 + asg * asg
    return np.stack([b0, b1, b2, b3])


# --------------------------------------------------------------------------------------------
# regions (cached per system) and pieces (one visit of a region)
# --------------------------------------------------------------------------------------------
_ZERO1 = np.zeros(1, dtype=complex)


class _RegionCore:
    """The data of a modal region that do not depend on the input frequencies (shared by the
    models of a frequency family, :meth:`_Model.derive`): ``V^-1 b``, ``V^-1 (u_k - i v_k)``,
    ``C V``, the columns of ``V`` and the eigenvalues as numpy scalars (the arithmetic of
    the per-frequency part is that of one loop over them), and the constant particular
    solution per classification of the modes (zero band relative to ``rho``)."""

    def __init__(self, model: _Model, key, b, lam, V, Vinv) -> None:
        n = V.shape[0]
        self.beta0 = Vinv @ b
        self.betas = [Vinv @ uvk for uvk in model.uv]
        # the modes each source excites (beta == 0 skipped, as the loops did)
        self.nz = [[j for j in range(n) if beta[j] != 0.0] for beta in self.betas]
        self.nz0 = [j for j in range(n) if self.beta0[j] != 0.0]
        # (the same as index arrays, and the columns of V and the eigenvalues they pick: the
        # particular solution of each input in one product, see _ModalRegion)
        self.nz_idx = [np.array(nz, dtype=int) for nz in self.nz]
        self.V_nz = [V[:, nz] for nz in self.nz_idx]
        self.lam_nz = [lam[nz].astype(complex) for nz in self.nz_idx]
        self.beta_nz = [beta[nz] for beta, nz in zip(self.betas, self.nz_idx, strict=True)]
        self.lamj = [lam[j] for j in range(n)]
        self.Vcols = [V[:, j] for j in range(n)]
        self.lam_max = float(np.max(np.abs(lam))) if n else 0.0
        self.C, self.d = model.C, model.d
        self.lamc = lam.astype(complex)
        self.CV = model.C @ V
        self.YWV = np.concatenate([V.astype(complex), self.CV.astype(complex)], axis=0)
        self.sig = np.array(key, dtype=float)
        self.sig3 = self.sig[None, :, None]
        ns = model.C.shape[0]
        self.no_res = (
            np.zeros(0, dtype=complex),
            np.zeros(0, dtype=complex),
            np.zeros((n, 0), dtype=complex),
            np.zeros((ns, 0), dtype=complex),
        )
        for arr in (*self.no_res, self.YWV, self.sig, self.CV):
            arr.setflags(write=False)
        self._constant: dict[tuple[bool, ...], tuple[tuple, np.ndarray]] = {}

    def constant(self, rho: float) -> tuple[tuple, np.ndarray]:
        """(resonant entries of the constant source, the constant particular solution) for
        the zero band ``_ZERO_BAND rho`` (cached per classification of the modes)."""
        lamj = self.lamj
        zero = tuple(bool(abs(lamj[j]) <= _ZERO_BAND * rho or lamj[j] == 0.0) for j in self.nz0)
        hit = self._constant.get(zero)
        if hit is None:
            beta0 = self.beta0
            res = []
            yconst = np.zeros(len(lamj), dtype=complex)
            for j, z in zip(self.nz0, zero, strict=True):
                if z:
                    res.append((complex(lamj[j]), 0j, self.Vcols[j] * beta0[j]))
                else:
                    yconst -= self.Vcols[j] * (beta0[j] / lamj[j])
            # the real part: conjugate modes are classified alike, so the imaginary parts
            # cancel
            yc = yconst.real.copy()
            yc.setflags(write=False)
            # the constant column of the piece data: the state's rows, the surfaces' rows
            col = np.concatenate([yc, self.C @ yc - self.d])[:, None]
            col.setflags(write=False)
            hit = self._constant[zero] = (tuple(res), yc, col)
        return hit


class _ModalRegion:
    """A region in the modal representation (see the module docstring)."""

    kind = "modal"

    def __init__(self, model: _Model, key, A, b, lam, V, Vinv) -> None:
        self.model = model
        self.key = key
        self.A, self.b = A, b
        self.lam, self.V, self.Vinv = lam, V, Vinv
        n = A.shape[0]
        om = model.omegas
        # the data that do not depend on the input frequencies, shared by the models of a
        # frequency family (see _Model.derive): computed once per region
        core = model.region_core.get(key)
        if core is None:
            core = model.region_core[key] = _RegionCore(model, key, b, lam, V, Vinv)
        rho = max(core.lam_max, model.omega_max)
        self.rho = rho
        # sources: sigma_0 = 0 with b, sigma_k = i omega_k with u_k - i v_k
        res, yconst, ycol = core.constant(rho)
        res = list(res)  # (lambda, sigma, V_j beta_jm)
        C = model.C
        lamj, Vcols = core.lamj, core.Vcols
        Z = np.zeros((om.size, n), dtype=complex)
        for k, w in enumerate(om):
            s = 1j * w
            d = s - core.lam_nz[k]
            if not d.size:
                continue
            if np.abs(d).min() >= _RESONANCE_BAND * w:
                # no mode resonant with this input (the common case): one product
                Z[k] = core.V_nz[k] @ (core.beta_nz[k] / d)
                continue
            beta = core.betas[k]
            for j in core.nz[k]:
                if abs(lamj[j] - s) < _RESONANCE_BAND * w:
                    res.append((complex(lamj[j]), s, Vcols[j] * beta[j]))
                else:
                    Z[k] += Vcols[j] * (beta[j] / (s - lamj[j]))
        ZW = np.concatenate([Z.T, (Z @ C.T).T])
        self.yconst = yconst
        self.Z = Z
        self.res = res
        self.CV = core.CV  # (ns, n)
        mu = self.mu = np.concatenate([core.lamc, _ZERO1, 1j * om])
        mupow = self.mupow = np.empty((4, mu.size), dtype=complex)
        mupow[0] = 1.0
        mupow[1] = mu
        np.multiply(mu, mu, out=mupow[2])
        np.multiply(mupow[2], mu, out=mupow[3])
        self.amupow = np.abs(mupow)
        if res:
            self.res_rho = max(max(abs(r[0]), abs(r[1])) for r in res)
            self.res_lam = np.array([r[0] for r in res], dtype=complex)
            self.res_sig = np.array([r[1] for r in res], dtype=complex)
            self.res_vec = np.array([r[2] for r in res], dtype=complex).reshape(len(res), n).T
            self.res_C = C @ self.res_vec  # (ns, nr)
        else:
            self.res_rho = 0.0
            self.res_lam, self.res_sig, self.res_vec, self.res_C = core.no_res
        # per-piece data are these columns times the piece's coefficients (alpha, 1, e^{i w t0}):
        # the state's rows (n), then the surfaces' (ns); Ybase and Wbase are views
        self.YWbase = np.concatenate([core.YWV, ycol, ZW], axis=1)
        self.Ybase, self.Wbase = self.YWbase[:n], self.YWbase[n:]
        self.n = n
        self.sig = core.sig
        self.absd = model.absd
        self._sig3 = core.sig3

    # (the Python scan's data: built when first needed, the compiled scan does without)
    @functools.cached_property
    def mupow_sig(self) -> np.ndarray:
        return self.mupow[:3, None, :] * self._sig3

    @functools.cached_property
    def amu1_list(self) -> list[float]:
        return self.amupow[1].tolist()

    @functools.cached_property
    def mu_re(self) -> np.ndarray:
        return self.mu.real.copy()

    def particular(self, t: float) -> np.ndarray:
        """The regular particular solution ``y_p(t)`` (resonant pairs excluded)."""
        om = self.model.omegas
        if om.size:
            return self.yconst + (np.exp(1j * om * t) @ self.Z).real
        return self.yconst.copy()

    def piece(self, t0: float, y0: np.ndarray) -> _ModalPiece:
        return _ModalPiece(self, t0, y0)

    def transition(self, h: float) -> np.ndarray:
        """``e^{A h}``."""
        return ((self.V * np.exp(self.lam * h)) @ self.Vinv).real


class _ModalPiece:
    """The closed form of one visit of a modal region, from ``y0`` at ``t0``."""

    __slots__ = (
        "region",
        "t0",
        "y0",
        "mu",
        "Y",
        "W",
        "_Wp",
        "_aWp23",
        "_Gp",
        "trans",
        "_tol",
        "sig",
        "rv",
        "rc",
        "has_res",
        "ns",
        "_colnorm",
        "_YY",
        "y_scan",
    )

    def __init__(self, region: _ModalRegion, t0: float, y0: np.ndarray) -> None:
        # (called once per piece: few, whole-array operations; see _ModalRegion.Ybase)
        self.region = region
        self.t0 = t0
        self.y0 = y0
        self.sig = region.sig
        self.ns = region.Wbase.shape[0]
        om = region.model.omegas
        self.mu = region.mu
        if om.size == 1:
            # (one harmonic input, the common case: Python complex arithmetic for its phase)
            ph1 = cmath.exp(complex(0.0, float(om[0]) * t0))
            yp = region.yconst + (ph1 * region.Z[0]).real  # the particular solution at t0
            coef = np.concatenate([region.Vinv @ (y0 - yp), _ONE, (ph1,)])
        elif om.size:
            ph = np.exp(1j * om * t0)
            yp = region.yconst + (ph @ region.Z).real
            coef = np.concatenate([region.Vinv @ (y0 - yp), _ONE, ph])
        else:
            coef = np.concatenate([region.Vinv @ (y0 - region.yconst), _ONE])
        n = region.n
        YW = region.YWbase * coef  # the state's terms (n rows), then the surfaces' (ns rows)
        self.Y = YW[:n]
        self.W = YW[n:]
        self._Wp = None  # W mu^p, (4, ns, nt): built when first needed (see Wp)
        self._YY = None  # (Y; Y mu), (2n, nt): built when first needed (see state_rate)
        # the state where the compiled scan stopped: at the crossing, already placed on the
        # surface, or at the end of the interval (None: the Python scan, see _run)
        self.y_scan = None
        self.trans = None  # (h, e^{A h}) once the sensitivity has computed it (see _sensitivity)
        # the Python scan's data (Gp, aWp23, colnorm, tol): built when first needed (the
        # compiled scan computes its own from W and Y)
        self._Gp = self._aWp23 = self._colnorm = self._tol = None
        self.has_res = bool(region.res)
        if self.has_res:
            phr = np.exp(region.res_sig * t0)
            self.rv = region.res_vec * phr  # (n, nr)
            self.rc = region.res_C * phr  # (ns, nr)
        else:
            self.rv = self.rc = None

    # -- the Python scan's data ---------------------------------------------------------------
    @property
    def Gp(self) -> np.ndarray:
        """``g = sigma s`` (the scan's function): ``W mu^p sigma``, ``p < 3``, shape
        ``(3, ns, nt)`` (a sign flip is exact)."""
        if self._Gp is None:
            self._Gp = self.W[None] * self.region.mupow_sig
        return self._Gp

    @property
    def Gp2(self) -> np.ndarray:
        """:attr:`Gp` with the rows ``(p, j)`` stacked (gridg's product)."""
        Gp = self.Gp
        return Gp.reshape(3 * self.ns, Gp.shape[2])

    @property
    def aWp23(self) -> np.ndarray:
        """``|W mu^p|`` for ``p = 2, 3`` only (the bounds of the second and third
        derivatives), the rows ``(p, j)`` stacked, shape ``(2 ns, nt)``."""
        if self._aWp23 is None:
            aW = np.abs(self.W)
            nt = aW.shape[1]
            self._aWp23 = (aW[None] * self.region.amupow[2:, None, :]).reshape(2 * self.ns, nt)
        return self._aWp23

    @property
    def colnorm(self) -> np.ndarray:
        """``sum_i |Y_iq|``: the size of each term in the state."""
        if self._colnorm is None:
            self._colnorm = np.abs(self.Y).sum(axis=0)
        return self._colnorm

    @property
    def tol(self) -> np.ndarray:
        """Tangency tolerance of each surface: ``_TOL_ULPS`` rounding units of the size of the
        terms of ``s_j``."""
        if self._tol is None:
            scale = np.abs(self.W).sum(axis=1) + self.region.absd
            if self.has_res:
                scale = scale + np.abs(self.rc).sum(axis=1)
            self._tol = _TOL_ULPS * _EPS * scale
        return self._tol

    # -- rates --------------------------------------------------------------------------------
    def step(self, tau: float) -> float:
        """Grid step ``1/(8 rho)`` from the terms that still matter at ``tau``."""
        reg = self.region
        if tau == 0.0:
            mag = self.colnorm.tolist()
        else:
            mag = (self.colnorm * np.exp(np.minimum(reg.mu_re * tau, 700.0))).tolist()
        # the largest rate |mu_q| among the terms above 1e-16 of the largest (a handful of
        # terms: Python lists are cheaper than numpy here)
        thr = 1e-16 * max(mag)
        rho = max([r for r, m in zip(reg.amu1_list, mag, strict=True) if m > thr], default=0.0)
        rho = max(rho, reg.res_rho)
        return math.inf if rho == 0.0 else 1.0 / (_STEPS_PER_SCALE * rho)

    # -- evaluation ---------------------------------------------------------------------------
    def state(self, tau: np.ndarray) -> np.ndarray:
        """``y(t0 + tau)``, shape ``(n, len(tau))``."""
        tau = np.asarray(tau, dtype=float).reshape(-1)
        out = (self.Y @ np.exp(self.mu[:, None] * tau)).real
        if self.has_res:
            reg = self.region
            for r in range(self.rv.shape[1]):
                E = _E_all(reg.res_lam[r], reg.res_sig[r], tau)[0]
                out += (np.outer(self.rv[:, r], E)).real
        return out

    def state1(self, tau: float) -> np.ndarray:
        if self.has_res:
            return self.state(np.array([tau]))[:, 0]
        return (self.Y @ np.exp(self.mu * tau)).real

    def state_rate(self, tau: np.ndarray) -> np.ndarray | None:
        """``(y; y')`` at ``t0 + tau``, shape ``(2n, len(tau))`` (the derivative of the closed
        form, one product for both); None with a resonant pair (callers use the field)."""
        if self.has_res:
            return None
        if self._YY is None:
            self._YY = np.concatenate([self.Y, self.Y * self.mu])
        return (self._YY @ np.exp(self.mu[:, None] * tau)).real

    def state_rate1(self, tau: float) -> np.ndarray | None:
        """:meth:`state_rate` at one time: ``(y; y')``, shape ``(2n,)`` (None with a resonant
        pair)."""
        if self.has_res:
            return None
        if self._YY is None:
            self._YY = np.concatenate([self.Y, self.Y * self.mu])
        return (self._YY @ np.exp(self.mu * tau)).real

    def grid(self, taus: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(s, s', s'')`` of every surface at ``taus`` (shape ``(3, ns, m)``) and the bound
        and ``|s'''|`` on every interval (shape ``(2, ns, m - 1)``)."""
        E = np.exp(self.mu[:, None] * taus)  # (nt, m)
        S = (self.Wp[:3] @ E).real  # (3, ns, m)
        aE = np.abs(E)
        B = self.aWp23.reshape(2, self.ns, E.shape[0]) @ np.maximum(aE[:, :-1], aE[:, 1:])
        if self.has_res:
            reg = self.region
            for r in range(self.rc.shape[1]):
                lam, sg = reg.res_lam[r], reg.res_sig[r]
                Es = _E_all(lam, sg, taus)
                for p in range(3):
                    S[p] += np.outer(self.rc[:, r], Es[p]).real
                bnd = _E_bounds(lam, sg, taus[:-1], taus[1:])
                B[0] += np.outer(np.abs(self.rc[:, r]), bnd[2])
                B[1] += np.outer(np.abs(self.rc[:, r]), bnd[3])
        return S, B

    def gridg(self, taus: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`grid` for ``g = sigma s``: ``(g, g', g'')`` and the bounds."""
        if self.has_res:
            S, B = self.grid(taus)
            return S * self.sig[None, :, None], B
        E = np.exp(self.mu[:, None] * taus)  # (nt, m)
        aE = np.abs(E)
        ns, m = self.ns, taus.size
        # (one 2-D product each: the rows of (p, j) stacked)
        G = (self.Gp2 @ E).real.reshape(3, ns, m)
        B = (self.aWp23 @ np.maximum(aE[:, :-1], aE[:, 1:])).reshape(2, ns, m - 1)
        return G, B

    @property
    def Wp(self) -> np.ndarray:
        """``W mu^p``, shape ``(4, ns, nt)`` (the derivatives of ``s``)."""
        if self._Wp is None:
            self._Wp = self.W[None] * self.region.mupow[:, None, :]
        return self._Wp

    def g01(self, j: int, tau: float) -> tuple[float, float]:
        """``(g_j, g_j')`` at ``tau`` as Python floats (``g_j = sigma_j s_j``; the root
        solvers' function)."""
        if self.has_res:
            dd = self.derivs(j, tau)
            sg = float(self.sig[j])
            return sg * float(dd[0]), sg * float(dd[1])
        return tuple((self.Gp[:2, j, :] @ np.exp(self.mu * tau)).real.tolist())

    def g012(self, j: int, tau: float) -> tuple[float, float, float]:
        """``(g_j, g_j', g_j'')`` at ``tau`` as Python floats."""
        if self.has_res:
            dd = self.derivs(j, tau)
            sg = float(self.sig[j])
            return sg * float(dd[0]), sg * float(dd[1]), sg * float(dd[2])
        return tuple((self.Gp[:, j, :] @ np.exp(self.mu * tau)).real.tolist())

    def derivs(self, j: int, tau: float) -> np.ndarray:
        """``(s_j, s_j', s_j'', s_j''')`` at ``tau``."""
        out = (self.Wp[:, j, :] @ np.exp(self.mu * tau)).real
        if self.has_res:
            reg = self.region
            ta = np.array([tau])
            for r in range(self.rc.shape[1]):
                Es = _E_all(reg.res_lam[r], reg.res_sig[r], ta)
                c = self.rc[j, r]
                out = out + np.array([(c * Es[p][0]).real for p in range(4)])
        return out

    def bound(self, p: int, j: int, ta: float, tb: float) -> float:
        """A rigorous bound of ``|s_j^{(p)}|`` on ``[ta, tb]``."""
        re = self.mu.real
        e = np.exp(np.maximum(re * ta, re * tb))
        out = float(self.aWp23[(p - 2) * self.ns + j] @ e)  # (p is 2 or 3)
        if self.has_res:
            reg = self.region
            for r in range(self.rc.shape[1]):
                bnd = _E_bounds(reg.res_lam[r], reg.res_sig[r], np.array([ta]), np.array([tb]))
                out += abs(self.rc[j, r]) * float(bnd[p, 0])
        return out


class _ExpmRegion:
    """A region in the augmented-matrix (Van Loan) representation."""

    kind = "expm"

    def __init__(self, model: _Model, key, A, b) -> None:
        self.model = model
        self.key = key
        self.A, self.b = A, b
        n = A.shape[0]
        om = model.omegas
        N = n + 1 + 2 * om.size
        At = np.zeros((N, N))
        At[:n, :n] = A
        At[:n, n] = b
        for k, w in enumerate(om):
            ic, is_ = n + 1 + 2 * k, n + 2 + 2 * k
            At[:n, ic] = model.u[k]
            At[:n, is_] = model.v[k]
            At[ic, is_] = -w  # (cos w t)' = -w sin w t
            At[is_, ic] = w
        self.At = At
        Caug = np.zeros((model.C.shape[0], N))
        Caug[:, :n] = model.C
        Caug[:, n] = -model.d
        P = [Caug]
        for _ in range(3):
            P.append(P[-1] @ At)
        self.Cp = np.stack(P)  # (4, ns, N)
        self.Cp_norm = np.linalg.norm(self.Cp, axis=2)  # (4, ns)
        self.nu = max(0.0, float(np.linalg.eigvalsh(0.5 * (At + At.T)).max()))
        rho = float(np.linalg.norm(At, 2))
        self.At_norm = rho
        self.h = math.inf if rho == 0.0 else 1.0 / (_STEPS_PER_SCALE * rho)
        # once per region: the grid step's exponential
        self.Phi_h = scipy.linalg.expm(At * self.h) if math.isfinite(self.h) else None
        self._powers = None if self.Phi_h is None else np.stack([np.eye(N), self.Phi_h])
        self.rho = rho

    def powers(self, k: int) -> np.ndarray:
        """``(e^{At h})^i`` for ``i < k``, shape ``(k, N, N)`` (extended on demand)."""
        P = self._powers
        if P.shape[0] < k:
            out = [P[i] for i in range(P.shape[0])]
            while len(out) < k:
                out.append(self.Phi_h @ out[-1])
            P = self._powers = np.stack(out)
        return P[:k]

    def lift(self, t0: float, y0: np.ndarray) -> np.ndarray:
        om = self.model.omegas
        z = np.empty(self.At.shape[0])
        n = y0.size
        z[:n] = y0
        z[n] = 1.0
        z[n + 1 :: 2] = np.cos(om * t0)
        z[n + 2 :: 2] = np.sin(om * t0)
        return z

    def piece(self, t0: float, y0: np.ndarray) -> _ExpmPiece:
        return _ExpmPiece(self, t0, y0)

    def transition(self, h: float) -> np.ndarray:
        return _expm(self.A * h)


class _ExpmPiece:
    """The closed form of one visit of an expm region: ``z(tau) = e^{At tau} z0``.

    The scan's grid nodes ``z(tau_k)`` are kept; any other time is reached from the node
    before it by :func:`_expm_apply` (a Taylor series of a step below ``1/(8 |At|)``)."""

    def __init__(self, region: _ExpmRegion, t0: float, y0: np.ndarray) -> None:
        self.region = region
        self.t0 = t0
        self.y0 = y0
        self.z0 = region.lift(t0, y0)
        self.sig = np.array(region.key, dtype=float)
        self.ns = region.Cp.shape[1]
        self.tol = _TOL_ULPS * _EPS * region.Cp_norm[0] * np.linalg.norm(self.z0)
        self._tz = [0.0]
        self._zz = [self.z0]

    def step(self, tau: float) -> float:
        return self.region.h

    def _node(self, tau: float, z: np.ndarray) -> None:
        # A long visit keeps every _NODE_STRIDE-th node only (z between nodes is reached by
        # the Taylor sub-steps of _expm_apply): a stiff region scanned for millions of grid
        # intervals would otherwise hold ~200 B per interval (gigabytes before the budget)
        if tau > self._tz[-1] and (
            len(self._tz) < _NODES_DENSE or tau - self._tz[-1] >= _NODE_STRIDE * self.region.h
        ):
            self._tz.append(tau)
            self._zz.append(z)

    def z(self, tau: float) -> np.ndarray:
        k = bisect.bisect_right(self._tz, tau) - 1
        ta = self._tz[k]
        if ta == tau:
            return self._zz[k]
        return _expm_apply(self.region.At, self.region.At_norm, tau - ta, self._zz[k])

    def state(self, tau: np.ndarray) -> np.ndarray:
        tau = np.asarray(tau, dtype=float).reshape(-1)
        n = self.y0.size
        out = np.empty((n, tau.size))
        for i, t in enumerate(tau):
            out[:, i] = self.z(float(t))[:n]
        return out

    def state1(self, tau: float) -> np.ndarray:
        return self.z(float(tau))[: self.y0.size].copy()

    def state_rate(self, tau: np.ndarray) -> None:
        """None: callers take the rate from the field (see :meth:`_ModalPiece.state_rate`)."""
        return None

    def grid(self, taus: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        reg = self.region
        m = taus.size
        Zs = np.empty((reg.At.shape[0], m))
        z_first = self.z(float(taus[0]))
        # the grid steps of h (tau + k h, equal to k h up to the rounding of tau) at once, by
        # the cached powers of e^{At h}; a last shorter step by the Taylor series
        L = np.diff(taus)
        k = m if reg.Phi_h is None else 1 + int(np.count_nonzero(np.abs(L - reg.h) <= 1e-9 * reg.h))
        k = min(k, m)
        if reg.Phi_h is not None and k > 1:
            Zs[:, :k] = (reg.powers(k) @ z_first).T
        else:
            k = 1
            Zs[:, 0] = z_first
        for i in range(k, m):
            Zs[:, i] = _expm_apply(reg.At, reg.At_norm, float(L[i - 1]), Zs[:, i - 1])
        for i in range(1, m):
            self._node(float(taus[i]), Zs[:, i])
        S = reg.Cp[:3] @ Zs  # (3, ns, m)
        zn = np.linalg.norm(Zs[:, :-1], axis=0) * np.exp(reg.nu * np.diff(taus))
        B = reg.Cp_norm[2:, :, None] * zn[None, None, :]
        return S, B

    def gridg(self, taus: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        S, B = self.grid(taus)
        return S * self.sig[None, :, None], B

    def g01(self, j: int, tau: float) -> tuple[float, float]:
        v, d = (self.region.Cp[:2, j, :] @ self.z(float(tau))).tolist()
        return (v, d) if self.sig[j] > 0.0 else (-v, -d)

    def g012(self, j: int, tau: float) -> tuple[float, float, float]:
        v, d, c = (self.region.Cp[:3, j, :] @ self.z(float(tau))).tolist()
        return (v, d, c) if self.sig[j] > 0.0 else (-v, -d, -c)

    def derivs(self, j: int, tau: float) -> np.ndarray:
        return self.region.Cp[:, j, :] @ self.z(float(tau))

    def bound(self, p: int, j: int, ta: float, tb: float) -> float:
        reg = self.region
        return float(
            reg.Cp_norm[p, j] * np.linalg.norm(self.z(float(ta))) * math.exp(reg.nu * (tb - ta))
        )


#: an expm piece keeps every grid node up to this many, then one per _NODE_STRIDE intervals
_NODES_DENSE = 8192
_NODE_STRIDE = 32


def _expm_apply(M: np.ndarray, norm: float, tau: float, z: np.ndarray) -> np.ndarray:
    """``e^{M tau} z`` by Taylor series on sub-steps with ``|M| dt <= 1/2`` (matrix-vector
    products only: 20 terms reach ``0.5^20/20! ~ 4e-25``).

    Why not :func:`scipy.linalg.expm` here: it is called at every root iterate, and on a
    loaded machine scipy's BLAS thread pool made each call of a 7x7 exponential take ~10 ms
    (measured), against a few microseconds for these products."""
    if tau == 0.0 or norm == 0.0:
        return z.copy()
    k = max(1, math.ceil(2.0 * norm * abs(tau)))
    dt = tau / k
    out = z
    for _ in range(k):
        term = out
        acc = out.copy()
        for i in range(1, 25):
            term = (M @ term) * (dt / i)
            acc += term
            if not np.any(np.abs(term) > _EPS * 1e-3 * np.abs(acc)):
                break
        out = acc
    return out


def _expm(M: np.ndarray) -> np.ndarray:
    """``e^M`` by scaling and squaring of a Taylor series (numpy products only; see
    :func:`_expm_apply` for why not scipy's)."""
    norm = float(np.abs(M).sum(axis=0).max()) if M.size else 0.0
    s = max(0, math.ceil(math.log2(norm / 0.25))) if norm > 0.25 else 0
    X = M / 2.0**s
    n = M.shape[0]
    E = np.eye(n)
    term = np.eye(n)
    for i in range(1, 25):
        term = (term @ X) / i
        E = E + term
        if not np.any(np.abs(term) > _EPS * 1e-3 * np.abs(E)):
            break
    for _ in range(s):
        E = E @ E
    return E


#: the state is rescaled only when balancing shrinks the norm of the regions' matrices by
#: more than this factor (a well-scaled system keeps its arithmetic bit for bit)
_BALANCE_GAIN = 16.0


def _state_scale(system: PiecewiseAffineSystem) -> np.ndarray:
    r"""The diagonal ``D`` (powers of two) of the internal state ``z = D^{-1} y``.

    A system whose states differ by many orders of magnitude (the hydraulic mount: pressures
    ~1e4 Pa next to flows ~1e-5 m^3/s, entries of ``A`` from 1e-7 to 2.5e10) has eigenvectors
    that are ill conditioned only through the units (``cond(V) ~ 1e8``): the modal form is
    refused and the augmented exponential's grid step follows ``|A| ~ 2.5e10`` although the
    eigenvalues are a few hundred.  The similarity ``D^{-1} A D`` has the same eigenvalues
    and, with ``D`` from :func:`scipy.linalg.matrix_balance` of ``sum_r |A_r|`` (one ``D`` for
    every region, so the surfaces are shared), rows and columns of comparable norms.  Powers
    of two make ``y = D z`` and ``D^{-1} y`` exact.  ``D = I`` unless balancing reduces the
    1-norm of ``sum_r |A_r|`` by more than ``_BALANCE_GAIN``."""
    n = system.n
    mats = [np.asarray(reg.A, dtype=float) for reg in system.regions.values()]
    # (a frequency response builds one system per frequency with the same matrices)
    ckey = (n, b"".join(A.tobytes() for A in mats))
    hit = _SCALE_CACHE.get(ckey)
    if hit is not None:
        return hit
    S = np.zeros((n, n))
    for A in mats:
        S += np.abs(A)
    one = np.ones(n)
    norm = float(S.sum(axis=0).max())
    if not (norm > 0.0 and math.isfinite(norm)):
        return one
    _, (scale, _) = scipy.linalg.matrix_balance(S, permute=False, separate=True)
    scale = np.asarray(scale, dtype=float)
    if scale.shape != (n,) or not np.all(np.isfinite(scale) & (scale > 0.0)):
        return one
    # exact powers of two (matrix_balance returns them; rounding guards against any other)
    scale = np.exp2(np.round(np.log2(scale)))
    balanced = float((S * (scale[None, :] / scale[:, None])).sum(axis=0).max())
    out = scale if balanced * _BALANCE_GAIN < norm else one
    _remember(_SCALE_CACHE, ckey, out)
    return out


#: caches keyed by matrix bytes, shared by the systems of a family (a frequency response
#: builds one PiecewiseAffineSystem per frequency; only the inputs change): the state scale
#: of a set of region matrices, and the eigen-decomposition of one matrix
_SCALE_CACHE: dict = {}
_EIG_CACHE: dict = {}
_CACHE_SIZE = 512


def _remember(cache: dict, key, value) -> None:
    if len(cache) >= _CACHE_SIZE:
        cache.pop(next(iter(cache)))  # the oldest entry
    cache[key] = value


def _eig(A: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, np.ndarray | None]:
    """``(lambda, V, cond(V), V^-1 or None)`` of ``A`` (``V^-1`` only when ``cond(V)`` is
    finite and at most ``_COND_MAX``), cached by the bytes of ``A``."""
    key = (A.shape, A.tobytes())
    hit = _EIG_CACHE.get(key)
    if hit is None:
        lam, V = np.linalg.eig(A)
        cond = float(np.linalg.cond(V))
        Vinv = np.linalg.inv(V) if math.isfinite(cond) and cond <= _COND_MAX else None
        for arr in (lam, V, Vinv):
            if arr is not None:
                arr.setflags(write=False)  # shared by every region built from A
        hit = (lam, V, cond, Vinv)
        _remember(_EIG_CACHE, key, hit)
    return hit


class _Model:
    """The per-system data of the propagator: surfaces as arrays and the region cache."""

    def __init__(self, system: PiecewiseAffineSystem, representation: str = "auto") -> None:
        self.system = system
        self.representation = representation
        n = system.n
        self.n = n
        # omega-independent data of each region (_ModalRegion), shared with derived models
        self.region_core: dict[tuple[int, ...], tuple] = {}
        # the internal state is z = y / D (D a power-of-two diagonal, see _state_scale): every
        # array below is of the scaled system, and y = D z is exact in binary floating point
        D = _state_scale(system)
        self.D, self.Dinv = D, 1.0 / D
        self.scaled = bool(np.any(D != 1.0))
        C = np.array([s.normal for s in system.surfaces], dtype=float).reshape(-1, n)
        self.C = C * D[None, :]
        self.d = np.array([s.offset for s in system.surfaces], dtype=float)
        self.cc = np.einsum("ij,ij->i", self.C, self.C)
        self.omegas = np.array([h.omega for h in system.inputs], dtype=float)
        self.omega_max = float(self.omegas.max()) if self.omegas.size else 0.0
        self.u = np.array([h.u for h in system.inputs], dtype=float).reshape(-1, n) * self.Dinv
        self.v = np.array([h.v for h in system.inputs], dtype=float).reshape(-1, n) * self.Dinv
        self.uv = self.u - 1j * self.v
        self.continuous = tuple(system.continuous) or (False,) * len(system.surfaces)
        self.absd = np.abs(self.d)
        self._regions: dict[tuple[int, ...], _ModalRegion | _ExpmRegion] = {}
        self._Ab: dict[tuple[int, ...], tuple[np.ndarray, np.ndarray]] = {}
        self.eye = np.eye(n)  # (read-only: the start of every sensitivity product)
        self.eye.setflags(write=False)

    def derive(self, system: PiecewiseAffineSystem) -> _Model:
        """The model of ``system``, which differs from this model's system only by the input
        frequencies and the period (:func:`_same_but_frequencies`): everything but the
        frequencies and the regions built from them is shared (a frequency response builds
        one system per parameter value, see ``SystemFlowFamily``)."""
        out = object.__new__(_Model)
        out.__dict__.update(self.__dict__)
        out.system = system
        out.omegas = np.array([h.omega for h in system.inputs], dtype=float)
        out.omega_max = float(out.omegas.max()) if out.omegas.size else 0.0
        out._regions = {}
        return out

    def region_data(self, key: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
        """``(A, b)`` of the scaled system in region ``key`` (ModelError when missing)."""
        ab = self._Ab.get(key)
        if ab is None:
            data = self.system.region(key)  # ModelError naming the pattern when missing
            A = np.asarray(data.A, dtype=float)
            b = np.asarray(data.b, dtype=float)
            if self.scaled:
                A = self.Dinv[:, None] * A * self.D[None, :]
                b = b * self.Dinv
            ab = self._Ab[key] = (A, b)
        return ab

    def region(self, key: tuple[int, ...]) -> _ModalRegion | _ExpmRegion:
        reg = self._regions.get(key)
        if reg is None:
            A, b = self.region_data(key)
            reg = None
            if self.representation in ("auto", "modal"):
                lam, V, cond, Vinv = _eig(A)
                if Vinv is not None:
                    reg = _ModalRegion(self, key, A, b, lam, V, Vinv)
                elif self.representation == "modal":
                    raise PerturbError(
                        f"region {key}: the eigenvectors of A are ill conditioned (cond = "
                        f"{cond:.3g} > {_COND_MAX:g}); expected representation='auto' or 'expm'"
                    )
            if reg is None:
                reg = _ExpmRegion(self, key, A, b)
            self._regions[key] = reg
        return reg

    def forcing(self, t: float) -> np.ndarray:
        om = self.omegas
        if not om.size:
            return np.zeros(self.n)
        return np.cos(om * t) @ self.u + np.sin(om * t) @ self.v

    def field(self, key: tuple[int, ...], t: float, z: np.ndarray) -> np.ndarray:
        """The scaled field ``z' = D^-1 y'`` in region ``key``."""
        A, b = self.region_data(key)
        return A @ z + b + self.forcing(t)

    def initial_pattern(self, t: float, y: np.ndarray) -> tuple[tuple[int, ...], set[int]]:
        """The region holding ``y`` at ``t`` and the surfaces it lies exactly on.

        On a surface (``s_j = 0``) the side is the one the field moves into; both sides
        pushing into the surface of a discontinuous field is sliding (an error)."""
        sl = (self.C @ y - self.d).tolist()
        key = [1 if sj >= 0.0 else -1 for sj in sl]
        on: set[int] = set()
        for j in [i for i, sj in enumerate(sl) if sj == 0.0]:
            j = int(j)
            on.add(j)
            plus = tuple(key[:j] + [1] + key[j + 1 :])
            minus = tuple(key[:j] + [-1] + key[j + 1 :])
            rate_p = rate_m = None
            if plus in self.system.regions:
                rate_p = float(self.C[j] @ self.field(plus, t, y))
            if minus in self.system.regions:
                rate_m = float(self.C[j] @ self.field(minus, t, y))
            if rate_p is not None and rate_p >= 0.0:
                key[j] = 1
            elif rate_m is not None and rate_m <= 0.0:
                key[j] = -1
            elif rate_p is not None and rate_m is not None and not self.continuous[j]:
                raise PerturbError(
                    f"y0 = {y.tolist()!r} lies on the surface "
                    f"{self.system.surfaces[j].label!r} at t = {t!r} and the field on both "
                    f"sides points into it (sliding); {EVENT_DRIVEN_HINT}"
                )
            else:
                key[j] = 1 if rate_p is not None else -1
        return tuple(key), on


_MODEL_CACHE: list[tuple[PiecewiseAffineSystem, str, _Model]] = []


def _same_but_frequencies(a: PiecewiseAffineSystem, b: PiecewiseAffineSystem) -> bool:
    """Whether ``b`` is ``a`` with other input frequencies / period only: the same region
    mapping and surfaces (by identity: ``dataclasses.replace`` shares them), the same input
    vectors."""
    if a.regions is not b.regions or a.surfaces is not b.surfaces:
        return False
    if a.state_names != b.state_names or a.continuous != b.continuous:
        return False
    if len(a.inputs) != len(b.inputs):
        return False
    return all(
        (ha.u is hb.u or np.array_equal(ha.u, hb.u))
        and (ha.v is hb.v or np.array_equal(ha.v, hb.v))
        for ha, hb in zip(a.inputs, b.inputs, strict=True)
    )


def _model_of(system: PiecewiseAffineSystem, representation: str) -> _Model:
    """The cached model of ``system`` (the last few systems, by identity)."""
    for sys_, rep, model in _MODEL_CACHE:
        if sys_ is system and rep == representation:
            return model
    for sys_, rep, model in reversed(_MODEL_CACHE):
        if rep == representation and _same_but_frequencies(sys_, system):
            model = model.derive(system)
            break
    else:
        model = _Model(system, representation)
    _MODEL_CACHE.append((system, representation, model))
    if len(_MODEL_CACHE) > 8:
        _MODEL_CACHE.pop(0)
    return model


# --------------------------------------------------------------------------------------------
# root finding and the switch scan
# --------------------------------------------------------------------------------------------
def _solve(fd, a: float, b: float, fa: float, fb: float, start: float = math.nan) -> float:
    """Root of ``f`` in ``[a, b]`` (``fa``, ``fb`` of opposite signs or zero) by safeguarded
    Newton–bisection; ``fd(t) -> (f, f')`` exact.  Never leaves the bracket; stops at the
    resolution of ``t`` (``4 eps |t|``).  ``start``: a first iterate inside ``(a, b)`` (else
    the secant point)."""
    if fb == 0.0:
        return b
    if fa == 0.0:
        return a
    pos_a = fa > 0.0
    lo, hi = a, b  # f(lo) has the sign of fa, f(hi) that of fb
    t = start if a < start < b else a + (b - a) * fa / (fa - fb)
    if not a < t < b:
        t = 0.5 * (a + b)
    dx_old = dx = b - a
    for _ in range(_ROOT_ITER):
        f, df = fd(t)
        if f == 0.0:
            return t
        if (f > 0.0) == pos_a:
            lo = t
        else:
            hi = t
        left, right = (lo, hi) if lo < hi else (hi, lo)
        tol = max(4.0 * _EPS * abs(t), 1e-300)
        if abs(f) <= tol * abs(df):
            tn = t - f / df
            return tn if left <= tn <= right else t
        tn = t - f / df if df != 0.0 else math.nan
        if not (left < tn < right) or abs(2.0 * f) > abs(dx_old * df):
            dx_old, dx = dx, 0.5 * (right - left)
            tn = left + dx
        else:
            dx_old, dx = dx, t - tn
        if abs(dx) <= tol or right - left <= tol:
            return tn
        t = tn
    return t


class _Budget:
    __slots__ = ("left", "used", "limit")

    def __init__(self, limit: int) -> None:
        self.left = limit
        self.limit = limit
        self.used = 0

    def take(self, k: int, t: float) -> None:
        self.used += k
        self.left -= k
        if self.left < 0:
            raise PerturbError(
                f"more than max_steps = {self.limit} grid intervals scanned for switches "
                f"(reached t = {t!r}); raise max_steps or shorten the interval"
            )


def _first_event(piece, j, u, w, gu, gw, touching, clamp, bounds=None, depth=0, nodes=None):
    """The first root (crossing) or tangency of ``g = sigma_j s_j`` in ``(u, w]``.

    ``gu``, ``gw``: ``(g, g', g'')`` at the ends (``g(u) > 0``, or ``touching``: the orbit
    is on the surface at ``u`` and ``g(u)`` counts as ``+0``; ``clamp``: it is known to be
    entering, ``g'(u) >= 0``); ``bounds``: the bounds of ``|g''|``, ``|g'''|`` on the interval
    when known (from the grid).  Returns ``(tau, kind)`` or None.  ``nodes``: the intervals
    examined so far in this search (a list of one count; at most ``_MAX_NODES``)."""
    if nodes is None:
        nodes = [0]
    nodes[0] += 1
    if nodes[0] > _MAX_NODES:
        raise PerturbError(
            f"the switch scan of surface {j} could not decide between t = {piece.t0 + u!r} "
            f"and {piece.t0 + w!r} after {_MAX_NODES} halvings (the switching function "
            "stays within rounding of zero there)"
        )
    sig = piece.sig[j]
    tol = float(piece.tol[j])
    g0u, g1u, g2u = gu
    g0w, g1w, g2w = gw
    if touching:
        g0u = 0.0
        if clamp:
            g1u = max(g1u, 0.0)
    L = w - u
    if bounds is not None:
        M2, M3 = bounds
    else:
        M3 = piece.bound(3, j, u, w)
        M2 = min(piece.bound(2, j, u, w), _taylor_bound(g2u, g2w, M3, L))
    if min(g0u, g0w) - 0.125 * M2 * L * L > tol:
        return None
    if g1u * g1w > 0.0 and abs(g1u) + abs(g1w) > M2 * L:
        # g' keeps its sign: g is monotone on the interval (no extremum, no tangency inside)
        if g1u > 0.0 or g0w > 0.0:
            return None
        if touching:
            return (u, "crossing")
        return _crossing_or_graze(piece, j, u, w, g0u, g0w, tol, (g1u, g1w))
    simple = g2u * g2w > 0.0 and abs(g2u) + abs(g2w) > M3 * L
    if not simple and depth < _MAX_DEPTH and L > 8.0 * _EPS * max(abs(u), abs(w), 1e-300):
        if g0u > 0.0 and g0w > 0.0 and (abs(g1u) + M2 * L) * L <= tol:
            # g stays within tol of g(u) > 0 on the interval (|g'| <= |g'(u)| + M2 L): flat to
            # rounding, neither a crossing nor a tangency to resolve (halving a constant g
            # within tol of zero would explore the whole tree, 2^_MAX_DEPTH intervals)
            return None
        m = 0.5 * (u + w)
        gm = sig * piece.derivs(j, m)[:3]
        ev = _first_event(piece, j, u, m, gu, gm, touching, clamp, None, depth + 1, nodes)
        if ev is not None:
            return ev
        return _first_event(piece, j, m, w, gm, gw, False, False, None, depth + 1, nodes)
    convex = (g2u + g2w) > 0.0

    def g01(t: float) -> tuple[float, float]:
        return piece.g01(j, t)

    def g12(t: float) -> tuple[float, float]:
        dd = piece.derivs(j, t)
        return sig * dd[1], sig * dd[2]

    if g0w <= 0.0:
        a, ga = u, g0u
        if touching:
            if convex:
                return None  # leaving the surface with g' >= 0 and g convex: g >= 0
            if g1u <= 0.0:
                return (u, "crossing")  # concave and not entering: it leaves at once
            if g1w >= 0.0:
                return None  # (rounding: increasing and concave ends at g(w) > 0)
            tmax = _solve(g12, u, w, g1u, g1w)
            gmax = g01(tmax)[0]
            if gmax <= 0.0:
                return (tmax, "crossing")
            a, ga = tmax, gmax
        return _crossing_or_graze(piece, j, a, w, ga, g0w, tol)
    if not convex or g1u >= 0.0 or g1w <= 0.0:
        return None  # concave, or monotone, with g > 0 at both ends
    tm = _solve(g12, u, w, g1u, g1w)
    gm = g01(tm)[0]
    if gm > tol:
        return None
    if gm >= -tol:
        return (tm, "tangency")
    return (_solve(g01, u, tm, g0u, gm), "crossing")


def _taylor_bound(g2u, g2w, M3, L):
    """A bound of ``|g''|`` on an interval of length ``L`` from its end values and the bound
    ``M3`` of ``|g'''|``: ``|g''(t)| <= min(|g''(u)| + M3 (t - u), |g''(w)| + M3 (w - t))``,
    whose largest value is ``(|g''(u)| + |g''(w)| + M3 L) / 2``.  Much tighter than the sum of
    the moduli of the terms when they cancel (a homogeneous part against a large particular
    solution right after a switch)."""
    return 0.5 * (np.abs(g2u) + np.abs(g2w) + M3 * L)


def _hermite_start(a: float, w: float, ga: float, gw: float, da: float, dw: float) -> float:
    """A first iterate for the root of ``g`` in ``(a, w)`` (``ga > 0 >= gw``): the root of the
    cubic Hermite interpolant of the end values and slopes (error ``O(L^4)``, so Newton
    needs one or two steps instead of four from the secant point), or NaN when it is not
    strictly inside."""
    L = w - a
    ma, mw = da * L, dw * L
    x = ga / (ga - gw)
    for _ in range(4):
        x2 = x * x
        x3 = x2 * x
        val = (2 * x3 - 3 * x2 + 1) * ga + (x3 - 2 * x2 + x) * ma + (3 * x2 - 2 * x3) * gw
        val += (x3 - x2) * mw
        der = (6 * x2 - 6 * x) * (ga - gw) + (3 * x2 - 4 * x + 1) * ma + (3 * x2 - 2 * x) * mw
        if der == 0.0:
            break
        xn = x - val / der
        if not 0.0 < xn < 1.0:
            break
        done = abs(xn - x) <= 1e-9
        x = xn
        if done:
            break
    t = a + L * x
    return t if a < t < w else math.nan


def _crossing_or_graze(piece, j, a, w, ga, gw, tol, slopes=None):
    """The root of ``g`` in ``(a, w]`` (``g(a) > 0 >= g(w)``): a crossing, or a tangency when
    the penetration depth ``g'^2 / (2 g'')`` there is below the rounding level ``tol``.
    ``slopes``: ``(g'(a), g'(w))`` when known (a better first iterate)."""
    start = math.nan if slopes is None or gw == 0.0 else _hermite_start(a, w, ga, gw, *slopes)
    root, t_last, r1, r2 = _solve_halley(piece, j, a, w, ga, gw, start)
    if r1 < 0.0 and r2 > 0.0 and r1 * r1 <= 2.0 * r2 * tol:
        return (t_last - r1 / r2, "tangency")
    return (root, "crossing")


def _solve_halley(piece, j, a, w, ga, gw, start):
    """The root of ``g_j`` in ``[a, w]`` (``ga > 0 >= gw``) by safeguarded Halley–bisection on
    the closed form (``g, g', g''`` from one evaluation: cubic convergence, so from the
    Hermite start one step reaches full precision), never leaving the bracket; stops at the
    resolution of ``t`` (``4 eps |t|``).  Returns ``(root, t, g'(t), g''(t))`` with ``t``
    the last point evaluated (within rounding of the root)."""
    for end, g_end in ((w, gw), (a, ga)):
        if g_end == 0.0:  # (the root is an end point, as in _solve)
            _, d1, d2 = piece.g012(j, end)
            return end, end, d1, d2
    lo, hi = a, w  # g(lo) > 0 > g(hi)
    t = start if a < start < w else a + (w - a) * ga / (ga - gw)
    if not a < t < w:
        t = 0.5 * (a + w)
    dx_old = dx = w - a
    f = df = d2f = 0.0
    for _ in range(_ROOT_ITER):
        f, df, d2f = piece.g012(j, t)
        if f == 0.0:
            return t, t, df, d2f
        if f > 0.0:
            lo = t
        else:
            hi = t
        tol = max(4.0 * _EPS * abs(t), 1e-300)
        if abs(f) <= tol * abs(df):
            tn = t - f / df
            return (tn if lo <= tn <= hi else t), t, df, d2f
        den = 2.0 * df * df - f * d2f
        if den != 0.0:
            tn = t - 2.0 * f * df / den
        else:
            tn = t - f / df if df != 0.0 else math.nan
        if not (lo < tn < hi) or abs(2.0 * f) > abs(dx_old * df):
            dx_old, dx = dx, 0.5 * (hi - lo)
            tn = lo + dx
        else:
            dx_old, dx = dx, t - tn
        if abs(dx) <= tol or hi - lo <= tol:
            return tn, t, df, d2f
        t = tn
    return t, t, df, d2f


def _scan(piece, tau_end: float, touching: set[int], budget: _Budget):
    """First crossing ``(tau, j)`` of the piece in ``(0, tau_end)`` (None if none) and the
    tangencies ``[(tau, j), ...]`` before it; see the module docstring.  The compiled kernel
    (:mod:`.scan_kernel`) where it applies and is installed, else :func:`_scan_python`."""
    if 0 < piece.ns <= 62 and tau_end > 0.0 and piece.region.kind == "modal" and not piece.has_res:
        kernel = scan_kernel.compiled_scan()
        if kernel is not None:
            try:
                return _scan_compiled(kernel, piece, tau_end, touching, budget)
            except PerturbError:
                raise
            except Exception as exc:  # a numba that cannot compile or run it: numpy from now on
                scan_kernel.disable("perturb.simulate.flows.scan_kernel_numba", "scan_modal", exc)
    return _scan_python(piece, tau_end, touching, budget)


def _scan_python(piece, tau_end: float, touching: set[int], budget: _Budget):
    """:func:`_scan` in Python: every kind of region (modal with or without resonant pairs,
    expm)."""
    ns = piece.ns
    tangs: list[tuple[float, int]] = []
    if ns == 0 or tau_end <= 0.0:
        return None, tangs
    if piece.region.kind == "expm" and tau_end > budget.left * piece.region.h:
        # A stiff region (ill-conditioned modes, e.g. a near-singular mass matrix: |A| ~ 1e10)
        # is scanned on a grid of 1/(8|A|): reaching tau_end would exhaust the budget only
        # after minutes of work. Refuse now, with the cause.
        need = tau_end / piece.region.h
        raise PerturbError(
            f"region {piece.region.key} is stiff (|A| = {piece.region.rho:.3g}, grid step "
            f"{piece.region.h:.3g}): scanning {tau_end:.6g} time units from t = "
            f"{piece.t0!r} for switches needs ~{need:.3g} grid intervals, more than the "
            f"{budget.left} left of max_steps = {budget.limit}. A near-singular mass matrix? "
            "(a coordinate without inertia is a first-order state: declare it so)"
        )
    tau = 0.0
    touch = set(touching)
    clamp = set(touching)
    batch = _BATCH_FIRST
    sig = piece.sig
    tol = piece.tol
    tol_col = tol[:, None]
    while tau < tau_end:
        h = piece.step(tau)
        if not h > 8.0 * _EPS * max(abs(tau), 1.0):
            h = 8.0 * _EPS * max(abs(tau), 1.0)
        span = tau_end - tau
        if h * batch < span:
            taus = tau + h * _ARANGE[: batch + 1]
        elif h < span:
            # the last batch: whole steps, then the remainder (a step of at least h / 2)
            k = max(1, math.ceil(span / h - 0.5))
            taus = tau + h * (_ARANGE[: k + 1] if k <= _BATCH_MAX else np.arange(k + 1.0))
            taus[-1] = tau_end
        else:
            taus = np.array([tau, tau_end])
        budget.take(taus.size - 1, piece.t0 + tau)
        G, B = piece.gridg(taus)
        # (an overflow anywhere makes the bounds inf or nan: B sums |W_q mu_q^p| max|e^{mu_q t}|
        # over every term, and 0 * inf is nan)
        if not math.isfinite(float(B.sum())):
            raise PerturbError(
                f"the orbit escapes to infinity in region {piece.region.key} near t = "
                f"{piece.t0 + float(taus[-1])!r} (floating-point overflow); shorten the interval"
            )
        L = taus[1:] - taus[:-1]
        a2 = np.abs(G[2])
        # _taylor_bound inline (one call fewer per batch; the same operations in place)
        B2 = a2[:, :-1] + a2[:, 1:]
        B2 += B[1] * L
        B2 *= 0.5
        np.minimum(B[0], B2, out=B2)
        starts = touch if min(G[0, :, 0].tolist()) >= 0.0 else range(ns)
        for j in starts:
            if j in touch:
                G[0, j, 0] = 0.0
                if j in clamp:
                    G[1, j, 0] = max(G[1, j, 0], 0.0)
            elif G[0, j, 0] < 0.0:
                if G[0, j, 0] < -tol[j]:
                    raise PerturbError(
                        f"the state at t = {piece.t0 + tau!r} is on the wrong side of surface "
                        f"{j} (s = {float(sig[j] * G[0, j, 0])!r}) for region "
                        f"{piece.region.key}: the propagation lost track of the region (a "
                        "non-finite or huge state?)"
                    )
                if G[1, j, 0] < 0.0:
                    return (tau, j), tangs  # on a second surface and leaving through it
                G[0, j, 0] = 0.0
                touch.add(j)
        G0 = G[0]
        drop = 0.125 * B2
        drop *= L
        drop *= L
        low = np.minimum(G0[:, :-1], G0[:, 1:])
        low -= drop
        for j in clamp:
            # leaving the surface at the rate g'(0) >= 0: g(tau) >= g'(0) tau - M2 tau^2 / 2,
            # a concave bound that is 0 at tau = 0, so g > 0 on the interval if it is at its end
            L0 = float(L[0])
            if float(G[1, j, 0]) * L0 - 0.5 * float(B2[j, 0]) * L0 * L0 > 0.0:
                low[j, 0] = math.inf
        # the flagged (interval, surface) pairs in the order of the intervals: one call
        flat = np.flatnonzero((low <= tol_col).T).tolist()
        best = None
        k_prev = -1
        for kj in flat:
            k, j = divmod(kj, ns)
            if k != k_prev:
                if best is not None:
                    break
                k_prev = k
            first = k == 0 and j in touch
            ev = _first_event(
                piece,
                j,
                float(taus[k]),
                float(taus[k + 1]),
                G[:, j, k].tolist(),  # Python floats: scalar arithmetic from here on
                G[:, j, k + 1].tolist(),
                first,
                first and j in clamp,
                (float(B2[j, k]), float(B[1, j, k])),
            )
            if ev is not None and (best is None or ev[0] < best[0]):
                best = (ev[0], j, ev[1])
        if best is None:
            tau = float(taus[-1])
            touch, clamp = set(), set()
            batch = min(2 * batch, _BATCH_MAX)
            continue
        t_ev, j, kind = best
        if t_ev >= tau_end:
            return None, tangs
        if kind == "crossing":
            return (t_ev, j), tangs
        tangs.append((t_ev, j))
        # resume at the tangency, on the surface and leaving it
        tau = max(t_ev, float(np.nextafter(tau, math.inf)))
        touch, clamp = {j}, {j}
        batch = _BATCH_FIRST
    return None, tangs


def _scan_compiled(kernel, piece, tau_end: float, touching: set[int], budget: _Budget):
    """:func:`_scan` by the compiled kernel (:mod:`.scan_kernel`): a modal piece without
    resonant pairs.  Same results to rounding, same errors."""
    mask = 0  # the surfaces the state is on, as bits (at most 62 surfaces, see _scan)
    for j in touching:
        mask |= 1 << j
    region = piece.region
    model = region.model
    status, tau, j, value, tt, tj, used, y = kernel(
        piece.W,
        piece.Y,
        region.mupow,
        region.amupow,
        piece.sig,
        region.absd,
        _TOL_ULPS,
        float(tau_end),
        mask,
        min(budget.left, 1 << 62),
        model.C,
        model.d,
        model.cc,
    )
    budget.take(used, piece.t0 + tau)  # (over the budget: raises, naming the time)
    tangs = list(zip(tt.tolist(), tj.tolist(), strict=True)) if tt.size else []
    if status == scan_kernel.CROSSING:
        piece.y_scan = y
        return (tau, j), tangs
    if status == scan_kernel.OVERFLOW:
        raise PerturbError(
            f"the orbit escapes to infinity in region {piece.region.key} near t = "
            f"{piece.t0 + tau!r} (floating-point overflow); shorten the interval"
        )
    if status == scan_kernel.UNDECIDED:
        raise PerturbError(
            f"the switch scan of surface {j} could not decide near t = {piece.t0 + tau!r} "
            f"after {_MAX_NODES} halvings (the switching function stays within rounding of "
            "zero there)"
        )
    if status == scan_kernel.WRONG_SIDE:
        raise PerturbError(
            f"the state at t = {piece.t0 + tau!r} is on the wrong side of surface "
            f"{j} (s = {value!r}) for region {piece.region.key}: the "
            "propagation lost track of the region (a non-finite or huge state?)"
        )
    piece.y_scan = y
    return None, tangs


# --------------------------------------------------------------------------------------------
# the propagator
# --------------------------------------------------------------------------------------------
@dataclass
class _Run:
    pieces: list  # (t_start, t_end, piece)
    events: list  # AffineEvent, crossings and tangencies
    crossings: list  # AffineEvent, crossings only, piece i ends with crossings[i]
    y: np.ndarray
    n_grid: int


def _check_args(system, y0, t0, t1, max_events, max_steps) -> tuple[np.ndarray, float, float]:
    if not isinstance(system, PiecewiseAffineSystem):
        raise ParameterError(f"system = {system!r}: expected a PiecewiseAffineSystem")
    try:
        y = np.array(y0, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ParameterError(f"y0 = {y0!r}: expected {system.n} finite numbers") from None
    if y.size != system.n or not np.isfinite(y).all():
        raise ParameterError(
            f"y0 = {y.tolist()!r}: expected {system.n} finite numbers "
            f"({', '.join(system.state_names)})"
        )
    try:
        t0, t1 = float(t0), float(t1)
    except (TypeError, ValueError):
        raise ParameterError(f"(t0, t1) = ({t0!r}, {t1!r}): expected numbers") from None
    if not (math.isfinite(t0) and math.isfinite(t1) and t1 > t0):
        raise ParameterError(f"(t0, t1) = ({t0!r}, {t1!r}): expected finite t1 > t0")
    for name, val in (("max_events", max_events), ("max_steps", max_steps)):
        if isinstance(val, bool) or not isinstance(val, (int, np.integer)) or val < 0:
            raise ParameterError(f"{name} = {val!r}: expected a non-negative integer")
    return y, t0, t1


def _run(model: _Model, y0: np.ndarray, t0: float, t1: float, max_events: int, max_steps: int):
    """Propagate ``y0`` (the system's units) over ``[t0, t1]``: the pieces work on the scaled
    state ``z = y / D``; the events and the final state are in the system's units."""
    D = model.D
    z0 = y0 * model.Dinv if model.scaled else y0
    key, on = model.initial_pattern(t0, z0)
    budget = _Budget(max_steps)
    t, y = t0, z0
    touching = on
    pieces: list = []
    events: list[AffineEvent] = []
    crossings: list[AffineEvent] = []
    recent: list[float] = []
    labels = model.system.surfaces
    while True:
        region = model.region(key)
        piece = region.piece(t, y)
        hit, tangs = _scan(piece, t1 - t, touching, budget)
        for tau, j in tangs:
            yt = piece.state1(tau)
            # inside side +1 (s >= 0) touches from above: a minimum of s, direction -1
            events.append(AffineEvent(t + tau, j, -key[j], key, key, yt * D, True))
        if hit is None:
            pieces.append((t, t1, piece))
            break
        tau, j = hit
        t_c = t + tau
        y_scan = getattr(piece, "y_scan", None)  # (the compiled scan: already on the surface)
        y_c = piece.state1(tau) if y_scan is None else y_scan
        if not (np.isfinite(y_c).all() and math.isfinite(t_c)):
            raise PerturbError(
                f"a switch at t = {t_c!r} with a non-finite state in region {key}: overflow"
            )
        if y_scan is None:
            # exactly onto the surface (rounding of the closed form leaves s ~ eps off)
            y_c = y_c - model.C[j] * ((model.C[j] @ y_c - model.d[j]) / model.cc[j])
        new = key[:j] + (-key[j],) + key[j + 1 :]
        model.region(new)  # a missing region is a ModelError naming the pattern
        if not model.continuous[j]:
            rate = float(model.C[j] @ model.field(new, t_c, y_c))
            if rate * new[j] <= 0.0:
                raise PerturbError(
                    f"sliding on the surface {labels[j].label!r} at t = {t_c!r}: the field "
                    f"jumps there and points into the surface from both sides (regions {key} "
                    f"and {new}); {EVENT_DRIVEN_HINT}"
                )
        pieces.append((t, t_c, piece))
        ev = AffineEvent(t_c, j, new[j], key, new, y_c * D, False)
        events.append(ev)
        crossings.append(ev)
        if len(events) > max_events:
            raise PerturbError(
                f"more than max_events = {max_events} events before t = {t1!r} (reached "
                f"t = {t_c!r}); raise max_events or shorten the interval"
            )
        recent.append(t_c)
        if len(recent) > _ZENO_COUNT:
            recent.pop(0)
            if recent[-1] - recent[0] <= 1e-9 * max(1.0, abs(t_c)):
                raise PerturbError(
                    f"{_ZENO_COUNT} switches within {recent[-1] - recent[0]:.3g} time units "
                    f"near t = {t_c!r} (Zeno behaviour or sliding on "
                    f"{labels[j].label!r}); {EVENT_DRIVEN_HINT}"
                )
        t, y, key, touching = t_c, y_c, new, {j}
    t_last, _, last = pieces[-1]
    y_scan = getattr(last, "y_scan", None)
    y_end = (last.state1(t1 - t_last) if y_scan is None else y_scan) * D
    if not np.isfinite(y_end).all():
        raise PerturbError(
            f"the orbit escapes to infinity in region {last.region.key} before t = {t1!r} "
            "(floating-point overflow); shorten the interval"
        )
    events.sort(key=lambda e: e.time)
    return _Run(pieces, events, crossings, y_end, budget.used)


_REPRESENTATIONS = ("auto", "modal", "expm")


def propagate(
    system: PiecewiseAffineSystem,
    y0: ArrayLike,
    t0: float,
    t1: float,
    *,
    max_events: int = 1_000_000,
    max_steps: int = 50_000_000,
    dense: bool = False,
    representation: str = "auto",
) -> AffinePropagation:
    r"""Propagate a piecewise-affine system exactly, region by region, in closed form.

    Parameters
    ----------
    system : PiecewiseAffineSystem
    y0 : array_like, shape (n,)
        State at ``t0``.  On a surface the side is the one the field moves into.
    t0, t1 : float
        The interval, ``t1 > t0``.
    max_events : int
        Largest number of events (crossings plus tangencies) before giving up.
    max_steps : int
        Largest number of grid intervals scanned for switches before giving up.
    dense : bool
        Also return the exact dense trajectory.
    representation : {"auto", "modal", "expm"}
        The closed form of each region: ``"auto"`` takes the eigen-decomposition when its
        eigenvectors are well conditioned, else the augmented matrix exponential; the other
        two force one (``"modal"`` raises for an ill-conditioned region).

    Returns
    -------
    AffinePropagation
        ``(y, events, trajectory, stats)``.

    Raises
    ------
    ParameterError
        Bad ``y0``, interval, limits or representation.
    ModelError
        The orbit reaches a sign pattern that names no region.
    PerturbError
        Sliding on a discontinuity, Zeno behaviour, more than ``max_events`` events or
        ``max_steps`` grid intervals, or overflow (an orbit escaping to infinity).

    Examples
    --------
    >>> sys_ = PiecewiseAffineSystem.build(
    ...     ("x", "v"), [((1.0, 0.0), 1.0)],
    ...     {(1,): ([[0, 1], [-5, -0.1]], (0, 4)), (-1,): ([[0, 1], [-1, -0.1]], (0, 0))},
    ...     inputs=[(1.0, (0.0, 2.0), (0.0, 0.0))])
    >>> y, events, traj, stats = propagate(sys_, (0.0, 0.0), 0.0, 20.0, dense=True)
    >>> traj(10.0).shape
    (2,)
    """
    y, t0, t1 = _check_args(system, y0, t0, t1, max_events, max_steps)
    if representation not in _REPRESENTATIONS:
        raise ParameterError(
            f"representation = {representation!r}: expected one of {_REPRESENTATIONS}"
        )
    model = _model_of(system, representation)
    run = _run(model, y, t0, t1, int(max_events), int(max_steps))
    return _result(model, run, t0, t1, dense)


def _result(model: _Model, run: _Run, t0: float, t1: float, dense: bool) -> AffinePropagation:
    n_tan = sum(1 for e in run.events if e.tangency)
    stats = AffineStats(
        n_pieces=len(run.pieces),
        n_crossings=len(run.crossings),
        n_tangencies=n_tan,
        n_grid=run.n_grid,
        n_expm_pieces=sum(1 for _, _, p in run.pieces if p.region.kind == "expm"),
    )
    traj = AffineTrajectory(model.system, run.pieces, run.events, (t0, t1)) if dense else None
    return AffinePropagation(run.y.copy(), tuple(run.events), traj, stats)


def _sensitivity(model: _Model, run: _Run) -> np.ndarray:
    """Product of the region exponentials and the saltation matrices at the crossings."""
    M = model.eye
    for i, (ta, tb, piece) in enumerate(run.pieces):
        h = tb - ta
        E = piece.region.transition(h)
        if piece.region.kind == "modal":
            piece.trans = (h, E)  # (reused by callers that need e^{A h} again, see
            # AffineTrajectory.transition)
        M = E @ M
        if i < len(run.crossings):
            ev = run.crossings[i]
            j = ev.surface
            if model.continuous[j]:
                continue  # S = I exactly: f+ = f- on the surface
            z = ev.y * model.Dinv  # (exact: powers of two)
            fm = model.field(ev.pattern_before, ev.time, z)
            fp = model.field(ev.pattern_after, ev.time, z)
            c = model.C[j]
            rate = float(c @ fm)
            if rate == 0.0:
                raise PerturbError(
                    f"the orbit crosses the discontinuity {model.system.surfaces[j].label!r} "
                    f"at t = {ev.time!r} tangentially (c . f = 0): the saltation matrix is "
                    "unbounded and the flow is not differentiable there"
                )
            M = M + np.outer(fp - fm, c @ M) / rate
    if model.scaled:
        M = model.D[:, None] * M * model.Dinv[None, :]  # dy1/dy0 = D (dz1/dz0) D^-1
    if M is model.eye:
        M = M.copy()
    if not np.isfinite(M).all():
        raise PerturbError("the sensitivity overflows (non-finite): shorten the interval")
    return M


class AffineExactFlow(Flow):
    r"""Exact flow (and exact sensitivity) of a piecewise-affine n-dimensional system.

    Parameters
    ----------
    system : PiecewiseAffineSystem
    representation : {"auto", "modal", "expm"}
        See :func:`propagate`.
    max_events : int
        Per call.

    Attributes
    ----------
    affine_system : PiecewiseAffineSystem
        The system (the declared ``system`` capability of :class:`Flow` stays None: it names
        the scalar :class:`~perturb.simulate.flows.piecewise_exact.PWLSystem` that the
        one-coordinate orbit tools read).
    period : float or None
        The system's forcing period.

    Examples
    --------
    >>> sys_ = PiecewiseAffineSystem.build(
    ...     ("x", "v"), [((1.0, 0.0), 1.0)],
    ...     {(1,): ([[0, 1], [-5, -0.1]], (0, 4)), (-1,): ([[0, 1], [-1, -0.1]], (0, 0))},
    ...     inputs=[(1.0, (0.0, 2.0), (0.0, 0.0))], period=2 * 3.141592653589793)
    >>> flow = AffineExactFlow(sys_)
    >>> flow([0.0, 0.0], 0.0, flow.period, sensitivity=True).sensitivity.shape
    (2, 2)
    """

    #: ``trajectory`` gives the exact dense output (declared capability, see Flow)
    exact_dense_output = True

    def __init__(
        self,
        system: PiecewiseAffineSystem,
        *,
        representation: str = "auto",
        max_events: int = 1_000_000,
    ) -> None:
        if not isinstance(system, PiecewiseAffineSystem):
            raise ParameterError(f"system = {system!r}: expected a PiecewiseAffineSystem")
        if representation not in _REPRESENTATIONS:
            raise ParameterError(
                f"representation = {representation!r}: expected one of {_REPRESENTATIONS}"
            )
        self.affine_system = system
        self.period = system.period
        self.max_events = int(max_events)
        # the region data (eigen-decompositions, particular solutions) depend only on the
        # immutable system: shared by every flow of the same system object, as the SDOF
        # propagator keeps its segment data on its PWLSystem
        self._model = _model_of(system, representation)
        self._memo: tuple[tuple, _Run] | None = None
        C = np.array([sf.normal for sf in system.surfaces], dtype=float).reshape(-1, system.n)
        self._C0, self._d0 = C, np.array([sf.offset for sf in system.surfaces], dtype=float)

    @property
    def autonomous(self) -> bool:
        """No harmonic input."""
        return not self.affine_system.inputs

    def __repr__(self) -> str:
        return (
            f"AffineExactFlow(n={self.affine_system.n}, "
            f"surfaces={len(self.affine_system.surfaces)}, period={self.period})"
        )

    def vector_field(self, t: float, y: ArrayLike) -> np.ndarray:
        """``A y + b + inputs(t)`` of the region holding ``y`` (``s_j = 0`` counts as +1).

        The arithmetic of :meth:`PiecewiseAffineSystem.field` with the sign pattern from one
        matrix-vector product (orbit statistics call this at every root iterate)."""
        sys_ = self.affine_system
        y = np.asarray(y, dtype=float)
        t = float(t)
        key = tuple([1 if s >= 0.0 else -1 for s in (self._C0 @ y - self._d0).tolist()])
        reg = sys_.regions.get(key)
        if reg is None:
            reg = sys_.region(key)  # ModelError naming the pattern
        out = reg.A @ y + reg.b
        for h in sys_.inputs:
            out = out + h.u * math.cos(h.omega * t) + h.v * math.sin(h.omega * t)
        return out

    def _propagate(self, y0: ArrayLike, t0: float, t1: float) -> _Run:
        y, t0, t1 = _check_args(self.affine_system, y0, t0, t1, self.max_events, 50_000_000)
        key = (tuple(y.tolist()), t0, t1)
        if self._memo is not None and self._memo[0] == key:
            return self._memo[1]
        run = _run(self._model, y, t0, t1, self.max_events, 50_000_000)
        self._memo = (key, run)
        return run

    def trajectory(self, y0: ArrayLike, t0: float, t1: float) -> AffineTrajectory:
        """The exact dense trajectory on ``[t0, t1]`` (memoised for the last arguments)."""
        run = self._propagate(y0, t0, t1)
        return AffineTrajectory(self.affine_system, run.pieces, run.events, (t0, t1))

    def __call__(
        self,
        y0: ArrayLike,
        t0: float,
        t1: float,
        *,
        sensitivity: bool = False,
        t_eval: ArrayLike | None = None,
    ) -> FlowResult:
        """Propagate ``y0`` from ``t0`` to ``t1 > t0``; see
        :class:`~perturb.simulate.flows.base.Flow` (states have ``n`` entries).

        Raises
        ------
        ParameterError
            Bad ``y0`` or interval, ``t_eval`` outside ``[t0, t1]``.
        PerturbError
            As :func:`propagate`; with ``sensitivity=True`` also a tangential crossing of a
            discontinuity (unbounded saltation).
        """
        run = self._propagate(y0, t0, t1)
        sens = _sensitivity(self._model, run) if sensitivity else None
        t_out = ys = None
        if t_eval is not None:
            t_out = np.asarray(t_eval, dtype=float).reshape(-1)
            traj = AffineTrajectory(self.affine_system, run.pieces, run.events, (t0, t1))
            ys = traj(t_out).T.copy() if t_out.size else np.empty((0, self.affine_system.n))
        return FlowResult(
            t0=float(t0),
            t1=float(t1),
            y=run.y.copy(),
            sensitivity=sens,
            t=t_out,
            ys=ys,
            n_events=len(run.crossings),
        )
