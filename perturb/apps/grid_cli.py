"""``perturb sweep``: a scene's question over a parameter grid, to netCDF/zarr and a heat map.

::

    perturb sweep SCENE.toml --param mu=0.02:0.4:40 --param k=-4:1:50 --out map.nc
                  [--param F=2] [--quantity peak_amplitude] [--solver approximation]
                  [--scheduler tcp://host:8786 | --workers N | --serial]
                  [--plot map.png | --no-plot] [--variable NAME] [--restart]

``--param NAME=START:STOP:COUNT`` (or ``NAME=V1,V2,...``) sweeps a parameter, replacing the
scene's ``[sweep] params`` entry of that name; ``--param NAME=VALUE`` fixes one.  Completed
cells are kept in ``OUT.partial/`` until the map is written, so an interrupted run continues
where it stopped when the same command is given again (``--restart`` discards them).

Registered in :mod:`perturb.apps.cli` by :func:`add_parser` (``perturb sweep``; this module
does not import the command, so the two form no import circle).
"""

from __future__ import annotations

import argparse
import shutil
import sys
from collections.abc import Sequence
from pathlib import Path

from perturb.errors import ParameterError, PerturbError

__all__ = ["add_parser", "cmd_sweep", "build_args"]


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``sweep`` subcommand to ``subparsers`` (from ``add_subparsers``)."""
    p = subparsers.add_parser(
        "sweep",
        help="a scene's peak amplitude, frequency response, ... over a parameter grid",
        description=(
            "Evaluate a scene over a parameter grid on local processes or a Dask cluster; "
            "write a netCDF (.nc) or zarr (.zarr) dataset and a heat-map PNG. Interrupted "
            "runs resume when the same command is given again."
        ),
    )
    p.add_argument("scene", help="scene TOML file (its [sweep] section sets the defaults)")
    p.add_argument(
        "--param",
        action="append",
        metavar="NAME=START:STOP:COUNT",
        help="swept parameter (also NAME=V1,V2,...); NAME=VALUE fixes a parameter",
    )
    p.add_argument("--out", default="sweep.nc", help="output .nc or .zarr (default sweep.nc)")
    p.add_argument("--quantity", help="peak_amplitude, peak_restoring_force, ... (default: scene)")
    p.add_argument("--solver", help="approximation or simulation (default: scene)")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--scheduler", metavar="ADDRESS", help="Dask scheduler, tcp://host:8786")
    where.add_argument("--workers", type=int, metavar="N", help="local processes (default: cores)")
    where.add_argument("--serial", action="store_true", help="run in this process")
    p.add_argument("--plot", help="heat-map PNG (default: OUT with suffix .png)")
    p.add_argument("--no-plot", action="store_true", help="do not draw the heat map")
    p.add_argument("--variable", help="variable of the heat map (default: the quantity)")
    p.add_argument("--restart", action="store_true", help="discard completed cells of OUT.partial")
    p.set_defaults(func=cmd_sweep)
    return p


def _grid_and_fixed(scene_grid, items: Sequence[str]):
    from perturb.apps.grid import parse_grid_item
    from perturb.checks import parse_number

    grid = dict(scene_grid)
    fixed: dict[str, float] = {}
    for text in items:
        name, values = parse_grid_item(text)
        value_text = text.partition("=")[2]
        for token in value_text.replace(":", ",").split(","):
            # a literal that underflows (1e-5000 -> 0) is refused, not swept as 0
            parse_number(token, f"--param {text!r}")
        if ":" not in value_text and "," not in value_text:
            fixed[name] = float(values[0])
            grid.pop(name, None)
        else:
            grid[name] = values
            fixed.pop(name, None)
    return grid, fixed


def cmd_sweep(args: argparse.Namespace) -> int:
    """Run ``perturb sweep`` for parsed ``args``; returns the exit status."""
    import dataclasses
    from types import MappingProxyType

    from perturb.apps.grid import load_sweep_scene, plot_map, save_dataset, sweep

    out = Path(args.out)
    if out.suffix not in (".nc", ".zarr"):
        raise ParameterError(f"--out {args.out!r}: expected a file name ending in .nc or .zarr")
    png_path = None if args.no_plot else (Path(args.plot) if args.plot else out.with_suffix(".png"))
    _check_outputs(args.out, png_path)
    if args.workers is not None and args.workers < 1:
        raise ParameterError(f"--workers {args.workers}: expected at least 1")
    ss = load_sweep_scene(args.scene)
    grid, fixed = _grid_and_fixed(ss.grid, args.param or ())
    if fixed:
        params = dict(ss.scene.params, **fixed)
        ss = dataclasses.replace(
            ss, scene=dataclasses.replace(ss.scene, params=MappingProxyType(params))
        )
    if not grid:
        raise ParameterError(
            "nothing to sweep: give --param NAME=START:STOP:COUNT or [sweep] params in the scene"
        )
    checkpoint = out.with_name(out.name + ".partial")
    if args.restart and checkpoint.exists():
        shutil.rmtree(checkpoint)

    client = None
    if args.scheduler:
        try:
            from distributed import Client
        except ImportError:
            raise PerturbError(
                "--scheduler needs Dask's distributed scheduler: pip install 'perturb[dask]'"
            ) from None
        try:
            client = Client(args.scheduler, timeout=30)
        except (OSError, TimeoutError) as exc:
            raise PerturbError(f"--scheduler {args.scheduler!r}: cannot connect ({exc})") from None
        executor = client
    elif args.serial:
        executor = "serial"
    else:
        executor = args.workers  # None: one process per core
    try:
        ds = sweep(
            ss,
            grid,
            executor,
            quantity=args.quantity,
            solver=args.solver,
            checkpoint=checkpoint,
        )
    except KeyboardInterrupt:
        print(
            f"perturb: interrupted; completed cells are kept in {checkpoint}: run the same "
            "command again to resume",
            file=sys.stderr,
        )
        return 130
    finally:
        if client is not None:
            client.close()
    if out.suffix == ".zarr":
        save_dataset(ds, out)  # a folder of chunks: not renamed into place
    else:
        from perturb.atomic import atomic_path

        with atomic_path(out) as tmp:  # complete or absent
            save_dataset(ds, tmp)
    shutil.rmtree(checkpoint, ignore_errors=True)
    shape = " x ".join(f"{n} {d}" for d, n in ((d, ds.sizes[d]) for d in ds.attrs["swept"].split()))
    print(
        f"[perturb] wrote {out} ({shape}; {ds.attrs.get('failed_cells', 0)} failed cells)",
        file=sys.stderr,
    )
    if png_path is not None:
        from perturb.atomic import atomic_path

        with atomic_path(png_path) as tmp:
            plot_map(ds, tmp, args.variable)
        print(f"[perturb] wrote {png_path}", file=sys.stderr)
    return 0


def _check_outputs(out: str, png: Path | None) -> None:
    """Refuse, before any work, a map and a picture with one path, or a missing or
    read-only output folder.

    Raises
    ------
    ParameterError
        Naming the path.
    """
    import os

    from perturb.atomic import check_distinct

    for flag, path in (("--out", Path(out)), ("--plot", png)):
        if path is None:
            continue
        folder = path.parent if str(path.parent) else Path(".")
        if not folder.is_dir():
            raise ParameterError(f"{flag} {str(path)!r}: the folder {str(folder)!r} does not exist")
        if not os.access(folder, os.W_OK | os.X_OK):
            raise ParameterError(
                f"{flag} {str(path)!r}: the folder {str(folder)!r} is not writable"
            )
    if png is not None:
        check_distinct([out, png])


def build_args(scene: str, out: str) -> argparse.Namespace:
    """The arguments of ``perturb sweep SCENE --out OUT`` with every default (for ``perturb
    run`` on a sweep scene)."""
    parser = argparse.ArgumentParser(prog="perturb")
    add_parser(parser.add_subparsers(dest="command"))
    return parser.parse_args(["sweep", scene, "--out", out])
