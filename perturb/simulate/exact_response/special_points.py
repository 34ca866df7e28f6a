"""Branch switching at special points: the start of the other branch at a branch
point or of the period-doubled branch (``branch_off``, the public ``switch_branch``), and
the thawing of a stored point back into a march point.

Part of :mod:`perturb.simulate.exact_response` (the method is described there).
"""

from __future__ import annotations

import math

import numpy as np

from perturb.errors import ParameterError, PerturbError
from perturb.simulate.exact_response.base import JOIN_FRACTION
from perturb.simulate.exact_response.march import Tracer, refine
from perturb.simulate.exact_response.options import settings
from perturb.simulate.exact_response.problem import Pt
from perturb.simulate.exact_response.results import ContinuationBranch, SpecialPoint
from perturb.simulate.exact_response.steps import Poly, correct_point


def branch_off(parent: Tracer, pts: list[Pt], sp: SpecialPoint, child: Tracer) -> Pt | None:
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
        crit = refine(parent, a, b, target)
        if crit.blocks is None or crit.J is None:
            parent.with_jacobian(crit)
    except PerturbError:
        return None
    n = parent.eng.n
    M = np.eye(n)
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
    W = np.empty((Np * reps, n))
    wv = phi.copy()
    for j in range(Np * reps):
        W[j] = wv
        wv = crit.blocks[j % Np] @ wv
    Zc = np.tile(crit.Z, (reps, 1))
    st = child.st
    parent_poly = Poly.of(pts, child.eng.Sp, child.st.ds_max, pm)
    Dc = np.r_[np.full(n * Zc.shape[0], R * math.sqrt(Zc.shape[0])), child.eng.Sp]
    dvec = np.r_[phi, np.zeros(n * Zc.shape[0] - n), 0.0]
    for delta in (2.0, 6.0, 0.7):
        for sgn in (1.0, -1.0):
            dist = delta * st.ds_max
            Z = Zc + sgn * dist * R * W
            q, _ = correct_point(
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
            child.set_tangent(q, None, np.r_[np.zeros(child.eng.n), 1.0])
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
    st = settings(ds_max or branch.ds_max, 1e-7, tol, max_points, max_periods)
    parent = Tracer(
        branch.family,
        branch.m,
        branch.t0,
        branch.window,
        st,
        closed_form=False,
        output=branch.output_vector,
    )
    pts = [_thaw(branch, j) for j in range(len(branch.points))]
    for j in (sp.index, sp.index + 1):
        pts[j].mode = "shoot"
        parent.with_jacobian(pts[j])
    mc = branch.m * (2 if sp.kind == "period_doubling" else 1)
    child = Tracer(
        branch.family,
        mc,
        branch.t0,
        branch.window,
        st,
        closed_form=mc == 1,
        registry=parent.registry,
        output=branch.output_vector,
    )
    if mc == branch.m:
        parent.registry.add(pts, branch.m)
    q = branch_off(parent, pts, sp, child)
    if q is None:
        raise PerturbError(f"no new branch could be started at {sp!r}")
    return child.trace(q, "both", parent_m=branch.m if mc > branch.m else None)[0]


def _thaw(branch: ContinuationBranch, j: int) -> Pt:
    """An internal point from a frozen one (no Jacobian)."""
    q = branch.points[j]
    Z = q.nodes if q.nodes is not None else q.y0[None, :]
    n = q.y0.size
    pt = Pt(q.parameter, Z, n)
    pt.mult = np.array(q.multipliers)
    pt.stats = (q.amplitude, q.first_harmonic_amplitude, q.mean)
    pt.sig = np.array(q.signature)
    pt.switches = q.switches
    pt.source = q.source
    pt.mode = "closed" if q.source == "closed form" else "shoot"
    if q.coordinate_amplitudes is not None and q.coordinate_means is not None:
        pt.extra = (np.array(q.coordinate_amplitudes), np.array(q.coordinate_means))
    pt.tangent = np.r_[q.tangent[:n], np.zeros(n * pt.N - n), q.tangent[n]]
    return pt
