r"""Exact piecewise-analytic propagation of forced oscillators with a piecewise-linear force.

The system is

.. math::

    \ddot x + \mu \dot x + f(x) = c + \sum_j F_j \cos(\omega_j t + \varphi_j),
    \qquad f(x) = s_i x + o_i \quad \text{for } d_i \le x < d_{i+1},

with strictly increasing breakpoints :math:`d_1 < \dots < d_m` (segment ``i`` lies between
``breakpoints[i-1]`` and ``breakpoints[i]``; ``d_0 = -\infty``, ``d_{m+1} = +\infty``).  The force
may be continuous or jump at a breakpoint, slopes may be negative or zero and
:math:`\mu \ge 0`.

Closed form in one segment
--------------------------
With :math:`y = (x, \dot x)`, :math:`A = \begin{pmatrix}0 & 1\\ -s & -\mu\end{pmatrix}`,
:math:`p = -\mu/2`, :math:`q = p^2 - s` and :math:`N = A - pI` (so :math:`N^2 = qI`),

.. math::

    e^{A\tau} = e^{p\tau}\bigl(C(\tau)\,I + S(\tau)\,N\bigr),\qquad
    (C, S) = \begin{cases}
        (\cos\beta\tau,\ \sin(\beta\tau)/\beta) & q = -\beta^2 < 0 \\
        (1,\ \tau) & q = 0 \\
        (\cosh\beta\tau,\ \sinh(\beta\tau)/\beta) & q = \beta^2 > 0
    \end{cases}

which covers complex, repeated and real roots (saddles :math:`s < 0` and :math:`s = 0`
included) without the cancellation of the distinct-root formula near a repeated root:
:math:`\sin(\beta\tau)/\beta` and :math:`\sinh(\beta\tau)/\beta` are evaluated directly and are
accurate for every small :math:`\beta`; for :math:`\beta\tau > 1` the real case switches to
:math:`\tfrac12(e^{\lambda_1\tau} \pm e^{\lambda_2\tau})` so that :math:`e^{p\tau}` and
:math:`\cosh\beta\tau` never overflow separately.

Each harmonic gets the particular solution
:math:`x_p = \operatorname{Re}\bigl(F e^{i(\omega t+\varphi)}/\delta\bigr)`,
:math:`\delta = s - \omega^2 + i\mu\omega`.  Near resonance (:math:`q < 0` and a root
:math:`\lambda` with :math:`|\lambda - i\omega| < \omega/4`, which includes the undamped exact
resonance :math:`s = \omega^2, \mu = 0`) the response from zero initial data is used instead,

.. math::

    y_F(\tau) = \operatorname{Re}\Bigl(G e^{i\omega\tau}\int_0^\tau e^{(A - i\omega)\sigma}
    d\sigma\; e_2\Bigr),\qquad G = F e^{i(\omega t_0 + \varphi)},

evaluated with :math:`\varphi_1(z) = (e^z - 1)/z` at the two shifted roots
:math:`\nu_\pm = p - i\omega \pm \sqrt q`.  It contains the secular
:math:`t\sin` term at exact resonance and has no :math:`1/\delta` cancellation near it, so
**exact resonance is implemented, not rejected**.

The constant load :math:`g = c - o_i` gives :math:`x_c = g/s` when that is well conditioned
(:math:`|g/s| \le 10^3 (1 + \max|d|)`); otherwise (:math:`s = 0`, :math:`s \to 0`) its response
from zero initial data :math:`g\,(H_1(\tau), h(\tau))` is used, with :math:`h = e^{p\tau}S` and
:math:`H_1 = \int_0^\tau h = \tau^2\, e[0, \lambda_1\tau, \lambda_2\tau]` (a divided difference
of ``exp``), evaluated by its series :math:`\sum_k h_k/(k+2)!` (complete symmetric
polynomials of the scaled roots, real recurrence) while :math:`|\lambda|\tau \le 1`, by
:math:`(1 - \Phi_{11})/s` when :math:`|s|\tau^2 \ge 0.1`, and by the well separated real
divided difference otherwise.  This reproduces :math:`x = g\tau/\mu + \dots` for :math:`s = 0`,
:math:`\mu > 0` and :math:`x = g\tau^2/2` for :math:`s = \mu = 0`.

Switching
---------
In a segment the orbit is scanned with steps of at most ``h`` = 1/16 of the shortest time
scale (forcing periods, damped period, :math:`1/|\lambda|`), in scalar closed-form
evaluations.  From each node an *exclusion step* comes first: with the distance
:math:`\hat g` to a boundary, its rate :math:`\hat g'` and a rigorous bound :math:`A` of
:math:`|a|` ahead (the damped-cosine amplitude of the homogeneous part times
:math:`e^{p\tau}` plus :math:`\sum\omega_j^2|Z_j|`; monotone exponentials for real roots),
:math:`\hat g(\tau + s) \ge \hat g + \hat g' s - A s^2/2`, so no crossing and no tangency
lies where that stays above ``2 tol``; when this stretch is longer than ``h`` the scan jumps
over it (quasi-static motion deep inside a segment costs a few evaluations instead of a
grid).  Otherwise one grid step is taken.  A step is examined in detail only if the
boundary could be reached inside it: with :math:`\hat g = \pm(x - d) > 0` inside, a step is
flagged when
:math:`\min(\hat g_k, \hat g_{k+1}) \le \max(|a_k|, |a_{k+1}|) h^2/4 + \text{tol}`
(an interior minimum :math:`\le 0` forces :math:`\min \le A h^2/8`).  In a flagged step the
extrema of :math:`x` (roots of :math:`v`; two of them when the acceleration changes sign and
:math:`v` dips through zero) split it into monotone pieces, so a grazing orbit that touches the
boundary and turns back between two grid points is not missed (the step is short enough that
:math:`x` has at most two extrema in it: each component turns by at most 1/16 of a cycle).
Every root (crossing, extremum of x, extremum of v) is solved on the closed form inside its
bracket by a safeguarded Newton–bisection iteration (the derivative is exact: v, a or the
jerk), which never leaves the bracket and stops at full double precision of the local time
(``4 eps``); it needs about half the closed-form evaluations of :func:`scipy.optimize.brentq`.
The state is then placed exactly on the boundary and the next segment starts there.  A minimum
with :math:`|\hat g| \le` tol (a few rounding units of the terms of :math:`x`), or a crossing
whose penetration depth :math:`v^2/(2|a|)` is below tol, is a *tangency*: it is logged and the
segment is kept.

Discontinuous forces: when both neighbouring fields push into a breakpoint (sticking /
sliding, or an excursion of negligible depth that would chatter) a :class:`PerturbError` is
raised that points to the event-driven solver; a repelling discontinuity reached at rest is
non-unique and also raises.

Limitations
-----------
* Grazing is resolved to the rounding level of :math:`x`: an orbit that grazes a breakpoint
  *exactly* may be logged as a tangency or as a pair of crossings with :math:`|v|` of order
  :math:`\sqrt{\text{tol}}`, depending on rounding (harmless for a continuous force; across a
  jump the sensitivity of such an orbit is unbounded for any integrator).
* The bracketing assumes at most two extrema of :math:`x` per grid step, which the step
  (1/16 of the fastest component) guarantees for each component but not for contrived sums.
* Very fast decaying modes (large :math:`\mu` or :math:`|s|`) shrink the grid step for the
  whole segment visit; the cost grows accordingly, the accuracy does not suffer.
* Sliding and sticking on a discontinuity are not integrated (see above).
"""

from __future__ import annotations

import bisect
import cmath
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from perturb import checks
from perturb.errors import ParameterError, PerturbError

__all__ = [
    "PWLSystem",
    "SwitchEvent",
    "Piece",
    "PieceEvaluator",
    "PropagationStats",
    "Trajectory",
    "propagate",
    "sample_trajectories",
]

_EPS = float(np.finfo(float).eps)
_TWO_PI = 2.0 * math.pi
#: grid steps per shortest time scale of a segment (bracketing resolution)
_STEPS_PER_SCALE = 16
#: terms of the divided-difference series for H1 (|scaled roots| <= 1: error < 1e-20)
_SERIES_TERMS = 22
#: |g/s| above this multiple of the system scale switches the constant load to the zero-IC form
_CONST_COND = 1.0e3
#: a harmonic is treated as resonant when a root lies within this fraction of omega of i*omega
_RESONANCE_BAND = 0.25
#: tangency tolerance, in rounding units of the magnitude of the terms of x(t)
_TOL_ULPS = 32.0
#: an excursion across a discontinuity shallower than this many tol is treated as chattering
_CHATTER_TOLS = 64.0

EVENT_DRIVEN_HINT = (
    "use the event-driven solver for piecewise-smooth systems "
    "(perturb.simulate.flows.event_driven), "
    "which handles sticking and sliding"
)


# --------------------------------------------------------------------------------------------
# validation helpers
# --------------------------------------------------------------------------------------------
def _finite_float(name: str, value: object) -> float:
    return checks.finite(value, name)


def _finite_vector(name: str, value: ArrayLike) -> np.ndarray:
    try:
        arr = np.array(value, dtype=float).reshape(-1) if np.ndim(value) <= 1 else None
    except (TypeError, ValueError):
        raise ParameterError(f"{name} = {value!r}: expected a 1-D sequence of reals") from None
    if arr is None:
        raise ParameterError(f"{name} = {value!r}: expected a 1-D sequence of reals")
    if not np.all(np.isfinite(arr)):
        raise ParameterError(f"{name} = {arr.tolist()!r}: expected finite values")
    arr.setflags(write=False)
    return arr


