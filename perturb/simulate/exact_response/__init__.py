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
    Last, the *attractor stage* (``attractors=True``, :mod:`.attractors`): one vectorised RK4
    simulation of the piecewise-affine field at frequencies 2 % apart, from a grid of states
    and from both sides of every unstable traced orbit, whose settled states not on a traced
    branch seed Newton on the exact map — the stable isolas and the branches that lie in the
    window only near an edge and are stable on short stretches, which no sweep reaches.
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
    (``MAX_STEP_ATTEMPTS``), the points and propagated periods per march, the branches and
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

Systems of several coordinates
    A :class:`~perturb.model.system.System` (``FlowFamily(system)``: the exact affine flow
    :class:`~perturb.simulate.flows.affine_exact.AffineExactFlow`, built once and rescaled in
    the forcing frequency) is traced by the same core with its ``n`` states per node
    (``G_z`` blocks of ``n x n``; multipliers by ``eigvals``).  :math:`\partial G/\partial p`
    is exact for the frequency parameter (the particular solution above with
    :math:`R = (i\omega I - A)^{-1}` of each region, saltation at discontinuous crossings).
    Closed-form arcs are replaced by seeds: the steady state of every linear region that
    stays inside it (exact orbits, traced by shooting).  Every point carries, besides the
    statistics of the output :math:`c\cdot y` (``output=``, default the first coordinate),
    ``max |q_k|`` and the mean of every coordinate (extrema: cubic Hermite location on the
    sampled rates, value on the exact trajectory); a system's statistics are accepted within
    ``min(ND_STATS_TOL, 10 tol)`` = 1e-9 (the oscillator's ``STATS_TOL`` would leave ~5e-9 in
    the maxima and ~3e-7 in the multipliers), a tenth of it when a point is accepted after
    one propagation (the statistics are then those of the predicted orbit).  The predictor is
    a quintic Hermite arc through the last three points and their tangents, the branch
    written as a graph over the current tangent line (exact abscissae, error
    :math:`O(ds^6)`): at the default spacing the cubic's first correction (~1e-9 .. 1e-7)
    exceeds that threshold on most points, the quintic's (median ~1e-12) does not, and most
    points cost one propagation.  States and rates at the statistics' samples come from the
    closed form of each piece.  Odd symmetry is tested on the n-dimensional field.

Layout
    The package is split by concern, each module importing only earlier ones:
    ``base`` (constants) → ``problem`` (the shooting problem: points, evaluation of the flow
    family) → ``results`` (the public result objects) → ``closed_form`` (closed-form segment
    arcs) → ``options`` (``ExactResponseOptions``, windows, march settings) → ``steps``
    (step control, corrector, tangents, curve registry) → ``march`` (the ``Tracer`` and the
    detection of special points) → ``special_points`` (branch switching) → ``symmetry``
    (mirror images of odd systems) → ``parallel`` (forked marches) → ``branches``
    (``exact_branches``) → ``api`` (``continue_orbits``, ``exact_frequency_response``,
    ``exact_solutions_at``).  This module re-exports the public names.
"""

from __future__ import annotations

from perturb.simulate.exact_response.api import ONE_FREQUENCY_WINDOW as ONE_FREQUENCY_WINDOW
from perturb.simulate.exact_response.api import (
    continue_orbits,
    exact_frequency_response,
    exact_solutions_at,
)
from perturb.simulate.exact_response.base import JOIN_FRACTION as JOIN_FRACTION
from perturb.simulate.exact_response.base import MAX_MULTIPLIER as MAX_MULTIPLIER
from perturb.simulate.exact_response.base import MAX_NODES as MAX_NODES
from perturb.simulate.exact_response.base import NODE_GROWTH as NODE_GROWTH
from perturb.simulate.exact_response.base import SIG_PHASES as SIG_PHASES
from perturb.simulate.exact_response.base import STAT_SAMPLES as STAT_SAMPLES
from perturb.simulate.exact_response.base import STATS_TOL as STATS_TOL
from perturb.simulate.exact_response.base import SpecialKind as SpecialKind
from perturb.simulate.exact_response.branches import exact_branches
from perturb.simulate.exact_response.options import ExactResponseOptions
from perturb.simulate.exact_response.results import (
    ContinuationBranch,
    ContinuationPoint,
    ExactBranches,
    SpecialPoint,
)
from perturb.simulate.exact_response.special_points import switch_branch

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
