r"""Pseudo-arclength continuation of a solution curve of :math:`F(u, \lambda) = 0`.

THE pseudo-arclength core of the package (the exact frequency response of
:mod:`perturb.simulate.exact_response` shares its step control and predictor).  A generic
core: the caller supplies the residual :math:`F: \mathbb{R}^n \times \mathbb{R} \to
\mathbb{R}^n` and its Jacobian :math:`(F_u, F_\lambda)`; nothing here knows what the unknowns
mean (harmonic-balance coefficients, amplitude–phase unknowns of a symbolic method, shooting
states). :func:`continue_curve` traces the curve from a starting point through a window of
:math:`\lambda`, passing folds.

Coordinates
-----------
All steps, tangents and tolerances live in scaled coordinates :math:`\hat u = u / s_u`,
:math:`\hat\lambda = \lambda / s_\lambda` (``u_scale``, ``lam_scale``), so one arclength unit
means "the size of the solution" and "the width of the window" alike; without that, a
curve whose unknowns are of size 40 and whose parameter moves by 1 would be stepped almost
only by its unknowns. With ``adaptive_scale`` the scale of the unknowns follows the solution
(:math:`\max(s_u, \|u\|_\infty)`, re-set when it changes by more than 25 %, the current point
and tangent carried over), so the steps stay relative across a resonance peak.

Algorithm
---------
*Tangent*: the unit null vector :math:`t` of :math:`[F_u s_u \mid F_\lambda s_\lambda]`,
from the bordered system :math:`\begin{pmatrix}F_u s_u & F_\lambda s_\lambda\\ t_{prev}^T &
0\end{pmatrix} z = e_{n+1}`, which also orients it along the previous tangent (so a fold is
passed, not turned back from). At the start, :math:`F_u z = -F_\lambda` (SVD null vector if
:math:`F_u` is singular), oriented by ``direction``. The Jacobian used is the one of the last
Newton iterate of the point's correction, which differs from the point by the last (accepted
as negligible) correction: no extra evaluation per point.

*Predictor*: :math:`\hat w_{pred} = \hat w_i + \Delta s\, t_i`, or with ``predictor="hermite"``
the cubic Hermite arc through the last two points and their tangents, extrapolated by
:math:`\Delta s` (error :math:`O(h^2 \Delta s^2)` for points :math:`h` apart, against
:math:`O(\Delta s^2)`); the corrector then works on the hyperplane through the predicted point
orthogonal to :math:`t_i`. With ``early_accept`` a point whose first correction is small
enough, by the quadratic-convergence constant measured on recent points, is accepted after
that one correction: about one evaluation per point on a smooth curve.

*Corrector*: Newton on :math:`F(w) = 0,\ t_i\cdot(\hat w - \hat w_{pred}) = 0` (bordered
system): every correction is orthogonal to the tangent, so the corrector moves across the
curve, not along it, and works at folds where :math:`F_u` is singular. Converged when the
scaled correction is at most ``tol``, or from the second iteration on when the *next*
correction, estimated from quadratic convergence as :math:`|\Delta_k|^2/|\Delta_{k-1}|`, is
(the corrected iterate is then accepted without evaluating it); abandoned after
``max_newton`` iterations or when a correction does not at least halve.

*Step control*: a step whose corrector failed, or whose tangent turned by more than
``max_turn`` radians, is redone with half the step (a large turn means the predictor may have
jumped to a neighbouring part of the curve). After an accepted step the step grows by
``growth`` when the corrector needed at most two iterations, shrinks by 0.7 when it needed
more than three, and stays within ``[ds_min, ds_max]``.

*Folds*: the :math:`\lambda`-component of the tangent changes sign between consecutive
points. With ``refine_folds`` the fold is located by regula falsi (Illinois) on that
component as a function of the arclength from the point before it, each trial a full
correction, so the reported point lies on the curve and its :math:`\lambda` (stationary there)
is accurate to about the square of the arclength error.

*Branch points* (``detect_branch_points``): the determinant of the augmented Jacobian
:math:`\det\begin{pmatrix}F_u s_u & F_\lambda s_\lambda\\ t^T & 0\end{pmatrix}` is the test
function. It vanishes where the curve meets another one (the null space of :math:`[F_u \mid
F_\lambda]` becomes two-dimensional) and changes sign at a simple branch point, but not at a
fold, where :math:`\det F_u` changes sign while the augmented matrix stays regular (the
curve itself is regular there), so folds and branch points are told apart without looking
at :math:`d\lambda/ds`. Its sign does not depend on the (positive) scales, so it is compared
between consecutive points in whatever scaling is in force. A sign change is located by
regula falsi (bisection when it creeps) on the determinant along the arclength from the
point before it, each trial corrected onto the curve like a fold's; the second null vector
of :math:`[F_u s_u \mid F_\lambda s_\lambda]` there, orthogonal to the tangent (two smallest
right singular vectors), points off the traced curve (for a symmetry-breaking pitchfork:
along the other curve). :func:`branch_off` steps along it and
corrects onto the other curve. Cost: one LU (``slogdet``) of the augmented matrix per
accepted point, plus 10-40 corrections per branch point; off by default.

*Stopping*: at a window edge (the last point is placed exactly on the edge by Newton at fixed
:math:`\lambda`), on returning to the starting point (a closed curve), after ``max_points``
points, or when the step falls below ``ds_min``; :attr:`ContinuationCurve.stop_reason` says
which.

Layout
------
- :mod:`.curve`: the results (:class:`ContinuationCurve`, :class:`FoldPoint`,
  :class:`BranchPoint`) and argument checks;
- :mod:`.corrector`: the bordered Newton corrector :class:`Corrector` (evaluation,
  acceptance, step cap and Broyden column supplied by the caller; shared with the exact
  response) and the core's use of it in scaled coordinates (:class:`BorderedCorrector`),
  tangents (the SVD null vector :func:`null_tangent`, shared with the exact response),
  Newton at fixed parameter (:func:`newton_fixed`);
- :mod:`.predictors`: the cubic Hermite predictor (and a fold's Hermite estimate);
- :mod:`.steps`: :class:`StepControl` (the pace set by the corrector's iterations);
- :mod:`.events`: :class:`FoldTest` and :class:`BranchPointTest`, watched at every point,
  and :class:`FloquetCrossings` (stability changes of periodic orbits from multipliers);
- :mod:`.switching`: :func:`branch_off`;
- :mod:`.core`: the loop, :func:`continue_curve` and :class:`ContinuationOptions`.
"""