def _pair(value: object) -> tuple[float, float]:
    """Two floats from a length-2 sequence or array (NaN when it is not one: the caller then
    validates the value properly, with a message)."""
    if isinstance(value, np.ndarray) and value.shape != (2,):
        return math.nan, math.nan
    try:
        a, b = value  # type: ignore[misc]
        return float(a), float(b)
    except (TypeError, ValueError):
        return math.nan, math.nan


# --------------------------------------------------------------------------------------------
# public data objects
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class PWLSystem:
    r"""Oscillator :math:`\ddot x + \mu\dot x + f(x) = c + \sum_j F_j\cos(\omega_j t+\varphi_j)`.

    Parameters
    ----------
    breakpoints : array_like, shape (m,)
        Strictly increasing breakpoints :math:`d_1 < \dots < d_m` (``m = 0`` is a linear system).
    slopes, offsets : array_like, shape (m + 1,)
        :math:`f(x) = s_i x + o_i` on segment ``i``, which lies between ``breakpoints[i-1]`` and
        ``breakpoints[i]``.  At a breakpoint the force is taken from the segment above
        (right-continuous); the propagator never needs that convention.
    damping : float
        :math:`\mu \ge 0`.
    forcing : tuple of (F_j, omega_j, phi_j)
        Harmonic loads; :math:`\omega_j > 0`.
    static_force : float
        Constant load :math:`c`.

    Examples
    --------
    Zou–Nagarajaiah negative-stiffness device, :math:`k = -2`:

    >>> k = -2.0
    >>> nsd = PWLSystem([-1.0, 1.0], [1.0, k, 1.0], [1.0 - k, 0.0, k - 1.0], damping=0.05,
    ...                 forcing=((2.0, 0.6, 0.0),))
    >>> float(nsd.force(2.0))
    -1.0
    """

    breakpoints: np.ndarray
    slopes: np.ndarray
    offsets: np.ndarray
    damping: float = 0.0
    forcing: tuple[tuple[float, float, float], ...] = ()
    static_force: float = 0.0

    def __post_init__(self) -> None:
        bp = _finite_vector("breakpoints", self.breakpoints)
        sl = _finite_vector("slopes", self.slopes)
        of = _finite_vector("offsets", self.offsets)
        if bp.size and np.any(np.diff(bp) <= 0.0):
            raise ParameterError(
                f"breakpoints = {bp.tolist()!r}: expected strictly increasing values"
            )
        if sl.size != bp.size + 1:
            raise ParameterError(
                f"slopes has length {sl.size} ({sl.tolist()!r}): expected len(breakpoints) + 1 "
                f"= {bp.size + 1}"
            )
        if of.size != bp.size + 1:
            raise ParameterError(
                f"offsets has length {of.size} ({of.tolist()!r}): expected len(breakpoints) + 1 "
                f"= {bp.size + 1}"
            )
        mu = _finite_float("damping", self.damping)
        if mu < 0.0:
            raise ParameterError(f"damping = {mu!r}: expected mu >= 0")
        c = _finite_float("static_force", self.static_force)
        terms = []
        forcing = self.forcing
        if forcing is None:
            forcing = ()
        try:
            items = list(forcing)
        except TypeError:
            raise ParameterError(
                f"forcing = {forcing!r}: expected a sequence of (amplitude, omega, phase)"
            ) from None
        for j, term in enumerate(items):
            try:
                amp, om, ph = term
            except (TypeError, ValueError):
                raise ParameterError(
                    f"forcing[{j}] = {term!r}: expected (amplitude, omega, phase)"
                ) from None
            amp = _finite_float(f"forcing[{j}] amplitude", amp)
            om = _finite_float(f"forcing[{j}] omega", om)
            ph = _finite_float(f"forcing[{j}] phase", ph)
            if om <= 0.0:
                raise ParameterError(
                    f"forcing[{j}] omega = {om!r}: expected omega > 0 (put constant loads in "
                    "static_force)"
                )
            terms.append((amp, om, ph))
        object.__setattr__(self, "breakpoints", bp)
        object.__setattr__(self, "slopes", sl)
        object.__setattr__(self, "offsets", of)
        object.__setattr__(self, "damping", mu)
        object.__setattr__(self, "static_force", c)
        object.__setattr__(self, "forcing", tuple(terms))

    # -- construction helpers -----------------------------------------------------------------
    @classmethod
    def continuous(
        cls,
        breakpoints: ArrayLike,
        slopes: ArrayLike,
        offset0: float = 0.0,
        **kwargs: object,
    ) -> PWLSystem:
        r"""Continuous PWL force from its slopes and the offset of segment 0.

        Offsets follow from continuity, :math:`o_{i} = o_{i-1} + (s_{i-1} - s_{i}) d_i`.
        """
        bp = _finite_vector("breakpoints", breakpoints)
        sl = _finite_vector("slopes", slopes)
        if sl.size != bp.size + 1:
            raise ParameterError(
                f"slopes has length {sl.size}: expected len(breakpoints) + 1 = {bp.size + 1}"
            )
        off = [_finite_float("offset0", offset0)]
        for i, d in enumerate(bp):
            off.append(off[-1] + (sl[i] - sl[i + 1]) * d)
        return cls(bp, sl, np.array(off), **kwargs)  # type: ignore[arg-type]

    def with_forcing(self, forcing: Sequence[tuple[float, float, float]]) -> PWLSystem:
        """The same force, damping and static load with other harmonic loads.

        Frequency sweeps and continuation build thousands of systems that differ only in the
        forcing; this skips re-validating the (already validated, read-only) force arrays."""
        out = object.__new__(PWLSystem)
        for name in ("breakpoints", "slopes", "offsets", "damping", "static_force"):
            object.__setattr__(out, name, getattr(self, name))
        terms = []
        for term in forcing:
            try:
                amp, om, ph = (float(z) for z in term)
            except (TypeError, ValueError):
                amp = om = ph = math.nan
            if not (math.isfinite(amp) and math.isfinite(om) and math.isfinite(ph) and om > 0):
                # the full constructor names the bad value
                return PWLSystem(
                    self.breakpoints,
                    self.slopes,
                    self.offsets,
                    damping=self.damping,
                    forcing=tuple(forcing),
                    static_force=self.static_force,
                )
            terms.append((amp, om, ph))
        object.__setattr__(out, "forcing", tuple(terms))
        cont = self.__dict__.get("_continuous")
        if cont is not None:  # the same force: the same continuity
            object.__setattr__(out, "_continuous", cont)
        return out

    # -- queries -------------------------------------------------------------------------------
    @property
    def n_segments(self) -> int:
        """Number of linear segments, ``len(breakpoints) + 1``."""
        return int(self.slopes.size)

    @property
    def jumps(self) -> np.ndarray:
        r"""Jumps :math:`f(d_i^+) - f(d_i^-)` of the force at the breakpoints."""
        d = self.breakpoints
        return (self.slopes[1:] - self.slopes[:-1]) * d + (self.offsets[1:] - self.offsets[:-1])

    def continuous_at(self) -> np.ndarray:
        """Boolean per breakpoint: the jump is zero up to rounding of the two linear pieces
        (read-only; computed once per system, which every flow of a continuation asks)."""
        out = self.__dict__.get("_continuous")
        if out is None:
            d = self.breakpoints
            scale = np.abs(self.slopes[1:] * d) + np.abs(self.offsets[1:])
            scale = scale + np.abs(self.slopes[:-1] * d) + np.abs(self.offsets[:-1])
            out = np.abs(self.jumps) <= 8.0 * _EPS * scale
            out.setflags(write=False)
            object.__setattr__(self, "_continuous", out)
        return out

    def segment_of(self, x: ArrayLike) -> np.ndarray:
        """Segment index of ``x`` (a point on a breakpoint belongs to the segment above)."""
        return np.searchsorted(self.breakpoints, np.asarray(x, dtype=float), side="right")

    def force(self, x: ArrayLike) -> np.ndarray:
        r"""Restoring force :math:`f(x)`, vectorised (right-continuous at jumps)."""
        xa = np.asarray(x, dtype=float)
        i = self.segment_of(xa)
        return self.slopes[i] * xa + self.offsets[i]

    def load(self, t: ArrayLike) -> np.ndarray:
        r"""External load :math:`c + \sum_j F_j \cos(\omega_j t + \varphi_j)`."""
        ta = np.asarray(t, dtype=float)
        out = np.full(ta.shape, self.static_force)
        for amp, om, ph in self.forcing:
            out = out + amp * np.cos(om * ta + ph)
        return out

    def rhs(self, t: float, y: ArrayLike) -> np.ndarray:
        r"""First-order right-hand side :math:`(v,\ c + \text{forcing} - \mu v - f(x))`."""
        x, v = np.asarray(y, dtype=float)[:2]
        if np.ndim(t) == 0 and np.ndim(x) == 0:
            # one state (shooting, root refinement): the segment's scalar field
            model = _model_of(self)
            x, v, tt = float(x), float(v), float(t)
            seg = model.segments[bisect.bisect_right(model.bp_list, x)]
            return np.array([v, seg.accel_at(tt, x, v)])
        return np.array([v, self.load(t) - self.damping * v - self.force(x)], dtype=float)

    def field1(self, t: float, x: float, v: float) -> tuple[float, float]:
        """:meth:`rhs` of one state as a pair of floats, without array conversions (the
        same arithmetic: callers that evaluate it per node or per extremum get identical
        values)."""
        model = _model_of(self)
        return v, model.segments[bisect.bisect_right(model.bp_list, x)].accel_at(t, x, v)

    # -- identity -------------------------------------------------------------------------------
    def _key(self) -> tuple:
        return (
            tuple(self.breakpoints.tolist()),
            tuple(self.slopes.tolist()),
            tuple(self.offsets.tolist()),
            self.damping,
            self.forcing,
            self.static_force,
        )

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, PWLSystem):
            return NotImplemented
        return self._key() == other._key()

    def __hash__(self) -> int:
        return hash(self._key())

    def __repr__(self) -> str:
        return (
            f"PWLSystem(breakpoints={self.breakpoints.tolist()!r}, "
            f"slopes={self.slopes.tolist()!r}, offsets={self.offsets.tolist()!r}, "
            f"damping={self.damping!r}, forcing={self.forcing!r}, "
            f"static_force={self.static_force!r})"
        )


