r"""Pseudo-arclength continuation of periodic orbits, and exact frequency responses.

Problem
-------
A period-``m`` orbit of a forced oscillator at parameter value :math:`p` (the forcing
frequency by default) is a zero of the multiple-shooting residual on ``N`` nodes
:math:`z_i \approx y(t_i)`, :math:`t_i = t_0 + iP/N`, :math:`P = mT(p)`,

.. math::

    G_i(z, p) = \varphi_{t_i \to t_{i+1}}(z_i;\, p) - z_{(i+1) \bmod N},
    \qquad i = 0, \dots, N-1,

with :math:`\partial G_i/\partial z_i = M_i` (the flow's sensitivity, saltation included)
and :math:`\partial G_i/\partial z_{i+1} = -I`.  ``N = 1`` is single shooting,
:math:`G = \varphi_P(y_0) - y_0`, :math:`G_z = M - I`.  A node is added for every factor
``NODE_GROWTH`` (100) of the largest Floquet multiplier: the saddle-like orbits of a
negative-stiffness well reach multipliers of :math:`10^{20}` and more, and already beyond
~100 the initial state alone no longer separates neighbouring orbits at 0.5 % spacing.

:math:`\partial G/\partial p`: for the exact PWL flow, the forcing frequency as parameter and
a continuous force it is exact and costs no propagation.  On a piece of segment :math:`k`
(constant :math:`A_k`) the parameter sensitivity :math:`\zeta = \partial y/\partial p` at
fixed time obeys :math:`\dot\zeta = A_k\zeta + e_2 \sum_j \operatorname{Re}(c_j\, t\,
e^{i\omega_j t})`, :math:`c_j = iF_j\omega_j' e^{i\phi_j}`, whose particular solution is
:math:`\zeta_p = \operatorname{Re}\,[(R t - R^2) e_2 c_j e^{i\omega_j t}]`,
:math:`R = (i\omega_j I - A_k)^{-1}`; each piece adds
:math:`\zeta_p(b) - e^{A_k(b-a)}\zeta_p(a)`, and the moving node times add
:math:`f(t_{i+1})\,dt_{i+1}/dp - M_i f(t_i)\,dt_i/dp`.  The node sensitivities are assembled
from the same piece exponentials (saltation is the identity for a continuous force).
Otherwise :math:`G_p` is a forward difference at the first iterate of a correction, updated
by Broyden's secant condition on that column afterwards (:math:`G_z` is exact at every
iterate), which keeps Newton superlinear for the ODE flow of smooth models.

Continuation
------------
A shooting problem on the package's pseudo-arclength core (:mod:`perturb.numeric.continuation`):
the step control is the core's :class:`~perturb.numeric.continuation.StepControl` (with this
engine's pace and output-spacing cap), the predictor its Hermite arc
(:func:`~perturb.numeric.continuation.hermite_extrapolate`), folds are detected by
:class:`~perturb.numeric.continuation.FoldTest` and stability changes by
:class:`~perturb.numeric.continuation.FloquetCrossings`; special points are located by
:func:`perturb.numeric.roots.illinois` and seeds polished by
:func:`perturb.numeric.roots.damped_newton`.  What stays here is what shooting needs and the
generic core does not have: a corrector whose acceptance knows the orbit statistics and the
node growth, a variable number of nodes, closed-form arcs, and orbit-signature proximity tests.

Along the solution curve :math:`u(s) = (z, p)`, in coordinates scaled so that 1 is the
parameter window or the orbit's size (:math:`R = \max(1, \max|x|, \max|z|)`, shared by the
nodes as :math:`R\sqrt N`):

- *predictor*: a cubic Hermite extrapolation through the last two points and their tangents
  (error :math:`O(ds^4)`), or the tangent itself (the null vector of :math:`[G_z \mid G_p]`,
  by SVD, oriented by the last chord) after a sharp turn or a change of nodes; the chord
  where the Jacobian is rank deficient (at a branch point the tangent is not unique — the
  stall of the first version, which used a forward-difference column there);
- *corrector*: Newton on :math:`G = 0,\ \hat d\cdot(\hat u - \hat u_{pred}) = 0` with the exact
  :math:`G_z` of every iterate (the sensitivity costs less than a propagation, so a chord
  method would only add iterations).  A correction is accepted when the estimated error of
  the *next* iterate is below ``tol`` (:math:`C\|\Delta_0\|^2` after one propagation, with
  the quadratic constant :math:`C` observed on earlier corrections;
  :math:`\|\Delta_k\|\min(1, \|\Delta_k\|/\|\Delta_{k-1}\|)` later) *and* the correction is
  below ``STATS_TOL`` = 1e-7 divided by the growth over one node interval: that next iterate
  is stored (no propagation to confirm it), and its statistics (amplitude, mean, first
  harmonic, multipliers) come from the last propagated iterate, within ``STATS_TOL``
  (relative) of the stored orbit.  With the Hermite predictor
  most points cost **one** propagation;
- *step control*: the Newton iterations set the pace (grow x1.6 after at most two, shrink
  after five, halve after a failure); the *output spacing* caps it: consecutive points differ
  by at most ``ds_max`` of the window in the parameter and ``ds_max`` relative in amplitude
  (``max(1, A)``), a step that exceeds 1.5 ``ds_max`` is redone shorter.  The step in
  :math:`(z, p)` may exceed ``ds_max`` (up to 8x) where the orbit's phase turns while
  parameter and amplitude move little.  A step that underflows is retried once as a jump of
  several earlier steps (over an isolated point where Newton converges badly).

Closed-form arcs (PWL systems, ``m = 1``)
    Where the orbit stays inside one linear segment of the force (slope :math:`s`, offset
    :math:`o`) it is the segment's own steady state, exactly
    :math:`x = x_c + \operatorname{Re}\sum_j Z_j e^{i(\omega_j t+\phi_j)}`,
    :math:`x_c = (c - o)/s`, :math:`Z_j = F_j/(s - \omega_j^2 + i\mu\omega_j)`, with multipliers
    :math:`e^{\lambda P}`, :math:`\lambda^2 + \mu\lambda + s = 0`.  Such arcs (the saddle branch
    of ``nsd`` inside :math:`|x| < 1`, the one-well orbits off resonance) cost no propagation;
    they end where the orbit grazes a breakpoint (root of the margin
    :math:`\min(d_{i+1} - \max x,\ \min x - d_i)`), and continuation goes on numerically from
    the exact grazing orbit.  The Poincaré map is only :math:`C^1` there (a :math:`3/2`-power
    term), which Newton tolerates; the steps restart small.  A numerical orbit that enters a
    linear segment entirely (no switch) is recognised and continued in closed form.

Special points (between consecutive points): folds (sign change of :math:`dp/ds`; refined by
regula falsi on the tangent's parameter component over corrected points and inserted into the
branch as a point of its own — interpolation would put the fold inside the sampled range,
:math:`O(\Delta s^2)` short of it, since the parameter is extreme there), branch
points (a multiplier through +1, :math:`\det(M - I)` changes sign, without a fold: the
symmetry-breaking pitchforks of odd systems), period doublings (:math:`\det(M + I)` changes
sign), Neimark–Sacker (a complex pair through the unit circle) and grazings (the number of
switches per period changes).  :func:`switch_branch` starts the other branch at a branch
point or the period-``2m`` branch at a period doubling: the point is refined by regula falsi
along the branch, and the new branch is seeded along the Floquet eigenfunction of the critical
multiplier and corrected on the hyperplane :math:`\phi\cdot(y_0 - y_0^*) = \delta`.

Branches
    Proximity tests compare *orbit signatures* — the state at 8 phases per forcing period,
    the amplitude, first harmonic and mean — never the initial state alone: a strongly
    unstable flow maps initial states 0.5 % apart to orbits that differ by O(1), and at low
    frequency quasi-static orbits agree at most phases.  A march stops at the window edge
    (with a last point exactly on it), on closing a loop (two consecutive points on the
    branch's own earlier part, stepping along it), on running along an already traced branch
    (two consecutive points on it, stepping along it: a crossing at a branch point, however
    shallow, is passed), when a period-``2m`` branch collapses onto its period-``m`` orbit,
    when a budget of points or propagations is spent, when the wall-clock budget of
    :func:`exact_branches` (``max_seconds``) runs out ("time budget"), or when it creeps
    for 100 steps at the smallest step size ("stalled": a singular corner, e.g. a relay
    force touched at zero speed, where Newton converges badly at every step).

Exact frequency response
    :func:`exact_branches` seeds from the closed-form arcs of every segment, the caller's
    seeds (the front door :func:`perturb.solve.frequency_response` adds points along an
    approximation's branches, :func:`perturb.seeds.approximation_seeds`), and up and down
    sweeps; it polishes each seed by Newton at fixed parameter,
    skips it when it lies on a traced branch, switches at every branch point, completes
    branches by the symmetry :math:`(x, t) \to (-x, t + T/2)` of odd systems (an image branch
    costs at most half a propagation per point), and, on request, follows period doublings.
    The sweeps are *virtual* where possible: a sweep follows the stable part of a traced
    branch without integrating, and integrates (``transient_periods``, then Newton from a
    nearly periodic state) only where that branch ends or loses stability — where a real
    sweep jumps — and across regions without a stable period-1 orbit.  A system without
    dissipation (no term depends on :math:`x'`) is not traced: the result is empty with a
    note saying why (no transient decays; neutral multipliers; families of free orbits) and
    what to do instead.  Friction and other switch functions of non-PWL models are traced on
    the event-driven flow (saltation at every switch, sticking), method ``'shooting'``.

Bounded work
    Every loop has a cap: the corrector's Newton iterations, the step attempts per step
    (``_MAX_STEP_ATTEMPTS``), the points and propagated periods per march, the branches and
    the wall-clock time of :func:`exact_branches`; non-finite steps and residuals end a march
    with a stop reason.  Worker processes of the pool end when the process that started it
    dies (``PR_SET_PDEATHSIG`` on Linux, and a thread watching the parent id).

Parallel tracing
    With ``workers > 1`` (default: two on a machine with two or more CPUs, serial inside a
    worker of another pool) the two halves of a branch are marched at once in forked worker
    processes, and the branches of all closed-form seeds at once.  A march's steps do not
    depend on its stop tests, only its end does, so a march made blind to the other half and
    to branches registered meanwhile is cut afterwards where the serial march would have
    stopped (the missing tests replayed point by point), and results are used in submission
    order: the branches are exactly the serial ones, whatever the timing.
"""

from __future__ import annotations

import cmath
import math
import time
from collections import OrderedDict
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from perturb.errors import ParameterError, PerturbError
from perturb.model.oscillator import Oscillator
from perturb.model.segments import SegmentSteadyState, segment_steady_states
from perturb.model.symmetry import is_odd_symmetric, mirror_nodes
from perturb.numeric.continuation import (
    Corrector,
    Evaluation,
    FloquetCrossings,
    FoldTest,
    StepControl,
    crossing_weight,
    hermite_direction,
    hermite_extrapolate,
    null_tangent,
)
from perturb.numeric.roots import RootResult, damped_newton, illinois, lu_or_lstsq
from perturb.progress import Progress
from perturb.response import Branch, Response
from perturb.simulate.flows.base import ODEFlow
from perturb.simulate.flows.factory import FlowFamily
from perturb.simulate.flows.piecewise_exact import sample_trajectories
from perturb.simulate.flows.system import frequency_symbol
from perturb.simulate.orbits.shooting import (
    PeriodicOrbit,
    ShootingError,
    monodromy_multipliers,
    multiple_shooting,
    periodic_orbit,
)

__all__ = [
    "SpecialPoint",
    "ContinuationPoint",
    "ContinuationBranch",
    "ExactBranches",
    "ExactResponseOptions",
    "continue_orbits",
    "switch_branch",
    "exact_branches",
    "exact_frequency_response",
    "exact_solutions_at",
]

#: Largest growth of perturbations per shooting node before another node is added (beyond
#: ~100 the initial state alone no longer separates neighbouring orbits at 0.5 % spacing).
NODE_GROWTH = 100.0
#: Largest number of shooting nodes per forcing period.
MAX_NODES = 64
#: Samples per forcing period for the mean and the first harmonic (continuous PWL forces
#: alias like n^-5: ~1e-7 relative at 128); the extrema of x are refined by a quintic
#: Hermite interpolant of (x, v, a) (~1e-10 relative).
STAT_SAMPLES = 128
#: Phases per forcing period of the orbit signature (states compared by proximity tests).
SIG_PHASES = 8
#: A point lies on a traced curve within this fraction of the longest of ds_max, the curve's
#: segment and the point's own step (a sampled curve deviates from its chords by
#: kappa L^2 / 8, far below this unless the curve turns within a step).
JOIN_FRACTION = 0.25
#: Largest last Newton correction (scaled) whose iterate supplies the orbit statistics.
STATS_TOL = 1.0e-7
#: A march stops after this many consecutive steps no longer than _STALL_DS * ds_min.
_STALL_STEPS, _STALL_DS = 100, 4.0
#: Largest number of predictor-corrector attempts for one continuation step.
_MAX_STEP_ATTEMPTS = 400
#: A multiplier modulus above this is reported as this (e^700 would overflow later products).
MAX_MULTIPLIER = 1.0e300

SpecialKind = Literal["fold", "branch_point", "period_doubling", "torus", "grazing"]


# =============================================================================================
# result objects
# =============================================================================================
@dataclass(frozen=True)
class SpecialPoint:
    """A bifurcation or grazing located between two consecutive points of a branch.

    Attributes
    ----------
    kind : str
        ``'fold'``, ``'branch_point'`` (a multiplier through +1 without a fold: symmetry-
        breaking pitchfork or transcritical point), ``'period_doubling'`` (through -1),
        ``'torus'`` (a complex pair through the unit circle) or ``'grazing'`` (the orbit
        becomes tangent to a breakpoint; the number of switches per period changes).
    index : int
        The point before it (it lies between ``points[index]`` and ``points[index + 1]``).
    parameter, amplitude : float
        Linear interpolation of the test function's zero.
    y0 : tuple of float
        Interpolated ``(x, v)`` at ``t0``.
    """

    kind: SpecialKind
    index: int
    parameter: float
    amplitude: float
    y0: tuple[float, float]

    def __repr__(self) -> str:
        return (
            f"SpecialPoint({self.kind} at p = {self.parameter:.6g}, amplitude "
            f"{self.amplitude:.6g}, after point {self.index})"
        )


@dataclass(frozen=True, eq=False)
class ContinuationPoint:
    """A converged periodic orbit on a branch.

    Attributes
    ----------
    parameter : float
    y0 : ndarray, shape (2,)
        ``(x, v)`` at ``t0`` (read-only).
    multipliers : ndarray of complex, shape (2,)
        Floquet multipliers by decreasing modulus.
    max_multiplier : float
        Largest modulus (capped at ``1e300``).
    stable : bool
        ``max_multiplier < 1``.
    amplitude, first_harmonic_amplitude, mean : float
        ``max |x|`` over the orbit period, the amplitude of the component at the forcing
        frequency, and the mean of ``x``.
    tangent : ndarray, shape (3,)
        Unit tangent in scaled ``(x0, v0, p)`` (state over the orbit size, parameter over the
        window), oriented along the branch.
    switches : int
        Breakpoint crossings per orbit period (``-1`` for smooth flows, which do not count).
    source : str
        ``'closed form'`` (orbit inside one linear segment: exact formula), ``'shooting'``,
        ``'multiple shooting'`` or ``'mirror'`` (image of another branch's orbit under the
        symmetry of an odd system).
    signature : ndarray, shape (16m,)
        ``(x, v)`` at ``t0 + kT/8``, ``k = 0 .. 8m-1``: with the amplitude, first harmonic
        and mean, what the proximity tests (joins, closed loops, duplicate seeds) compare.
    nodes : ndarray or None
        Multiple-shooting nodes ``(N, 2)`` when ``N > 1``.
    """

    parameter: float
    y0: np.ndarray
    multipliers: np.ndarray
    max_multiplier: float
    stable: bool
    amplitude: float
    first_harmonic_amplitude: float
    mean: float
    tangent: np.ndarray
    switches: int
    source: str
    signature: np.ndarray
    nodes: np.ndarray | None = None

    def __repr__(self) -> str:
        return (
            f"ContinuationPoint(p={self.parameter:.8g}, y0=({self.y0[0]:.8g}, {self.y0[1]:.8g}), "
            f"amplitude={self.amplitude:.8g}, {'stable' if self.stable else 'unstable'}, "
            f"max|mu|={self.max_multiplier:.4g}, {self.source})"
        )


@dataclass(frozen=True, eq=False)
class ContinuationBranch:
    """A traced branch of period-``m`` orbits, ordered along the curve.

    Attributes
    ----------
    parameter : str
        Name of the continuation parameter.
    m : int
        Forcing periods per orbit period.
    t0 : float
        Phase of the section where ``y0`` is taken.
    window : tuple of float
        Parameter range of the run.
    points : tuple of ContinuationPoint
    special_points : tuple of SpecialPoint
    closed : bool
        The branch is a closed loop (an isola if no other branch reaches it).
    stop_reason : str
        Why each end stopped (``'backward end / forward end'``).
    periods : float
        Work: propagated time in forcing periods (the exact propagator dominates the cost).
    family : FlowFamily
        The flows (not printed).
    """

    parameter: str
    m: int
    t0: float
    window: tuple[float, float]
    points: tuple[ContinuationPoint, ...]
    special_points: tuple[SpecialPoint, ...]
    closed: bool
    stop_reason: str
    periods: float
    family: FlowFamily = field(repr=False, compare=False)
    ds_max: float = 0.005

    def __len__(self) -> int:
        return len(self.points)

    def __repr__(self) -> str:
        if not self.points:
            return "ContinuationBranch(empty)"
        p, a = self.parameters, self.amplitudes
        shape = "closed loop" if self.closed else f"ends: {self.stop_reason}"
        kinds = ", ".join(
            f"{n} {k}{'s' if n > 1 else ''}"
            for k in ("fold", "branch_point", "period_doubling", "torus", "grazing")
            if (n := sum(s.kind == k for s in self.special_points))
        )
        return (
            f"ContinuationBranch(period {self.m}, {len(self)} points, {self.parameter} "
            f"{p.min():.4g}..{p.max():.4g}, amplitude {a.min():.4g}..{a.max():.4g}, "
            f"{int(sum(q.stable for q in self.points))} stable, {kinds or 'no special points'}, "
            f"{shape})"
        )

    # -- arrays --------------------------------------------------------------------------------
    @property
    def parameters(self) -> np.ndarray:
        return np.array([q.parameter for q in self.points])

    @property
    def amplitudes(self) -> np.ndarray:
        return np.array([q.amplitude for q in self.points])

    @property
    def states(self) -> np.ndarray:
        """``y0`` of every point, shape ``(n, 2)``."""
        return np.array([q.y0 for q in self.points]).reshape(-1, 2)

    def _kind(self, kind: str) -> tuple[SpecialPoint, ...]:
        return tuple(s for s in self.special_points if s.kind == kind)

    @property
    def folds(self) -> tuple[SpecialPoint, ...]:
        return self._kind("fold")

    @property
    def branch_points(self) -> tuple[SpecialPoint, ...]:
        return self._kind("branch_point")

    @property
    def period_doublings(self) -> tuple[SpecialPoint, ...]:
        return self._kind("period_doubling")

    @property
    def grazings(self) -> tuple[SpecialPoint, ...]:
        return self._kind("grazing")

    # -- conversions ---------------------------------------------------------------------------
    def to_branch(self) -> Branch:
        """The :class:`~perturb.response.Branch` with the standard columns."""
        pts = self.points
        return Branch(
            omega=[q.parameter for q in pts],
            amplitude=[q.amplitude for q in pts],
            first_harmonic_amplitude=[q.first_harmonic_amplitude for q in pts],
            mean=[q.mean for q in pts],
            stable=[q.stable for q in pts],
            max_multiplier=[q.max_multiplier for q in pts],
        )

    def orbit(self, index: int, *, tol: float = 1e-12) -> PeriodicOrbit:
        """The :class:`~perturb.simulate.orbits.shooting.PeriodicOrbit` at ``points[index]``,
        polished
        by shooting (multiple shooting on the stored nodes for strongly unstable orbits)."""
        q = self.points[index]
        flow = self.family.at(q.parameter)
        if q.nodes is not None:
            return multiple_shooting(flow, q.nodes, m=self.m, t0=self.t0, tol=tol)
        return periodic_orbit(flow, q.y0, m=self.m, t0=self.t0, tol=tol)

    def orbit_at(self, index: int, value: float) -> PeriodicOrbit | None:
        """The orbit at exactly the parameter ``value`` between ``points[index]`` and
        ``points[index + 1]``: their states interpolated linearly in the parameter, then
        shooting at ``value`` (multiple shooting when both carry nodes or the orbit is
        strongly unstable); None when shooting fails there."""
        if not 0 <= int(index) < len(self.points) - 1:
            raise ParameterError(f"index = {index!r}: expected 0 <= index < {len(self.points) - 1}")
        return _polish_at(self, int(index), float(value))