from perturb.numeric.continuation.core import ContinuationOptions, continue_curve
from perturb.numeric.continuation.corrector import (
    BorderedCorrector,
    Correction,
    Corrector,
    CountedProblem,
    Evaluation,
    newton_fixed,
    null_tangent,
)
from perturb.numeric.continuation.curve import (
    BranchPoint,
    ContinuationCurve,
    ContinuationError,
    FoldPoint,
)
from perturb.numeric.continuation.events import (
    BranchPointTest,
    FloquetCrossings,
    FoldTest,
    crossing_weight,
)
from perturb.numeric.continuation.predictors import hermite_direction, hermite_extrapolate
from perturb.numeric.continuation.steps import StepControl
from perturb.numeric.continuation.switching import branch_off

__all__ = [
    "ContinuationError",
    "FoldPoint",
    "BranchPoint",
    "ContinuationCurve",
    "ContinuationOptions",
    "continue_curve",
    "branch_off",
    "newton_fixed",
    "null_tangent",
    "StepControl",
    "FoldTest",
    "BranchPointTest",
    "FloquetCrossings",
    "crossing_weight",
    "BorderedCorrector",
    "Corrector",
    "Correction",
    "Evaluation",
    "CountedProblem",
    "hermite_extrapolate",
    "hermite_direction",
]