@dataclass(frozen=True)
class SwitchEvent:
    """A crossing of a breakpoint, or a tangency (touch and turn back, no switch).

    Attributes
    ----------
    time : float
        Event time.
    breakpoint : int
        Index into ``system.breakpoints``.
    direction : int
        ``+1``: crossing upwards, or touching from below (a maximum of x); ``-1`` otherwise.
    x, v : float
        State at the event (``x`` is exactly the breakpoint for a crossing).
    tangency : bool
        ``True`` for a tangency (the segment is kept).
    segment_before, segment_after : int
        Segments before and after (equal for a tangency).
    """

    time: float
    breakpoint: int
    direction: int
    x: float
    v: float
    tangency: bool
    segment_before: int
    segment_after: int

    @property
    def state(self) -> tuple[float, float]:
        """``(x, v)`` at the event."""
        return (self.x, self.v)


@dataclass(frozen=True)
class Piece:
    """One closed-form piece: the solution in ``segment`` from ``(x0, v0)`` at ``t0``."""

    t0: float
    segment: int
    x0: float
    v0: float


@dataclass(frozen=True)
class PropagationStats:
    """Work counters of one :func:`propagate` call."""

    n_pieces: int
    n_switches: int
    n_tangencies: int
    n_grid_points: int
    n_root_solves: int


@dataclass(frozen=True, eq=False)
class Trajectory:
    """Result of :func:`propagate`: samples, event log and exact dense output.

    Attributes
    ----------
    t, x, v : ndarray
        Samples at ``t_eval``, or at the piece starts (switch times) plus the final time.
    events : tuple of SwitchEvent
        Crossings and tangencies in time order.
    n_segments : int
        Number of closed-form pieces used.
    pieces : tuple of Piece
        Start time, segment and initial state of every piece.
    stats : PropagationStats
        Work counters.
    system : PWLSystem
    t_span : tuple of float
    """

    t: np.ndarray
    x: np.ndarray
    v: np.ndarray
    events: tuple[SwitchEvent, ...]
    n_segments: int
    pieces: tuple[Piece, ...]
    stats: PropagationStats
    system: PWLSystem
    t_span: tuple[float, float]
    _evaluators: tuple = field(repr=False, default=())

    @property
    def switches(self) -> tuple[SwitchEvent, ...]:
        """Crossings only (tangencies removed)."""
        return tuple(e for e in self.events if not e.tangency)

    @property
    def tangencies(self) -> tuple[SwitchEvent, ...]:
        """Tangency events only."""
        return tuple(e for e in self.events if e.tangency)

    def __call__(self, t: ArrayLike) -> np.ndarray:
        """Exact state at ``t``: shape ``(2, len(t))`` (``(2,)`` for a scalar ``t``)."""
        ta = np.asarray(t, dtype=float)
        scalar = ta.ndim == 0
        ta = ta.reshape(-1)
        t0, t1 = self.t_span
        span = t1 - t0
        if (
            not np.all(np.isfinite(ta))
            or np.any(ta < t0 - 1e-12 * span)
            or np.any(ta > t1 + 1e-12 * span)
        ):
            raise ParameterError(f"t outside t_span = {self.t_span!r}: expected t0 <= t <= t1")
        pieces = self._evaluators
        starts = self.__dict__.get("_starts")
        if starts is None:
            starts = np.array([p.t0 for p in pieces])
            object.__setattr__(self, "_starts", starts)
        idx = np.clip(np.searchsorted(starts, ta, side="right") - 1, 0, len(starts) - 1)
        out = np.empty((2, ta.size))
        if ta.size == 1:
            # a single time (root refinement of extrema): scalar closed form, no array work
            piece = pieces[int(idx[0])]
            out[0, 0], out[1, 0] = piece.eval1(float(ta[0]) - piece.t0)[:2]
        elif ta.size and np.all(idx[1:] >= idx[:-1]):
            # sorted times: each piece owns one contiguous slice
            cuts = np.flatnonzero(idx[1:] != idx[:-1]) + 1
            lo_ = 0
            for hi_ in (*cuts.tolist(), ta.size):
                piece = pieces[int(idx[lo_])]
                out[0, lo_:hi_], out[1, lo_:hi_] = piece.eval(ta[lo_:hi_] - piece.t0)
                lo_ = hi_
        else:
            for k in np.unique(idx):
                sel = idx == k
                piece = pieces[k]
                xk, vk = piece.eval(ta[sel] - piece.t0)
                out[0, sel] = xk
                out[1, sel] = vk
        return out[:, 0] if scalar else out

    def piece_evaluator(self, index: int) -> PieceEvaluator:
        """The closed form of piece ``index`` (of :attr:`pieces`) as a
        :class:`PieceEvaluator`: the one the dense output evaluates, with the acceleration
        and its time derivative that :meth:`__call__` does not return."""
        pieces = self._evaluators
        if isinstance(index, bool) or not isinstance(index, int | np.integer):
            raise ParameterError(f"index = {index!r}: expected an integer")
        if not -len(pieces) <= index < len(pieces):
            raise ParameterError(f"index = {index!r}: the trajectory has {len(pieces)} pieces")
        return PieceEvaluator._of(pieces[int(index)])

    def transition_matrices(self) -> list[tuple[float, float, float, float]]:
        r"""The exact :math:`e^{A_k h_k}` of every piece, row-major ``(m00, m01, m10, m11)``.

        :math:`e^{A h} = e^{ph}(C I + S N)` with the closed-form ``(C, S)`` of the propagator
        (module docstring), evaluated in scalar arithmetic: for the handful of pieces of one
        forcing period this is several times cheaper than array code."""
        pieces = self._evaluators
        ends = [p.t0 for p in pieces[1:]]
        ends.append(self.t_span[1])
        out = []
        for p, t_end in zip(pieces, ends, strict=True):
            seg = p.seg
            ec, es = seg.ecs1(t_end - p.t0)
            hm = seg.half_mu * es
            out.append((ec + hm, es, -seg.s * es, ec - hm))
        return out


def sample_trajectories(
    trajs: Sequence[Trajectory], t: np.ndarray, owner: np.ndarray
) -> np.ndarray:
    """Exact states at the sorted times ``t``, time ``k`` taken on ``trajs[owner[k]]``.

    The trajectories are consecutive pieces of one orbit (the node intervals of multiple
    shooting) and ``owner`` is non-decreasing; every time must lie in its trajectory's span.
    The result equals ``trajs[owner[k]](t[k])`` up to rounding, but the closed form is
    evaluated once per *segment* of the force over all the samples of its pieces, not once
    per piece: an orbit period has a handful of pieces in two or three segments, and the
    per-call overhead of numpy, not the arithmetic, is what a per-piece evaluation pays.

    Returns
    -------
    ndarray, shape (2, len(t))
    """
    t = np.asarray(t, dtype=float)
    owner = np.asarray(owner)
    pieces: list[_Piece] = []
    gidx = np.empty(t.size, dtype=np.intp)
    cuts = np.searchsorted(owner, np.arange(len(trajs) + 1), side="left").tolist()
    for i, traj in enumerate(trajs):
        lo, hi = cuts[i], cuts[i + 1]
        ev = traj._evaluators
        if hi > lo:
            if len(ev) == 1:
                gidx[lo:hi] = len(pieces)
            else:
                loc = np.searchsorted([q.t0 for q in ev], t[lo:hi], side="right") - 1
                gidx[lo:hi] = np.maximum(loc, 0) + len(pieces)
        pieces.extend(ev)
    out = np.empty((2, t.size))
    # one table of the per-piece data, gathered per sample in one indexing operation
    width = max(len(q.th_list) for q in pieces)
    rows = []
    for q in pieces:
        th = q.th_list + [0.0] * (width - len(q.th_list))
        rows.append((q.t0, q.w0, q.n0, q.w1, q.n1, float(q.seg.idx), *th))
    G = np.array(rows)[gidx]
    segs = {q.seg.idx: q.seg for q in pieces}
    for idx_s, seg in segs.items():
        if len(segs) == 1:
            sel = slice(None)
            Gs = G
        else:
            sel = np.flatnonzero(G[:, 5] == idx_s)
            if sel.size == 0:
                continue
            Gs = G[sel]
        if seg.res or seg.const_mode == "zic":
            # resonant harmonics and the zero-IC constant load carry per-piece terms: the
            # piece's own evaluation (rare: near-resonant segments, zero slopes)
            sel = np.arange(t.size)[sel]
            for k, q in enumerate(pieces):
                if q.seg is seg:
                    sk = sel[gidx[sel] == k]
                    if sk.size:
                        out[0, sk], out[1, sk] = q.eval(t[sk] - q.t0)
            continue
        # the arithmetic of _Piece.eval, element by element
        tau = t[sel] - Gs[:, 0]
        ec, es = seg.ecs(tau)
        x = ec * Gs[:, 1] + es * Gs[:, 2]
        v = ec * Gs[:, 3] + es * Gs[:, 4]
        for j, (_amp, om, _ph, P, Q) in enumerate(seg.std):
            th = Gs[:, 6 + j] + om * tau
            c = np.cos(th)
            sn = np.sin(th)
            x = x + (P * c + Q * sn)
            v = v + om * (Q * c - P * sn)
        if seg.const_mode == "std":
            x = x + seg.xc
        out[0, sel] = x
        out[1, sel] = v
    return out


