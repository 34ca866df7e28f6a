"""The march of one branch (``Tracer``): predictor-corrector steps, node changes,
closed-form arcs, stop tests; detection of special points between consecutive points,
location of folds and refinement of crossings, and freezing of internal points into
``ContinuationPoint``.

Part of :mod:`perturb.simulate.exact_response` (the method is described there).
"""

from __future__ import annotations

import bisect
import math
import time
from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import brentq

from perturb.errors import PerturbError
from perturb.numeric.continuation import (
    FloquetCrossings,
    FoldTest,
    crossing_weight,
    hermite_direction,
    hermite_extrapolate,
)
from perturb.numeric.roots import RootResult, damped_newton, illinois, lu_or_lstsq
from perturb.simulate.exact_response.base import (
    JOIN_FRACTION,
    MAX_STEP_ATTEMPTS,
    STALL_DS,
    STALL_STEPS,
)
from perturb.simulate.exact_response.closed_form import Closed
from perturb.simulate.exact_response.options import Settings
from perturb.simulate.exact_response.problem import Engine, Eval, Pt, nodes_needed
from perturb.simulate.exact_response.results import (
    ContinuationBranch,
    ContinuationPoint,
    SpecialPoint,
)
from perturb.simulate.exact_response.steps import (
    Poly,
    Registry,
    ShootingStepControl,
    chord3,
    correct_point,
    key_step,
    orient,
    output_spacing,
    point_null_tangent,
    scaled_chord,
)
from perturb.simulate.flows.factory import FlowFamily
from perturb.simulate.orbits.shooting import (
    ShootingError,
)


