"""Collection of branches: the public ``exact_branches`` (seeds from closed-form arcs,
caller's seeds and sweeps; polishing, joins, mirroring, branch switching), the note for
undamped systems and the virtual sweeps.

Part of :mod:`perturb.simulate.exact_response` (the method is described there).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from perturb import checks
from perturb.errors import ParameterError, PerturbError
from perturb.model.oscillator import Oscillator
from perturb.model.system import System
from perturb.progress import Progress
from perturb.simulate.exact_response.attractors import attractor_stage
from perturb.simulate.exact_response.march import Tracer
from perturb.simulate.exact_response.options import (
    ALL_FIELDS,
    ExactResponseOptions,
    exact_options,
    parameter_window,
    settings,
)
from perturb.simulate.exact_response.parallel import Job, Speculator, resolve_workers
from perturb.simulate.exact_response.problem import Pt
from perturb.simulate.exact_response.results import ContinuationBranch, ExactBranches
from perturb.simulate.exact_response.special_points import branch_off
from perturb.simulate.exact_response.steps import key_step
from perturb.simulate.exact_response.symmetry import (
    engine_is_odd_symmetric,
    mirror_branch,
    mirror_point,
    walk,
)
from perturb.simulate.flows.factory import FlowFamily
from perturb.simulate.orbits.shooting import (
    ShootingError,
)


# =============================================================================================
# public: every branch
# =============================================================================================
def exact_branches(
    oscillator: Oscillator | System,
    window: Sequence[float] = (0.2, 2.0),
    *,
    seeds: Sequence[tuple[float, ArrayLike]] = (),
    output: str | ArrayLike | None = None,
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

    A :class:`~perturb.model.system.System` of several coordinates (its forcing frequency the
    parameter ``Omega``) is traced the same way on its exact piecewise-affine flow
    (:class:`~perturb.simulate.flows.affine_exact.AffineExactFlow`; ``SystemODEFlow`` when not
    piecewise linear): the shooting problem has the system's ``n`` states per node, the
    closed-form arcs of single segments are replaced by seeds from the steady state of every
    linear region that stays inside its region (exact orbits, traced numerically), and every
    point also carries ``max |q_k|`` and the mean of every coordinate
    (:meth:`ExactBranches.columns`); ``amplitude`` measures ``output``.

    Parameters
    ----------
    oscillator
        Forced at one frequency parameter; all other parameters set. Or a System.
    window
        ``(low, high)`` forcing frequencies, ``low > 0``.
    seeds
        Pairs ``(Omega, (x0, v0))`` at ``t = 0`` (a system: ``(Omega, y0)`` with its ``n``
        states), each only a start of Newton on the exact flow (a seed that does not converge
        is counted in a note).
    output : str or array_like, optional
        Systems only: what ``amplitude``, ``first_harmonic_amplitude`` and ``mean`` measure: a
        coordinate name or a linear combination (``"x1 - x2"``, :meth:`System.output
        <perturb.model.system.System.output>`), or the combination vector; default the first
        coordinate.
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
    o = exact_options(options, knobs, ALL_FIELDS, "exact_branches")
    sweep_points, transient_periods, max_branches = (
        o.sweep_points,
        o.transient_periods,
        o.max_branches,
    )
    max_seconds = o.max_seconds
    max_periods = 2e5 if o.max_periods is None else o.max_periods
    is_system = isinstance(oscillator, System)
    if not isinstance(oscillator, Oscillator) and not is_system:
        raise ParameterError(f"oscillator = {oscillator!r}: expected an Oscillator or a System")
    if output is not None and not is_system:
        raise ParameterError(
            f"output = {output!r}: an oscillator's amplitude is max |x|; output is for systems"
        )
    lo, hi = parameter_window(window)
    if lo <= 0:
        raise ParameterError(f"window = {window!r}: forcing frequencies must be positive")
    for name, v in (
        ("sweep_points", sweep_points),
        ("transient_periods", transient_periods),
        ("max_branches", max_branches),
    ):
        if isinstance(v, bool) or not isinstance(v, int) or v < 0:
            raise ParameterError(f"{name} = {v!r}: expected a non-negative integer")
    checks.flag(o.attractors, "attractors")
    if max_seconds is not None and not (
        isinstance(max_seconds, int | float)
        and not isinstance(max_seconds, bool)
        and max_seconds > 0
        and not math.isnan(max_seconds)
    ):
        raise ParameterError(f"max_seconds = {max_seconds!r}: expected a positive number or None")
    n_workers = resolve_workers(o.workers)
    family = FlowFamily(oscillator)
    out_vec, out_label = output_of(oscillator, output) if is_system else (None, "")
    st = settings(o.ds_max, o.ds_min, o.tol, o.max_points, max_periods)
    if max_seconds is not None:
        st.deadline = time.monotonic() + float(max_seconds)
    undamped = undamped_note(family, (lo, hi))
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
            **_labels(oscillator, out_label),
        )
    tracer = Tracer(family, 1, 0.0, (lo, hi), st, closed_form=o.closed_form, output=out_vec)
    tracer.output_label = out_label
    spec = Speculator(tracer, n_workers)
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
            attractors=o.attractors,
            max_branches=max_branches,
            max_periods=max_periods,
            progress=o.progress,
        )
    finally:
        spec.close()


def _exact_branches(
    oscillator: Oscillator | System,
    tracer: Tracer,
    spec: Speculator,
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
    attractors: bool = True,
) -> ExactBranches:
    """The body of :func:`exact_branches` (arguments checked, tracer and pool set up)."""
    family, st = tracer.eng.family, tracer.st
    lo, hi = tracer.eng.lo, tracer.eng.hi
    eng, reg = tracer.eng, tracer.registry
    sym = bool(symmetry) and engine_is_odd_symmetric(eng)
    branches: list[ContinuationBranch] = []
    internals: list[list[Pt]] = []
    mirror_of: list[int | None] = []
    tracers: list[Tracer] = []
    notes: list[str] = []

    def budget_left() -> bool:
        return (
            eng.periods < max_periods
            and len(branches) < max_branches
            and time.monotonic() <= st.deadline
        )

    def register(br: ContinuationBranch, pts: list[Pt], mo: int | None, tr: Tracer) -> None:
        branches.append(br)
        internals.append(pts)
        mirror_of.append(mo)
        tracers.append(tr)
        reg.add(pts, br.m)

    def add(br: ContinuationBranch, pts: list[Pt], tr: Tracer) -> None:
        idx = len(branches)
        register(br, pts, None, tr)
        if not sym or len(pts) < 2:
            return
        # self-symmetric (every orbit symmetric, or the loop contains its image)?
        probe = [pts[len(pts) // 4], pts[len(pts) // 2], pts[(3 * len(pts)) // 4]]
        images = [mirror_point(tr, q) for q in probe]
        where = [reg.near(r, br.m) for r in images]
        if all(b >= 0 for b, _ in where):
            return
        mpts = mirror_branch(tr, pts)
        mbr = tr.freeze(
            mpts, br.closed, br.stop_reason, 0.5 * sum(q.mode != "closed" for q in pts), m=br.m
        )
        register(mbr, mpts, idx, tr)

    def try_seed(pt: Pt) -> bool:
        if not budget_left() or reg.near(pt, 1)[0] >= 0:
            return False
        start = tracer.start_point(pt.p, None, seed=pt)
        br, pts = spec.result(spec.submit(start))
        add(br, pts, tracer)
        return True

    raw: list[tuple[float, np.ndarray]] = [(float(p), np.asarray(y, float)) for p, y in seeds]
    n = eng.n
    for p, y in raw:
        if not lo <= p <= hi or y.shape != (n,) or not np.all(np.isfinite(y)):
            what = "(x0, v0)" if n == 2 and not eng.nd else f"y0 of {n} states"
            raise ParameterError(f"seed ({p}, {y.tolist()}): expected (Omega in window, {what})")
    closed_seeds = tracer.closed.seeds() if tracer.closed is not None else []
    if eng.nd:
        closed_seeds = region_seeds(tracer)
    total = len(closed_seeds) + len(raw) + 2 * sweep_points
    # seeds differ widely in cost (a seed on a known branch costs nothing): no estimate of
    # the time left, which jumped about (~205 s left, then ~91 s, done at 48 s)
    with Progress(total, "exact frequency response", enabled=progress, eta=False) as bar:
        # the closed-form seeds' branches all at once (speculative with a pool: a seed on an
        # earlier seed's branch is dropped when its turn comes, as the serial run skips it)
        jobs: list[tuple[Pt, Job | None]] = []
        images: list[Pt] = []
        for pt in closed_seeds:
            # not speculated: the mirror image of an earlier seed (odd systems), whose branch
            # is the earlier one's mirror, registered by the time this seed's turn comes
            twin = any(key_step(r, pt, eng.Sp) < 1e-9 for r in images)
            if sym:
                images.append(mirror_point(tracer, pt))
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
            child = Tracer(
                family, 2, 0.0, (lo, hi), st, closed_form=False, registry=reg, output=eng.output
            )
            child.output_label = tracer.output_label

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
        # the other branch at every branch point (pitchforks of odd systems); then, once, the
        # attractor stage (stable orbits no sweep settles on: isolas, stable stretches of
        # branches that fold back out of the window) and the branch points of its branches.
        # Last, so the branches of the stages before are traced as without it
        done: set[int] = set()
        scan_pending = attractors
        while budget_left():
            todo = [
                b
                for b in range(len(branches))
                if branch_points and b not in done and mirror_of[b] is None and branches[b].m == 1
            ]
            if not todo:
                if not scan_pending:
                    break
                scan_pending = False
                primary = [
                    b for b in range(len(branches)) if mirror_of[b] is None and branches[b].m == 1
                ]
                attractor_stage(tracer, internals, primary, try_seed, budget_left, symmetric=sym)
                continue
            for b in todo:
                done.add(b)
                for sp_ in branches[b].branch_points:
                    if not budget_left():
                        break
                    q = branch_off(tracer, internals[b], sp_, tracer)
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
                    q = branch_off(tracer, internals[b], sp_, child)
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
        **_labels(oscillator, tracer.output_label),
    )


def _labels(model: Oscillator | System, output: str) -> dict[str, Any]:
    """The coordinates and output label of an ExactBranches (systems only)."""
    if not isinstance(model, System):
        return {}
    return {"coordinates": (*model.coordinates, *model.first_order), "output": output}


def output_of(system: System, output: str | ArrayLike | None) -> tuple[np.ndarray, str]:
    """The output combination of a system and its label: a coordinate name or combination
    text (:meth:`System.output`), a vector over the states, or None (the first coordinate)."""
    names = system.state_names
    if output is None:
        output = (*system.coordinates, *system.first_order)[0]
    if isinstance(output, str):
        return system.output(output), output
    try:
        c = np.array(output, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        c = np.zeros(0)
    if c.size != len(names) or not np.all(np.isfinite(c)) or not np.any(c):
        raise ParameterError(
            f"output = {output!r}: expected a coordinate name, a combination such as "
            f"'x1 - x2', or {len(names)} numbers (not all zero) over {', '.join(names)}"
        )
    label = " + ".join(f"{v:g}*{nm}" for v, nm in zip(c, names, strict=True) if v != 0.0)
    return c, label.replace("+ -", "- ")


def region_seeds(tracer: Tracer, n_grid: int = 64) -> list[Pt]:
    r"""Seeds of a piecewise-affine system: at ``n_grid`` frequencies of the window, the steady
    state of every linear region, :math:`y(t) = -A^{-1}b + \operatorname{Re}\sum_k
    (i\omega_k I - A)^{-1}(u_k - i v_k) e^{i\omega_k t}`, where it stays inside its region over
    the whole period (every switching function keeps its sign at 256 samples): an exact
    orbit. One seed per run of such frequencies (its middle), polished by Newton; as the
    closed-form seeds of an oscillator (the saddle branch of the nsd device inside
    :math:`|x_1| < 1`, the orbits off resonance that touch no contact), they reach branches no
    sweep settles on. None for other flows."""
    eng = tracer.eng
    pas0 = eng.affine0
    if pas0 is None or not pas0.inputs:
        return []
    grid = np.linspace(eng.lo, eng.hi, n_grid)
    keys = sorted(pas0.regions)
    inside = {k: np.zeros(n_grid, dtype=bool) for k in keys}
    states: dict[tuple[tuple[int, ...], int], np.ndarray] = {}
    C = np.array([q.normal for q in pas0.surfaces]).reshape(-1, eng.n)
    d = np.array([q.offset for q in pas0.surfaces])
    for gi, p in enumerate(grid):
        try:
            pas = eng.flow(float(p)).affine_system
        except PerturbError:
            continue
        T = float(pas.period)
        ts = T * np.arange(256) / 256
        for k in keys:
            reg = pas.regions[k]
            I = np.eye(eng.n)
            try:
                y = np.tile(-np.linalg.solve(reg.A, reg.b)[:, None], (1, ts.size))
                for h in pas.inputs:
                    Zk = np.linalg.solve(1j * h.omega * I - reg.A, h.u - 1j * h.v)
                    y = y + (Zk[:, None] * np.exp(1j * h.omega * ts)[None, :]).real
            except np.linalg.LinAlgError:
                continue
            if not np.all(np.isfinite(y)):
                continue
            S = C @ y - d[:, None]
            want = np.array(k, dtype=float)[:, None]
            if S.size and not np.all(S * want > 0.0):
                continue
            inside[k][gi] = True
            states[(k, gi)] = y[:, 0].copy()
    out = []
    for k in keys:
        idx = np.flatnonzero(inside[k])
        if idx.size == 0:
            continue
        for run in np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1):
            gi = int(run[len(run) // 2])
            try:
                out.append(tracer.polish(float(grid[gi]), states[(k, gi)], max_iter=12))
            except (ShootingError, PerturbError):
                continue
    return out


def undamped_note(family: FlowFamily, window: tuple[float, float]) -> str | None:
    """A note when the oscillator dissipates no energy (no term depends on x'), else None.

    Forced orbits of such a system are at best neutrally stable (det M = 1: the Floquet
    multipliers lie on the unit circle or come in pairs mu, 1/mu), no transient decays, and
    the free oscillations form families of periodic orbits rather than isolated ones; the
    sweeps, seeds and stability tests of the exact continuation all assume damping."""
    osc = family.oscillator
    system = getattr(family, "system", None)
    if system is not None:
        # a system: undamped when the flow preserves volume in every region (tr A = 0:
        # det M = 1 on every orbit, Liouville)
        try:
            flow = family.at(0.5 * (window[0] + window[1]))
        except PerturbError:
            return None
        pas = getattr(flow, "affine_system", None)
        if pas is None:
            return None
        dissipative = any(float(np.trace(r.A)) != 0.0 for r in pas.regions.values())
    elif family.exact:
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
    tracer: Tracer,
    direction: int,
    n: int,
    transient: int,
    internals: list[list[Pt]],
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
    y = np.zeros(eng.n)
    fresh = True  # just left a branch (or at rest): the transient may be long
    for p in grid:
        bar.update()
        if not budget_left():
            return
        if state is not None:
            b, i = state
            ok, j, last = walk(internals[b], branches[b].closed, i, float(p))
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
                y = np.zeros(eng.n)
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
            d = [key_step(pts[j], found, eng.Sp) for j in (k, k2)]
            state = (b, k if d[0] <= d[1] else k2)