# --------------------------------------------------------------------------------------------
# closed form of one segment
# --------------------------------------------------------------------------------------------
def _phi1_real(z: np.ndarray) -> np.ndarray:
    """(e^z - 1)/z, vectorised, 1 at z = 0."""
    zs = np.where(z == 0.0, 1.0, z)
    return np.where(z == 0.0, 1.0, np.expm1(zs) / zs)


def _phi1_real_s(z: float) -> float:
    return 1.0 if z == 0.0 else math.expm1(z) / z


def _phi1_complex(z: np.ndarray) -> np.ndarray:
    """(e^z - 1)/z for complex z without cancellation near 0."""
    xr, yi = z.real, z.imag
    # expm1(x + iy) = expm1(x) cos y - 2 sin^2(y/2) + i e^x sin y  (no 1 - cos cancellation)
    num = (np.expm1(xr) * np.cos(yi) - 2.0 * np.sin(0.5 * yi) ** 2) + 1j * (np.exp(xr) * np.sin(yi))
    small = np.abs(z) < 1e-8
    zs = np.where(small, 1.0, z)
    return np.where(small, 1.0 + 0.5 * z + z * z / 6.0, num / zs)


def _phi1_complex_s(z: complex) -> complex:
    if abs(z) < 1e-8:
        return 1.0 + 0.5 * z + z * z / 6.0
    xr, yi = z.real, z.imag
    num = complex(
        math.expm1(xr) * math.cos(yi) - 2.0 * math.sin(0.5 * yi) ** 2,
        math.exp(xr) * math.sin(yi),
    )
    return num / z