class Tracer:
    """One continuation problem: engine, closed forms, registry and settings."""

    def __init__(
        self,
        family: FlowFamily,
        m: int,
        t0: float,
        window: tuple[float, float],
        st: Settings,
        *,
        closed_form: bool = True,
        registry: Registry | None = None,
        output: np.ndarray | None = None,
    ) -> None:
        self.eng = Engine(family, m, t0, window, st.tol, output=output)
        #: what the amplitude measures (systems; set by the caller, e.g. "x1 - x2")
        self.output_label = ""
        self.st = st
        self.closed = Closed(self.eng) if (closed_form and self.eng.closed_form) else None
        self.registry = registry if registry is not None else Registry(self.eng.Sp, st.ds_max)

    # -- points ---------------------------------------------------------------------------------
    def solve_fixed(self, p: float, Z: np.ndarray, max_iter: int = 40) -> Pt:
        """Damped Newton at fixed parameter (seeds, window ends); raises ShootingError.

        :func:`perturb.numeric.roots.damped_newton` on the shooting residual: converged when
        the correction is below ``max(tol, 1e-11)`` relative to ``max(1, |z|)`` (the
        corrected iterate is the point), a correction cut to 10 times that scale, halvings
        down to ``2**-9`` until the residual decreases (Armijo); the residual floor of a
        strongly unstable orbit (rounding times ``|M|``), where no step decreases it, is
        accepted when the Newton correction is below ``1e-9`` relative."""
        eng = self.eng
        Z = np.array(Z, dtype=float).reshape(-1, eng.n)
        N = Z.shape[0]

        def residual(z: np.ndarray) -> tuple[np.ndarray, np.ndarray, Eval]:
            ev = eng.evaluate(z.reshape(N, eng.n), p, gp=False)
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
        pt = Pt(p, res.z, eng.n)
        eng.finish(pt, res.data, res.z_evaluated.reshape(N, eng.n), p)
        return pt

    def polish(self, p: float, y: ArrayLike, max_iter: int = 40) -> Pt:
        """A seed ``(p, y)`` to a converged point (multiple shooting when strongly unstable)."""
        y = np.asarray(y, dtype=float).reshape(-1)
        Z = self.propagate_nodes(p, y, self.eng.m)
        pt = self.solve_fixed(p, Z, max_iter)
        need = nodes_needed(pt.max_mult, self.eng.m)
        if need > pt.N:
            pt = self.solve_fixed(p, self.propagate_nodes(p, pt.y0, need, old=pt), max_iter)
        return pt

    def propagate_nodes(self, p: float, y: np.ndarray, N: int, old: Pt | None = None) -> np.ndarray:
        """Nodes at ``t0 + iP/N`` from ``y`` (or from the nearest earlier node of ``old``, so a
        strongly unstable orbit is never propagated over a whole period)."""
        eng = self.eng
        flow = eng.flow(p)
        P = eng.m * float(flow.period)
        Z = np.empty((N, eng.n))
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

    def with_jacobian(self, pt: Pt) -> Pt:
        """Give a point the Jacobian [G_z | G_p] (one evaluation)."""
        eng = self.eng
        ev = eng.evaluate(pt.Z, pt.p)
        Gp = ev.Gp if ev.Gp is not None else eng.gp_fd(pt.Z, pt.p, ev.r)
        if pt.mode != "closed":
            eng.finish(pt, ev, pt.Z, pt.p)
        pt.blocks = ev.blocks
        pt.J = np.hstack([ev.Gz, Gp[:, None]])
        return pt

    def set_tangent(self, pt: Pt, prev: Pt | None, ref3: np.ndarray | None) -> None:
        t, sing = point_null_tangent(pt, self.eng.Sp)
        pt.tangent, pt.singular = orient(pt, t, prev, ref3, self.eng.Sp), sing

    def renode(self, pt: Pt) -> Pt:
        """Change the number of nodes when the growth per node left its range (with some
        hysteresis)."""
        need = nodes_needed(pt.max_mult, self.eng.m)
        if need > pt.N or need < pt.N - self.eng.m:
            Z = self.propagate_nodes(pt.p, pt.y0, need, old=pt if need > pt.N else None)
            new = Pt(pt.p, Z, self.eng.n)
            for a in ("mult", "stats", "sig", "switches", "mode", "seg", "grazing", "extra"):
                setattr(new, a, getattr(pt, a))
            ref = pt.tangent3()
            self.with_jacobian(new)
            self.set_tangent(new, None, ref)
            return new
        return pt

    def numeric_from_closed(self, pt: Pt, ref3: np.ndarray) -> Pt:
        """Nodes, Jacobian and tangent for continuing numerically from a closed-form point (the
        point keeps its exact data)."""
        assert self.closed is not None
        q = self.closed.point(pt.p, pt.seg, nodes_needed(pt.max_mult, 1))
        q.grazing = pt.grazing
        self.with_jacobian(q)
        self.set_tangent(q, None, ref3)
        return q

    def to_closed(self, pt: Pt, dirp: float) -> Pt:
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
        self, start: Pt, sign: float, other: list[Pt], parent_m: int | None
    ) -> tuple[list[Pt], str, bool]:
        """Continue from ``start`` along ``sign * tangent`` until a stop condition."""
        pts, reason, closed, _, _ = self.march_record(start, sign, other, parent_m)
        return pts, reason, closed

    def march_record(
        self, start: Pt, sign: float, other: list[Pt], parent_m: int | None
    ) -> tuple[list[Pt], str, bool, int, list[float]]:
        """:meth:`march`, and what a replay of its stop tests needs: the number of points
        (after ``start``) that went through :meth:`_joined` (a last point exactly on the
        window edge does not), and the propagated periods up to every point."""
        eng, st = self.eng, self.st
        pts = [start]
        work = [0.0]
        checked = 0
        own = Poly.of([start], eng.Sp, st.ds_max, eng.m)
        cum = [0.0]
        other_poly = Poly.of(other, eng.Sp, st.ds_max, eng.m)
        other_cum = np.cumsum(
            [0.0] + [key_step(a, b, eng.Sp) for a, b in zip(other[:-1], other[1:], strict=True)]
        )
        ctl = ShootingStepControl(st)
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
                dirp = 1.0 if dir3[-1] >= 0 else -1.0
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
                stalled = stalled + 1 if ctl.last_ok <= STALL_DS * st.ds_min else 0
                if stalled > STALL_STEPS:
                    reason = (
                        f"stalled at {eng.family.parameter} = {new.p:.8g} ({STALL_STEPS} "
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
                new = self.to_closed(new, 1.0 if new.tangent3()[-1] >= 0 else -1.0)
                if new.mode != "closed":
                    new = self.renode(new)
            h = key_step(cur, new, eng.Sp)
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
            c3 = chord3(cur, new, eng.Sp)
            if np.linalg.norm(c3) > 0:
                dir3 = c3 / np.linalg.norm(c3)
            cur, cur_t = new, new.tangent
        return pts, reason, closed, checked, work

    def _numeric_step(
        self,
        pts: list[Pt],
        cur: Pt,
        cur_t: np.ndarray | None,
        dir3: np.ndarray,
        ctl: ShootingStepControl,
    ) -> tuple[Pt | None, str]:
        """One predictor-corrector step from ``cur``: (new point or None, stop reason)."""
        eng, st = self.eng, self.st
        D = cur.D(eng.Sp)
        u0 = cur.u()
        d = cur_t
        if (cur.singular or d is None) and len(pts) >= 2:
            # rank-deficient Jacobian (branch point): the tangent is not unique, use the secant
            ch = scaled_chord(pts[-2], cur, eng.Sp)
            if ch is not None:
                d = ch
        if d is None or d.size != u0.size:
            return None, "no tangent"
        nd = float(np.linalg.norm(d))
        if nd == 0.0 or not np.isfinite(nd):
            return None, "no tangent"
        d = d / nd
        underflow = f"step size underflow at {eng.family.parameter} = {cur.p:.8g}"
        herm = self._graph_quintic(pts, cur, d, D) if eng.nd else None
        if herm is None:
            herm = self._hermite(pts, cur, d, D)
        jumped = False
        # the step shrinks geometrically on every redo and failure (to ds_min): the cap is
        # only reached when a NaN keeps it from shrinking
        for _attempt in range(MAX_STEP_ATTEMPTS):
            ds = ctl.step
            if not (math.isfinite(ds) and ds > 0.0):
                return None, f"non-finite step at {eng.family.parameter} = {cur.p:.8g}"
            if herm is not None:
                uh, dh = herm(ds)
                new, evals = correct_point(eng, uh * D, cur.N, D, dh, ds, st, ctl=ctl)
            else:
                new, evals = correct_point(eng, u0 + ds * d * D, cur.N, D, d, ds, st, ctl=ctl)
            if new is not None:
                if ctl.accept(ds, evals, output_spacing(cur, new, eng.Sp)):
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
                new, evals = correct_point(
                    eng, u0 + dj * d * D, cur.N, D, d, dj, st, max_iter=12, first_cap=2.0
                )
                if new is not None:
                    ctl.accept(dj, evals, output_spacing(cur, new, eng.Sp), force=True)
                    break
            if new is not None:
                break
            return None, underflow
        else:
            return None, f"step control did not settle at {eng.family.parameter} = {cur.p:.8g}"
        self.set_tangent(new, cur, dir3)
        return new, ""

    def _hermite(self, pts: list[Pt], cur: Pt, tb: np.ndarray, D: np.ndarray):
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

    def _graph_quintic(self, pts: list[Pt], cur: Pt, t: np.ndarray, D: np.ndarray):
        """Quintic Hermite extrapolation through the last three points and their tangents
        (systems), as a function ``ds -> (scaled predicted point, unit hyperplane normal)``, or
        None (then the cubic of :meth:`_hermite`).

        The branch is written as a graph over the current tangent line, ``u = u_c + sigma t +
        w(sigma)`` with ``w`` normal to ``t``: the abscissae ``sigma_k = t . (u_k - u_c)`` of
        the earlier points are exact, so the interpolant of ``w`` (values and slopes
        ``t_k / (t_k . t) - t`` at ``sigma_a < sigma_b < 0``, ``w(0) = w'(0) = 0``) is O(ds^6)
        accurate on a smooth arc.  The chord-length parameter of the cubic puts its nodes
        O(ds^3) off the arclength, which caps it at O(ds^4): at the default output spacing its
        first correction (~1e-9 .. 1e-7) is above the acceptance threshold of the statistics
        (1e-9) on most points, which then cost a second propagation."""
        if len(pts) < 3 or cur.singular or cur.mode == "closed":
            return None
        a, b = pts[-3], pts[-2]
        size = t.size
        for q in (a, b):
            if q.N != cur.N or q.tangent is None or q.singular or q.tangent.size != size:
                return None
            if q.mode == "closed":
                return None
        Sp = self.eng.Sp
        uc = cur.u() / D
        nodes = []
        for q, nxt in ((a, b), (b, cur)):
            uq = q.u() / D
            tq = q.tangent * q.D(Sp) / D
            nq = float(np.linalg.norm(tq))
            if not (math.isfinite(nq) and nq > 0.0):
                return None
            tq = tq / nq
            if float(tq @ (nxt.u() / D - uq)) < 0.0:
                tq = -tq
            c = float(tq @ t)
            if c < 0.5:
                return None  # a sharp turn: not a graph over the tangent line
            du = uq - uc
            sig = float(t @ du)
            nodes.append((sig, du - sig * t, tq / c - t))
        (sa, wa, da), (sb, wb, db) = nodes
        if not (sa < sb < 0.0) or sb - sa < 0.05 * -sb:
            return None
        # w(s) = s^2 (c0 + c1 s + c2 s^2 + c3 s^3) in s = sigma / |sigma_b| (w(0) = w'(0) = 0),
        # its values and slopes at s_a, s_b = -1: a 4 x 4 system for the four coefficients
        hb = -sb
        s_a = sa / hb
        M = np.array(
            [
                [s_a**2, s_a**3, s_a**4, s_a**5],
                [2 * s_a, 3 * s_a**2, 4 * s_a**3, 5 * s_a**4],
                [1.0, -1.0, 1.0, -1.0],
                [-2.0, 3.0, -4.0, 5.0],
            ]
        )
        try:
            coef = np.linalg.solve(M, np.array([wa, hb * da, wb, hb * db]))
        except np.linalg.LinAlgError:
            return None
        if not np.all(np.isfinite(coef)):
            return None

        def predict(ds: float) -> tuple[np.ndarray, np.ndarray]:
            x = ds / hb
            w = np.array([x * x, x**3, x**4, x**5]) @ coef
            dw = np.array([2 * x, 3 * x * x, 4 * x**3, 5 * x**4]) @ coef / hb
            d = t + dw
            return uc + ds * t + w, d / np.linalg.norm(d)

        return predict

    def _edge_point(self, cur: Pt, new: Pt) -> Pt | None:
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
            t3, n = new.tangent3(), eng.n
            q.tangent = np.r_[t3[:n], np.zeros(n * q.N - n), t3[n]]
        return self.to_closed(q, 1.0 if new.tangent3()[-1] >= 0 else -1.0)

    def _closed_step(self, cur: Pt, dirp: float) -> tuple[Pt, bool, bool]:
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
            spacing = output_spacing(cur, q, eng.Sp)
            if spacing > 1.2 * st.ds_max and abs(p1 - cur.p) > 1e-12 * eng.Sp:
                # the amplitude curves (a resonance peak): a shorter step, exact anyway
                dp = abs(p1 - cur.p) * 0.9 * st.ds_max / spacing
                continue
            break
        self.closed.set_tangent(q, dirp)
        return q, final, graze

    def _joined(
        self,
        pts: list[Pt],
        own: Poly,
        cum: list[float],
        new: Pt,
        h: float,
        other: Poly,
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

        def on(poly: Poly, start: int = 0, stop: int | None = None, kn=kn, kc=kc) -> bool:
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
        if cum[-1] == cum[-1]:
            # (cum is non-decreasing: bisect on the list, not a new array of the whole branch
            # at every step, which made this test quadratic in the branch length)
            n_far = bisect.bisect_right(cum, s_new - gap)
        else:
            n_far = int(np.searchsorted(np.asarray(cum), s_new - gap, side="right"))  # NaN
        n_far = min(n_far, len(pts) - 3)
        if own_loop and n_far >= 2 and on(own, 0, n_far - 1):
            # a loop closes where it began; a march that runs onto its own earlier part
            # farther along is not back at its start but past a sharp (grazing) fold whose two
            # sides lie within the join distance (impact_pair at Omega ~ 0.9698): the curve
            # beyond the start, in the other direction, is still to be traced
            k = own.near(kn, h, 0, n_far - 1)
            if k >= 0 and cum[k] > 2.0 * gap:
                return (
                    f"ran onto its own earlier part at {self.eng.family.parameter} = "
                    f"{new.p:.8g} (a sharp fold)",
                    False,
                )
            return "closed loop", True
        if len(other) >= 2:
            k0 = int(np.searchsorted(other_cum, gap - s_new, side="left"))
            if len(other) - k0 >= 2 and on(other, k0):
                return "closed loop", True
        return None

    # -- a whole branch -------------------------------------------------------------------------
    def start_point(self, p: float, y: ArrayLike | None, seed: Pt | None = None) -> Pt:
        """The first point with its tangent: closed form if possible, else polished."""
        pt = seed if seed is not None else self.polish(p, y)
        pt = self.to_closed(pt, 1.0)
        if pt.mode == "closed":
            assert self.closed is not None
            self.closed.set_tangent(pt, 1.0)
            return pt
        if pt.J is None:
            self.with_jacobian(pt)
        self.set_tangent(pt, None, np.r_[np.zeros(self.eng.n), 1.0])
        return pt

    def trace(
        self, start: Pt, directions: str = "both", parent_m: int | None = None
    ) -> tuple[ContinuationBranch, list[Pt]]:
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

    def _collapsed(self, q: Pt) -> bool:
        """A period-``m > 1`` orbit that is (nearly) its own shift by one forcing period: the
        turn of a period-``2m`` branch where it is born at a period doubling is that period
        doubling (a pitchfork of the doubled orbit), not a saddle-node."""
        m = self.eng.m
        if m == 1 or q.N % m:
            return False
        k = q.N // m
        return bool(np.max(np.abs(q.Z[k] - q.Z[0])) < 1e-3 * q.R)

    def refine_folds(self, pts: list[Pt]) -> list[Pt]:
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
        self, pts: list[Pt], closed: bool, reason: str, periods: float, m: int | None = None
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
            **(
                {
                    "coordinates": tuple(eng.coordinate_names),
                    "output": self.output_label,
                    "output_vector": eng.output,
                }
                if eng.nd
                else {}
            ),
        )


def _freeze_point(q: Pt) -> ContinuationPoint:
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
    extra: dict[str, np.ndarray] = {}
    if q.extra is not None:
        for name, arr in zip(("coordinate_amplitudes", "coordinate_means"), q.extra, strict=True):
            a = np.array(arr, dtype=float)
            a.setflags(write=False)
            extra[name] = a
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
        **extra,
    )