@dataclass(frozen=True, eq=False)
class ExactBranches:
    """Every branch found by :func:`exact_branches`, with the work it took.

    Attributes
    ----------
    branches : tuple of ContinuationBranch
    mirror_of : tuple of (int or None)
        For each branch, the branch it is the symmetric image of (odd systems), else None.
    notes : tuple of str
        What was done and what was skipped (budget, failed seeds).
    periods : float
        Propagated time in forcing periods (continuation, seeds and sweeps).
    seconds : float
        Wall-clock time.
    model : str
    params : mapping
    method : str
        ``'exact'`` for the exact PWL propagator, ``'shooting'`` for the ODE flow.
    """

    branches: tuple[ContinuationBranch, ...]
    mirror_of: tuple[int | None, ...]
    notes: tuple[str, ...]
    periods: float
    seconds: float
    model: str
    params: Any
    method: str

    def __len__(self) -> int:
        return len(self.branches)

    def __repr__(self) -> str:
        lines = [
            f"ExactBranches({self.model}: {len(self.branches)} branches, "
            f"{sum(len(b) for b in self.branches)} points, {self.periods:.0f} periods "
            f"propagated, {self.seconds:.2f} s)"
        ]
        for i, (b, mo) in enumerate(zip(self.branches, self.mirror_of, strict=True)):
            lines.append(f"  {i}: {b!r}" + (f" [mirror of {mo}]" if mo is not None else ""))
        return "\n".join(lines)

    def to_response(self) -> Response:
        """The :class:`~perturb.response.Response` (CSV columns of the project)."""
        notes = []
        for i, (b, mo) in enumerate(zip(self.branches, self.mirror_of, strict=True)):
            what = "closed loop" if b.closed else b.stop_reason
            extra = f", mirror image of branch {mo}" if mo is not None else ""
            per = f", period {b.m}" if b.m != 1 else ""
            notes.append(f"branch {i}: {what}{extra}{per}")
        folds = tuple(
            (s.parameter, s.amplitude)
            for b in self.branches
            for s in b.special_points
            if s.kind == "fold"
        )
        return Response(
            tuple(b.to_branch() for b in self.branches),
            self.method,
            self.model,
            dict(self.params),
            folds=folds,
            notes=tuple(notes) + self.notes,
        )


# =============================================================================================
# internal point record and evaluation
# =============================================================================================
class _Pt:
    """A converged point while tracing (mutable; frozen into ContinuationPoint at the end)."""

    __slots__ = (
        "p",
        "Z",
        "J",
        "mult",
        "stats",
        "sig",
        "switches",
        "mode",
        "seg",
        "tangent",
        "singular",
        "grazing",
        "source",
        "blocks",
        "fold",
        "_zmax",
    )

    def __init__(self, p: float, Z: np.ndarray) -> None:
        self.p = float(p)
        self.Z = np.array(Z, dtype=float).reshape(-1, 2)
        # max |Z| for R, asked for by every proximity test (Z is never changed in place)
        self._zmax = float(np.max(np.abs(self.Z)))
        self.J: np.ndarray | None = None  # [G_z | G_p], unscaled, at (or next to) the point
        self.mult = np.zeros(2, dtype=complex)
        self.stats = (0.0, 0.0, 0.0)  # amplitude, first harmonic, mean
        self.sig = np.zeros(2 * SIG_PHASES)  # states at SIG_PHASES phases per forcing period
        self.switches = -1
        self.mode = "shoot"  # or "closed"
        self.seg = -1
        self.tangent: np.ndarray | None = None  # unit tangent in scaled (Z, p), oriented
        self.singular = False
        self.grazing = False
        self.source = "shooting"
        self.blocks: list[np.ndarray] | None = None  # node sensitivities (branch switching)
        self.fold = False  # a refined fold (dp/ds = 0), inserted between two sampled points

    @property
    def N(self) -> int:
        return self.Z.shape[0]

    @property
    def y0(self) -> np.ndarray:
        return self.Z[0]

    @property
    def R(self) -> float:
        return max(1.0, self._zmax, self.stats[0])

    @property
    def max_mult(self) -> float:
        return float(min(MAX_MULTIPLIER, np.max(np.abs(self.mult))))

    def D(self, Sp: float) -> np.ndarray:
        """Scales of (Z, p): a unit step is the orbit size (shared by the N nodes) or the
        window."""
        out = np.full(2 * self.N + 1, self.R * math.sqrt(self.N))
        out[-1] = Sp
        return out

    def u(self) -> np.ndarray:
        return np.append(self.Z.ravel(), self.p)

    def tangent3(self) -> np.ndarray:
        t = self.tangent
        if t is None:
            return np.zeros(3)
        v = np.array([t[0], t[1], t[-1]])
        n = np.linalg.norm(v)
        return v / n if n > 0 else v

    def keys(self, m: int) -> list[np.ndarray]:
        """The key of every representation of a period-``m`` orbit: its initial state taken
        after 0, 1, .., m-1 forcing periods (the signature shifted by whole periods)."""
        if m == 1:
            return [self.key()]
        phases = self.sig.reshape(-1, 2)
        tail = np.concatenate((self.stats, (self.p, self.R)))
        return [
            np.concatenate((np.roll(phases, -j * SIG_PHASES, axis=0).ravel(), tail))
            for j in range(m)
        ]

    def key(self) -> np.ndarray:
        """``(signature, amplitude, first harmonic, mean, p, R)``: what proximity tests
        compare.  The state at several phases and the orbit's extremes separate orbits that a
        strongly unstable flow maps from nearly equal initial states (their ``y0`` can be
        0.5 % apart while the orbits differ by O(1)), and quasi-static orbits at low
        frequency that agree at most phases and differ in a short excursion."""
        return np.concatenate((self.sig, self.stats, (self.p, self.R)))


@dataclass
class _Eval:
    r: np.ndarray
    Gz: np.ndarray
    Gp: np.ndarray | None
    M: np.ndarray
    switches: int
    blocks: list[np.ndarray]
    trajs: list[Any] | None


def _node_growth(M: np.ndarray, N: int) -> float:
    """Growth of a perturbation over one of ``N`` node intervals, from the monodromy."""
    tr = abs(float(M[0, 0] + M[1, 1]))
    det = abs(float(M[0, 0] * M[1, 1] - M[0, 1] * M[1, 0]))
    rho = 0.5 * (tr + math.sqrt(tr * tr + 4.0 * det))  # bounds the spectral radius
    return max(1.0, rho) ** (1.0 / N) if math.isfinite(rho) else NODE_GROWTH


def _nodes_needed(max_mult: float, m: int) -> int:
    """Shooting nodes for an orbit: a growth of at most NODE_GROWTH per node, and a node at
    every forcing period."""
    k = 1
    if max_mult > NODE_GROWTH:
        k = int(math.ceil(math.log(min(max_mult, MAX_MULTIPLIER)) / math.log(NODE_GROWTH)))
    n = max(m, k)
    n = int(math.ceil(n / m) * m)
    return min(n, MAX_NODES * m)