class _Segment:
    """Precomputed closed-form data of one linear segment (internal)."""

    __slots__ = (
        "idx", "s", "o", "mu", "half_mu", "g", "p", "q", "kind", "beta", "lam1", "lam2",
        "lam_bound", "const_mode", "xc", "std", "res", "harm", "h", "lo", "hi", "lo_bp",
        "hi_bp", "rate", "p_mag", "a_part", "bounded",
    )  # fmt: skip

    def __init__(
        self,
        idx: int,
        s: float,
        o: float,
        mu: float,
        c: float,
        forcing: tuple[tuple[float, float, float], ...],
        lo: float,
        hi: float,
        scale: float,
    ) -> None:
        self.idx, self.s, self.o, self.mu = idx, s, o, mu
        self.half_mu = 0.5 * mu
        self.g = c - o
        self.lo, self.hi = lo, hi
        self.lo_bp = idx - 1
        self.hi_bp = idx
        p = -0.5 * mu
        q = p * p - s
        self.p, self.q = p, q
        self.kind = -1 if q < 0.0 else (1 if q > 0.0 else 0)
        self.beta = math.sqrt(abs(q))
        if self.kind > 0:
            # lam2 = p - beta has no cancellation; lam1 from the product lam1*lam2 = s
            self.lam2 = p - self.beta
            self.lam1 = s / self.lam2
        else:
            self.lam1 = self.lam2 = p
        self.lam_bound = abs(p) + self.beta  # >= |lambda_1|, |lambda_2|

        if s != 0.0 and abs(self.g) <= _CONST_COND * abs(s) * scale:
            self.const_mode, self.xc = "std", self.g / s
        elif self.g == 0.0:
            self.const_mode, self.xc = "none", 0.0
        else:
            self.const_mode, self.xc = "zic", 0.0

        self.std: list[tuple[float, float, float, float, float]] = []
        self.res: list[tuple[float, float, float, complex, complex, complex]] = []
        for amp, om, ph in forcing:
            near = False
            if self.kind < 0:
                nu_p = complex(p, self.beta - om)
                nu_m = complex(p, -self.beta - om)
                near = min(abs(nu_p), abs(nu_m)) < _RESONANCE_BAND * om
            if near:
                self.res.append((amp, om, ph, nu_p, nu_m, complex(0.0, self.beta)))
            else:
                dr = s - om * om
                di = mu * om
                den = dr * dr + di * di
                self.std.append((amp, om, ph, amp * dr / den, amp * di / den))
        self.harm = tuple(forcing)
        # |x_p''| <= sum omega^2 |Z| over the standard harmonics (resonant ones: per piece);
        # with the zero-IC constant load there is no cheap bound on |a| and the scan uses its
        # grid
        self.a_part = sum(om * om * math.hypot(P, Q) for _, om, _, P, Q in self.std)
        self.bounded = self.const_mode != "zic"

        rates = [om for _, om, _ in forcing]
        rates.append(self.lam_bound)
        rate = max(rates)
        self.rate = rate
        self.p_mag = sum(abs(t[3]) + abs(t[4]) for t in self.std)
        self.h = _TWO_PI / (_STEPS_PER_SCALE * rate) if rate > 0.0 else math.inf

    # e^{p tau} C(tau), e^{p tau} S(tau) -------------------------------------------------------
    def ecs(self, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        p, beta = self.p, self.beta
        if self.kind < 0:
            e = np.exp(p * tau)
            bt = beta * tau
            return e * np.cos(bt), e * (np.sin(bt) / beta)
        if self.kind == 0:
            e = np.exp(p * tau)
            return e, e * tau
        bt = beta * tau
        small = bt <= 1.0
        bts = np.where(small, bt, 0.0)
        e = np.exp(np.where(small, p * tau, 0.0))
        with np.errstate(over="ignore", invalid="ignore"):
            taul = np.where(small, 0.0, tau)
            e1 = np.exp(self.lam1 * taul)
            e2 = np.exp(self.lam2 * taul)
            ec = np.where(small, e * np.cosh(bts), 0.5 * (e1 + e2))
            es = np.where(small, e * (np.sinh(bts) / beta), (e1 - e2) / (2.0 * beta))
        return ec, es

    def ecs1(self, tau: float) -> tuple[float, float]:
        p, beta = self.p, self.beta
        if self.kind < 0:
            e = math.exp(p * tau)
            bt = beta * tau
            return e * math.cos(bt), e * (math.sin(bt) / beta)
        if self.kind == 0:
            e = math.exp(p * tau)
            return e, e * tau
        bt = beta * tau
        if bt <= 1.0:
            e = math.exp(p * tau)
            return e * math.cosh(bt), e * (math.sinh(bt) / beta)
        try:
            e1 = math.exp(self.lam1 * tau)
        except OverflowError:
            e1 = math.inf
        e2 = math.exp(self.lam2 * tau)
        return 0.5 * (e1 + e2), (e1 - e2) / (2.0 * beta)

    # H1(tau) = int_0^tau e^{p s} S(s) ds (response of x to a unit constant load, zero IC) -----
    def h1(self, tau: np.ndarray, ec: np.ndarray, es: np.ndarray) -> np.ndarray:
        s, mu = self.s, self.mu
        out = np.empty_like(tau)
        r_series = self.lam_bound * tau <= 1.0
        st2 = s * tau * tau
        r_direct = ~r_series & (np.abs(st2) >= 0.1)
        r_dd = ~r_series & ~r_direct
        if np.any(r_series):
            tt = tau[r_series]
            sig1 = -mu * tt
            sig2 = s * tt * tt
            hkm2 = np.ones_like(tt)
            hkm1 = sig1
            acc = 0.5 + sig1 / 6.0
            fact = 6.0
            for k in range(2, _SERIES_TERMS):
                hk = sig1 * hkm1 - sig2 * hkm2
                fact *= k + 2
                acc = acc + hk / fact
                hkm2, hkm1 = hkm1, hk
            out[r_series] = tt * tt * acc
        if np.any(r_direct):
            phi11 = ec[r_direct] + self.half_mu * es[r_direct]
            out[r_direct] = (1.0 - phi11) / s
        if np.any(r_dd):
            tt = tau[r_dd]
            # here q > 0, p < 0: two well separated real roots
            out[r_dd] = (
                tt
                * (_phi1_real(self.lam1 * tt) - _phi1_real(self.lam2 * tt))
                / (self.lam1 - self.lam2)
            )
        return out

    def h1_1(self, tau: float, ec: float, es: float) -> float:
        s, mu = self.s, self.mu
        if self.lam_bound * tau <= 1.0:
            sig1 = -mu * tau
            sig2 = s * tau * tau
            hkm2, hkm1 = 1.0, sig1
            acc = 0.5 + sig1 / 6.0
            fact = 6.0
            for k in range(2, _SERIES_TERMS):
                hk = sig1 * hkm1 - sig2 * hkm2
                fact *= k + 2
                acc += hk / fact
                hkm2, hkm1 = hkm1, hk
            return tau * tau * acc
        if abs(s * tau * tau) >= 0.1:
            return (1.0 - (ec + self.half_mu * es)) / s
        return (
            tau
            * (_phi1_real_s(self.lam1 * tau) - _phi1_real_s(self.lam2 * tau))
            / (self.lam1 - self.lam2)
        )

    # accelerations at a boundary (for the choice of side) ------------------------------------
    def accel_at(self, t: float, x: float, v: float) -> float:
        load = self.g
        for amp, om, ph in self.harm:
            load += amp * math.cos(om * t + ph)
        return load - self.mu * v - self.s * x


class _Piece:
    """Closed-form solution in one segment from (x0, v0) at t0 (internal)."""

    __slots__ = (
        "seg", "t0", "x0", "v0", "w0", "w1", "n0", "n1", "th_list", "res", "tol", "al", "ga",
        "a_hom", "a_extra", "bounded", "memo",
    )  # fmt: skip

    def __init__(
        self, seg: _Segment, t0: float, x0: float, v0: float, horizon: float = math.inf
    ) -> None:
        self.seg, self.t0, self.x0, self.v0 = seg, t0, x0, v0
        # the last scalar evaluation: a root is evaluated again by the caller (state at the
        # switch, grazing depth)
        self.memo: tuple[float, tuple[float, float, float, float]] = (math.nan, (0.0,) * 4)
        # phases reduced mod 2 pi once per piece (the closed form then uses small arguments)
        th = [math.fmod(om * t0 + ph, _TWO_PI) for _, om, ph, _, _ in seg.std]
        self.th_list = th
        xp = vp = 0.0
        for (_, om, _, P, Q), thk in zip(seg.std, th, strict=True):
            c, sn = math.cos(thk), math.sin(thk)
            xp += P * c + Q * sn
            vp += om * (Q * c - P * sn)
        w0 = x0 - xp - seg.xc
        w1 = v0 - vp
        self.w0, self.w1 = w0, w1
        self.n0 = seg.half_mu * w0 + w1
        self.n1 = -seg.s * w0 - seg.half_mu * w1
        # homogeneous acceleration a_h = ec * al + es * ga (x_h'' = -s x_h - mu v_h); for
        # complex roots |a_h| <= e^{p tau} a_hom, the amplitude of the damped cosine
        self.al = -seg.s * w0 - seg.mu * w1
        self.ga = -seg.s * self.n0 - seg.mu * self.n1
        self.a_hom = math.hypot(self.al, self.ga / seg.beta) if seg.kind < 0 else math.inf
        res = []
        mag_res = 0.0
        self.a_extra = 0.0
        self.bounded = seg.bounded
        for amp, om, ph, nu_p, nu_m, bc in seg.res:
            th0 = math.fmod(om * t0 + ph, _TWO_PI)
            G = amp * cmath.exp(1j * th0)
            res.append((G, om, th0, nu_p, nu_m, bc))
            mag_res += abs(amp) / (om * om)
            # for the bound on |a| only: the zero-IC response is the steady state Re(Z e^{iwt})
            # minus the free motion from its initial state (exact whenever delta != 0; the
            # closed form above avoids its cancellation, the bound need not)
            delta = complex(seg.s - om * om, seg.mu * om)
            if delta == 0.0:
                self.bounded = False
                continue
            Z = G / delta
            u0, u1 = Z.real, (1j * om * Z).real
            m0 = seg.half_mu * u0 + u1
            m1 = -seg.s * u0 - seg.half_mu * u1
            self.a_hom += math.hypot(
                -seg.s * u0 - seg.mu * u1, (-seg.s * m0 - seg.mu * m1) / seg.beta
            )
            self.a_extra += om * om * abs(Z)
        self.res = res
        # rounding scale of the terms that make up x(tau), tau <= horizon: the velocity and
        # constant-load terms grow like tau and tau**2 up to the segment's time scale 1/rate,
        # which is unbounded for s -> 0, mu = 0 without forcing (free flight), where only the
        # horizon bounds them
        scale_t = min(1.0 / seg.rate if seg.rate > 0.0 else math.inf, horizon)
        if not math.isfinite(scale_t):
            scale_t = 1.0
        mag = (
            abs(x0)
            + abs(w0)
            + abs(self.n0) * scale_t
            + abs(seg.xc)
            + seg.p_mag
            + mag_res
            + (abs(seg.g) * scale_t * scale_t if seg.const_mode == "zic" else 0.0)
        )
        for d in (seg.lo, seg.hi):
            if math.isfinite(d):
                mag += abs(d)
        self.tol = _TOL_ULPS * _EPS * mag

    # ---- evaluation -------------------------------------------------------------------------
    def eval(self, tau: np.ndarray, accel: bool = False):
        """x(tau), v(tau) [and a(tau)] for an array of local times."""
        seg = self.seg
        tau = np.asarray(tau, dtype=float)
        ec, es = seg.ecs(tau)
        x = ec * self.w0 + es * self.n0
        v = ec * self.w1 + es * self.n1
        force = seg.g
        # a loop over the (few) harmonics, each vectorised over tau
        for (amp, om, _ph, P, Q), th0 in zip(seg.std, self.th_list, strict=True):
            th = th0 + om * tau
            c = np.cos(th)
            sn = np.sin(th)
            x = x + (P * c + Q * sn)
            v = v + om * (Q * c - P * sn)
            if accel:
                force = force + amp * c
        if seg.const_mode == "std":
            x = x + seg.xc
        elif seg.const_mode == "zic":
            x = x + seg.g * seg.h1(tau, ec, es)
            v = v + seg.g * es
        for G, om, _th0, nu_p, nu_m, bc in self.res:
            f_p = _phi1_complex(nu_p * tau)
            f_m = _phi1_complex(nu_m * tau)
            a0 = 0.5 * tau * (f_p + f_m)
            a1 = tau * (f_p - f_m) / (2.0 * bc)
            z = G * np.exp(1j * om * tau)
            x = x + np.real(z * a1)
            v = v + np.real(z * (a0 - seg.half_mu * a1))
            if accel:
                force = force + np.real(z)
        if accel:
            return x, v, force - seg.mu * v - seg.s * x
        return x, v

    def eval1(self, tau: float) -> tuple[float, float, float, float]:
        """Scalar x, v, a, da/dt at local time tau (pure Python math: fast in root finders)."""
        memo = self.memo
        if memo[0] == tau:
            return memo[1]
        seg = self.seg
        ec, es = seg.ecs1(tau)
        x = ec * self.w0 + es * self.n0
        v = ec * self.w1 + es * self.n1
        force = seg.g
        dforce = 0.0
        for (amp, om, _ph, P, Q), th0 in zip(seg.std, self.th_list, strict=True):
            th = th0 + om * tau
            c = math.cos(th)
            sn = math.sin(th)
            x += P * c + Q * sn
            v += om * (Q * c - P * sn)
            force += amp * c
            dforce -= amp * om * sn
        if seg.const_mode == "std":
            x += seg.xc
        elif seg.const_mode == "zic":
            x += seg.g * seg.h1_1(tau, ec, es)
            v += seg.g * es
        for G, om, _th0, nu_p, nu_m, bc in self.res:
            f_p = _phi1_complex_s(nu_p * tau)
            f_m = _phi1_complex_s(nu_m * tau)
            a0 = 0.5 * tau * (f_p + f_m)
            a1 = tau * (f_p - f_m) / (2.0 * bc)
            z = G * cmath.exp(1j * om * tau)
            x += (z * a1).real
            v += (z * (a0 - seg.half_mu * a1)).real
            force += z.real
            dforce -= om * z.imag
        a = force - seg.mu * v - seg.s * x
        out = (x, v, a, dforce - seg.mu * a - seg.s * v)
        self.memo = (tau, out)
        return out

    def x1(self, tau: float) -> float:
        return self.eval1(tau)[0]

    def v1(self, tau: float) -> float:
        return self.eval1(tau)[1]

    def va1(self, tau: float) -> tuple[float, float, float]:
        return self.eval1(tau)[1:4]

    def aj1(self, tau: float) -> tuple[float, float, float]:
        _, _, a, j = self.eval1(tau)
        return a, j, math.nan


# --------------------------------------------------------------------------------------------
# switching detection
# --------------------------------------------------------------------------------------------
def _sign(z: float) -> int:
    return (z > 0.0) - (z < 0.0)


class _Counter:
    __slots__ = ("grid", "roots")

    def __init__(self) -> None:
        self.grid = 0
        self.roots = 0


def _root_newton(fdf, a: float, b: float, sa: int, fa: float, fb: float, counter: _Counter):
    """Safeguarded Newton–bisection root of ``f`` in the bracket (a, b), ``f' `` exact.

    ``fdf(t)`` returns ``(f, f', f'')`` (``f''`` may be NaN: unknown); ``sa`` is the sign
    of f just after ``a`` (f changes sign in the bracket).  Each Newton step that would leave
    the current bracket, or not halve the step before last, is replaced by bisection, so the
    iteration never leaves the bracket and converges at least linearly; near the root it is
    quadratic (closed-form derivative), which needs about half the closed-form evaluations of
    brentq.  Stops when the step is below
    ``4 eps |t|`` (full double precision of the local time), or when the quadratic error
    estimate ``|f''/(2f')| dx^2`` of the new iterate is (saves the confirming evaluation).
    """
    counter.roots += 1
    lo, hi = (a, b) if sa < 0 else (b, a)  # f(lo) < 0 < f(hi)
    if fa * fb < 0.0:
        t = a + (b - a) * fa / (fa - fb)  # secant guess from the true end values
        if not a < t < b:
            t = 0.5 * (a + b)
    else:
        t = 0.5 * (a + b)
    width = abs(b - a)
    dx_old = dx = width
    for _ in range(200):
        f, df, d2f = fdf(t)
        if f == 0.0:
            return t
        if f < 0.0:
            lo = t
        else:
            hi = t
        tol = max(4.0 * _EPS * abs(t), 1e-17 * width, 1e-300)
        if abs(f) <= tol * abs(df):
            return t - f / df  # the Newton correction is below the resolution of t
        lo_, hi_ = (lo, hi) if lo < hi else (hi, lo)
        t_new = t - f / df if df != 0.0 else math.nan
        if not (lo_ < t_new < hi_) or abs(2.0 * f) > abs(dx_old * df):
            dx_old, dx = dx, 0.5 * (hi_ - lo_)
            t_new = lo_ + dx
        else:
            dx_old, dx = dx, t - t_new
            # quadratic convergence: the error of t_new is ~ |f''/(2 f')| dx^2; below the
            # resolution of t (with a safety factor 10) no further evaluation is needed
            if 10.0 * abs(d2f) * dx * dx <= 2.0 * tol * abs(df):
                return t_new
        if abs(dx) <= tol or hi_ - lo_ <= tol:
            return t_new
        t = t_new
    return t


def _critical_points(
    piece: _Piece,
    u0: float,
    w0: float,
    vu: float,
    au: float,
    vw: float,
    aw: float,
    counter: _Counter,
) -> list[float]:
    """Interior roots of v (extrema of x) in (u0, w0); at most two (one dip of v)."""
    su = _sign(vu) or _sign(au)  # direction just after u0
    sw = _sign(vw) or -_sign(aw)  # direction just before w0
    if su == 0 or sw == 0:
        return []
    if su != sw:
        return [_root_newton(piece.va1, u0, w0, su, vu, vw, counter)]
    if su * au < 0.0 < su * aw:
        # |v| decreases, then increases: v has one extremum and two roots iff it changes sign
        # there (v monotone on each side of it)
        ta = _root_newton(piece.aj1, u0, w0, _sign(au), au, aw, counter)
        vt = piece.v1(ta)
        if vt * su < 0.0:
            return [
                _root_newton(piece.va1, u0, ta, su, vu, vt, counter),
                _root_newton(piece.va1, ta, w0, -su, vt, vw, counter),
            ]
    return []


def _analyze_step(
    piece: _Piece,
    u0: float,
    w0: float,
    xu: float,
    vu: float,
    au: float,
    xw: float,
    vw: float,
    aw: float,
    bounds: list[tuple[float, int, int]],
    last_tan: dict[int, float],
    counter: _Counter,
) -> tuple[tuple[float, int] | None, list[tuple[float, int, float, float]]]:
    """Earliest exit in (u0, w0] and tangencies before it.

    ``bounds`` holds ``(d, sigma, bp)`` with ``sigma * (x - d) > 0`` inside the segment.
    Returns ``((tau, bp) or None, [(tau, bp, x, v), ...])``.
    """
    tol = piece.tol
    window = 1e-3 * piece.seg.h if math.isfinite(piece.seg.h) else 1e-3 * (w0 - u0)
    crit = _critical_points(piece, u0, w0, vu, au, vw, aw, counter)
    nodes = [u0, *crit, w0]
    xs = [xu, *(piece.x1(c) for c in crit), xw]
    n_last = len(nodes) - 1
    best: tuple[float, int] | None = None
    tangs: list[tuple[float, int, float, float]] = []

    def add_tangency(tau: float, bp: int) -> None:
        prev = last_tan.get(bp)
        if prev is not None and abs(tau - prev) <= window:
            return
        last_tan[bp] = tau
        xt, vt, _, _ = piece.eval1(tau)
        tangs.append((tau, bp, xt, vt))

    for d, sig, bp in bounds:
        G = [sig * (xx - d) for xx in xs]

        def ghat(t: float, d: float = d, sig: int = sig) -> tuple[float, float, float]:
            xt, vt, at, _ = piece.eval1(t)
            return sig * (xt - d), sig * vt, sig * at

        for j in range(n_last):
            u, w, gu, gw = nodes[j], nodes[j + 1], G[j], G[j + 1]
            if gw >= gu:
                continue  # moving inwards (or stationary): no exit on this monotone piece
            if j + 1 < n_last:  # w is a critical point: a local minimum of ghat
                if gw > tol:
                    continue
                if gw >= -tol:
                    add_tangency(w, bp)
                    continue
                root = _root_newton(ghat, u, w, 1, gu, gw, counter) if gu > 0.0 else u
            else:
                if gw > 0.0:
                    continue
                if gw == 0.0 and gu > 0.0:
                    root = w
                else:
                    root = _root_newton(ghat, u, w, 1, gu, gw, counter) if gu > 0.0 else u
                # grazing that straddles a grid node: judge by the penetration depth
                _, vr, ar, _ = piece.eval1(root)
                out_speed = -sig * vr
                a_in = sig * ar
                if a_in > 0.0 and out_speed * out_speed <= 2.0 * a_in * tol:
                    tm = root + max(out_speed, 0.0) / a_in
                    add_tangency(tm, bp)
                    continue
            if best is None or root < best[0]:
                best = (root, bp)
            break
    if best is not None:
        tangs = [tg for tg in tangs if tg[0] < best[0]]
    return best, tangs


def _accel_bound(piece: _Piece, ta: float, tb: float) -> float:
    """An upper bound of ``|a(tau)|`` for ``ta <= tau <= tb`` (``inf`` when none is known).

    ``a = a_h + a_p``: the particular part is bounded by ``seg.a_part``; the homogeneous part
    ``ec(tau) al + es(tau) ga`` by the closed forms of ``ec``, ``es`` (``p <= 0`` always):
    ``e^{p tau}`` times the damped-cosine amplitude for complex roots, the monotone
    exponentials at the ends of the interval otherwise (with ``sinh(x)/x <= cosh(x)``)."""
    seg = piece.seg
    if seg.kind < 0:
        return math.exp(seg.p * ta) * piece.a_hom + seg.a_part + piece.a_extra
    al, ga = abs(piece.al), abs(piece.ga)
    if seg.kind == 0:
        return math.exp(seg.p * ta) * (al + ga * tb) + seg.a_part
    lam1 = seg.lam1
    try:
        e1 = math.exp(lam1 * (tb if lam1 > 0.0 else ta))
    except OverflowError:
        return math.inf
    ec = 0.5 * (e1 + math.exp(seg.lam2 * ta))
    es = min(tb * ec, e1 / (2.0 * seg.beta))
    return ec * al + es * ga + seg.a_part


class PieceEvaluator:
    r"""The closed-form solution in one segment of a :class:`PWLSystem`, from ``(x0, v0)`` at
    ``t0``: the object :func:`propagate` evaluates for its dense output and its switch scan.

    Build one for any segment and initial state with ``PieceEvaluator(system, segment, t0,
    x0, v0)``, or get those of a trajectory with :meth:`Trajectory.piece_evaluator`.  The
    solution is that of the linear equation of ``segment`` *as if the segment extended
    everywhere* (the evaluator does not stop at the segment's breakpoints).  Times are local:
    ``tau = t - t0``.

    Parameters
    ----------
    system : PWLSystem
    segment : int
        Index of the segment (``0 .. system.n_segments - 1``).
    t0, x0, v0 : float
        Start time and state.
    """

    __slots__ = ("_piece",)

    def __init__(self, system: PWLSystem, segment: int, t0: float, x0: float, v0: float) -> None:
        if not isinstance(system, PWLSystem):
            raise ParameterError(f"system = {system!r}: expected a PWLSystem")
        if (
            isinstance(segment, bool)
            or not isinstance(segment, int | np.integer)
            or not 0 <= segment < system.n_segments
        ):
            raise ParameterError(
                f"segment = {segment!r}: expected an integer in 0 .. {system.n_segments - 1}"
            )
        seg = _model_of(system).segments[int(segment)]
        self._piece = _Piece(
            seg, _finite_float("t0", t0), _finite_float("x0", x0), _finite_float("v0", v0)
        )

    @classmethod
    def _of(cls, piece: _Piece) -> PieceEvaluator:
        out = cls.__new__(cls)
        out._piece = piece
        return out

    @property
    def t0(self) -> float:
        """Start time."""
        return self._piece.t0

    @property
    def segment(self) -> int:
        """Index of the segment."""
        return self._piece.seg.idx

    @property
    def bounded(self) -> bool:
        """Whether :meth:`acceleration_bound` is a finite bound: False for a constant load
        on a segment in its zero-initial-condition form (``s`` near 0) and for a forcing
        harmonic in exact resonance with the segment, whose responses grow without bound."""
        return self._piece.bounded

    def __call__(self, tau: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(x, v, a)`` at the local times ``tau`` (arrays, vectorised): position,
        velocity and acceleration ``a = load - mu v - f(x)``."""
        return self._piece.eval(np.asarray(tau, dtype=float), accel=True)

    def derivatives(self, tau: float) -> tuple[float, float, float, float]:
        """``(x, v, a, da/dt)`` at one local time ``tau``, in scalar arithmetic (the path
        of the root finders)."""
        return self._piece.eval1(float(tau))

    def acceleration_bound(self, tau_a: float, tau_b: float) -> float:
        """An upper bound of ``|a(tau)|`` for ``tau_a <= tau <= tau_b`` (local times, ``0 <=
        tau_a <= tau_b``): what lets the switch scan step over stretches where ``x`` cannot
        reach a breakpoint.  ``inf`` when none is known; only meaningful when
        :attr:`bounded`."""
        return _accel_bound(self._piece, float(tau_a), float(tau_b))


def _safe_length(g: float, gp: float, amax: float, margin: float) -> float:
    """A stretch ``(0, L]`` on which the distance ``g(h) >= g + gp h - amax h^2 / 2`` to a
    boundary can neither reach it nor have a minimum within ``margin`` of it (0 if none).

    Normally the quadratic bound stays above ``margin`` there.  Leaving the boundary
    (``0 <= g <= margin``, ``gp > 0``), ``g`` increases while ``h < gp / amax`` (``|g''| <=
    amax``), so the stretch reaches the larger root even though it starts below ``margin``.
    """
    c = g - margin
    if c <= 0.0 and not (gp > 0.0 and g >= 0.0):
        return 0.0
    if amax <= 0.0:
        return math.inf if gp >= 0.0 else c / -gp
    disc2 = gp * gp + 2.0 * amax * c
    if disc2 <= 0.0:
        return 0.0
    disc = math.sqrt(disc2)
    # the two forms of the positive root avoid cancellation for either sign of gp
    return (gp + disc) / amax if gp >= 0.0 else 2.0 * c / (disc - gp)


def _scan_piece(
    piece: _Piece,
    tau_end: float,
    start_bp: int | None,
    counter: _Counter,
) -> tuple[tuple[float, int] | None, list[tuple[float, int, float, float]]]:
    """First exit of the piece before ``tau_end`` and the tangencies on the way.

    From every node the distance to each boundary, its rate and a bound ``amax`` of
    ``|a|`` give a stretch on which the distance provably stays above ``2 tol``
    (Taylor with the remainder bounded by ``amax``): no crossing and no tangency can lie
    there, and the scan jumps over it.  Otherwise it takes one grid step (``seg.h``) and
    examines it as described in the module docstring."""
    seg = piece.seg
    bounds: list[tuple[float, int, int]] = []
    if math.isfinite(seg.lo):
        bounds.append((seg.lo, 1, seg.lo_bp))
    if math.isfinite(seg.hi):
        bounds.append((seg.hi, -1, seg.hi_bp))
    if not bounds:
        return None, []
    h = seg.h if math.isfinite(seg.h) else tau_end
    h = min(h, tau_end)
    # a piece that starts on a boundary has "just touched" it: suppress a tangency at tau = 0
    last_tan: dict[int, float] = {} if start_bp is None else {start_bp: 0.0}
    tangs_all: list[tuple[float, int, float, float]] = []
    tol = piece.tol
    margin = 2.0 * tol
    bounded = piece.bounded
    # over [tau, tau + reach] for the real-root bounds (they grow with the interval)
    reach = 8.0 * h
    eval1 = piece.eval1
    # the exact initial state, not its re-evaluation (rounding could flip signs)
    tau, x, v = 0.0, piece.x0, piece.v0
    a = seg.accel_at(piece.t0, x, v)
    counter.grid += 1
    if not (h > 0.0 and math.isfinite(h) and math.isfinite(tau_end)):
        raise PerturbError(
            f"segment {seg.idx}: step {h!r} over {tau_end!r} (a non-finite or zero time scale; "
            "are the parameters finite and of moderate size?)"
        )
    # every pass advances tau by at least h (or returns): a cap that only a NaN can reach
    passes = 0
    max_passes = 4 * math.ceil(tau_end / h) + 1000
    while tau < tau_end:
        passes += 1
        if passes > max_passes or not math.isfinite(tau):
            raise PerturbError(
                f"segment {seg.idx}: the scan for switches stalled at tau = {tau!r} of "
                f"{tau_end!r} after {passes} steps (a NaN in the propagation?)"
            )
        if bounded:
            tb = min(tau_end, tau + reach)
            amax = _accel_bound(piece, tau, tb) * (1.0 + 1e-12)
            if amax < math.inf:
                safe = tb - tau if seg.kind >= 0 else tau_end - tau
                for d, sig, _bp in bounds:
                    safe = min(safe, _safe_length(sig * (x - d), sig * v, amax, margin))
                if safe > h:
                    tau = tau + safe
                    if tau >= tau_end:
                        return None, tangs_all
                    x, v, a, _ = eval1(tau)
                    counter.grid += 1
                    if not (math.isfinite(x) and math.isfinite(v)):
                        _escape(piece, tau)
                    continue
        w = tau + h
        if w >= tau_end:
            w = tau_end
        xw, vw, aw, _ = eval1(w)
        counter.grid += 1
        if not (math.isfinite(xw) and math.isfinite(vw)):
            _escape(piece, w)
        dt = w - tau
        bound = 0.25 * max(abs(a), abs(aw)) * dt * dt + tol
        flagged = False
        for d, sig, _bp in bounds:
            gu, gw = sig * (x - d), sig * (xw - d)
            if min(gu, gw) > bound:
                continue
            # ... unless x moves inwards all through the step (v inwards at both ends and no
            # dip of |v| in between: then x is monotone there) and ends inside
            if (
                sig * v > 0.0
                and sig * vw > 0.0
                and not (sig * a < 0.0 and sig * aw > 0.0)
                and gw > 0.0
            ):
                continue
            flagged = True
            break
        if flagged:
            exit_, tangs = _analyze_step(
                piece, tau, w, x, v, a, xw, vw, aw, bounds, last_tan, counter
            )
            tangs_all.extend(tangs)
            if exit_ is not None and exit_[0] < tau_end:
                return exit_, tangs_all
        tau, x, v, a = w, xw, vw, aw
    return None, tangs_all


def _escape(piece: _Piece, tau: float) -> None:
    seg = piece.seg
    raise PerturbError(
        f"the orbit escapes to infinity in segment {seg.idx} (slope {seg.s!r}) near "
        f"t = {float(piece.t0 + tau)!r}: floating-point overflow; shorten t_span"
    )


# --------------------------------------------------------------------------------------------
# the propagator
# --------------------------------------------------------------------------------------------
class _Model:
    """Segments of a system plus the rules for choosing a side at a breakpoint (internal)."""

    def __init__(self, system: PWLSystem) -> None:
        bp = system.breakpoints
        self.system = system
        self.bp = bp
        self.bp_list = [float(d) for d in bp]
        scale = 1.0 + (float(np.max(np.abs(bp))) if bp.size else 0.0)
        edges = np.concatenate(([-np.inf], bp, [np.inf]))
        self.segments = [
            _Segment(
                i,
                float(system.slopes[i]),
                float(system.offsets[i]),
                system.damping,
                system.static_force,
                system.forcing,
                float(edges[i]),
                float(edges[i + 1]),
                scale,
            )
            for i in range(system.n_segments)
        ]
        self.continuous = system.continuous_at()
        hs = [sg.h for sg in self.segments if math.isfinite(sg.h)]
        self.t_ref = _STEPS_PER_SCALE * min(hs) if hs else math.inf

    def side_at(self, b: int, t: float, v: float) -> int:
        """Segment to continue in from x = breakpoints[b] with velocity v at time t."""
        below, above = b, b + 1
        if v > 0.0:
            return above
        if v < 0.0:
            return below
        d = float(self.bp[b])
        a_up = self.segments[above].accel_at(t, d, 0.0)
        a_dn = self.segments[below].accel_at(t, d, 0.0)
        if self.continuous[b]:
            a_up = a_dn = 0.5 * (a_up + a_dn)
        if a_up > 0.0 and a_dn < 0.0:
            raise PerturbError(
                f"at t = {t!r} the state rests on the discontinuity x = {d!r} and both sides "
                f"push away from it (accelerations {a_dn!r} below, {a_up!r} above): the "
                f"solution is not unique; {EVENT_DRIVEN_HINT}"
            )
        if a_up > 0.0:
            return above
        if a_dn < 0.0:
            return below
        if a_up < 0.0 or a_dn > 0.0:
            raise PerturbError(
                f"sticking at the discontinuity x = {d!r} at t = {t!r}: the force field points "
                f"into the breakpoint from both sides (accelerations {a_dn!r} below, {a_up!r} "
                f"above); the exact propagator does not slide; {EVENT_DRIVEN_HINT}"
            )
        # a = v = 0: the next nonzero derivative of x is a derivative of the load
        jerk = sum(-amp * om * math.sin(om * t + ph) for amp, om, ph in self.system.forcing)
        if jerk != 0.0:
            return above if jerk > 0.0 else below
        snap = sum(-amp * om * om * math.cos(om * t + ph) for amp, om, ph in self.system.forcing)
        return below if snap < 0.0 else above

    def initial_segment(self, t: float, x: float, v: float) -> tuple[int, int | None]:
        # bisect on the list of breakpoints: np.searchsorted's semantics without its per-call
        # overhead (called once per propagation)
        b = bisect.bisect_left(self.bp_list, x)
        if b < len(self.bp_list) and self.bp_list[b] == x:
            return self.side_at(b, t, v), b
        return bisect.bisect_right(self.bp_list, x), None


# The segment data depend only on the (immutable) system; continuation and shooting propagate
# the same system thousands of times, so it is built once per system object and kept on it
# (a dictionary keyed by the system would hash its arrays on every call).
def _model_of(system: PWLSystem) -> _Model:
    model = system.__dict__.get("_model")
    if model is None:
        model = _Model(system)
        object.__setattr__(system, "_model", model)
    return model


def propagate(
    system: PWLSystem,
    y0: ArrayLike,
    t_span: Sequence[float],
    *,
    t_eval: ArrayLike | None = None,
    max_events: int = 1_000_000,
) -> Trajectory:
    r"""Propagate a PWL oscillator exactly, segment by segment, in closed form.

    Parameters
    ----------
    system : PWLSystem
    y0 : array_like, shape (2,)
        Initial ``(x, v)`` at ``t_span[0]``.  On a breakpoint the segment is chosen by the sign
        of ``v``, then of the acceleration (then of the load derivatives).
    t_span : (t0, t1)
        ``t1 > t0``.
    t_eval : array_like, optional
        Output times in ``[t0, t1]``; default: piece starts (switch times) and ``t1``.
    max_events : int
        Largest number of events (crossings plus tangencies) before giving up.

    Returns
    -------
    Trajectory
        Samples, event log, piece list and exact dense output ``traj(t)``.

    Raises
    ------
    ParameterError
        Bad ``y0``, ``t_span``, ``t_eval`` or ``max_events``.
    PerturbError
        Sticking / sliding / chattering at a discontinuity, a non-unique start on a repelling
        discontinuity, more than ``max_events`` events, or overflow (orbit escaping).

    Notes
    -----
    Accuracy is that of evaluating the closed form in double precision: switching times are
    solved to a relative ``4 eps`` and the state is reset exactly onto the breakpoint.

    Examples
    --------
    >>> import math
    >>> k = -2.0
    >>> nsd = PWLSystem([-1.0, 1.0], [1.0, k, 1.0], [1.0 - k, 0.0, k - 1.0], damping=0.05,
    ...                 forcing=((2.0, 0.6, 0.0),))
    >>> traj = propagate(nsd, (0.0, 0.0), (0.0, 10 * 2 * math.pi / 0.6))
    >>> traj.n_segments, len(traj.switches)
    (42, 41)
    >>> x, v = traj(5.0)  # exact dense output
    """
    if not isinstance(system, PWLSystem):
        raise ParameterError(f"system = {system!r}: expected a PWLSystem")
    x, v = _pair(y0)
    if not (math.isfinite(x) and math.isfinite(v)):
        y = _finite_vector("y0", y0)
        if y.size != 2:
            raise ParameterError(f"y0 = {y.tolist()!r}: expected two values (x, v)")
    t0, t1 = _pair(t_span)
    if not (math.isfinite(t0) and math.isfinite(t1) and t1 > t0):
        ts = _finite_vector("t_span", t_span)
        if ts.size != 2 or not ts[1] > ts[0]:
            raise ParameterError(f"t_span = {ts.tolist()!r}: expected (t0, t1) with t1 > t0")
    if (
        isinstance(max_events, bool)
        or not isinstance(max_events, int | np.integer)
        or (max_events < 0)
    ):
        raise ParameterError(f"max_events = {max_events!r}: expected a non-negative integer")
    te = None
    if t_eval is not None:
        te = _finite_vector("t_eval", t_eval)
        if te.size and (te.min() < t0 or te.max() > t1):
            raise ParameterError(
                f"t_eval spans [{te.min()!r}, {te.max()!r}]: expected values inside t_span = "
                f"({t0!r}, {t1!r})"
            )

    model = _model_of(system)
    counter = _Counter()
    seg_i, start_bp = model.initial_segment(t0, x, v)
    t = t0
    pieces: list[_Piece] = []
    events: list[SwitchEvent] = []
    n_switch = n_tan = 0
    # Zeno / chattering guard: many switches within a negligible time
    recent: list[float] = []
    while True:
        seg = model.segments[seg_i]
        piece = _Piece(seg, t, x, v, t1 - t)
        pieces.append(piece)
        exit_, tangs = _scan_piece(piece, t1 - t, start_bp, counter)
        for tau, bp, xt, vt in tangs:
            direction = 1 if bp == seg.hi_bp else -1
            events.append(SwitchEvent(t + tau, bp, direction, xt, vt, True, seg_i, seg_i))
            n_tan += 1
        if exit_ is None:
            break
        tau, bp = exit_
        _, v_new, _, _ = piece.eval1(tau)
        d = float(model.bp[bp])
        t_new = t + tau
        if not (math.isfinite(t_new) and math.isfinite(v_new)) or t_new < t:
            raise PerturbError(
                f"a switch at t = {t_new!r} with x' = {v_new!r} after t = {t!r}: the "
                "propagation produced a non-finite or backward time (overflow or NaN)"
            )
        going_up = bp == seg.hi_bp
        if v_new == 0.0:
            new_i = model.side_at(bp, t_new, 0.0)
        else:
            new_i = seg_i + 1 if going_up else seg_i - 1
            if (v_new > 0.0) != going_up:
                # rounding put the root a hair past the turning point: keep the segment
                new_i = model.side_at(bp, t_new, v_new)
        touch = new_i == seg_i
        # touch: the orbit reached the breakpoint but turns back (v or a points inwards), not a
        # switch; the next piece continues in the same segment from the boundary
        events.append(SwitchEvent(t_new, bp, 1 if going_up else -1, d, v_new, touch, seg_i, new_i))
        n_tan += touch
        n_switch += not touch
        if n_switch + n_tan > max_events:
            raise PerturbError(
                f"more than max_events = {max_events} events before t = {t1!r} (reached "
                f"t = {t_new!r}); raise max_events or shorten t_span"
            )
        if not touch and not model.continuous[bp]:
            nseg = model.segments[new_i]
            a_new = nseg.accel_at(t_new, d, v_new)
            inward = 1.0 if new_i > seg_i else -1.0
            if a_new * inward < 0.0:
                depth = v_new * v_new / (2.0 * abs(a_new))
                probe = _Piece(nseg, t_new, d, v_new, t1 - t_new)
                if depth <= _CHATTER_TOLS * probe.tol:
                    raise PerturbError(
                        f"chattering at the discontinuity x = {d!r} near t = {t_new!r}: the "
                        f"excursion into segment {new_i} would be {depth:.3g} deep (|v| = "
                        f"{abs(v_new):.3g}) and both sides push into the breakpoint "
                        f"(sliding/sticking); {EVENT_DRIVEN_HINT}"
                    )
        recent.append(t_new)
        if len(recent) > 64:
            recent.pop(0)
            # (1 + |t| bounds the reference for systems without a time scale of their own:
            # zero slopes, no damping and no forcing give t_ref = inf)
            if recent[-1] - recent[0] < 1e-9 * min(model.t_ref, 1.0 + abs(t_new)):
                raise PerturbError(
                    f"64 switches within {recent[-1] - recent[0]:.3g} time units near t = "
                    f"{t_new!r} (Zeno behaviour / sliding); {EVENT_DRIVEN_HINT}"
                )
        t, x, v, seg_i, start_bp = t_new, d, v_new, new_i, bp

    events.sort(key=lambda e: e.time)
    x_end, v_end, _, _ = pieces[-1].eval1(t1 - pieces[-1].t0)
    if not (math.isfinite(x_end) and math.isfinite(v_end)):
        raise PerturbError(
            f"the orbit escapes to infinity in segment {pieces[-1].seg.idx} before t = {t1!r} "
            "(floating-point overflow); shorten t_span"
        )
    public_pieces = tuple(Piece(p.t0, p.seg.idx, p.x0, p.v0) for p in pieces)
    stats = PropagationStats(
        n_pieces=len(pieces),
        n_switches=n_switch,
        n_tangencies=n_tan,
        n_grid_points=counter.grid,
        n_root_solves=counter.roots,
    )
    traj = Trajectory(
        t=np.empty(0),
        x=np.empty(0),
        v=np.empty(0),
        events=tuple(events),
        n_segments=len(pieces),
        pieces=public_pieces,
        stats=stats,
        system=system,
        t_span=(t0, t1),
        _evaluators=tuple(pieces),
    )
    if te is None:
        tt = np.array([p.t0 for p in pieces] + [t1])
        xx = np.array([p.x0 for p in pieces] + [x_end])
        vv = np.array([p.v0 for p in pieces] + [v_end])
    else:
        tt = te.copy()
        xx, vv = traj(tt) if tt.size else (np.empty(0), np.empty(0))
    for arr in (tt, xx, vv):
        arr.setflags(write=False)
    object.__setattr__(traj, "t", tt)
    object.__setattr__(traj, "x", np.asarray(xx))
    object.__setattr__(traj, "v", np.asarray(vv))
    return traj
