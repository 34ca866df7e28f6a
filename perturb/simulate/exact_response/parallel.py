"""Parallel tracing: the forked marches (``_march_task`` on tracers registered in
``_FORKED`` before the fork), the replay of the stop tests a blind march missed, the
speculative pool (``Speculator``, ``Job``) whose workers die with their parent, and the
resolution of the worker count.

Part of :mod:`perturb.simulate.exact_response` (the method is described there).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from perturb.errors import ParameterError
from perturb.simulate.exact_response.march import Tracer
from perturb.simulate.exact_response.problem import Pt
from perturb.simulate.exact_response.results import ContinuationBranch
from perturb.simulate.exact_response.steps import Poly, Registry, key_step

# =============================================================================================
# parallel tracing: the two halves of every branch in worker processes
# =============================================================================================
#: Tracers of running :func:`exact_branches` calls, by key.  Forked workers inherit them
#: (a tracer holds compiled flows, which do not pickle), so a task sends only its start point,
#: direction and the registry of traced branches.
_FORKED: dict[int, Tracer] = {}


def _march_task(
    key: int, start: Pt, sign: float, registry: Registry, parent_m: int | None
) -> tuple[tuple[list[Pt], str, bool, int, list[float]], float]:
    """One half of a branch, in a worker: :meth:`Tracer.march_record` without the other
    half (its closed-loop test is replayed when the result is used), and the periods spent."""
    tracer = _FORKED[key]
    tracer.registry = registry
    p0 = tracer.eng.periods
    rec = tracer.march_record(start, sign, [], parent_m)
    return rec, tracer.eng.periods - p0


def _replay(
    tracer: Tracer,
    rec: tuple[list[Pt], str, bool, int, list[float]],
    other: list[Pt],
    first: int,
    parent_m: int | None,
) -> tuple[list[Pt], str, bool, int, list[float]]:
    """A speculative march cut where the serial march would have stopped.

    The march's steps do not depend on its stop tests, only its end does: it was made with
    the branches registered up to ``first`` and without ``other`` (the first half), so the
    stop tests against later branches and against ``other`` are replayed point by point; the
    last tested point gets every test, in the serial order (which also decides the reason)."""
    pts, reason, closed, checked, work = rec
    if first >= len(tracer.registry.items) and not other:
        return rec
    eng, st = tracer.eng, tracer.st
    own = Poly.of([pts[0]], eng.Sp, st.ds_max, eng.m)
    other_poly = Poly.of(other, eng.Sp, st.ds_max, eng.m)
    other_cum = np.cumsum(
        [0.0] + [key_step(a, b, eng.Sp) for a, b in zip(other[:-1], other[1:], strict=True)]
    )
    cum = [0.0]
    done = [pts[0]]
    for k in range(1, checked + 1):
        new = pts[k]
        h = key_step(done[-1], new, eng.Sp)
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


class Job:
    """A branch being traced from ``start``: both halves submitted, or (serial) nothing yet."""

    __slots__ = ("start", "parent_m", "first", "fwd", "bwd")

    def __init__(self, start: Pt, parent_m: int | None, first: int) -> None:
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


class Speculator:
    """Traces branches for :func:`exact_branches`, in worker processes when it may.

    A branch is two marches from its start point; with a pool they run at once, each in a
    worker, and a march is blind to branches registered after it was submitted and (the
    second half) to the first half.  :func:`_replay` cuts each where the serial march would
    have stopped, and the result is used in submission order, so the branches, their points
    and the decisions made from them (seeds skipped, the budget) are those of the serial run,
    whatever the timing.  Speculative work past such a cut, and on a branch that turns out to
    be traced already, is counted in ``wasted``.  ``workers == 1`` runs :meth:`Tracer.trace`
    when the result is asked for (nothing speculative)."""

    def __init__(self, tracer: Tracer, workers: int) -> None:
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

    def submit(self, start: Pt, parent_m: int | None = None) -> Job:
        job = Job(start, parent_m, len(self.tracer.registry.items))
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

    def discard(self, job: Job) -> None:
        """A job whose start turned out to lie on a traced branch (or a second half not
        needed): cancelled if it has not started, else left to finish (not waited for)."""
        for fut in (job.fwd, job.bwd):
            if fut is not None and not fut.cancel():
                fut.add_done_callback(self._count_waste)

    def _count_waste(self, fut: Any) -> None:
        if not fut.cancelled() and fut.exception() is None:
            self.wasted += fut.result()[1]

    def result(self, job: Job) -> tuple[ContinuationBranch, list[Pt]]:
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


def resolve_workers(workers: int | None) -> int:
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