class _Engine:
    """Flows, residuals, Jacobians and the work counter of one continuation problem."""

    def __init__(
        self, family: FlowFamily, m: int, t0: float, window: tuple[float, float], tol: float
    ) -> None:
        self.family = family
        self.m = int(m)
        self.t0 = float(t0)
        self.lo, self.hi = window
        self.Sp = self.hi - self.lo
        self.tol = tol
        self.periods = 0.0
        self.calls = 0
        self._flows: OrderedDict[float, Any] = OrderedDict()
        self.exact = bool(family.exact)
        sym = frequency_symbol(family.oscillator)
        # the forcing frequency must stay positive (other parameters may change sign)
        self.positive = sym is not None and sym.name == family.parameter
        probe = self.flow(0.5 * (self.lo + self.hi))
        if getattr(probe, "period", None) is None:
            raise ParameterError(
                f"the flow of {family.oscillator.name!r} has no forcing period: continuation of "
                "forced orbits needs a periodic forcing"
            )
        self.system0 = getattr(probe, "system", None)
        # own sensitivities from the trajectory pieces where saltation is the identity
        self._continuous = self.exact and bool(np.all(self.system0.continuous_at()))
        self._dw = self._frequency_rates() if self.exact else None
        self.closed_form = self.exact and self.m == 1 and bool(self.system0.forcing)

    # -- flows ---------------------------------------------------------------------------------
    def flow(self, p: float) -> Any:
        key = float(p)
        f = self._flows.get(key)
        if f is None:
            f = self.family.at(key)
            self._flows[key] = f
            if len(self._flows) > 24:
                self._flows.popitem(last=False)
        else:
            self._flows.move_to_end(key)
        return f

    def system(self, p: float) -> Any:
        return self.flow(p).system

    def period(self, p: float) -> float:
        return float(self.flow(p).period)

    def _frequency_rates(self) -> np.ndarray | None:
        """d omega_j / dp when p enters the PWL system only through the forcing frequencies,
        linearly and proportionally, and the force is continuous; else None (forward
        differences)."""
        try:
            vals = [self.lo, 0.5 * (self.lo + self.hi), self.hi]
            systems = [self.family.at(v).system for v in vals]
        except PerturbError:
            return None
        s0 = systems[1]
        if not np.all(s0.continuous_at()) or not s0.forcing:
            return None
        for s in systems:
            same = (
                np.array_equal(s.breakpoints, s0.breakpoints)
                and np.array_equal(s.slopes, s0.slopes)
                and np.array_equal(s.offsets, s0.offsets)
                and s.damping == s0.damping
                and s.static_force == s0.static_force
                and len(s.forcing) == len(s0.forcing)
                and all(
                    a[0] == b[0] and a[2] == b[2]
                    for a, b in zip(s.forcing, s0.forcing, strict=True)
                )
            )
            if not same:
                return None
        w = np.array([[f[1] for f in s.forcing] for s in systems])
        slope = (w[2] - w[0]) / (vals[2] - vals[0])
        # linear in p (so the rate is constant) and proportional (the period scales with it)
        mid = w[0] + slope * (vals[1] - vals[0])
        if not np.allclose(mid, w[1], rtol=1e-12, atol=0.0) or np.any(slope == 0.0):
            return None
        rel = slope / w[1]
        if not np.allclose(rel, rel[0], rtol=1e-10, atol=0.0):
            return None
        return slope

    # -- residual ------------------------------------------------------------------------------
    def node_times(self, P: float, N: int) -> np.ndarray:
        t = self.t0 + P * np.arange(N + 1) / N
        t[-1] = self.t0 + P
        return t

    def evaluate(self, Z: np.ndarray, p: float, gp: bool = True) -> _Eval:
        """Residual, Jacobians, monodromy and switches of the multiple-shooting problem.

        For a continuous PWL force the node sensitivities are assembled here from the
        trajectory's pieces (products of the exact exponentials; saltation is the identity),
        together with the parameter rate, so the exponentials are computed once."""
        flow = self.flow(p)
        P = self.m * float(flow.period)
        N = Z.shape[0]
        tn = self.node_times(P, N)
        r = np.empty(2 * N)
        Gz = np.zeros((2 * N, 2 * N))
        own = self._continuous
        Gp = np.empty(2 * N) if (gp and self._dw is not None) else None
        M = np.eye(2)
        blocks = []
        trajs: list[Any] | None = [] if self.exact else None
        switches = 0
        dP = -P * self._dw[0] / flow.system.forcing[0][1] if Gp is not None else 0.0
        self.periods += self.m
        self.calls += N
        system = flow.system if own else None
        for i in range(N):
            ta, tb = tn[i], tn[i + 1]
            if own:
                # the trajectory itself (its end state and switches), without the flow's
                # result object: a continuous force needs no saltation, and the sensitivity
                # comes from the pieces below
                traj = flow.trajectory(Z[i], ta, tb)
                trajs.append(traj)
                yb = np.array([traj.x[-1], traj.v[-1]], dtype=float)
                n_ev = sum(1 for e in traj.events if not e.tangency)
                Mi, zeta = self._pieces(flow, traj, tb, Gp is not None)
            else:
                res = flow(Z[i], ta, tb, sensitivity=True)
                if trajs is not None:
                    trajs.append(flow.trajectory(Z[i], ta, tb))  # memoised: no propagation
                yb, n_ev = res.y, res.n_events
                Mi, zeta = np.asarray(res.sensitivity, dtype=float), None
            blocks.append(Mi)
            j = (i + 1) % N
            r[2 * i : 2 * i + 2] = yb - Z[j]
            Gz[2 * i : 2 * i + 2, 2 * i : 2 * i + 2] += Mi
            Gz[2 * i, 2 * j] -= 1.0
            Gz[2 * i + 1, 2 * j + 1] -= 1.0
            M = Mi @ M
            switches += int(n_ev)
            if Gp is not None:
                if zeta is None:
                    Gp = None
                else:
                    # the field at both ends (scalar: the same values as vector_field)
                    fb = np.array(system.field1(float(tb), float(yb[0]), float(yb[1])))
                    fa = np.array(system.field1(float(ta), float(Z[i, 0]), float(Z[i, 1])))
                    Gp[2 * i : 2 * i + 2] = zeta + fb * ((i + 1) / N) * dP - Mi @ fa * (i / N) * dP
        if not np.all(np.isfinite(M)):
            raise PerturbError("the monodromy overflows: the orbit is too unstable for its nodes")
        return _Eval(r, Gz, Gp, M, switches if self.exact else -1, blocks, trajs)

    def gp_fd(self, Z: np.ndarray, p: float, r: np.ndarray) -> np.ndarray:
        """Forward difference of G in p (one propagation without sensitivity).  The step
        balances truncation against the flow's own error: ~sqrt(rtol) for an integrator,
        1e-7 (~sqrt(eps)) for the exact flow."""
        rtol = float(getattr(self.flow(p), "rtol", 0.0))
        h = max(1e-7, 3.0 * math.sqrt(rtol)) * max(1.0, abs(p))
        flow = self.flow(p + h)
        P = self.m * float(flow.period)
        N = Z.shape[0]
        tn = self.node_times(P, N)
        rh = np.empty(2 * N)
        for i in range(N):
            rh[2 * i : 2 * i + 2] = flow(Z[i], tn[i], tn[i + 1]).y - Z[(i + 1) % N]
        self.periods += self.m
        self.calls += N
        return (rh - r) / h

    @staticmethod
    def _samples(flow: Any, y: np.ndarray, a: float, b: float, t: np.ndarray) -> np.ndarray:
        """States at times ``t`` in [a, b]: one integration with dense output for an ODE flow
        (its ``t_eval`` would integrate twice), else the flow's own sampling."""
        rhs = getattr(flow, "rhs", None)
        if isinstance(flow, ODEFlow) and rhs is not None:
            sol = solve_ivp(
                rhs.fun,
                (a, b),
                y,
                method="DOP853",
                rtol=flow.rtol,
                atol=flow.atol,
                dense_output=True,
            )
            if sol.status == 0:
                return sol.sol(t)
        return np.asarray(flow(y, a, b, t_eval=t).ys).T

    def _pieces(
        self, flow: Any, traj: Any, tb: float, want_rate: bool
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """Sensitivity ``d y(tb) / d y(ta)`` (continuous force) and, on request, the exact
        parameter rate ``d phi / dp`` at fixed times (frequency parameter), from the
        trajectory's pieces; see the module docstring.  Scalar arithmetic throughout: a node
        interval has a handful of pieces, where array code is mostly call overhead."""
        sys_ = flow.system
        mu = float(sys_.damping)
        pieces = traj.pieces
        n = len(pieces)
        E = traj.transition_matrices()
        m00, m01, m10, m11 = E[0]
        for e00, e01, e10, e11 in E[1:]:
            m00, m01, m10, m11 = (
                e00 * m00 + e01 * m10,
                e00 * m01 + e01 * m11,
                e10 * m00 + e11 * m10,
                e10 * m01 + e11 * m11,
            )
        M = np.array([[m00, m01], [m10, m11]])
        if not want_rate:
            return M, None
        a = [q.t0 for q in pieces]
        b = a[1:] + [float(tb)]
        slopes = [float(sys_.slopes[q.segment]) for q in pieces]
        inc0 = [0.0] * n
        inc1 = [0.0] * n
        for (F, w, ph), dw in zip(sys_.forcing, self._dw, strict=True):
            if F == 0.0:
                continue
            cF = 1j * F * float(dw) * cmath.exp(1j * ph)
            ww = w * w
            for k in range(n):
                sk = slopes[k]
                det = complex(sk - ww, mu * w)
                if abs(det) < 1e-12 * (abs(sk) + ww):
                    return M, None  # undamped resonance in a segment: no particular solution
                c = cF / det
                # zeta_p(t) = Re[(R t - R^2) e2 c' e^{iwt}], R e2 = (1, iw)/det,
                # R^2 e2 = (2iw + mu, -s - w^2)/det^2  (c' = c det)
                ak, bk = a[k], b[k]
                ea, eb = cmath.exp(1j * w * ak), cmath.exp(1j * w * bk)
                q0 = (2j * w + mu) / det
                q1 = (-sk - ww) / det
                za0 = c * (ak - q0) * ea
                za1 = c * (1j * w * ak - q1) * ea
                zb0 = c * (bk - q0) * eb
                zb1 = c * (1j * w * bk - q1) * eb
                e00, e01, e10, e11 = E[k]
                inc0[k] += (zb0 - e00 * za0 - e01 * za1).real
                inc1[k] += (zb1 - e10 * za0 - e11 * za1).real
        z0 = z1 = 0.0
        for k in range(n):
            e00, e01, e10, e11 = E[k]
            z0, z1 = e00 * z0 + e01 * z1 + inc0[k], e10 * z0 + e11 * z1 + inc1[k]
        if not (math.isfinite(z0) and math.isfinite(z1)):
            return M, None
        return M, np.array([z0, z1])

    # -- orbit data ----------------------------------------------------------------------------
    def finish(self, pt: _Pt, ev: _Eval, Zev: np.ndarray, p_ev: float) -> None:
        """Multipliers, statistics, signature and switches of a converged point, from the
        evaluation at ``(Zev, p_ev)``, the last propagated iterate (its trajectories are
        reused: the statistics cost no propagation)."""
        flow = self.flow(p_ev)
        P = self.m * float(flow.period)
        det = flow.sensitivity_determinant(self.t0, self.t0 + P)  # None: not known exactly
        pt.mult = monodromy_multipliers(ev.M, det)
        pt.switches = ev.switches
        *stats, sig = self.statistics(flow, Zev, P, ev.trajs)
        pt.stats = tuple(stats)
        pt.sig = sig
        pt.J = None
        pt.blocks = ev.blocks
        pt.source = "multiple shooting" if pt.N > 1 else "shooting"

    def statistics(
        self, flow: Any, Z: np.ndarray, P: float, trajs: list[Any] | None = None
    ) -> tuple[float, float, float, np.ndarray]:
        """(max |x|, first-harmonic amplitude, mean, signature) over one orbit period.

        Mean and first harmonic by the FFT of ``STAT_SAMPLES`` samples per forcing period,
        the signature from every ``STAT_SAMPLES / SIG_PHASES``-th of them, the extrema of x
        refined between the samples."""
        m, N = self.m, Z.shape[0]
        n = STAT_SAMPLES * m
        t = self.t0 + P * np.arange(n + 1) / n
        node_t = self.node_times(P, N)
        idx = np.clip(np.searchsorted(node_t, t, side="right") - 1, 0, N - 1)
        if trajs is None and self.exact:
            trajs = [flow.trajectory(Z[i], node_t[i], node_t[i + 1]) for i in range(N)]
        if trajs is not None:
            # one vectorised evaluation per segment of the force over all node intervals
            X = sample_trajectories(trajs, np.clip(t, node_t[idx], node_t[idx + 1]), idx)
        else:
            X = np.empty((2, n + 1))
            for i in range(N):
                sel = idx == i
                if not np.any(sel):
                    continue
                a, b = node_t[i], node_t[i + 1]
                X[:, sel] = self._samples(flow, Z[i], a, b, np.clip(t[sel], a, b))
                self.periods += self.m / N
                self.calls += 1
        x = X[0, :n]
        c = np.fft.rfft(x) / n
        mean = float(c[0].real)
        first = float(2.0 * abs(c[m])) if m < c.size else 0.0
        sig = X[:, : n : STAT_SAMPLES // SIG_PHASES].T.ravel().copy()
        # extrema of x: the quintic Hermite interpolant of (x, v, a) on the sample interval
        # where v changes sign next to the extreme sample, O(h^6) (~1e-10 relative); the
        # stored orbit differs from the sampled one by up to STATS_TOL anyway
        best = [float(x.max()), float(x.min())]
        for which, sign in enumerate((1.0, -1.0)):
            j = int(np.argmax(sign * x))
            for a_i, b_i in (((j - 1) % n, j), (j, j + 1)):
                ta, tb = t[a_i], t[b_i]
                if not (sign * X[1, a_i] >= 0.0 >= sign * X[1, b_i] and tb > ta):
                    continue
                xr = self._reversal_extremum(flow, ta, tb, X[:, a_i], sign)
                if xr is None:
                    xr = self._hermite_extremum(flow, ta, tb, X[:, a_i], X[:, b_i], sign)
                if sign * xr > sign * best[which]:
                    best[which] = xr
        return max(abs(best[0]), abs(best[1])), first, mean, sig

    @staticmethod
    def _reversal_extremum(
        flow: Any, ta: float, tb: float, ya: np.ndarray, sign: float
    ) -> float | None:
        """For an event-driven flow whose field switches at x' = 0 (friction ``sign(x')``):
        the extremum of x on ``[ta, tb]``, read at the velocity reversal the flow locates.
        The acceleration jumps there, so the Hermite interpolant of (x, v, a) would be
        accurate to O(h^2) only (~3e-6 relative at 128 samples per period).  None when the
        flow has no such surface or meets no reversal in the interval."""
        surfaces = getattr(flow, "surfaces", None)
        simulate = getattr(flow, "simulate", None)
        if not surfaces or simulate is None:
            return None
        rev = {j for j, q in enumerate(surfaces) if q.a == 0.0 and q.c == 0.0 and q.b != 0.0}
        if not rev:
            return None
        try:
            tr = simulate(ya, (ta, tb))
        except PerturbError:
            return None
        xs = [e.x for e in tr.events if e.surface in rev and e.kind != "graze"]
        if not xs:
            return None
        return max(xs) if sign > 0 else min(xs)

    @staticmethod
    def _hermite_extremum(
        flow: Any, ta: float, tb: float, ya: np.ndarray, yb: np.ndarray, sign: float
    ) -> float:
        """Extreme value of x on ``[ta, tb]`` from the quintic Hermite interpolant of
        (x, v, a) at the ends, O(h^6) accurate (~1e-10 relative at 128 samples per period; a
        switch inside the interval costs little accuracy because v, which multiplies the
        jump of the third derivative, vanishes at the extremum)."""
        h = tb - ta
        system = getattr(flow, "system", None)
        if system is not None:
            # the exact flow's scalar field (same arithmetic as its vector_field)
            aa = system.field1(float(ta), float(ya[0]), float(ya[1]))[1]
            ab = system.field1(float(tb), float(yb[0]), float(yb[1]))[1]
        else:
            aa = float(flow.vector_field(ta, ya)[1])
            ab = float(flow.vector_field(tb, yb)[1])
        _, xr = _hermite5_extremum(ya[0], ya[1] * h, aa * h * h, yb[0], yb[1] * h, ab * h * h, sign)
        return xr


def _hermite5_extremum(x0, d0, s0, x1, d1, s1, sign) -> tuple[float, float]:
    """(s, value) of the extremum on [0, 1] of the quintic with the given values, first and
    second derivatives at the ends (derivatives already scaled by h, h^2): safeguarded Newton
    on p'(s) = 0 (p' changes sign on the bracket by construction)."""
    c0, c1, c2 = x0, d0, 0.5 * s0
    r1 = x1 - c0 - c1 - c2
    r2 = d1 - c1 - 2 * c2
    r3 = s1 - 2 * c2
    # [[1, 1, 1], [3, 4, 5], [6, 12, 20]] (c3, c4, c5) = (r1, r2, r3), solved in closed form
    c3 = 10 * r1 - 4 * r2 + 0.5 * r3
    c4 = -15 * r1 + 7 * r2 - r3
    c5 = 6 * r1 - 3 * r2 + 0.5 * r3

    def val(s: float) -> float:
        return c0 + s * (c1 + s * (c2 + s * (c3 + s * (c4 + s * c5))))

    def der(s: float) -> float:
        return c1 + s * (2 * c2 + s * (3 * c3 + s * (4 * c4 + s * 5 * c5)))

    def der2(s: float) -> float:
        return 2 * c2 + s * (6 * c3 + s * (12 * c4 + s * 20 * c5))

    lo, hi = 0.0, 1.0
    g_lo = sign * der(lo)
    if g_lo <= 0.0 or sign * der(hi) >= 0.0:
        return (0.0, x0) if sign * x0 >= sign * x1 else (1.0, x1)
    s = 0.5
    for _ in range(30):
        g = sign * der(s)
        if g > 0.0:
            lo = s
        else:
            hi = s
        g2 = sign * der2(s)
        sn = s - g / g2 if g2 != 0.0 else 0.5 * (lo + hi)
        if not lo < sn < hi:
            sn = 0.5 * (lo + hi)
        if abs(sn - s) < 1e-14:
            s = sn
            break
        s = sn
    return s, val(s)


# =============================================================================================
# closed-form orbits inside one linear segment
# =============================================================================================
def _segment_state(sys_: Any, seg: int) -> SegmentSteadyState | None:
    """The closed-form steady state of linear segment ``seg`` (:mod:`perturb.model.segments`,
    the one place the formula is written), or None."""
    return segment_steady_states(
        sys_.breakpoints,
        sys_.slopes,
        sys_.offsets,
        sys_.damping,
        sys_.forcing,
        sys_.static_force,
    )[seg]


def _segment_orbit(sys_: Any, seg: int, P: float, t: np.ndarray) -> tuple[np.ndarray, ...] | None:
    """(x, v) of the steady state of linear segment ``seg`` at times ``t``, or None."""
    state = _segment_state(sys_, seg)
    return None if state is None else state.states(t)


def _segment_info(sys_: Any, seg: int, P: float) -> tuple[float, float, float, float] | None:
    """(margin, xmin, xmax, xc) of segment ``seg``'s steady state; margin > 0 when it stays
    inside the segment."""
    state = _segment_state(sys_, seg)
    if state is None:
        return None
    if len(state.forcing) == 1:
        xmin, xmax = state.xmin, state.xmax  # exact for one load
    else:
        # several loads: the extremes of the sampled orbit (the segment's half_range is only
        # a bound there)
        x, _ = state.states(np.linspace(0.0, P, 513))
        xmin, xmax = float(x.min()), float(x.max())
    return min(state.upper - xmax, xmin - state.lower), xmin, xmax, state.centre


class _Closed:
    """Closed-form points for one engine (m = 1, exact PWL flows)."""

    def __init__(self, eng: _Engine) -> None:
        self.eng = eng

    def margin(self, p: float, seg: int) -> float:
        info = _segment_info(self.eng.system(p), seg, self.eng.period(p))
        return -math.inf if info is None else info[0]

    def y0(self, p: float, seg: int) -> np.ndarray:
        eng = self.eng
        out = _segment_orbit(eng.system(p), seg, eng.period(p), np.array([eng.t0]))
        assert out is not None
        return np.array([out[0][0], out[1][0]])

    def amplitude(self, p: float, seg: int) -> float:
        info = _segment_info(self.eng.system(p), seg, self.eng.period(p))
        return 0.0 if info is None else max(abs(info[1]), abs(info[2]))

    def damplitude(self, p: float, seg: int) -> float:
        h = 1e-6 * max(self.eng.Sp, 1e-3)
        return (self.amplitude(p + h, seg) - self.amplitude(p - h, seg)) / (2 * h)

    def dydp(self, p: float, seg: int) -> np.ndarray:
        h = 1e-6 * max(self.eng.Sp, 1e-3)
        return (self.y0(p + h, seg) - self.y0(p - h, seg)) / (2 * h)

    def point(self, p: float, seg: int, N: int = 1) -> _Pt:
        """The exact orbit of segment ``seg`` at ``p`` (nodes at ``t0 + iT/N``)."""
        eng = self.eng
        sys_ = eng.system(p)
        P = eng.period(p)
        tn = eng.t0 + P * np.arange(N) / N
        out = _segment_orbit(sys_, seg, P, tn)
        info = _segment_info(sys_, seg, P)
        assert out is not None and info is not None
        pt = _Pt(p, np.column_stack(out))
        s, mu = float(sys_.slopes[seg]), float(sys_.damping)
        lam = np.roots([1.0, mu, s]).astype(complex) * P
        mult = np.exp(np.minimum(lam.real, 700.0)) * np.exp(1j * lam.imag)
        pt.mult = mult[np.argsort(-np.abs(mult), kind="stable")]
        tt = eng.t0 + P * np.arange(STAT_SAMPLES) / STAT_SAMPLES
        xs, vs = _segment_orbit(sys_, seg, P, tt)
        c = np.fft.rfft(xs) / STAT_SAMPLES
        _, xmin, xmax, xc = info
        pt.stats = (max(abs(xmin), abs(xmax)), float(2.0 * abs(c[1])), float(xc))
        q = STAT_SAMPLES // SIG_PHASES
        pt.sig = np.column_stack([xs[::q], vs[::q]]).ravel()
        pt.switches = 0
        pt.mode = "closed"
        pt.seg = seg
        pt.source = "closed form"
        return pt

    def set_tangent(self, pt: _Pt, direction: float) -> None:
        """Tangent of a closed-form arc (a graph over p), oriented by ``direction``."""
        d = self.dydp(pt.p, pt.seg)
        D = pt.D(self.eng.Sp)
        t = np.r_[d / D[0], np.zeros(2 * pt.N - 2), 1.0 / D[-1]]
        pt.tangent = direction * t / np.linalg.norm(t)
        pt.singular = False

    def match(self, pt: _Pt) -> int:
        """Segment whose closed-form orbit ``pt`` is (strictly inside it), else -1."""
        if pt.switches != 0 or pt.N != 1:
            return -1
        seg = int(self.eng.system(pt.p).segment_of(float(pt.y0[0])))
        if self.margin(pt.p, seg) <= 1e-9 * pt.R:
            return -1
        if np.max(np.abs(self.y0(pt.p, seg) - pt.y0)) > 1e-6 * pt.R:
            return -1
        return seg

    def seeds(self, n: int = 64) -> list[_Pt]:
        """One closed-form point per run of the window where a segment's orbit stays inside."""
        eng = self.eng
        grid = np.linspace(eng.lo, eng.hi, n)
        out = []
        for seg in range(eng.system0.n_segments):
            inside = np.array([self.margin(p, seg) > 0 for p in grid])
            idx = np.flatnonzero(inside)
            if idx.size == 0:
                continue
            for run in np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1):
                out.append(self.point(float(grid[run[len(run) // 2]]), seg))
        return out


# =============================================================================================
# proximity to traced branches (orbit signatures)
# =============================================================================================
def _segment_distance(
    q: np.ndarray, A: np.ndarray, B: np.ndarray, Sp: float
) -> tuple[np.ndarray, np.ndarray]:
    """Distances of key ``q`` to the segments [A_k, B_k] and their lengths, with states
    scaled per segment by the largest ``R`` of the point and the ends, the parameter by
    ``Sp``."""
    R = np.maximum(np.maximum(A[:, -1], B[:, -1]), q[-1])
    inv = (1.0 / R)[:, None]
    a = A[:, :-2] * inv
    ab = B[:, :-2] * inv - a
    qa = q[None, :-2] * inv - a
    abp = (B[:, -2] - A[:, -2]) / Sp
    qap = (q[-2] - A[:, -2]) / Sp
    L2 = np.einsum("ij,ij->i", ab, ab) + abp * abp
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.where(L2 > 0, (np.einsum("ij,ij->i", qa, ab) + qap * abp) / L2, 0.0)
    s = np.clip(s, 0.0, 1.0)
    e = qa - s[:, None] * ab
    ep = qap - s * abp
    return np.sqrt(np.einsum("ij,ij->i", e, e) + ep * ep), np.sqrt(L2)


def _key_step(a: _Pt, b: _Pt, Sp: float) -> float:
    """Distance of two points in the proximity metric."""
    R = max(a.R, b.R)
    if a.sig.size != b.sig.size:
        return math.inf
    ds_ = b.sig - a.sig
    d2 = float(ds_ @ ds_) + sum((x - y) ** 2 for x, y in zip(b.stats, a.stats, strict=True))
    return math.sqrt(d2 / (R * R) + ((b.p - a.p) / Sp) ** 2)


class _Growing:
    """An array that grows along its first axis by appending rows (amortised O(1))."""

    def __init__(self, shape: tuple[int, ...] = ()) -> None:
        self._a = np.empty((64, *shape))
        self.n = 0

    def append(self, row: Any) -> None:
        if self.n == self._a.shape[0]:
            self._a = np.concatenate([self._a, np.empty_like(self._a)])
        self._a[self.n] = row
        self.n += 1

    @property
    def arr(self) -> np.ndarray:
        return self._a[: self.n]


class _Poly:
    """The keys of a traced curve, for "does this point lie on it" queries.

    A point lies on segment k when its distance is below JOIN_FRACTION of the longest of
    ``ds_max``, the segment and the step ``h`` that produced the point (a sampled curve
    deviates from its chords by ``kappa L^2 / 8``).  The distance is at least the parameter
    gap over ``Sp``, so a per-segment parameter range (grown by that tolerance) rules out
    most segments before any distance is computed."""

    def __init__(self, width: int, Sp: float, ds_max: float, m: int = 1) -> None:
        self.keys = _Growing((width,))
        self.lo = _Growing()
        self.hi = _Growing()
        self.lo_min, self.hi_max = math.inf, -math.inf
        self.Sp, self.base, self.m = Sp, ds_max, m

    @classmethod
    def of(cls, pts: list[_Pt], Sp: float, ds_max: float, m: int = 1) -> _Poly:
        width = pts[0].key().size if pts else 2 * SIG_PHASES * m + 5
        out = cls(width, Sp, ds_max, m)
        for q in pts:
            out.append(q.key())
        return out

    def __len__(self) -> int:
        return self.keys.n

    def append(self, key: np.ndarray) -> None:
        if self.keys.n:
            prev = self.keys.arr[-1]
            # the segment's length in the metric of _segment_distance (a margin of the
            # parameter prefilter only: computed without its array machinery)
            inv = 1.0 / max(float(prev[-1]), float(key[-1]))
            ab = key[:-2] * inv - prev[:-2] * inv
            abp = (float(key[-2]) - float(prev[-2])) / self.Sp
            L = math.sqrt(float(ab @ ab) + abp * abp)
            grow = self.Sp * JOIN_FRACTION * max(L, self.base)
            lo, hi = min(prev[-2], key[-2]) - grow, max(prev[-2], key[-2]) + grow
            self.lo.append(lo)
            self.hi.append(hi)
            self.lo_min, self.hi_max = min(self.lo_min, lo), max(self.hi_max, hi)
        self.keys.append(key)

    def near(self, q: np.ndarray, h: float = 0.0, start: int = 0, stop: int | None = None) -> int:
        """Index of a segment (among segments ``start .. stop-1``) that key ``q`` lies on,
        else -1."""
        n = self.keys.n
        if n == 0 or self.keys.arr.shape[1] != q.size:
            return -1
        if n == 1:
            d, _ = _segment_distance(q, self.keys.arr, self.keys.arr, self.Sp)
            return 0 if d[0] < JOIN_FRACTION * max(h, self.base) else -1
        stop = n - 1 if stop is None else min(stop, n - 1)
        if stop <= start:
            return -1
        extra = self.Sp * JOIN_FRACTION * h
        qp = q[-2]
        if start == 0 and not self.lo_min - extra <= qp <= self.hi_max + extra:
            return -1
        lo, hi = self.lo.arr[start:stop], self.hi.arr[start:stop]
        idx = np.flatnonzero((lo - extra <= qp) & (qp <= hi + extra)) + start
        if idx.size == 0:
            return -1
        K = self.keys.arr
        d, L = _segment_distance(q, K[idx], K[idx + 1], self.Sp)
        ok = d < JOIN_FRACTION * np.maximum(np.maximum(L, h), self.base)
        if not np.any(ok):
            return -1
        return int(idx[int(np.argmin(np.where(ok, d, np.inf)))])

    def parallel(self, k: int, a: np.ndarray, b: np.ndarray) -> float:
        """|cos| of the angle between segment ``k`` and the step from key ``a`` to ``b``."""
        K = self.keys.arr
        R = max(K[k, -1], K[k + 1, -1], a[-1], b[-1])
        scale = np.append(np.full(a.size - 2, R), self.Sp)
        u = (K[k + 1, :-1] - K[k, :-1]) / scale
        v = (b[:-1] - a[:-1]) / scale
        nu, nv = float(np.linalg.norm(u)), float(np.linalg.norm(v))
        return abs(float(u @ v)) / (nu * nv) if nu > 0 and nv > 0 else 1.0


class _Registry:
    """Traced branches (their key polylines), to skip seeds on them and to stop where a march
    runs into one."""

    def __init__(self, Sp: float, ds_max: float) -> None:
        self.items: list[_Poly] = []
        self.Sp = Sp
        self.ds_max = ds_max

    def add(self, pts: list[_Pt], m: int) -> int:
        self.items.append(_Poly.of(pts, self.Sp, self.ds_max, m))
        return len(self.items) - 1

    def near(self, q: _Pt, m: int, h: float = 0.0) -> tuple[int, int]:
        """(branch, segment) of a traced branch of period ``m`` that ``q`` (in any of its
        ``m`` representations) lies on, else (-1, -1)."""
        keys = q.keys(m)
        for i, it in enumerate(self.items):
            if it.m != m:
                continue
            for key in keys:
                k = it.near(key, h)
                if k >= 0:
                    return i, k
        return -1, -1


# =============================================================================================
# the corrector and the march
# =============================================================================================
@dataclass
class _Settings:
    ds_max: float
    ds_min: float
    tol: float
    max_points: int
    max_periods: float
    max_iter: int = 6
    #: time.monotonic() after which marches stop ("time budget"); the same clock in forked
    #: workers
    deadline: float = math.inf


def _spacing(a: _Pt, b: _Pt, Sp: float) -> float:
    """Output spacing of two consecutive points: the larger of the parameter step over the
    window and the relative amplitude step."""
    da = abs(b.stats[0] - a.stats[0]) / max(1.0, a.stats[0], b.stats[0])
    return max(abs(b.p - a.p) / Sp, da)


class _StepControl(StepControl):
    """Step length in scaled (Z, p) arclength: the core's :class:`~perturb.numeric.
    continuation.StepControl` with this engine's pace and an output-spacing cap.

    The corrector's work sets the pace (grow after at most two propagations, shrink after
    four); the output spacing caps it: the ratio of output spacing to step of the last step
    predicts the step that gives ``ds_max`` of spacing, and a step whose spacing exceeds
    ``1.5 ds_max`` is redone shorter.  The step itself may exceed ``ds_max`` where the state
    turns (the phase of the orbit rotates through a resonance) while (p, amplitude) move
    little, up to ``DS_CAP`` times ``ds_max``.
    """

    DS_CAP = 8.0
    #: (most Newton iterations, step factor)
    PACE = ((2, 1.6), (3, 1.15), (4, 1.0), (math.inf, 0.6))

    def __init__(self, st: _Settings) -> None:
        # start a quarter of the largest step: the spacing ratio is not known yet
        super().__init__(0.25 * st.ds_max, st.ds_min, st.ds_max, self.PACE)
        self.st = st
        self.last_ok = st.ds_max
        self.iters = 0
        # quadratic-convergence constant |d1| / |d0|^2 of the corrector (largest recent)
        self.quad = 1.0e4
        self._quads: list[float] = []

    def observe(self, c: float) -> None:
        self._quads = (self._quads + [min(max(c, 1.0), 1e8)])[-8:]
        self.quad = max(max(self._quads), 10.0)

    def restart(self) -> None:
        self.step = 0.25 * self.st.ds_max

    def accept(self, ds: float, evals: int, spacing: float, force: bool = False) -> bool:
        """Pace the next step after a converged step ``ds``; False (and a shorter step) when
        its output spacing is too coarse and it must be redone."""
        st = self.st
        rho = spacing / ds if ds > 0 else 1.0
        if not force and spacing > 1.5 * st.ds_max and ds > 4 * st.ds_min:
            self.step = max(st.ds_min, 0.8 * st.ds_max / max(rho, 1e-12))
            return False
        self.last_ok = ds
        # the pace follows the Newton iterations (a forward-difference column is not one)
        it = self.iters if self.iters else evals
        self.iters = 0
        self.step = ds
        self.accepted(it, limit=min(self.DS_CAP * st.ds_max, 0.9 * st.ds_max / max(rho, 1e-12)))
        return True

    def jumps(self) -> list[float]:
        return [min(self.st.ds_max, k * self.last_ok) for k in (4.0, 16.0)]


def _correct(
    eng: _Engine,
    u_pred: np.ndarray,
    N: int,
    D: np.ndarray,
    dvec: np.ndarray,
    ds: float,
    st: _Settings,
    *,
    max_iter: int | None = None,
    first_cap: float = 0.75,
    ctl: _StepControl | None = None,
) -> tuple[_Pt | None, int]:
    r"""Newton on :math:`G(u) = 0,\ \hat d\cdot(\hat u - \hat u_{pred}) = 0` from ``u_pred``
    (scales ``D``, unit normal ``dvec`` in scaled coordinates).

    A correction is accepted when the estimated error of the next iterate is below ``tol``
    and the correction itself below STATS_TOL (the statistics come from the propagated
    iterate).  With a step control that knows the quadratic-convergence constant
    :math:`C = \|\Delta_1\|/\|\Delta_0\|^2` of earlier corrections, a first correction with
    :math:`C\|\Delta_0\|^2 \le` tol is accepted after one propagation (an accurate
    predictor).  Returns the point (None on failure) and the propagations used.

    The Newton loop is the continuation core's :class:`~perturb.numeric.continuation.Corrector`
    in unscaled coordinates (``u += du D``, border through the scaled prediction), with one
    shooting propagation per iterate for :math:`G, G_Z, G_p` and the monodromy, the forward
    difference + Broyden column when the flow gives no :math:`G_p`, the parameter window as an
    unevaluable iterate, and the first-step cap ``first_cap ds + 10 tol``."""
    Sp = eng.Sp
    max_iter = st.max_iter if max_iter is None else max_iter

    def evaluate(u: np.ndarray) -> Evaluation | None:
        p = float(u[-1])
        if not (eng.lo - 0.5 * Sp < p < eng.hi + 0.5 * Sp) or (eng.positive and p <= 0.0):
            return None
        try:
            ev = eng.evaluate(u[:-1].reshape(N, 2), p)
        except PerturbError:
            return None
        return Evaluation(ev.r, ev.Gz, ev.Gp, ev)

    def fd_column(u: np.ndarray, r: np.ndarray) -> np.ndarray | None:
        try:
            return eng.gp_fd(u[:-1].reshape(N, 2), float(u[-1]), r)
        except PerturbError:
            return None

    def observe(k: int, n: float, prev: float) -> None:
        if ctl is not None and k == 1 and prev > 1e-12:
            ctl.observe(n / (prev * prev))

    def accept(k: int, n: float, prev: float, e: Evaluation) -> bool:
        # accept: the next iterate's error is below tol, and the statistics (from the
        # propagated iterate) within STATS_TOL of the stored orbit: the correction times the
        # growth of a perturbation over one node interval
        if k == 0:
            est = n if ctl is None else max(n * n * ctl.quad, 1e-3 * n)
        else:
            est = n * min(1.0, n / prev)
        return est <= st.tol and n * _node_growth(e.payload.M, N) <= STATS_TOL

    newton = Corrector(evaluate, scaled=False, fd_column=fd_column)
    c = newton.correct(
        u_pred,
        D,
        dvec,
        max_iter=max_iter,
        accept=accept,
        observe=observe,
        anchor=u_pred / D,
        cap=first_cap * ds + 10 * st.tol,
    )
    if c is None:
        return None, newton.evaluations
    pt = _Pt(float(c.x[-1]), c.x[:-1])
    eng.finish(
        pt, c.evaluation.payload, c.x_evaluated[:-1].reshape(N, 2).copy(), float(c.x_evaluated[-1])
    )
    pt.J = np.hstack([c.evaluation.ju, c.jl[:, None]])
    if ctl is not None:
        ctl.iters = c.iterations
    return pt, c.evaluations


def _null_tangent(pt: _Pt, Sp: float) -> tuple[np.ndarray, bool]:
    """Scaled unit null vector of [G_z | G_p] and whether the Jacobian is rank deficient."""
    assert pt.J is not None
    return null_tangent(pt.J * pt.D(Sp)[None, :])


def _chord(a: _Pt, b: _Pt, Sp: float) -> np.ndarray | None:
    """Scaled chord from a to b in (Z, p) with b's scales, or None if N differs."""
    if a.N != b.N:
        return None
    return (b.u() - a.u()) / b.D(Sp)


def _chord3(a: _Pt, b: _Pt, Sp: float) -> np.ndarray:
    """Scaled chord on (x0, v0, p)."""
    R = max(a.R, b.R)
    return np.array([(b.Z[0, 0] - a.Z[0, 0]) / R, (b.Z[0, 1] - a.Z[0, 1]) / R, (b.p - a.p) / Sp])


def _orient(pt: _Pt, t: np.ndarray, prev: _Pt | None, ref3: np.ndarray | None, Sp: float):
    """Orient a tangent of ``pt`` along the chord from ``prev`` (or along ``ref3``)."""
    if prev is not None:
        ch = _chord(prev, pt, Sp)
        if ch is not None and np.linalg.norm(ch) > 0:
            return -t if float(t @ ch) < 0 else t
        ref3 = _chord3(prev, pt, Sp)
    if ref3 is None:
        return t
    t3 = np.array([t[0], t[1], t[-1]])
    return -t if float(t3 @ ref3) < 0 else t


class _Tracer:
    """One continuation problem: engine, closed forms, registry and settings."""

    def __init__(
        self,
        family: FlowFamily,
        m: int,
        t0: float,
        window: tuple[float, float],
        st: _Settings,
        *,
        closed_form: bool = True,
        registry: _Registry | None = None,
    ) -> None:
        self.eng = _Engine(family, m, t0, window, st.tol)
        self.st = st
        self.closed = _Closed(self.eng) if (closed_form and self.eng.closed_form) else None
        self.registry = registry if registry is not None else _Registry(self.eng.Sp, st.ds_max)

    # -- points ---------------------------------------------------------------------------------
    def solve_fixed(self, p: float, Z: np.ndarray, max_iter: int = 40) -> _Pt:
        """Damped Newton at fixed parameter (seeds, window ends); raises ShootingError.

        :func:`perturb.numeric.roots.damped_newton` on the shooting residual: converged when
        the correction is below ``max(tol, 1e-11)`` relative to ``max(1, |z|)`` (the
        corrected iterate is the point), a correction cut to 10 times that scale, halvings
        down to ``2**-9`` until the residual decreases (Armijo); the residual floor of a
        strongly unstable orbit (rounding times ``|M|``), where no step decreases it, is
        accepted when the Newton correction is below ``1e-9`` relative."""
        eng = self.eng
        Z = np.array(Z, dtype=float).reshape(-1, 2)
        N = Z.shape[0]

        def residual(z: np.ndarray) -> tuple[np.ndarray, np.ndarray, _Eval]:
            ev = eng.evaluate(z.reshape(N, 2), p, gp=False)
            return ev.r, ev.Gz, ev

        res = damped_newton(
            residual,
            Z.ravel().copy(),
            tol=0.0,
            max_iter=max_iter,
            scale=lambda z: max(1.0, float(np.max(np.abs(z)))),
            step_tol=max(self.st.tol, 1e-11),
            take_final_step=True,
            floor_step_tol=1e-9,
            max_step=10.0,
            max_halvings=9,
            solve=lu_or_lstsq,
            catch=(PerturbError,),
        )
        if res.status == "initial_error":
            z = Z.ravel()
            raise ShootingError(
                f"the flow failed at the seed: {res.error}", math.inf, 0, z
            ) from res.error
        if res.status == "initial_nonfinite":
            raise ShootingError("non-finite residual at the seed", math.inf, 0, Z.ravel())
        if not res.converged:
            raise ShootingError(
                f"Newton at fixed {eng.family.parameter} = {p:.6g} did not converge",
                res.rnorm,
                max_iter,
                res.z,
            )
        pt = _Pt(p, res.z)
        eng.finish(pt, res.data, res.z_evaluated.reshape(N, 2), p)
        return pt

    def polish(self, p: float, y: ArrayLike, max_iter: int = 40) -> _Pt:
        """A seed ``(p, y)`` to a converged point (multiple shooting when strongly unstable)."""
        y = np.asarray(y, dtype=float).reshape(-1)
        Z = self.propagate_nodes(p, y, self.eng.m)
        pt = self.solve_fixed(p, Z, max_iter)
        need = _nodes_needed(pt.max_mult, self.eng.m)
        if need > pt.N:
            pt = self.solve_fixed(p, self.propagate_nodes(p, pt.y0, need, old=pt), max_iter)
        return pt

    def propagate_nodes(
        self, p: float, y: np.ndarray, N: int, old: _Pt | None = None
    ) -> np.ndarray:
        """Nodes at ``t0 + iP/N`` from ``y`` (or from the nearest earlier node of ``old``, so a
        strongly unstable orbit is never propagated over a whole period)."""
        eng = self.eng
        flow = eng.flow(p)
        P = eng.m * float(flow.period)
        Z = np.empty((N, 2))
        Z[0] = y
        tn = eng.node_times(P, N)
        old_t = eng.node_times(P, old.N) if old is not None else None
        for i in range(1, N):
            if old is not None:
                k = int(np.searchsorted(old_t[:-1], tn[i], side="right") - 1)
                if abs(old_t[k] - tn[i]) <= 1e-14 * P:
                    Z[i] = old.Z[k]
                    continue
                start, ys = old_t[k], old.Z[k]
            else:
                start, ys = tn[i - 1], Z[i - 1]
            Z[i] = flow(ys, start, tn[i]).y
            eng.periods += eng.m * (tn[i] - start) / P
            eng.calls += 1
        return Z

    def with_jacobian(self, pt: _Pt) -> _Pt:
        """Give a point the Jacobian [G_z | G_p] (one evaluation)."""
        eng = self.eng
        ev = eng.evaluate(pt.Z, pt.p)
        Gp = ev.Gp if ev.Gp is not None else eng.gp_fd(pt.Z, pt.p, ev.r)
        if pt.mode != "closed":
            eng.finish(pt, ev, pt.Z, pt.p)
        pt.blocks = ev.blocks
        pt.J = np.hstack([ev.Gz, Gp[:, None]])
        return pt

    def set_tangent(self, pt: _Pt, prev: _Pt | None, ref3: np.ndarray | None) -> None:
        t, sing = _null_tangent(pt, self.eng.Sp)
        pt.tangent, pt.singular = _orient(pt, t, prev, ref3, self.eng.Sp), sing

    def renode(self, pt: _Pt) -> _Pt:
        """Change the number of nodes when the growth per node left its range (with some
        hysteresis)."""
        need = _nodes_needed(pt.max_mult, self.eng.m)
        if need > pt.N or need < pt.N - self.eng.m:
            Z = self.propagate_nodes(pt.p, pt.y0, need, old=pt if need > pt.N else None)
            new = _Pt(pt.p, Z)
            for a in ("mult", "stats", "sig", "switches", "mode", "seg", "grazing"):
                setattr(new, a, getattr(pt, a))
            ref = pt.tangent3()
            self.with_jacobian(new)
            self.set_tangent(new, None, ref)
            return new
        return pt

    def numeric_from_closed(self, pt: _Pt, ref3: np.ndarray) -> _Pt:
        """Nodes, Jacobian and tangent for continuing numerically from a closed-form point (the
        point keeps its exact data)."""
        assert self.closed is not None
        q = self.closed.point(pt.p, pt.seg, _nodes_needed(pt.max_mult, 1))
        q.grazing = pt.grazing
        self.with_jacobian(q)
        self.set_tangent(q, None, ref3)
        return q

    def to_closed(self, pt: _Pt, dirp: float) -> _Pt:
        """The exact closed-form point if ``pt`` is an orbit inside one linear segment."""
        if self.closed is None or pt.mode == "closed":
            return pt
        seg = self.closed.match(pt)
        if seg < 0:
            return pt
        q = self.closed.point(pt.p, seg)
        self.closed.set_tangent(q, dirp)
        return q

    # -- one direction ---------------------------------------------------------------------------
    def march(
        self, start: _Pt, sign: float, other: list[_Pt], parent_m: int | None
    ) -> tuple[list[_Pt], str, bool]:
        """Continue from ``start`` along ``sign * tangent`` until a stop condition."""
        pts, reason, closed, _, _ = self.march_record(start, sign, other, parent_m)
        return pts, reason, closed

    def march_record(
        self, start: _Pt, sign: float, other: list[_Pt], parent_m: int | None
    ) -> tuple[list[_Pt], str, bool, int, list[float]]:
        """:meth:`march`, and what a replay of its stop tests needs: the number of points
        (after ``start``) that went through :meth:`_joined` (a last point exactly on the
        window edge does not), and the propagated periods up to every point."""
        eng, st = self.eng, self.st
        pts = [start]
        work = [0.0]
        checked = 0
        own = _Poly.of([start], eng.Sp, st.ds_max, eng.m)
        cum = [0.0]
        other_poly = _Poly.of(other, eng.Sp, st.ds_max, eng.m)
        other_cum = np.cumsum(
            [0.0] + [_key_step(a, b, eng.Sp) for a, b in zip(other[:-1], other[1:], strict=True)]
        )
        ctl = _StepControl(st)
        periods0 = eng.periods
        cur = start
        cur_t = None if start.tangent is None else sign * start.tangent
        dir3 = sign * start.tangent3()
        reason = "max_points"
        closed = False
        stalled = 0
        while len(pts) < st.max_points:
            if eng.periods - periods0 > st.max_periods:
                reason = "work budget"
                break
            if time.monotonic() > st.deadline:
                reason = "time budget"
                break
            final = False
            if cur.mode == "closed" and cur.J is None:
                dirp = 1.0 if dir3[2] >= 0 else -1.0
                new, final, graze = self._closed_step(cur, dirp)
                if graze:
                    new.grazing = True
                    new = self.numeric_from_closed(new, new.tangent3())
                    ctl.restart()
            else:
                new, stop = self._numeric_step(pts, cur, cur_t, dir3, ctl)
                if new is None:
                    reason = stop
                    break
                # a march that creeps at the smallest step (a singular corner: grazing at
                # zero speed, sticking at a discontinuity) would take max_points such steps
                stalled = stalled + 1 if ctl.last_ok <= _STALL_DS * st.ds_min else 0
                if stalled > _STALL_STEPS:
                    reason = (
                        f"stalled at {eng.family.parameter} = {new.p:.8g} ({_STALL_STEPS} "
                        "steps at the smallest step size)"
                    )
                    break
                if not eng.lo <= new.p <= eng.hi:
                    edge_pt = self._edge_point(cur, new)
                    if edge_pt is not None:
                        pts.append(edge_pt)
                        work.append(eng.periods - periods0)
                    reason = "window edge"
                    break
                new = self.to_closed(new, 1.0 if new.tangent3()[2] >= 0 else -1.0)
                if new.mode != "closed":
                    new = self.renode(new)
            h = _key_step(cur, new, eng.Sp)
            stop2 = self._joined(pts, own, cum, new, h, other_poly, other_cum, parent_m)
            cum.append(cum[-1] + h)
            pts.append(new)
            work.append(eng.periods - periods0)
            checked = len(pts) - 1
            own.append(new.key())
            if stop2 is not None:
                reason, closed = stop2
                break
            if final:
                reason = "window edge"
                break
            c3 = _chord3(cur, new, eng.Sp)
            if np.linalg.norm(c3) > 0:
                dir3 = c3 / np.linalg.norm(c3)
            cur, cur_t = new, new.tangent
        return pts, reason, closed, checked, work

    def _numeric_step(
        self,
        pts: list[_Pt],
        cur: _Pt,
        cur_t: np.ndarray | None,
        dir3: np.ndarray,
        ctl: _StepControl,
    ) -> tuple[_Pt | None, str]:
        """One predictor-corrector step from ``cur``: (new point or None, stop reason)."""
        eng, st = self.eng, self.st
        D = cur.D(eng.Sp)
        u0 = cur.u()
        d = cur_t
        if (cur.singular or d is None) and len(pts) >= 2:
            # rank-deficient Jacobian (branch point): the tangent is not unique, use the secant
            ch = _chord(pts[-2], cur, eng.Sp)
            if ch is not None:
                d = ch
        if d is None or d.size != u0.size:
            return None, "no tangent"
        nd = float(np.linalg.norm(d))
        if nd == 0.0 or not np.isfinite(nd):
            return None, "no tangent"
        d = d / nd
        underflow = f"step size underflow at {eng.family.parameter} = {cur.p:.8g}"
        herm = self._hermite(pts, cur, d, D)
        jumped = False
        # the step shrinks geometrically on every redo and failure (to ds_min): the cap is
        # only reached when a NaN keeps it from shrinking
        for _attempt in range(_MAX_STEP_ATTEMPTS):
            ds = ctl.step
            if not (math.isfinite(ds) and ds > 0.0):
                return None, f"non-finite step at {eng.family.parameter} = {cur.p:.8g}"
            if herm is not None:
                uh, dh = herm(ds)
                new, evals = _correct(eng, uh * D, cur.N, D, dh, ds, st, ctl=ctl)
            else:
                new, evals = _correct(eng, u0 + ds * d * D, cur.N, D, d, ds, st, ctl=ctl)
            if new is not None:
                if ctl.accept(ds, evals, _spacing(cur, new, eng.Sp)):
                    break
                continue  # too coarse for the output: the control shortened the step
            if ctl.failed():
                continue
            if jumped:
                return None, underflow
            # a jump over an isolated point where Newton converges badly (grazing, branch
            # point): a few earlier steps long, with a relaxed Newton
            jumped = True
            for dj in ctl.jumps():
                new, evals = _correct(
                    eng, u0 + dj * d * D, cur.N, D, d, dj, st, max_iter=12, first_cap=2.0
                )
                if new is not None:
                    ctl.accept(dj, evals, _spacing(cur, new, eng.Sp), force=True)
                    break
            if new is not None:
                break
            return None, underflow
        else:
            return None, f"step control did not settle at {eng.family.parameter} = {cur.p:.8g}"
        self.set_tangent(new, cur, dir3)
        return new, ""

    def _hermite(self, pts: list[_Pt], cur: _Pt, tb: np.ndarray, D: np.ndarray):
        """Cubic Hermite extrapolation through the last two points and their tangents, as a
        function ``ds -> (scaled predicted point, unit hyperplane normal)``, or None.  Its
        error is O(ds^4) on smooth arcs, against O(ds^2) for the tangent, so the first
        correction is often below the acceptance threshold: one propagation per point."""
        if len(pts) < 2 or cur.singular or cur.mode == "closed":
            return None
        prev = pts[-2]
        if prev.N != cur.N or prev.tangent is None or prev.singular:
            return None
        if prev.tangent.size != tb.size:
            return None
        ua = prev.u() / D
        ub = cur.u() / D
        chord = ub - ua
        h = float(np.linalg.norm(chord))
        if not (math.isfinite(h) and h > 0.0):
            return None
        ta = prev.tangent * prev.D(self.eng.Sp) / D
        ta = ta / np.linalg.norm(ta)
        if ta @ chord < 0:
            ta = -ta
        if tb @ chord < 0 or ta @ tb < 0.5:
            return None  # a sharp turn: the cubic would not help

        def predict(ds: float) -> tuple[np.ndarray, np.ndarray]:
            u = hermite_extrapolate(ua, ta, ub, tb, ds, h)
            return u, hermite_direction(ua, ta, ub, tb, ds, h)

        return predict

    def _edge_point(self, cur: _Pt, new: _Pt) -> _Pt | None:
        """The orbit exactly at the window edge between ``cur`` and ``new``."""
        eng = self.eng
        edge = eng.hi if new.p > eng.hi else eng.lo
        w = (edge - cur.p) / (new.p - cur.p)
        Z = cur.Z + w * (new.Z - cur.Z) if new.N == cur.N else cur.Z
        try:
            q = self.solve_fixed(edge, Z, max_iter=12)
        except ShootingError:
            return None
        q.tangent = new.tangent if new.N == q.N else None
        if q.tangent is None:
            q.tangent = np.r_[new.tangent3()[:2], np.zeros(2 * q.N - 2), new.tangent3()[2]]
        return self.to_closed(q, 1.0 if new.tangent3()[2] >= 0 else -1.0)

    def _closed_step(self, cur: _Pt, dirp: float) -> tuple[_Pt, bool, bool]:
        """Next closed-form point: (point, reached the window edge, grazes).  The parameter
        step keeps the output spacing: ``ds_max`` of the window and of the amplitude."""
        assert self.closed is not None
        eng, st = self.eng, self.st
        if cur.tangent is None:
            self.closed.set_tangent(cur, dirp)
        dadp = self.closed.damplitude(cur.p, cur.seg)
        rate = max(1.0 / eng.Sp, abs(dadp) / max(1.0, cur.stats[0]))
        dp = st.ds_max / rate
        edge = eng.hi if dirp > 0 else eng.lo
        for _ in range(40):
            p1 = cur.p + dirp * dp
            final = (p1 - edge) * dirp >= 0
            if final:
                p1 = edge
            graze = self.closed.margin(p1, cur.seg) <= 0
            if graze:
                p1 = brentq(
                    lambda p: self.closed.margin(p, cur.seg),
                    cur.p,
                    p1,
                    xtol=1e-14 * eng.Sp,
                    rtol=1e-15,
                )
                if self.closed.margin(p1, cur.seg) < 0:  # stay inside: the formula holds
                    p1 = cur.p + (p1 - cur.p) * (1 - 1e-13)
                final = False
            q = self.closed.point(p1, cur.seg)
            spacing = _spacing(cur, q, eng.Sp)
            if spacing > 1.2 * st.ds_max and abs(p1 - cur.p) > 1e-12 * eng.Sp:
                # the amplitude curves (a resonance peak): a shorter step, exact anyway
                dp = abs(p1 - cur.p) * 0.9 * st.ds_max / spacing
                continue
            break
        self.closed.set_tangent(q, dirp)
        return q, final, graze

    def _joined(
        self,
        pts: list[_Pt],
        own: _Poly,
        cum: list[float],
        new: _Pt,
        h: float,
        other: _Poly,
        other_cum: np.ndarray,
        parent_m: int | None,
        first: int = 0,
        own_loop: bool = True,
    ) -> tuple[str, bool] | None:
        """Why the march stops at ``new`` (reason, closed loop), or None.  ``first`` and
        ``own_loop`` restrict a replay (:func:`_replay`) to the tests a speculative march
        could not make: branches registered from ``first`` on, and the other half."""
        eng, st = self.eng, self.st
        cur = pts[-1]
        # a period-2m branch collapsing onto its period-m orbit (at the period doubling)
        if parent_m is not None and eng.m > parent_m and new.N == cur.N:
            R = max(cur.R, new.R)
            k = new.N * parent_m // eng.m
            d_new = (new.Z[k] - new.Z[0]) / R
            d_cur = (cur.Z[k] - cur.Z[0]) / R
            if np.max(np.abs(d_new)) < JOIN_FRACTION * st.ds_max or float(d_new @ d_cur) < 0:
                return f"collapsed onto the period-{parent_m} orbit (period doubling)", False
        if not np.isfinite(h):
            return None
        kn, kc = new.key(), cur.key()

        def on(poly: _Poly, start: int = 0, stop: int | None = None, kn=kn, kc=kc) -> bool:
            # two consecutive points on a traced curve, stepping along it: running along it
            # (a crossing at a branch point is passed, however shallow)
            i = poly.near(kn, h, start, stop)
            if i < 0 or poly.near(kc, h, start, stop) < 0:
                return False
            return poly.parallel(i, kc, kn) >= 0.9

        # another branch, in any representation of a period-m orbit
        shifted = list(zip(new.keys(eng.m), cur.keys(eng.m), strict=True))
        items = self.registry.items
        for i in range(first, len(items)):
            it = items[i]
            if it.m == eng.m and any(on(it, kn=a, kc=b) for a, b in shifted):
                return f"joined branch {i}", False
        # back on this branch, far along the curve: a closed loop
        s_new = cum[-1] + h
        gap = 6 * st.ds_max + 3 * h
        n_far = int(np.searchsorted(np.asarray(cum), s_new - gap, side="right"))
        n_far = min(n_far, len(pts) - 3)
        if own_loop and n_far >= 2 and on(own, 0, n_far - 1):
            return "closed loop", True
        if len(other) >= 2:
            k0 = int(np.searchsorted(other_cum, gap - s_new, side="left"))
            if len(other) - k0 >= 2 and on(other, k0):
                return "closed loop", True
        return None

    # -- a whole branch -------------------------------------------------------------------------
    def start_point(self, p: float, y: ArrayLike | None, seed: _Pt | None = None) -> _Pt:
        """The first point with its tangent: closed form if possible, else polished."""
        pt = seed if seed is not None else self.polish(p, y)
        pt = self.to_closed(pt, 1.0)
        if pt.mode == "closed":
            assert self.closed is not None
            self.closed.set_tangent(pt, 1.0)
            return pt
        if pt.J is None:
            self.with_jacobian(pt)
        self.set_tangent(pt, None, np.array([0.0, 0.0, 1.0]))
        return pt

    def trace(
        self, start: _Pt, directions: str = "both", parent_m: int | None = None
    ) -> tuple[ContinuationBranch, list[_Pt]]:
        periods0 = self.eng.periods
        fwd, reason_f, closed = self.march(start, 1.0, [], parent_m)
        if directions == "both" and not closed:
            bwd, reason_b, closed = self.march(start, -1.0, fwd, parent_m)
            # the backward half was marched against the tangent: flip it to the branch order
            for q in bwd[1:]:
                if q.tangent is not None:
                    q.tangent = -q.tangent
            pts = bwd[:0:-1] + fwd
            reason = "closed loop" if closed else f"{reason_b} / {reason_f}"
        else:
            pts = fwd
            reason = "closed loop" if closed else reason_f
        pts = self.refine_folds(pts)
        return self.freeze(pts, closed, reason, self.eng.periods - periods0), pts

    def _collapsed(self, q: _Pt) -> bool:
        """A period-``m > 1`` orbit that is (nearly) its own shift by one forcing period: the
        turn of a period-``2m`` branch where it is born at a period doubling is that period
        doubling (a pitchfork of the doubled orbit), not a saddle-node."""
        m = self.eng.m
        if m == 1 or q.N % m:
            return False
        k = q.N // m
        return bool(np.max(np.abs(q.Z[k] - q.Z[0])) < 1e-3 * q.R)

    def refine_folds(self, pts: list[_Pt]) -> list[_Pt]:
        """``pts`` with the refined fold (:func:`_fold_point`) inserted between every two
        consecutive points where the parameter component of the tangent changes sign."""
        out = [pts[0]] if pts else []
        for a, b in zip(pts[:-1], pts[1:], strict=True):
            ta, tb = a.tangent, b.tangent
            if ta is not None and tb is not None and FoldTest.crossed(ta, tb):
                q = _fold_point(self, a, b)
                if q is not None and not self._collapsed(q):
                    out.append(q)
            out.append(b)
        return out

    def freeze(
        self, pts: list[_Pt], closed: bool, reason: str, periods: float, m: int | None = None
    ) -> ContinuationBranch:
        points = tuple(_freeze_point(q) for q in pts)
        eng = self.eng
        return ContinuationBranch(
            parameter=eng.family.parameter,
            m=eng.m if m is None else m,
            t0=eng.t0,
            window=(eng.lo, eng.hi),
            points=points,
            special_points=tuple(_special_points(pts, points)),
            closed=closed,
            stop_reason=reason,
            periods=float(periods),
            family=eng.family,
            ds_max=self.st.ds_max,
        )


def _freeze_point(q: _Pt) -> ContinuationPoint:
    y0 = np.array(q.Z[0], dtype=float)
    y0.setflags(write=False)
    mult = np.array(q.mult, dtype=complex)
    mult.setflags(write=False)
    t3 = q.tangent3()
    t3.setflags(write=False)
    nodes = None
    if q.N > 1:
        nodes = np.array(q.Z, dtype=float)
        nodes.setflags(write=False)
    sig = np.array(q.sig, dtype=float)
    sig.setflags(write=False)
    mm = q.max_mult
    return ContinuationPoint(
        parameter=float(q.p),
        y0=y0,
        multipliers=mult,
        max_multiplier=mm,
        stable=bool(mm < 1.0),
        amplitude=float(q.stats[0]),
        first_harmonic_amplitude=float(q.stats[1]),
        mean=float(q.stats[2]),
        tangent=t3,
        switches=int(q.switches),
        source=q.source,
        signature=sig,
        nodes=nodes,
    )


def _special_points(pts: list[_Pt], points: Sequence[ContinuationPoint]) -> list[SpecialPoint]:
    out: list[SpecialPoint] = []
    n = len(pts)

    def interp(i: int, w: float, kind: str) -> SpecialPoint:
        a, b = points[i], points[i + 1]
        y = (1 - w) * a.y0 + w * b.y0
        return SpecialPoint(
            kind,
            i,
            float((1 - w) * a.parameter + w * b.parameter),
            float((1 - w) * a.amplitude + w * b.amplitude),
            (float(y[0]), float(y[1])),
        )

    tp = [q.tangent[2] for q in points]
    fold_at = set()
    refined = {i for i, q in enumerate(pts) if q.fold}
    for i in sorted(refined):
        # a refined fold is a point of the branch: reported there, and the sign changes of
        # dp/ds and det(M - I) on either side of it belong to it
        fold_at.update((i - 1, i))
        q = points[i]
        out.append(
            SpecialPoint(
                "fold", i, float(q.parameter), float(q.amplitude), (float(q.y0[0]), float(q.y0[1]))
            )
        )
    for i in range(n - 1):
        if tp[i] * tp[i + 1] < 0 and not ({i, i + 1} & refined):
            # not refined (closed-form neighbour, or the refinement failed): interpolated, but
            # never inside the sampled range (the parameter is extreme at a fold)
            fold_at.add(i)
            sp_ = interp(i, crossing_weight(tp[i], tp[i + 1]), "fold")
            pa, pb = points[i].parameter, points[i + 1].parameter
            edge = max(pa, pb) if tp[i] > 0 else min(pa, pb)
            if (sp_.parameter - edge) * tp[i] < 0:
                sp_ = SpecialPoint("fold", i, float(edge), sp_.amplitude, sp_.y0)
            out.append(sp_)
    for i in range(n - 1):
        a, b = pts[i], pts[i + 1]
        if a.mode == "closed" and b.mode == "closed" and a.seg == b.seg:
            continue
        # stability changes (the core's multiplier test functions); a multiplier through +1
        # next to a fold is that fold
        for kind, w in FloquetCrossings.crossings(a.mult, b.mult):
            if kind == "branch_point" and fold_at & {i - 1, i, i + 1}:
                continue
            out.append(interp(i, w, kind))
        if a.grazing:
            out.append(interp(i, 0.0, "grazing"))
        elif b.grazing and i == n - 2:
            out.append(interp(i, 1.0, "grazing"))
        elif a.switches >= 0 and b.switches >= 0 and a.switches != b.switches and not b.grazing:
            out.append(interp(i, 0.5, "grazing"))
    out.sort(key=lambda s: (s.index, s.parameter))
    return out


# =============================================================================================
# public: continue_orbits
# =============================================================================================
@dataclass(frozen=True)
class ExactResponseOptions:
    """Tuning knobs of the exact frequency response (:func:`exact_branches`,
    :func:`continue_orbits`; :func:`exact_frequency_response` and :func:`exact_solutions_at`
    pass them on).

    Each function also takes the fields as keyword arguments, which replace those of
    ``options`` (so ``exact_branches(osc, w, tol=1e-9)`` and
    ``exact_branches(osc, w, options=ExactResponseOptions(tol=1e-9))`` are the same call); a
    keyword the function does not use is a :class:`~perturb.errors.ParameterError` naming it.
    :func:`continue_orbits` uses the first six fields, :func:`exact_branches` all of them.
    Values are checked by the functions.  The defaults are those the functions had before
    the options object existed.

    Attributes
    ----------
    ds_max : float
        Output spacing: consecutive points differ by at most ``ds_max`` of the window in the
        parameter and ``ds_max`` relative (to ``max(1, amplitude)``) in amplitude; 0.005 =
        0.5 %.  (The corrector's step in the scaled state may be up to 8 times longer where
        the orbit's phase turns at nearly constant parameter and amplitude.)
    ds_min : float
        Smallest step before giving up (after one jump attempt).
    tol : float
        Newton tolerance in scaled coordinates (estimated error of the stored point).
    max_points : int
        Points per march (per direction) at most.
    max_periods : float, optional
        Budget of propagated time in forcing periods (the cost measure: one Newton iteration
        propagates ``m`` forcing periods): per direction for :func:`continue_orbits`
        (None: 1e6), for all stages of :func:`exact_branches` (None: 2e5).
    closed_form : bool
        Trace orbits that stay inside one linear segment of a PWL force from the exact
        formula (no propagation).  ``False`` shoots everywhere (for checks).
    sweep_points : int
        Frequencies of the virtual sweeps (0: none).
    transient_periods : int
        Periods integrated per attempt where a sweep jumps (up to three attempts).
    branch_points, period_doubling, symmetry : bool
        Switches of the stages of :func:`exact_branches`: the other branch at branch points,
        period-2 branches, mirror images of odd systems.
    max_branches : int
        Budget of branches.
    max_seconds : float, optional
        Wall-clock budget of :func:`exact_branches` (None: none).
    progress : bool, optional
        Progress line (None: on unless ``PERTURB_PROGRESS=0``).
    workers : int, optional
        Processes that trace (None: ``PERTURB_WORKERS``, else 2 on a machine with two or
        more CPUs); see :func:`exact_branches`.
    """

    ds_max: float = 0.005
    ds_min: float = 1e-7
    tol: float = 1e-10
    max_points: int = 20000
    max_periods: float | None = None
    closed_form: bool = True
    sweep_points: int = 60
    transient_periods: int = 40
    branch_points: bool = True
    period_doubling: bool = False
    symmetry: bool = True
    max_branches: int = 40
    max_seconds: float | None = 300.0
    progress: bool | None = None
    workers: int | None = None


#: The fields of :class:`ExactResponseOptions` that shape one march (:func:`continue_orbits`).
_ORBIT_FIELDS = frozenset(("ds_max", "ds_min", "tol", "max_points", "max_periods", "closed_form"))
_ALL_FIELDS = frozenset(ExactResponseOptions.__dataclass_fields__)


def _exact_options(
    options: ExactResponseOptions | None,
    knobs: dict[str, Any],
    allowed: frozenset[str],
    where: str,
) -> ExactResponseOptions:
    """``options`` (default: the defaults) with the keyword arguments ``knobs`` of ``where``
    in place of its fields; only the fields ``allowed`` may be given as keywords."""
    if options is None:
        options = ExactResponseOptions()
    elif not isinstance(options, ExactResponseOptions):
        raise ParameterError(
            f"{where}: options = {options!r}: expected an ExactResponseOptions (or keywords)"
        )
    unknown = sorted(set(knobs) - allowed)
    if unknown:
        raise ParameterError(
            f"{where}: unknown option(s) {', '.join(unknown)}; "
            f"expected {', '.join(sorted(allowed))}"
        )
    return replace(options, **knobs) if knobs else options


def _window(window: Sequence[float]) -> tuple[float, float]:
    try:
        lo, hi = (float(w) for w in window)
    except (TypeError, ValueError):
        raise ParameterError(f"window = {window!r}: expected (low, high)") from None
    if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
        raise ParameterError(f"window = {window!r}: expected finite (low, high) with low < high")
    return lo, hi


def _settings(ds_max: float, ds_min: float, tol: float, max_points: int, max_periods: float):
    for name, v in (("ds_max", ds_max), ("ds_min", ds_min), ("tol", tol)):
        if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
            raise ParameterError(f"{name} = {v!r}: expected a positive number")
    if ds_min > ds_max:
        raise ParameterError(f"ds_min = {ds_min} > ds_max = {ds_max}")
    if isinstance(max_points, bool) or not isinstance(max_points, int) or max_points < 2:
        raise ParameterError(f"max_points = {max_points!r}: expected an integer >= 2")
    if not max_periods > 0:
        raise ParameterError(f"max_periods = {max_periods!r}: expected a positive number")
    return _Settings(float(ds_max), float(ds_min), float(tol), int(max_points), float(max_periods))


def _family(oscillator: Oscillator | FlowFamily, parameter: str | None) -> FlowFamily:
    if isinstance(oscillator, FlowFamily):
        if parameter is not None and parameter != oscillator.parameter:
            raise ParameterError(
                f"parameter = {parameter!r} but the FlowFamily varies {oscillator.parameter!r}"
            )
        return oscillator
    if not isinstance(oscillator, Oscillator):
        raise ParameterError(f"oscillator = {oscillator!r}: expected an Oscillator or FlowFamily")
    return FlowFamily(oscillator, parameter)


def continue_orbits(
    oscillator: Oscillator | FlowFamily,
    start: float,
    y_guess: ArrayLike,
    window: Sequence[float],
    *,
    parameter: str | None = None,
    m: int = 1,
    t0: float = 0.0,
    directions: Literal["both", "forward"] = "both",
    options: ExactResponseOptions | None = None,
    **knobs: Any,
) -> ContinuationBranch:
    r"""Trace the branch of period-``m`` orbits through ``(start, y_guess)``.

    Parameters
    ----------
    oscillator
        The system, or a :class:`~perturb.simulate.flows.factory.FlowFamily` built from it (exact
        flow for PWL models, ``solve_ivp`` otherwise).
    start
        Parameter value of the seed (inside ``window``).
    y_guess
        ``(x, v)`` at ``t0`` near an orbit; polished by Newton at ``start`` first.
    window
        ``(low, high)``: the branch stops at the edges, with a point exactly on them.
    parameter
        Name of the continuation parameter (default: the forcing frequency).
    m
        Forcing periods per orbit period.
    t0
        Phase of the section.
    directions
        ``'both'`` (default) or ``'forward'`` (increasing parameter at the seed).
    options : ExactResponseOptions, optional
        The tuning knobs: ``ds_max`` (output spacing, default 0.005), ``ds_min``, ``tol``,
        ``max_points`` and ``max_periods`` (budgets per direction; default 20000 points and
        1e6 forcing periods), ``closed_form``; see :class:`ExactResponseOptions`.
    **knobs
        Those fields as keywords, replacing those of ``options``.

    Returns
    -------
    ContinuationBranch

    Raises
    ------
    ParameterError
        Bad arguments (also a keyword that is not one of the fields above).
    ShootingError
        The seed does not converge to an orbit.

    Examples
    --------
    >>> from perturb.model.builtins import builtin_model
    >>> br = continue_orbits(builtin_model("nsd", k=-2, mu=0.05, F=2), 1.6, [5.0, 0.0],
    ...                      (1.5, 2.0))
    >>> br.closed, br.points[0].parameter, br.points[-1].parameter
    (False, 1.5, 2.0)
    """
    o = _exact_options(options, knobs, _ORBIT_FIELDS, "continue_orbits")
    max_periods = 1e6 if o.max_periods is None else o.max_periods
    family = _family(oscillator, parameter)
    lo, hi = _window(window)
    start = float(start)
    if not lo <= start <= hi:
        raise ParameterError(f"start = {start} is outside the window ({lo}, {hi})")
    if isinstance(m, bool) or not isinstance(m, int) or m < 1:
        raise ParameterError(f"m = {m!r}: expected a positive integer")
    if directions not in ("both", "forward"):
        raise ParameterError(f"directions = {directions!r}: expected 'both' or 'forward'")
    st = _settings(o.ds_max, o.ds_min, o.tol, o.max_points, max_periods)
    tracer = _Tracer(family, m, float(t0), (lo, hi), st, closed_form=o.closed_form)
    pt = tracer.start_point(start, y_guess)
    return tracer.trace(pt, directions)[0]


# =============================================================================================
# branch switching
# =============================================================================================
def _refine(tracer: _Tracer, a: _Pt, b: _Pt, target: float, steps: int = 8) -> _Pt:
    r"""The point between ``a`` and ``b`` where :math:`\prod_i(\text{target} - \mu_i)` changes
    sign: regula falsi (Illinois) on the arclength of corrector steps from ``a``."""
    eng = tracer.eng

    def f(q: _Pt) -> float:
        return float(np.prod(target - q.mult).real)

    if a.J is None or a.mode == "closed":
        a.mode = "shoot"
        tracer.with_jacobian(a)
    D = a.D(eng.Sp)
    ch = _chord(a, b, eng.Sp)
    if ch is None:
        return a if abs(f(a)) < abs(f(b)) else b
    L = float(np.linalg.norm(ch))
    t, _ = _null_tangent(a, eng.Sp)
    t = -t if t @ ch < 0 else t
    fa, fb = f(a), f(b)
    best = a if abs(fa) < abs(fb) else b
    if not (fa * fb <= 0.0 and L > 0.0 and math.isfinite(L)):
        return best  # no sign change measured again: the closer end
    found = _illinois(tracer, a, t, D, L, f, fa, fb, steps, 1e-7, ends=True)
    if found.payload is not None:
        return found.payload
    return a if found.root == 0.0 else b if found.root == L else best


def _illinois(
    tracer: _Tracer,
    a: _Pt,
    t: np.ndarray,
    D: np.ndarray,
    L: float,
    f: Callable[[_Pt], float],
    fa: float,
    fb: float,
    steps: int,
    s_tol: float,
    ends: bool,
    need_jacobian: bool = False,
) -> RootResult:
    """Regula falsi (Illinois, :func:`perturb.numeric.roots.illinois`) for a sign change of
    ``f`` on ``s`` in ``[0, L]``: the point ``a + s t`` (scaled by ``D``) corrected onto the
    branch on the hyperplane normal to ``t`` through it, ``f(a) = fa`` and ``f(end) = fb`` of
    opposite signs.  The result's ``payload`` is the corrected point with the smallest
    ``|f|`` seen (None when no iterate beats the ends, with ``ends``, or none was made); it
    stops after ``steps`` corrections, when the bracket is below ``s_tol * L``, when ``f`` is
    exactly 0, or when a correction fails (or lacks its Jacobian and ``need_jacobian``)."""
    eng = tracer.eng
    u0 = a.u()

    def trial(s: float) -> tuple[float, _Pt] | None:
        q, _ = _correct(eng, u0 + s * t * D, a.N, D, t, max(s, 1e-9), tracer.st, first_cap=10.0)
        if q is None or (need_jacobian and q.J is None):
            return None
        return f(q), q

    return illinois(trial, 0.0, L, fa, fb, xtol=s_tol * L, max_iter=steps, include_ends=ends)


def _fold_point(tracer: _Tracer, a: _Pt, b: _Pt, steps: int = 12) -> _Pt | None:
    r"""The fold between consecutive points ``a`` and ``b`` (``dp/ds`` changes sign), or None.

    Regula falsi (Illinois) on the parameter component of the tangent, over points corrected
    on hyperplanes normal to the chord from ``a`` to ``b`` (the arc between two sampled points
    crosses each of them once).  Linear interpolation of that component between the sampled
    points is not enough: near a fold :math:`p(s) \approx p^* - c(s - s^*)^2`, so the
    interpolated parameter lies *inside* the sampled range, short of the fold by
    :math:`O(\Delta s^2)` (2.4e-4 on the Duffing jump-down fold at 0.5 % spacing); here the
    error in :math:`s` is squared instead, ~1e-12 in :math:`p`."""
    eng = tracer.eng
    if a.N != b.N or a.mode == "closed" or b.mode == "closed":
        return None
    if a.tangent is None or b.tangent is None:
        return None
    D = a.D(eng.Sp)
    ch = (b.u() - a.u()) / D
    L = float(np.linalg.norm(ch))
    if L == 0.0 or not math.isfinite(L):
        return None
    t = ch / L

    def f(q: _Pt) -> float:
        # the tangent's parameter component, oriented along the branch (the chord); below
        # 1e-12 it is the fold to rounding: stop there (as at an exact zero)
        v, _ = _null_tangent(q, eng.Sp)
        value = float(-v[-1] if float(v @ ch) < 0 else v[-1])
        return 0.0 if abs(value) <= 1e-12 else value

    if not FoldTest.crossed(a.tangent, b.tangent):
        return None
    fa, fb = float(a.tangent[-1]), float(b.tangent[-1])
    best = _illinois(
        tracer, a, t, D, L, f, fa, fb, steps, 1e-10, ends=False, need_jacobian=True
    ).payload
    if best is None:
        return None
    v, sing = _null_tangent(best, eng.Sp)
    best.tangent = -v if float(v @ ch) < 0 else v
    best.singular = sing
    best.fold = True
    return best


def _branch_off(parent: _Tracer, pts: list[_Pt], sp: SpecialPoint, child: _Tracer) -> _Pt | None:
    r"""First point of the branch born at ``sp`` (branch point: same period; period doubling:
    the child's period ``2m``), or None.

    The seed is the critical orbit plus :math:`\delta w(t)`, :math:`w` the Floquet
    eigenfunction of the multiplier :math:`\pm 1`, evaluated at the child's nodes by the
    parent's node sensitivities (:math:`w_{i+1} = M_i w_i`; after one period
    :math:`w \to \pm w`), so no propagation is needed; the corrector keeps
    :math:`\phi\cdot(y_0 - y_0^*) = \delta` and frees the parameter."""
    i = sp.index
    a, b = pts[i], pts[i + 1]
    target = 1.0 if sp.kind == "branch_point" else -1.0
    try:
        crit = _refine(parent, a, b, target)
        if crit.blocks is None or crit.J is None:
            parent.with_jacobian(crit)
    except PerturbError:
        return None
    M = np.eye(2)
    for B in crit.blocks:
        M = B @ M
    w, V = np.linalg.eig(M)
    k = int(np.argmin(np.abs(w - target)))
    phi = np.real(V[:, k])
    phi /= np.linalg.norm(phi)
    R = crit.R
    pm, mc = parent.eng.m, child.eng.m
    reps = mc // pm
    Np = crit.N
    # eigenfunction at the parent's nodes, over the child's period
    W = np.empty((Np * reps, 2))
    wv = phi.copy()
    for j in range(Np * reps):
        W[j] = wv
        wv = crit.blocks[j % Np] @ wv
    Zc = np.tile(crit.Z, (reps, 1))
    st = child.st
    parent_poly = _Poly.of(pts, child.eng.Sp, child.st.ds_max, pm)
    Dc = np.r_[np.full(2 * Zc.shape[0], R * math.sqrt(Zc.shape[0])), child.eng.Sp]
    dvec = np.r_[phi, np.zeros(2 * Zc.shape[0] - 2), 0.0]
    for delta in (2.0, 6.0, 0.7):
        for sgn in (1.0, -1.0):
            dist = delta * st.ds_max
            Z = Zc + sgn * dist * R * W
            q, _ = _correct(
                child.eng,
                np.r_[Z.ravel(), crit.p],
                Z.shape[0],
                Dc,
                sgn * dvec,
                dist,
                st,
                max_iter=15,
                first_cap=50.0,
            )
            if q is None:
                continue
            if mc > pm:
                kk = q.N * pm // mc
                if np.max(np.abs(q.Z[kk] - q.Z[0])) < 1e-6 * q.R:
                    continue  # converged back onto the period-m orbit
            elif parent_poly.near(q.key(), 0.3 * dist / JOIN_FRACTION) >= 0:
                continue  # back on the parent branch
            if q.J is None:
                child.with_jacobian(q)
            child.set_tangent(q, None, np.array([0.0, 0.0, 1.0]))
            return q
    return None


def switch_branch(
    branch: ContinuationBranch,
    index: int | SpecialPoint,
    *,
    ds_max: float | None = None,
    tol: float = 1e-10,
    max_points: int = 20000,
    max_periods: float = 1e6,
) -> ContinuationBranch:
    r"""The branch born at a branch point or a period doubling of ``branch``.

    At a period doubling (a multiplier through -1) this is the period-``2m`` branch; at a
    branch point (through +1 without a fold: the symmetry-breaking pitchfork of odd systems)
    the other period-``m`` branch.  The point is refined along ``branch`` (regula falsi on
    :math:`\det(M \mp I)` over corrector steps), the new branch is seeded ``2 ds_max`` along
    the Floquet eigenfunction of the critical multiplier and corrected on the hyperplane
    :math:`\phi\cdot(y_0 - y_0^*) = \delta` (the parameter free), then traced both ways; a
    period-``2m`` branch stops where it collapses onto the period-``m`` orbit.

    Parameters
    ----------
    branch
        From :func:`continue_orbits` or :func:`exact_branches`.
    index
        Index into ``branch.special_points``, or the :class:`SpecialPoint` itself.
    ds_max, tol, max_points, max_periods
        As in :func:`continue_orbits` (``ds_max`` defaults to the branch's).

    Raises
    ------
    ParameterError
        The special point is not a branch point or period doubling of this branch.
    PerturbError
        No new branch could be started there.
    """
    sp = branch.special_points[index] if isinstance(index, int) else index
    if sp not in branch.special_points:
        raise ParameterError(f"{sp!r} is not a special point of this branch")
    if sp.kind not in ("branch_point", "period_doubling"):
        raise ParameterError(f"{sp!r}: expected a branch point or a period doubling")
    st = _settings(ds_max or branch.ds_max, 1e-7, tol, max_points, max_periods)
    parent = _Tracer(branch.family, branch.m, branch.t0, branch.window, st, closed_form=False)
    pts = [_thaw(branch, j) for j in range(len(branch.points))]
    for j in (sp.index, sp.index + 1):
        pts[j].mode = "shoot"
        parent.with_jacobian(pts[j])
    mc = branch.m * (2 if sp.kind == "period_doubling" else 1)
    child = _Tracer(
        branch.family,
        mc,
        branch.t0,
        branch.window,
        st,
        closed_form=mc == 1,
        registry=parent.registry,
    )
    if mc == branch.m:
        parent.registry.add(pts, branch.m)
    q = _branch_off(parent, pts, sp, child)
    if q is None:
        raise PerturbError(f"no new branch could be started at {sp!r}")
    return child.trace(q, "both", parent_m=branch.m if mc > branch.m else None)[0]


def _thaw(branch: ContinuationBranch, j: int) -> _Pt:
    """An internal point from a frozen one (no Jacobian)."""
    q = branch.points[j]
    Z = q.nodes if q.nodes is not None else q.y0[None, :]
    pt = _Pt(q.parameter, Z)
    pt.mult = np.array(q.multipliers)
    pt.stats = (q.amplitude, q.first_harmonic_amplitude, q.mean)
    pt.sig = np.array(q.signature)
    pt.switches = q.switches
    pt.source = q.source
    pt.mode = "closed" if q.source == "closed form" else "shoot"
    pt.tangent = np.r_[q.tangent[:2], np.zeros(2 * pt.N - 2), q.tangent[2]]
    return pt


# =============================================================================================
# symmetry of odd systems
# =============================================================================================
def _is_odd_symmetric(eng: _Engine) -> bool:
    r"""True when :math:`f(t + T/2, -y) = -f(t, y)` (odd force, odd harmonics only):
    :func:`perturb.model.symmetry.is_odd_symmetric` on the vector field at two parameter
    values (the symmetry may hold only for some parameters of the family), in the box
    :math:`|x|, |v| \le 16` (past the breakpoints of the builtin models) to ``1e-10``."""
    for p in (eng.lo + 0.3 * eng.Sp, eng.lo + 0.8 * eng.Sp):
        flow = eng.flow(p)
        if not is_odd_symmetric(flow.vector_field, float(flow.period), 16.0, rtol=1e-10):
            return False
    return True


def _mirror_point(tracer: _Tracer, q: _Pt) -> _Pt:
    r"""The orbit :math:`-y(t + T/2)` of an odd system: same multipliers and amplitude,
    opposite mean, signature shifted by two quarter periods and negated."""
    eng = tracer.eng
    m = eng.m
    if q.mode == "closed" and q.seg >= 0 and tracer.closed is not None:
        r = tracer.closed.point(q.p, eng.system0.n_segments - 1 - q.seg)
        r.grazing = q.grazing
        return r
    N = q.N
    if N % (2 * m) == 0:
        Z = mirror_nodes(q.Z, m)
    else:
        # node i of the image is -y(t_i + T/2): propagate from the nearest earlier node of
        # the orbit (never over a whole period: the orbit may be strongly unstable)
        flow = eng.flow(q.p)
        T = float(flow.period)
        P = m * T
        tn = eng.node_times(P, N)
        Z = np.empty_like(q.Z)
        for i in range(N):
            tau = eng.t0 + ((tn[i] + T / 2 - eng.t0) % P)
            k = min(int(np.searchsorted(tn, tau, side="right") - 1), N - 1)
            if abs(tn[k] - tau) <= 1e-14 * P:
                Z[i] = -q.Z[k]
                continue
            Z[i] = -flow(q.Z[k], tn[k], tau).y
            eng.periods += m * (tau - tn[k]) / P
            eng.calls += 1
    r = _Pt(q.p, Z)
    r.mult = q.mult.copy()
    r.stats = (q.stats[0], q.stats[1], -q.stats[2])
    r.sig = -np.roll(q.sig.reshape(-1, 2), -(SIG_PHASES // 2), axis=0).ravel()
    r.switches, r.grazing, r.mode, r.fold = q.switches, q.grazing, "shoot", q.fold
    r.source = "mirror"
    return r


def _mirror_branch(tracer: _Tracer, pts: list[_Pt]) -> list[_Pt]:
    out = [_mirror_point(tracer, q) for q in pts]
    Sp = tracer.eng.Sp
    n = len(out)
    for i, (r, q) in enumerate(zip(out, pts, strict=True)):
        tq = q.tangent3()
        a, b = out[max(i - 1, 0)], out[min(i + 1, n - 1)]
        sec = _chord3(a, b, Sp)[:2] if n > 1 else np.zeros(2)
        ns = float(np.linalg.norm(sec))
        ypart = sec / ns * math.sqrt(max(0.0, 1 - tq[2] ** 2)) if ns > 0 else np.zeros(2)
        r.tangent = np.r_[ypart, np.zeros(2 * r.N - 2), tq[2]]
    return out


def _walk(pts: list[_Pt], closed: bool, i: int, target: float) -> tuple[bool, int, int]:
    """Follow a branch from point ``i`` towards parameter ``target`` over stable points only:
    (reached, index reached, last stable index)."""
    n = len(pts)
    sgn = float(np.sign(target - pts[i].p))
    if sgn == 0.0:
        return True, i, i

    def step(j: int, s: int) -> int | None:
        k = j + s
        if closed:
            return k % n
        return k if 0 <= k < n else None

    s = 0
    for cand in (1, -1):
        k = step(i, cand)
        if k is not None and (pts[k].p - pts[i].p) * sgn > 0:
            s = cand
            break
    if s == 0:
        return False, i, i
    j = i
    for _ in range(n):
        k = step(j, s)
        if k is None or (pts[k].p - pts[j].p) * sgn < 0 or pts[k].max_mult >= 1.0:
            return False, j, j
        j = k
        if (pts[j].p - target) * sgn >= 0:
            return True, j, j
    return False, j, j


# =============================================================================================
# parallel tracing: the two halves of every branch in worker processes
# =============================================================================================
#: Tracers of running :func:`exact_branches` calls, by key.  Forked workers inherit them
#: (a tracer holds compiled flows, which do not pickle), so a task sends only its start point,
#: direction and the registry of traced branches.
_FORKED: dict[int, _Tracer] = {}


def _march_task(
    key: int, start: _Pt, sign: float, registry: _Registry, parent_m: int | None
) -> tuple[tuple[list[_Pt], str, bool, int, list[float]], float]:
    """One half of a branch, in a worker: :meth:`_Tracer.march_record` without the other
    half (its closed-loop test is replayed when the result is used), and the periods spent."""
    tracer = _FORKED[key]
    tracer.registry = registry
    p0 = tracer.eng.periods
    rec = tracer.march_record(start, sign, [], parent_m)
    return rec, tracer.eng.periods - p0


def _replay(
    tracer: _Tracer,
    rec: tuple[list[_Pt], str, bool, int, list[float]],
    other: list[_Pt],
    first: int,
    parent_m: int | None,
) -> tuple[list[_Pt], str, bool, int, list[float]]:
    """A speculative march cut where the serial march would have stopped.

    The march's steps do not depend on its stop tests, only its end does: it was made with
    the branches registered up to ``first`` and without ``other`` (the first half), so the
    stop tests against later branches and against ``other`` are replayed point by point; the
    last tested point gets every test, in the serial order (which also decides the reason)."""
    pts, reason, closed, checked, work = rec
    if first >= len(tracer.registry.items) and not other:
        return rec
    eng, st = tracer.eng, tracer.st
    own = _Poly.of([pts[0]], eng.Sp, st.ds_max, eng.m)
    other_poly = _Poly.of(other, eng.Sp, st.ds_max, eng.m)
    other_cum = np.cumsum(
        [0.0] + [_key_step(a, b, eng.Sp) for a, b in zip(other[:-1], other[1:], strict=True)]
    )
    cum = [0.0]
    done = [pts[0]]
    for k in range(1, checked + 1):
        new = pts[k]
        h = _key_step(done[-1], new, eng.Sp)
        last = k == checked
        stop = tracer._joined(
            done,
            own,
            cum,
            new,
            h,
            other_poly,
            other_cum,
            parent_m,
            first=0 if last else first,
            own_loop=last,
        )
        if stop is not None:
            return pts[: k + 1], stop[0], stop[1], k, work[: k + 1]
        cum.append(cum[-1] + h)
        done.append(new)
        own.append(new.key())
    return rec


class _Job:
    """A branch being traced from ``start``: both halves submitted, or (serial) nothing yet."""

    __slots__ = ("start", "parent_m", "first", "fwd", "bwd")

    def __init__(self, start: _Pt, parent_m: int | None, first: int) -> None:
        self.start, self.parent_m, self.first = start, parent_m, first
        self.fwd: Any = None
        self.bwd: Any = None


#: seconds between checks of the watchdog thread of a worker process
_WATCHDOG_PERIOD = 0.5


def _die_with_parent(parent: int) -> None:
    """Initializer of the tracing workers: end the worker when the process that started the
    pool dies (SIGKILL included, which runs no clean-up of the parent's): on Linux the kernel
    sends SIGTERM (``prctl(PR_SET_PDEATHSIG)``); everywhere a daemon thread polls the parent
    id and exits when the worker has been re-parented."""
    import os
    import signal
    import sys
    import threading

    # a handler the parent installed (e.g. to finish writing on SIGTERM) is inherited by fork:
    # a worker has nothing to finish and must end on the signal below
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            pr_set_pdeathsig = 1
            libc.prctl(pr_set_pdeathsig, int(signal.SIGTERM), 0, 0, 0)
        except (OSError, AttributeError):
            pass  # the watchdog below still applies
    if os.getppid() != parent:  # the parent died before the signal was armed
        os._exit(1)

    def watch() -> None:
        # (a daemon thread: it ends with the worker, or ends the worker)
        while True:
            time.sleep(_WATCHDOG_PERIOD)
            if os.getppid() != parent:
                os._exit(1)

    threading.Thread(target=watch, name="perturb-parent-watchdog", daemon=True).start()


class _Speculator:
    """Traces branches for :func:`exact_branches`, in worker processes when it may.

    A branch is two marches from its start point; with a pool they run at once, each in a
    worker, and a march is blind to branches registered after it was submitted and (the
    second half) to the first half.  :func:`_replay` cuts each where the serial march would
    have stopped, and the result is used in submission order, so the branches, their points
    and the decisions made from them (seeds skipped, the budget) are those of the serial run,
    whatever the timing.  Speculative work past such a cut, and on a branch that turns out to
    be traced already, is counted in ``wasted``.  ``workers == 1`` runs :meth:`_Tracer.trace`
    when the result is asked for (nothing speculative)."""

    def __init__(self, tracer: _Tracer, workers: int) -> None:
        self.tracer = tracer
        self.workers = workers
        self.pool: Any = None
        self.key = id(tracer)
        self.wasted = 0.0
        self.failure: str | None = None

    @property
    def parallel(self) -> bool:
        return self.workers > 1 and self.failure is None

    def _pool(self) -> Any:
        if self.pool is None:
            import concurrent.futures as cf
            import multiprocessing as mp
            import os

            _FORKED[self.key] = self.tracer
            self.pool = cf.ProcessPoolExecutor(
                self.workers,
                mp_context=mp.get_context("fork"),
                initializer=_die_with_parent,
                initargs=(os.getpid(),),
            )
        return self.pool

    def submit(self, start: _Pt, parent_m: int | None = None) -> _Job:
        job = _Job(start, parent_m, len(self.tracer.registry.items))
        if self.parallel:
            try:
                pool = self._pool()
                reg = self.tracer.registry
                job.fwd = pool.submit(_march_task, self.key, start, 1.0, reg, parent_m)
                job.bwd = pool.submit(_march_task, self.key, start, -1.0, reg, parent_m)
            except Exception as exc:  # no pool here (resources, platform): serial
                self._fail(exc)
                job.fwd = job.bwd = None
        return job

    def _fail(self, exc: BaseException) -> None:
        self.failure = f"parallel tracing off after {type(exc).__name__}: {exc}"
        self.close()

    def _get(self, fut: Any) -> Any:
        try:
            rec, periods = fut.result()
        except Exception as exc:  # a broken pool: the caller redoes the branch serially
            self._fail(exc)
            return None
        return rec, periods

    def discard(self, job: _Job) -> None:
        """A job whose start turned out to lie on a traced branch (or a second half not
        needed): cancelled if it has not started, else left to finish (not waited for)."""
        for fut in (job.fwd, job.bwd):
            if fut is not None and not fut.cancel():
                fut.add_done_callback(self._count_waste)

    def _count_waste(self, fut: Any) -> None:
        if not fut.cancelled() and fut.exception() is None:
            self.wasted += fut.result()[1]

    def result(self, job: _Job) -> tuple[ContinuationBranch, list[_Pt]]:
        tr = self.tracer
        if job.fwd is None:
            return tr.trace(job.start, parent_m=job.parent_m)
        got_f = self._get(job.fwd)
        if got_f is None:
            return tr.trace(job.start, parent_m=job.parent_m)
        rec_f = _replay(tr, got_f[0], [], job.first, job.parent_m)
        fwd, reason_f, closed, _, work_f = rec_f
        periods = work_f[-1]
        self.wasted += got_f[1] - work_f[-1]
        if closed:
            self.discard(job)  # the second half: the loop is closed already
            pts, reason = fwd, "closed loop"
        else:
            got_b = self._get(job.bwd)
            if got_b is None:
                return tr.trace(job.start, parent_m=job.parent_m)
            bwd, reason_b, closed, _, work_b = _replay(tr, got_b[0], fwd, job.first, job.parent_m)
            periods += work_b[-1]
            self.wasted += got_b[1] - work_b[-1]
            for q in bwd[1:]:
                if q.tangent is not None:
                    q.tangent = -q.tangent
            pts = bwd[:0:-1] + fwd
            reason = "closed loop" if closed else f"{reason_b} / {reason_f}"
        # the serial run's work (budget and the branch's record), whatever was speculated
        tr.eng.periods += periods
        p0 = tr.eng.periods
        pts = tr.refine_folds(pts)
        periods += tr.eng.periods - p0
        return tr.freeze(pts, closed, reason, periods), pts

    def close(self) -> None:
        if self.pool is not None:
            self.pool.shutdown(wait=True, cancel_futures=True)
            self.pool = None
        _FORKED.pop(self.key, None)


def _resolve_workers(workers: int | None) -> int:
    """Worker processes for tracing: ``workers``, or by default ``PERTURB_WORKERS`` or 2 on a
    machine with two or more CPUs; 1 (serial) inside a worker process of any pool (a response
    computed on a pool must not start pools of its own) and where ``fork`` is unavailable."""
    import multiprocessing as mp
    import os

    if workers is None:
        env = os.environ.get("PERTURB_WORKERS", "").strip()
        if env:
            try:
                workers = int(env)
            except ValueError:
                raise ParameterError(
                    f"PERTURB_WORKERS = {env!r}: expected a positive integer"
                ) from None
        else:
            workers = 2
        workers = min(workers, os.cpu_count() or 1)
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ParameterError(f"workers = {workers!r}: expected a positive integer or None")
    if workers > 1 and (
        mp.parent_process() is not None or "fork" not in mp.get_all_start_methods()
    ):
        return 1
    return workers


# =============================================================================================
# public: every branch
# =============================================================================================
def exact_branches(
    oscillator: Oscillator,
    window: Sequence[float] = (0.2, 2.0),
    *,
    seeds: Sequence[tuple[float, ArrayLike]] = (),
    options: ExactResponseOptions | None = None,
    **knobs: Any,
) -> ExactBranches:
    r"""Every branch of periodic orbits found over ``window`` of the forcing frequency.

    Seeds, in order (each polished by Newton at its frequency and skipped when it lies on a
    branch already traced): the closed-form orbits of every linear segment of a PWL force that
    stay in their segment (the saddle branch of ``nsd`` inside :math:`|x| < 1`, the one-well
    orbits off resonance); the caller's ``seeds`` (e.g. points along every branch of an
    approximation, :func:`perturb.seeds.approximation_seeds`, as the front door
    :func:`perturb.solve.frequency_response` passes them); virtual sweeps up and down (module
    docstring).  Then the other branch at every branch point (symmetry-breaking pitchforks),
    and with ``period_doubling=True`` the period-2 branch at every period doubling and the
    branch of any period-2 motion a sweep settles on (detached period-2 loops included).  With
    ``symmetry`` (odd systems), every branch that is not its own image under
    :math:`(x, t) \to (-x, t + T/2)` gets its mirror image.

    Parameters
    ----------
    oscillator
        Forced at one frequency parameter; all other parameters set.
    window
        ``(low, high)`` forcing frequencies, ``low > 0``.
    seeds
        Pairs ``(Omega, (x0, v0))`` at ``t = 0``, each only a start of Newton on the exact
        flow (a seed that does not converge is counted in a note).
    options : ExactResponseOptions, optional
        The tuning knobs below (default: the defaults); see :class:`ExactResponseOptions`.
    **knobs
        Its fields as keywords, replacing those of ``options``:

    sweep_points
        Frequencies of the virtual sweeps (0: none).
    transient_periods
        Periods integrated per attempt where a sweep jumps (up to three attempts).
    ds_max, ds_min, tol, max_points
        As in :func:`continue_orbits` (defaults 0.005, 1e-7, 1e-10, 20000).
    branch_points, period_doubling, symmetry, closed_form
        Switches of the stages above.
    max_branches, max_periods
        Budgets: branches (default 40), and propagated time in forcing periods (all stages;
        default 2e5).
    max_seconds
        Wall-clock budget (None: none).  When it runs out, the march in progress stops
        (stop reason ``"time budget"``), no further seed or sweep is tried, and a note says
        so: the branches traced so far are returned.
    progress
        Progress line (default: on unless ``PERTURB_PROGRESS=0``).
    workers
        Processes that trace (default: ``PERTURB_WORKERS``, else 2 on a machine with two or
        more CPUs).  With more than one, the two halves of every period-1 branch are marched
        at once in a process pool (``fork``), and the closed-form seeds' branches all at
        once; each march is cut afterwards where the serial march would have stopped
        (branches registered meanwhile, the other half) and results are used in submission
        order, so the branches are exactly those of ``workers=1``.  Serial inside a worker
        process of another pool (e.g. :func:`perturb.apps.grid.sweep`), where ``fork`` is not
        available, and if the pool fails (noted).  The pool starts at the first branch.

    Returns
    -------
    ExactBranches
        ``.to_response()`` gives the :class:`~perturb.response.Response`.
    """
    t_begin = time.perf_counter()
    o = _exact_options(options, knobs, _ALL_FIELDS, "exact_branches")
    sweep_points, transient_periods, max_branches = (
        o.sweep_points,
        o.transient_periods,
        o.max_branches,
    )
    max_seconds = o.max_seconds
    max_periods = 2e5 if o.max_periods is None else o.max_periods
    if not isinstance(oscillator, Oscillator):
        raise ParameterError(f"oscillator = {oscillator!r}: expected an Oscillator")
    lo, hi = _window(window)
    if lo <= 0:
        raise ParameterError(f"window = {window!r}: forcing frequencies must be positive")
    for name, v in (
        ("sweep_points", sweep_points),
        ("transient_periods", transient_periods),
        ("max_branches", max_branches),
    ):
        if isinstance(v, bool) or not isinstance(v, int) or v < 0:
            raise ParameterError(f"{name} = {v!r}: expected a non-negative integer")
    if max_seconds is not None and not (
        isinstance(max_seconds, int | float)
        and not isinstance(max_seconds, bool)
        and max_seconds > 0
        and not math.isnan(max_seconds)
    ):
        raise ParameterError(f"max_seconds = {max_seconds!r}: expected a positive number or None")
    n_workers = _resolve_workers(o.workers)
    family = FlowFamily(oscillator)
    st = _settings(o.ds_max, o.ds_min, o.tol, o.max_points, max_periods)
    if max_seconds is not None:
        st.deadline = time.monotonic() + float(max_seconds)
    undamped = _undamped_note(family, (lo, hi))
    if undamped is not None:
        return ExactBranches(
            branches=(),
            mirror_of=(),
            notes=(undamped,),
            periods=0.0,
            seconds=time.perf_counter() - t_begin,
            model=oscillator.name,
            params=MappingProxyType(
                {k: float(v) for k, v in oscillator.params.items() if v is not None}
            ),
            method="exact" if family.exact else "shooting",
        )
    tracer = _Tracer(family, 1, 0.0, (lo, hi), st, closed_form=o.closed_form)
    spec = _Speculator(tracer, n_workers)
    try:
        return _exact_branches(
            oscillator,
            tracer,
            spec,
            t_begin,
            seeds=seeds,
            sweep_points=sweep_points,
            transient_periods=transient_periods,
            branch_points=o.branch_points,
            period_doubling=o.period_doubling,
            symmetry=o.symmetry,
            max_branches=max_branches,
            max_periods=max_periods,
            progress=o.progress,
        )
    finally:
        spec.close()


def _exact_branches(
    oscillator: Oscillator,
    tracer: _Tracer,
    spec: _Speculator,
    t_begin: float,
    *,
    seeds: Sequence[tuple[float, ArrayLike]],
    sweep_points: int,
    transient_periods: int,
    branch_points: bool,
    period_doubling: bool,
    symmetry: bool,
    max_branches: int,
    max_periods: float,
    progress: bool | None,
) -> ExactBranches:
    """The body of :func:`exact_branches` (arguments checked, tracer and pool set up)."""
    family, st = tracer.eng.family, tracer.st
    lo, hi = tracer.eng.lo, tracer.eng.hi
    eng, reg = tracer.eng, tracer.registry
    sym = bool(symmetry) and _is_odd_symmetric(eng)
    branches: list[ContinuationBranch] = []
    internals: list[list[_Pt]] = []
    mirror_of: list[int | None] = []
    tracers: list[_Tracer] = []
    notes: list[str] = []

    def budget_left() -> bool:
        return (
            eng.periods < max_periods
            and len(branches) < max_branches
            and time.monotonic() <= st.deadline
        )

    def register(br: ContinuationBranch, pts: list[_Pt], mo: int | None, tr: _Tracer) -> None:
        branches.append(br)
        internals.append(pts)
        mirror_of.append(mo)
        tracers.append(tr)
        reg.add(pts, br.m)

    def add(br: ContinuationBranch, pts: list[_Pt], tr: _Tracer) -> None:
        idx = len(branches)
        register(br, pts, None, tr)
        if not sym or len(pts) < 2:
            return
        # self-symmetric (every orbit symmetric, or the loop contains its image)?
        probe = [pts[len(pts) // 4], pts[len(pts) // 2], pts[(3 * len(pts)) // 4]]
        images = [_mirror_point(tr, q) for q in probe]
        where = [reg.near(r, br.m) for r in images]
        if all(b >= 0 for b, _ in where):
            return
        mpts = _mirror_branch(tr, pts)
        mbr = tr.freeze(
            mpts, br.closed, br.stop_reason, 0.5 * sum(q.mode != "closed" for q in pts), m=br.m
        )
        register(mbr, mpts, idx, tr)

    def try_seed(pt: _Pt) -> bool:
        if not budget_left() or reg.near(pt, 1)[0] >= 0:
            return False
        start = tracer.start_point(pt.p, None, seed=pt)
        br, pts = spec.result(spec.submit(start))
        add(br, pts, tracer)
        return True

    raw: list[tuple[float, np.ndarray]] = [(float(p), np.asarray(y, float)) for p, y in seeds]
    for p, y in raw:
        if not lo <= p <= hi or y.shape != (2,) or not np.all(np.isfinite(y)):
            raise ParameterError(f"seed ({p}, {y.tolist()}): expected (Omega in window, (x0, v0))")
    closed_seeds = tracer.closed.seeds() if tracer.closed is not None else []
    total = len(closed_seeds) + len(raw) + 2 * sweep_points
    # seeds differ widely in cost (a seed on a known branch costs nothing): no estimate of
    # the time left, which jumped about (~205 s left, then ~91 s, done at 48 s)
    with Progress(total, "exact frequency response", enabled=progress, eta=False) as bar:
        # the closed-form seeds' branches all at once (speculative with a pool: a seed on an
        # earlier seed's branch is dropped when its turn comes, as the serial run skips it)
        jobs: list[tuple[_Pt, _Job | None]] = []
        images: list[_Pt] = []
        for pt in closed_seeds:
            # not speculated: the mirror image of an earlier seed (odd systems), whose branch
            # is the earlier one's mirror, registered by the time this seed's turn comes
            twin = any(_key_step(r, pt, eng.Sp) < 1e-9 for r in images)
            if sym:
                images.append(_mirror_point(tracer, pt))
            job = None
            if spec.parallel and not twin:
                job = spec.submit(tracer.start_point(pt.p, None, seed=pt))
            jobs.append((pt, job))
        for pt, job in jobs:
            bar.update()
            if job is None:
                try_seed(pt)
            elif not budget_left() or reg.near(pt, 1)[0] >= 0:
                spec.discard(job)
            else:
                br, pts = spec.result(job)
                add(br, pts, tracer)
        failed = 0
        for p, y in raw:
            bar.update()
            if not budget_left():
                break
            try:
                pt = tracer.polish(p, y, max_iter=25)
            except (ShootingError, PerturbError):
                failed += 1
                continue
            try_seed(pt)
        if failed:
            notes.append(f"{failed} of {len(raw)} given/approximation seeds did not converge")
        child = None
        seed2 = None
        if period_doubling:
            child = _Tracer(family, 2, 0.0, (lo, hi), st, closed_form=False, registry=reg)

            def seed2(p: float, y: np.ndarray) -> None:
                # period-2 motion met by a sweep: its branch (e.g. a detached period-2 loop
                # that no period doubling in the window reaches)
                if not budget_left():
                    return
                try:
                    q = child.polish(p, y, max_iter=12)
                except (ShootingError, PerturbError):
                    return
                if np.max(np.abs(q.Z[q.N // 2] - q.Z[0])) < 1e-6 * q.R:
                    return  # a period-1 orbit after all
                if reg.near(q, 2)[0] >= 0:
                    return
                br2, pts2 = child.trace(child.start_point(p, None, seed=q), parent_m=1)
                add(br2, pts2, child)

        for direction in (1, -1):
            _virtual_sweep(
                tracer,
                direction,
                sweep_points,
                transient_periods,
                internals,
                branches,
                try_seed,
                budget_left,
                bar,
                seed2,
            )
        # the other branch at every branch point (pitchforks of odd systems)
        done: set[int] = set()
        while branch_points and budget_left():
            todo = [
                b
                for b in range(len(branches))
                if b not in done and mirror_of[b] is None and branches[b].m == 1
            ]
            if not todo:
                break
            for b in todo:
                done.add(b)
                for sp_ in branches[b].branch_points:
                    if not budget_left():
                        break
                    q = _branch_off(tracer, internals[b], sp_, tracer)
                    if q is None:
                        notes.append(f"branch {b}: no new branch at {sp_!r}")
                        continue
                    if reg.near(q, 1)[0] >= 0:
                        continue
                    br, pts = spec.result(spec.submit(q))
                    add(br, pts, tracer)
        if child is not None:
            for b in range(len(branches)):
                if mirror_of[b] is not None or branches[b].m != 1:
                    continue
                for sp_ in branches[b].period_doublings:
                    if not budget_left():
                        break
                    q = _branch_off(tracer, internals[b], sp_, child)
                    if q is None:
                        notes.append(f"branch {b}: no period-2 branch at {sp_!r}")
                        continue
                    if reg.near(q, 2)[0] >= 0:
                        continue
                    br, pts = child.trace(q, parent_m=1)
                    add(br, pts, child)
            eng.periods += child.eng.periods
    if time.monotonic() > st.deadline:
        notes.append(
            f"time budget reached ({time.perf_counter() - t_begin:.0f} s): the search for "
            f"branches stopped early, {len(branches)} branches traced so far may be incomplete "
            "(raise max_seconds, narrow the window, or use a cheaper method)"
        )
    elif not budget_left():
        notes.append(
            f"budget reached: {len(branches)} branches (max {max_branches}), "
            f"{eng.periods:.0f} periods (max {max_periods:g})"
        )
    if spec.failure is not None:
        notes.append(spec.failure)
    elif spec.pool is not None:
        # (the speculative work not used depends on timing: ``spec.wasted``, not a note)
        notes.append(f"traced with {spec.workers} worker processes")
    return ExactBranches(
        branches=tuple(branches),
        mirror_of=tuple(mirror_of),
        notes=tuple(notes),
        periods=float(eng.periods),
        seconds=time.perf_counter() - t_begin,
        model=oscillator.name,
        params=MappingProxyType(
            {k: float(v) for k, v in oscillator.params.items() if v is not None}
        ),
        method="exact" if family.exact else "shooting",
    )


def _undamped_note(family: FlowFamily, window: tuple[float, float]) -> str | None:
    """A note when the oscillator dissipates no energy (no term depends on x'), else None.

    Forced orbits of such a system are at best neutrally stable (det M = 1: the Floquet
    multipliers lie on the unit circle or come in pairs mu, 1/mu), no transient decays, and
    the free oscillations form families of periodic orbits rather than isolated ones; the
    sweeps, seeds and stability tests of the exact continuation all assume damping."""
    osc = family.oscillator
    if family.exact:
        try:
            mu = float(family.at(0.5 * (window[0] + window[1])).system.damping)
        except PerturbError:
            return None
        dissipative = mu != 0.0
    else:
        subs = {s: v for s, v in osc.substitutions().items() if s.name != family.parameter}
        dissipative = osc.v in osc.g.xreplace(subs).free_symbols
    if dissipative:
        return None
    return (
        "no branches traced: the system is undamped (no term in x' dissipates energy), so no "
        "transient decays and every periodic orbit is at best neutrally stable (Floquet "
        "multipliers on the unit circle); the free oscillations form families of periodic "
        "orbits, not isolated ones, and the sweeps, seeds and stability tests of the exact "
        "continuation assume damping. Add damping (e.g. a small mu*x') for the damped "
        "response, or use an approximation (hb1, hb, mlp) or a backbone for the undamped one"
    )


def _virtual_sweep(
    tracer: _Tracer,
    direction: int,
    n: int,
    transient: int,
    internals: list[list[_Pt]],
    branches: list[ContinuationBranch],
    try_seed,
    budget_left,
    bar: Progress,
    seed2=None,
) -> None:
    """A stepped sweep that follows the stable part of traced branches without integrating,
    and integrates (then polishes) only where the followed branch ends or loses stability.
    ``seed2(p, y)`` receives states that settled on period-2 motion."""
    if n == 0:
        return
    eng, reg = tracer.eng, tracer.registry
    grid = np.linspace(eng.lo, eng.hi, max(2, n))[::direction]
    state: tuple[int, int] | None = None
    y = np.zeros(2)
    fresh = True  # just left a branch (or at rest): the transient may be long
    for p in grid:
        bar.update()
        if not budget_left():
            return
        if state is not None:
            b, i = state
            ok, j, last = _walk(internals[b], branches[b].closed, i, float(p))
            if ok:
                state = (b, j)
                continue
            y = internals[b][last].y0.copy()
            state, fresh = None, True
        flow = eng.flow(float(p))
        T = float(flow.period)
        found = None
        # where no stable period-1 orbit is known (after a jump, or in a region of period-2
        # or chaotic motion) integrate: twice after a jump, once per frequency otherwise
        for _ in range(2 if fresh else 1):
            try:
                y = flow(y, eng.t0, eng.t0 + transient * T).y
                y1 = flow(y, eng.t0, eng.t0 + T).y
            except PerturbError:
                y = np.zeros(2)
                break
            eng.periods += transient + 1
            eng.calls += 2
            # Newton only from a nearly periodic state: in a region of period-2 or chaotic
            # motion a failing Newton costs more than the transient
            scale = max(1.0, float(np.max(np.abs(y))))
            if np.max(np.abs(y1 - y)) > 0.05 * scale:
                if seed2 is not None:
                    try:
                        y2 = flow(y1, eng.t0, eng.t0 + T).y
                        eng.periods += 1
                        eng.calls += 1
                        if np.max(np.abs(y2 - y)) <= 0.05 * scale:
                            seed2(float(p), y)  # settled period-2 motion: its branch
                        y1 = y2
                    except PerturbError:
                        pass
                y = y1
                continue
            try:
                pt = tracer.polish(float(p), y1, max_iter=8)
            except (ShootingError, PerturbError):
                y = y1
                continue
            if pt.max_mult < 1.0:
                found = pt
                break
            try_seed(pt)  # an unstable orbit is an orbit too: its branch may be new
        fresh = False
        if found is None:
            continue
        b, k = reg.near(found, 1)
        if b < 0:
            try_seed(found)
            b, k = reg.near(found, 1)
        if b >= 0 and branches[b].m == 1:
            pts = internals[b]
            k2 = min(k + 1, len(pts) - 1)
            d = [_key_step(pts[j], found, eng.Sp) for j in (k, k2)]
            state = (b, k if d[0] <= d[1] else k2)


def exact_frequency_response(
    oscillator: Oscillator,
    window: Sequence[float] = (0.2, 2.0),
    **options: Any,
) -> Response:
    """Every branch found by :func:`exact_branches` as a :class:`~perturb.response.Response`
    (method ``'exact'`` for PWL models, ``'shooting'`` for the ODE flow of smooth ones); the
    options are those of :func:`exact_branches`.  ``notes`` say which branches are closed
    loops and which are mirror images."""
    return exact_branches(oscillator, window, **options).to_response()


def _polish_at(branch: ContinuationBranch, j: int, w: float) -> PeriodicOrbit | None:
    """The orbit of ``branch`` at exactly ``Omega = w`` between points ``j`` and ``j + 1``:
    the stored states interpolated linearly in the parameter, then shooting at ``w`` (multiple
    shooting when both points carry nodes, as strongly unstable orbits need)."""
    a, b = branch.points[j], branch.points[j + 1]
    dp = b.parameter - a.parameter
    s = 0.5 if dp == 0.0 else min(1.0, max(0.0, (w - a.parameter) / dp))
    flow = branch.family.at(w)
    try:
        if a.nodes is not None and b.nodes is not None and a.nodes.shape == b.nodes.shape:
            nodes = (1.0 - s) * a.nodes + s * b.nodes
            return multiple_shooting(flow, nodes, m=branch.m, t0=branch.t0)
        y = (1.0 - s) * a.y0 + s * b.y0
        orbit = periodic_orbit(flow, y, m=branch.m, t0=branch.t0)
        if orbit.max_multiplier > NODE_GROWTH:
            # one period from y0 amplifies its rounding by the multiplier: the statistics of a
            # strongly unstable orbit come from nodes that each grow it by NODE_GROWTH at most
            n = _nodes_needed(orbit.max_multiplier, branch.m)
            _, x, v = orbit.sample(n)
            orbit = multiple_shooting(flow, np.column_stack([x, v]), m=branch.m, t0=branch.t0)
        return orbit
    except PerturbError:
        return None


#: the window traced around a single requested frequency: [w / f, w * f]
ONE_FREQUENCY_WINDOW = 1.25
#: wall-clock budget of that tracing (seconds) unless the caller gives max_seconds
_ONE_SECONDS = 120.0


def _same_orbit(a: PeriodicOrbit, b: PeriodicOrbit) -> bool:
    if a.m != b.m:
        return False
    scale = max(1.0, float(np.max(np.abs(a.y0))), float(np.max(np.abs(b.y0))))
    return float(np.max(np.abs(np.asarray(a.y0) - np.asarray(b.y0)))) <= 1e-6 * scale


def _solutions_at_one(
    oscillator: Oscillator,
    w: float,
    options: dict[str, Any],
    orbit_guesses: Callable[[float], Sequence[np.ndarray]] | None = None,
) -> Response:
    """Every orbit at the single frequency ``w``: the brute-force search of
    :func:`~perturb.simulate.orbits.search.periodic_orbits` (started also from
    ``orbit_guesses(w)``), and every crossing of ``w`` by the branches that
    :func:`exact_branches` traces over ``[w / 1.25, w * 1.25]`` (seeded with the orbits
    found), polished by shooting at exactly ``w``; duplicates removed."""
    from perturb.simulate.orbits.search import periodic_orbits

    family = FlowFamily(oscillator)
    notes: list[str] = []
    nodes = orbit_guesses(w) if orbit_guesses is not None else ()
    orbits: list[PeriodicOrbit] = list(periodic_orbits(oscillator, w, node_guesses=nodes))
    n_search = len(orbits)
    undamped = _undamped_note(family, (w, w))
    if undamped is not None:
        notes.append(undamped.replace("no branches traced", "no continuation"))
    else:
        opts = dict(options)
        seeds = list(opts.pop("seeds", ()))
        seeds += [(w, o.y0) for o in orbits if o.m == 1]
        if opts.get("options") is None:  # else the options object's max_seconds holds
            opts.setdefault("max_seconds", _ONE_SECONDS)
        lo, hi = w / ONE_FREQUENCY_WINDOW, w * ONE_FREQUENCY_WINDOW
        try:
            found = exact_branches(oscillator, (lo, hi), seeds=seeds, **opts)
        except PerturbError as exc:
            found = None
            notes.append(f"continuation over [{lo:.6g}, {hi:.6g}] failed: {exc}")
        added = 0
        if found is not None:
            notes += [n for n in found.notes if not n.startswith("traced with")]
            for bi, br in enumerate(found.branches):
                p = br.parameters
                for j in range(len(p) - 1):
                    a, b = sorted((p[j], p[j + 1]))
                    if not a <= w <= b or (w == p[j + 1] and j + 1 < len(p) - 1):
                        continue
                    orbit = _polish_at(br, j, w)
                    if orbit is None:
                        notes.append(f"branch {bi}: shooting at Omega = {w!r} failed")
                        continue
                    if not any(_same_orbit(orbit, o) for o in orbits):
                        orbits.append(orbit)
                        added += 1
        notes.append(
            f"{n_search} orbits from periodic_orbits, {added} more where the branches traced "
            f"over [{lo:.6g}, {hi:.6g}] cross Omega = {w!r}"
        )
    orbits.sort(key=lambda o: (o.amplitude, o.mean))
    params = {k: v for k, v in oscillator.params.items() if k != family.parameter}
    branches = tuple(
        Branch(
            omega=[w],
            amplitude=[o.amplitude],
            first_harmonic_amplitude=[o.first_harmonic_amplitude],
            mean=[o.mean],
            # max |mu| < 1, as on traced branches: is_stable is False within unit_tol of
            # the unit circle, which every lightly damped orbit is (mu -> 0)
            stable=[o.max_multiplier < 1.0],
            max_multiplier=[o.max_multiplier],
        )
        for o in orbits
    )
    method = "exact" if family.exact else "shooting"
    notes.insert(0, f"{len(orbits)} orbits at Omega = {w!r} (one per branch)")
    return Response(branches, method, oscillator.name, params, notes=tuple(notes))


def exact_solutions_at(
    oscillator: Oscillator,
    frequencies: Sequence[float],
    *,
    orbit_guesses: Callable[[float], Sequence[np.ndarray]] | None = None,
    **options: Any,
) -> Response:
    """Every exact periodic orbit at exactly the forcing frequencies ``frequencies``.

    With two or more distinct frequencies the branches are traced by :func:`exact_branches`
    over ``[min, max]`` (``options`` are its options) and every crossing of a branch with a
    requested frequency is polished by shooting at that frequency, so the output holds the
    requested values exactly and keeps the branch structure (a branch that folds back meets a
    frequency more than once).  A single frequency is answered by
    :func:`~perturb.simulate.orbits.search.periodic_orbits` together with the crossings of the
    branches traced over ``[w / 1.25, w * 1.25]`` (each orbit its own branch; the tracing
    has a wall-clock budget of 120 s unless ``max_seconds`` is given, as a keyword or by an
    ``options=`` :class:`ExactResponseOptions`).

    ``orbit_guesses(Omega)``, when given, returns node guesses (arrays of states over one
    forcing period) that :func:`~perturb.simulate.orbits.search.periodic_orbits` also shoots
    from (``node_guesses``); the front door :func:`perturb.solve.frequency_response` passes
    :func:`perturb.seeds.periodic_orbit_guesses` (approximations' solutions).  They only start
    shooting on the exact flow.

    Raises
    ------
    ParameterError
        Empty, non-finite or non-positive frequencies.
    """
    try:
        w_all = np.asarray(frequencies, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ParameterError(
            f"frequencies = {frequencies!r}: expected a sequence of positive numbers"
        ) from None
    if w_all.size == 0 or not np.all(np.isfinite(w_all)) or np.any(w_all <= 0.0):
        raise ParameterError(
            f"frequencies = {w_all.tolist()!r}: expected positive finite forcing frequencies"
        )
    from perturb.simulate.orbits.search import periodic_orbits

    targets = np.unique(w_all)
    if targets.size == 1:
        return _solutions_at_one(oscillator, float(targets[0]), options, orbit_guesses)

    # a short window gives the sweeps and closed-form seeds few chances to meet every branch,
    # so the orbits found at the middle frequency (brute force over initial conditions plus
    # the caller's orbit guesses) seed the tracing as well
    w_mid = float(targets[targets.size // 2])
    seeds = list(options.pop("seeds", ()))
    nodes = orbit_guesses(w_mid) if orbit_guesses is not None else ()
    seeds += [
        (w_mid, o.y0) for o in periodic_orbits(oscillator, w_mid, node_guesses=nodes) if o.m == 1
    ]
    found = exact_branches(
        oscillator, (float(targets[0]), float(targets[-1])), seeds=seeds, **options
    )
    branches = []
    notes = list(found.to_response().notes)
    for bi, br in enumerate(found.branches):
        p = br.parameters
        rows: list[tuple[float, PeriodicOrbit]] = []
        for j in range(len(p) - 1):
            lo, hi = sorted((p[j], p[j + 1]))
            # half-open on the far end so a frequency hit exactly by a point is polished once
            inside = targets[(targets >= lo) & (targets <= hi)]
            for w in inside:
                if w == p[j + 1] and j + 1 < len(p) - 1:
                    continue
                orbit = _polish_at(br, j, float(w))
                if orbit is None:
                    notes.append(f"branch {bi}: shooting at Omega = {w!r} failed; row left out")
                    continue
                rows.append((float(w), orbit))
        if rows:
            branches.append(
                Branch(
                    omega=[w for w, _ in rows],
                    amplitude=[o.amplitude for _, o in rows],
                    first_harmonic_amplitude=[o.first_harmonic_amplitude for _, o in rows],
                    mean=[o.mean for _, o in rows],
                    stable=[o.max_multiplier < 1.0 for _, o in rows],
                    max_multiplier=[o.max_multiplier for _, o in rows],
                )
            )
    return Response(
        tuple(branches),
        found.method,
        found.model,
        dict(found.params),
        notes=tuple(notes),
    )
