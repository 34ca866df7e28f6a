"""Benchmark: parameter sweeps serially, on a local process pool and on a Dask cluster.

1. Speed-up of the process pool: the peak-amplitude map of ``scenes/peak_map.toml`` (nsd,
   hb1, mu x k) computed serially and with ``executor=N`` (default: one process per core),
   each run paying for its own compiled kernel (the cache is emptied first).  Runs alternate
   and the fastest of ``--repeat`` is kept, since a shared machine's load varies.
2. Overhead per task on Dask: a ``LocalCluster`` on the loopback interface (``--workers``
   processes, one thread each) runs (a) tasks that do nothing, one cell each, and (b) the
   same map as above, cold (each worker builds its kernel) and warm (the workers kept it).
   (a) gives the round trip of a task as seen by the client; (b) the overhead in a real
   sweep, ``(t_dask - t_serial / workers) * workers / tasks``.  The workers' statistical
   profiler is switched off (``--dask-profile`` keeps it): sampling the stack of a
   pure-Python task every 10 ms made these cells ~1.6x slower on a loaded 2-core machine.

The results of every run are compared with the serial map: they must be bit-identical.

Run from the repository root::

    python benchmarks/bench_sweep.py                     # 20 x 25 cells
    python benchmarks/bench_sweep.py --mu 40 --k 50      # the scene's full 2000-cell map
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), os.pardir))
os.environ.setdefault("PERTURB_PROGRESS", "0")

import perturb.apps.grid as ps  # noqa: E402

SCENE = os.path.join(
    os.path.dirname(os.path.abspath(__file__)), os.pardir, "scenes", "peak_map.toml"
)


def nothing(a: float) -> float:
    return a


def timed(fn, *args, **kw):
    ps.clear_kernel_cache()  # every run builds its own kernel, as a fresh process would
    info: dict = {}
    t = time.perf_counter()
    ds = fn(*args, run_info=info, **kw)
    return time.perf_counter() - t, ds, info


def same(a, b) -> bool:
    return all(np.array_equal(a[v].values, b[v].values, equal_nan=True) for v in a.data_vars)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--mu", type=int, default=20, help="mu values (default 20)")
    ap.add_argument("--k", type=int, default=25, help="k values (default 25)")
    ap.add_argument("--workers", type=int, default=ps.machine_workers())
    ap.add_argument("--repeat", type=int, default=2, help="runs of each, fastest kept")
    ap.add_argument("--tiny", type=int, default=200, help="empty tasks for the Dask overhead")
    ap.add_argument("--no-dask", action="store_true")
    ap.add_argument(
        "--dask-profile", action="store_true", help="keep the Dask workers' profiler on"
    )
    args = ap.parse_args()

    spec = ps.load_sweep_scene(SCENE)
    grid = {"mu": f"0.02:0.4:{args.mu}", "k": f"-4:1:{args.k}"}
    n = args.mu * args.k
    print(f"load average before: {os.getloadavg()}, cores: {os.cpu_count()}")
    print(f"peak-amplitude map (nsd, hb1): {args.mu} mu x {args.k} k = {n} cells")

    best_serial, best_pool = float("inf"), float("inf")
    ref = pool_info = None
    for _ in range(args.repeat):
        t, ds, _ = timed(ps.sweep, spec, grid, "serial")
        best_serial = min(best_serial, t)
        ref = ds if ref is None else ref
        t, ds, info = timed(ps.sweep, spec, grid, args.workers)
        assert same(ref, ds), "the process pool changed the results"
        if t < best_pool:
            best_pool, pool_info = t, info
    assert pool_info is not None
    cells = pool_info["task_cells"]
    print(f"  serial:        {best_serial:7.2f} s  ({1e3 * best_serial / n:.1f} ms a cell)")
    print(
        f"  process pool:  {best_pool:7.2f} s  ({args.workers} workers, {pool_info['tasks']} "
        f"tasks, median {int(np.median(cells))} cells a task)"
    )
    print(f"  speed-up:      {best_serial / best_pool:7.2f}x  (identical results)")

    if not args.no_dask:
        try:
            from distributed import Client, LocalCluster
        except ImportError:
            print("dask.distributed is not installed: pip install 'perturb[dask]'")
            return
        import dask

        # the workers' statistical profiler samples the stacks of the running task every
        # 10 ms, which slows these pure-Python cells noticeably; it is on by default
        dask.config.set({"distributed.worker.profile.enabled": bool(args.dask_profile)})
        print(f"Dask worker profiler: {'on' if args.dask_profile else 'off'}")
        with (
            LocalCluster(
                n_workers=args.workers,
                threads_per_worker=1,
                processes=True,
                host="127.0.0.1",
                dashboard_address=None,
                silence_logs=50,
            ) as cluster,
            Client(cluster) as client,
        ):
            ps.sweep(nothing, {"a": [0.0, 1.0]}, client, chunk_size=1)  # warm up the workers
            tiny = {"a": np.arange(args.tiny, dtype=float)}
            t, _, info = timed(ps.sweep, nothing, tiny, client, chunk_size=1)
            print(
                f"Dask LocalCluster ({args.workers} workers): {info['tasks']} empty tasks in "
                f"{t:.2f} s = {1e3 * t / info['tasks']:.1f} ms a task (client round trip)"
            )
            t, _, info = timed(ps.sweep, nothing, tiny, args.workers, chunk_size=1)
            print(
                f"  (process pool, same tasks: {1e3 * t / info['tasks']:.1f} ms a task, "
                "pool start-up included)"
            )
            for run in ("cold", "warm"):
                # cold: each worker builds the kernel first; warm: the workers still have it
                t0 = time.perf_counter()
                info = {}
                ds = ps.sweep(spec, grid, client, run_info=info)
                t = time.perf_counter() - t0
                assert same(ref, ds), "Dask changed the results"
                over = (t - best_serial / args.workers) * args.workers / info["tasks"]
                print(
                    f"  map on Dask ({run}, {info['builds']} kernel builds): {t:.2f} s, "
                    f"{info['tasks']} tasks, speed-up {best_serial / t:.2f}x, overhead "
                    f"{1e3 * over:.0f} ms a task (identical results)"
                )
    print(f"load average after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