def _special_points(pts: list[Pt], points: Sequence[ContinuationPoint]) -> list[SpecialPoint]:
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
            tuple(float(v) for v in y),
        )

    tp = [q.tangent[-1] for q in points]
    fold_at = set()
    refined = {i for i, q in enumerate(pts) if q.fold}
    for i in sorted(refined):
        # a refined fold is a point of the branch: reported there, and the sign changes of
        # dp/ds and det(M - I) on either side of it belong to it
        fold_at.update((i - 1, i))
        q = points[i]
        out.append(
            SpecialPoint(
                "fold", i, float(q.parameter), float(q.amplitude), tuple(float(v) for v in q.y0)
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
# branch switching
# =============================================================================================
def refine(tracer: Tracer, a: Pt, b: Pt, target: float, steps: int = 8) -> Pt:
    r"""The point between ``a`` and ``b`` where :math:`\prod_i(\text{target} - \mu_i)` changes
    sign: regula falsi (Illinois) on the arclength of corrector steps from ``a``."""
    eng = tracer.eng

    def f(q: Pt) -> float:
        return float(np.prod(target - q.mult).real)

    if a.J is None or a.mode == "closed":
        a.mode = "shoot"
        tracer.with_jacobian(a)
    D = a.D(eng.Sp)
    ch = scaled_chord(a, b, eng.Sp)
    if ch is None:
        return a if abs(f(a)) < abs(f(b)) else b
    L = float(np.linalg.norm(ch))
    t, _ = point_null_tangent(a, eng.Sp)
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
    tracer: Tracer,
    a: Pt,
    t: np.ndarray,
    D: np.ndarray,
    L: float,
    f: Callable[[Pt], float],
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

    def trial(s: float) -> tuple[float, Pt] | None:
        q, _ = correct_point(
            eng, u0 + s * t * D, a.N, D, t, max(s, 1e-9), tracer.st, first_cap=10.0
        )
        if q is None or (need_jacobian and q.J is None):
            return None
        return f(q), q

    return illinois(trial, 0.0, L, fa, fb, xtol=s_tol * L, max_iter=steps, include_ends=ends)


def _fold_point(tracer: Tracer, a: Pt, b: Pt, steps: int = 12) -> Pt | None:
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

    def f(q: Pt) -> float:
        # the tangent's parameter component, oriented along the branch (the chord); below
        # 1e-12 it is the fold to rounding: stop there (as at an exact zero)
        v, _ = point_null_tangent(q, eng.Sp)
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
    v, sing = point_null_tangent(best, eng.Sp)
    best.tangent = -v if float(v @ ch) < 0 else v
    best.singular = sing
    best.fold = True
    return best
