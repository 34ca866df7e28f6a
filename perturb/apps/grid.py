r"""Parameter sweeps at scale: one function, any executor, labelled and resumable results.

:func:`sweep` evaluates one question about a system — the frequency response, the peak
amplitude or peak restoring force of the resonance, a bifurcation-diagram column, or any user
function — at every point of a parameter grid, and returns an :class:`xarray.Dataset` whose
coordinates are the swept parameters and whose variables are the outputs::

    import perturb.apps.grid as ps

    spec = ps.load_sweep_scene("scenes/peak_map.toml")       # nsd, mu x k, peak amplitude
    ds = ps.sweep(spec, {"mu": "0.02:0.4:40", "k": "-4:1:50"}, checkpoint="map.partial")
    ps.save_dataset(ds, "map.nc")                            # or "map.zarr"

The top-level ``perturb.sweep(...)`` is :func:`sweep`.

Executors
---------
``executor=None`` uses a :class:`concurrent.futures.ProcessPoolExecutor` with one process per
core; an ``int`` sizes that pool; ``"serial"`` runs in this process; any
:class:`concurrent.futures.Executor` is used as given; a Dask ``distributed.Client``
(``pip install perturb[dask]``) runs the tasks on its cluster.  The result does not depend on
the executor: every cell is computed from its own parameter values alone.  Dask workers run a
statistical profiler by default, which slows these pure-Python cells (~1.6x measured); start
them with ``DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED=False`` for sweeps.

Work goes out in *chunks* of cells.  The first tasks hold one cell each; from their measured
cost the chunk size is set so that a task takes about ``chunk_seconds`` (0.25 s on processes,
1 s on Dask; at least 0.1 s, so scheduling costs stay small, unless the cells left are too
few to fill all workers).
The compiled solver of a scene (the derivation and its lambdified coefficient functions) is
built once per worker process and kept in a module-level cache keyed by the scene, so later
tasks only evaluate.

Resuming
--------
With ``checkpoint=DIR`` every finished chunk is written to ``DIR`` as a JSON file (atomically:
written aside, then renamed), next to ``sweep.json``, which identifies the sweep by a hash of
its scene, grid and perturb's version.  A sweep that was interrupted — even killed — is
resumed by running the same call again: cells found in ``DIR`` are not recomputed.  JSON keeps
every float exactly (``repr`` round-trips), so a resumed sweep gives bit-identical results.
Checkpoints are data only, never pickles: nothing in ``DIR`` is executed.  On resume every
part is validated (its cells within the grid and in no other part, one number — or NaN — of
the expected shape per cell and output) and, when the user has a cache key
(:mod:`perturb.io.cache`), authenticated by an HMAC, so an edited value is detected; a part that
fails is ignored with a :class:`CheckpointWarning` and its cells are computed again.  A
``sweep.json`` that does not describe the sweep is a clear error.  The outputs of
:func:`save_dataset` and :func:`plot_map` are written beside the destination and renamed when
complete.  The workers of a pool the sweep creates die with the process that owns it (on Linux
the kernel signals them; everywhere a watchdog thread polls the parent).

What a scene sweep computes per cell (``[sweep] quantity`` / ``solver``)
----------------------------------------------------------------------
``solver = "approximation"`` (default) uses the scene's ``[method]`` (``hb1`` by default),
derived once with the swept parameters left symbolic and compiled once by the amplitude
parametrisation of :mod:`perturb.numeric.amplitude` (``compile_response(..., parameters=...)``,
the swept parameters as arguments); its phase-eliminated amplitude equation
:math:`c_0(A) + c_1(A)W + c_2(A)W^2 = 0`, :math:`W = \Omega^2`, is scanned on 2000 amplitudes
:math:`10^{-8} \dots 10^8` per cell.

* ``peak_amplitude`` / ``peak_restoring_force``: the largest amplitude of the response in the
  scene's frequency window (the resonance peak: the fold of a hardening branch or the top of
  a detached loop), refined to rounding by nested grids; reported as ``peak_amplitude``
  (:math:`\max|x(t)|` of the waveform there), ``peak_omega`` and ``peak_restoring_force``
  (:math:`\max|f(x(t))|` over that orbit, with :math:`f` the restoring force: the largest
  :math:`|f|` on :math:`[\min x, \max x]`, exact at the breakpoints of a PWL force; the
  extremes of :math:`x` at the waveform's critical points).  About 6 ms of CPU per cell for
  ``hb1`` on ``nsd`` (a 2000-cell map in well under a minute on one core), mostly the fixed
  cost of the calls of the closed-form Fourier functions, of which a cell makes eight rounds;
  building the kernel takes 1–3 s once per worker.  The approximation's
  peak is checked against the simulated one in ``tests/test_sweep.py``; super- and
  subharmonic resonances, which a single-harmonic method does not see, are not included.
* ``frequency_response``: every solution at ``omega_points`` equally spaced frequencies of the
  window, amplitudes sorted in decreasing order and padded with NaN to ``max_solutions``
  (dimensions ``Omega``, ``solution``); no stability (use the simulation solver for what is
  reached in practice).  The roots are those of
  :meth:`~perturb.numeric.amplitude.FrequencyResponseSolver.roots_at` on the 2000-amplitude
  scan, without its search for root pairs closer than the scan's spacing (which would cost
  several times the rest of a cell).  About 20 ms of CPU per cell with 41 frequencies.

``solver = "simulation"`` integrates the equation of motion (the exact piecewise-linear flow
for PWL models, else DOP853) as a stepped-sine sweep over ``omega_points`` frequencies
(:func:`perturb.simulate.studies.frequency_sweep`, ``direction`` up, down or both): the peak
is the largest settled amplitude on that grid (so it lies below the true peak by the grid
spacing's share of the resonance), ``frequency_response`` the settled amplitude per
frequency and direction.  Seconds per cell for a lightly damped PWL oscillator (0.4 s at
``mu = 0.4``, ~10 s at ``mu = 0.02`` with 17 frequencies).

``quantity = "bifurcation"``: the stroboscopic points of the attractor reached from ``y0``
after ``transient_periods`` (:func:`perturb.simulate.studies.bifurcation_diagram` with one
value and no continuation from the neighbouring cell, which would make cells depend on each
other): variables ``x_section`` and ``v_section`` (dimension ``sample`` of
``record_periods``), ``period`` (0 = not periodic) and ``residual``.  ~0.1–1 s per cell.

A cell whose computation raises a :class:`~perturb.errors.PerturbError` (an unbounded
response, say) gets NaN and ``failed = 1``; a frequency window with no solution gives NaN with
``failed = 0``.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import hashlib
import hmac
import json
import math
import os
import re
import shutil
import signal
import sys
import threading
import time
import tomllib
import uuid
import warnings
from collections import deque
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from perturb.atomic import atomic_path, write_text
from perturb.checks import parse_number
from perturb.errors import ParameterError, PerturbError
from perturb.progress import Progress
from perturb.simulate.flows import scan_kernel

__all__ = [
    "QUANTITIES",
    "SOLVERS",
    "CheckpointWarning",
    "SweepScene",
    "sweep",
    "parse_range",
    "parse_grid_item",
    "parse_sweep_scene",
    "load_sweep_scene",
    "save_dataset",
    "load_dataset",
    "plot_map",
]

QUANTITIES = ("peak_amplitude", "peak_restoring_force", "frequency_response", "bifurcation")
SOLVERS = ("approximation", "simulation")
#: shortest task the chunking aims for; shorter ones spend a noticeable share on scheduling
MIN_TASK_SECONDS = 0.1
_MAX_CELLS = 10**7
_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]*")
_PEAK_VARS = ("peak_amplitude", "peak_omega", "peak_restoring_force")

# options of [sweep] besides quantity, solver and params; defaults in _check_options
_OPTION_KEYS = {
    "omega_points",
    "direction",
    "transient_periods",
    "record_periods",
    "y0",
    "tol",
    "max_solutions",
}


# --------------------------------------------------------------------------------------------
# grids
# --------------------------------------------------------------------------------------------


def parse_range(text: str, what: str | None = None) -> np.ndarray:
    """Values from ``"start:stop:count"`` (``count`` equally spaced values, both ends
    included), ``"v1,v2,..."`` or a single ``"value"``; nothing is evaluated.

    Raises
    ------
    ParameterError
        Naming the text, for anything else (a count below 1 or not whole, non-numbers).
    """
    what = what or f"range {text!r}"
    if not isinstance(text, str):
        raise ParameterError(f"{what}: expected text like 0.02:0.4:40, got {text!r}")
    body = text.strip()
    if ":" in body:
        parts = body.split(":")
        if len(parts) != 3:
            raise ParameterError(f"{what}: expected start:stop:count, e.g. 0.02:0.4:40")
        lo, hi = parse_number(parts[0], what), parse_number(parts[1], what)
        count = parse_number(parts[2], what)
        if count != int(count) or not 1 <= count <= _MAX_CELLS:
            raise ParameterError(f"{what}: count {parts[2].strip()!r} must be a whole number >= 1")
        if int(count) > 1 and lo == hi:
            raise ParameterError(f"{what}: start = stop with {int(count)} values")
        return np.linspace(lo, hi, int(count))
    items = [p for p in body.split(",")]
    if not body or any(not p.strip() for p in items):
        raise ParameterError(f"{what}: expected start:stop:count or v1,v2,... (got {text!r})")
    return np.array([parse_number(p, what) for p in items])


def parse_grid_item(text: str) -> tuple[str, np.ndarray]:
    """``"mu=0.02:0.4:40"`` -> ``("mu", 40 values)``; also ``NAME=v1,v2`` and ``NAME=value``.

    Raises
    ------
    ParameterError
        Naming the text.
    """
    name, sep, value = text.partition("=")
    name = name.strip()
    if not sep or not _NAME.fullmatch(name):
        raise ParameterError(
            f"--param {text!r}: expected NAME=START:STOP:COUNT, NAME=V1,V2,... or NAME=VALUE"
        )
    return name, parse_range(value, f"--param {text!r}")


def _grid(grid: Mapping[str, Any] | None) -> dict[str, np.ndarray]:
    if grid is None or not isinstance(grid, Mapping) or not grid:
        raise ParameterError(
            f"grid = {grid!r}: expected a mapping NAME -> values, e.g. "
            "{'mu': '0.02:0.4:40', 'k': [-4, -2, 0]}"
        )
    out: dict[str, np.ndarray] = {}
    for name, values in grid.items():
        if not isinstance(name, str) or not _NAME.fullmatch(name):
            raise ParameterError(f"grid name {name!r}: expected a parameter name such as mu")
        if isinstance(values, str):
            arr = parse_range(values, f"grid {name} = {values!r}")
        else:
            try:
                arr = np.array(values, dtype=float).reshape(-1)
            except (TypeError, ValueError):
                raise ParameterError(
                    f"grid {name} = {values!r}: expected numbers or 'start:stop:count'"
                ) from None
        if arr.size == 0 or not np.all(np.isfinite(arr)):
            raise ParameterError(
                f"grid {name} = {np.asarray(values).tolist()!r}: expected finite values"
            )
        if np.unique(arr).size != arr.size:
            raise ParameterError(f"grid {name} = {arr.tolist()!r}: values repeat")
        out[name] = arr
    n = math.prod(a.size for a in out.values())
    if n > _MAX_CELLS:
        raise ParameterError(f"the grid has {n} cells: at most {_MAX_CELLS} are allowed")
    return out


# --------------------------------------------------------------------------------------------
# scenes with a [sweep] section
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SweepScene:
    """A scene plus what to sweep: read from a TOML scene with a ``[sweep]`` section.

    ``[sweep]`` keys: ``quantity`` (one of :data:`QUANTITIES`), ``solver`` (one of
    :data:`SOLVERS`), ``params`` (table NAME = "start:stop:count" or a list of values),
    and the options ``omega_points``, ``direction``, ``transient_periods``,
    ``record_periods``, ``y0``, ``tol``, ``max_solutions`` (see the module docstring).
    """

    scene: Any  # perturb.apps.scene.Scene (imported lazily: scene imports the methods)
    quantity: str = "peak_amplitude"
    solver: str = "approximation"
    grid: Mapping[str, np.ndarray] = field(default_factory=lambda: MappingProxyType({}))
    options: Mapping[str, Any] = field(default_factory=lambda: MappingProxyType({}))


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return repr(value) if math.isfinite(value) else str(value)
    if isinstance(value, str):
        return json.dumps(value)  # a JSON string is a valid TOML basic string
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise ParameterError(f"cannot write {value!r} ({type(value).__name__}) to a scene")


def _dump_toml(data: Mapping[str, Mapping[str, Any]]) -> str:
    lines = []
    for section, body in data.items():
        lines.append(f"[{section}]")
        lines += [f"{k} = {_toml_value(v)}" for k, v in body.items()]
    return "\n".join(lines) + "\n"


def parse_sweep_scene(text: str, source: str = "<scene>") -> SweepScene:
    """Read a scene with an optional ``[sweep]`` section from TOML text (no code evaluated).

    The other sections are those of :func:`perturb.apps.scene.parse_scene`.

    Raises
    ------
    PerturbError
        Invalid TOML, unknown keys, bad values (the message names them).
    """
    from perturb.apps.scene import parse_scene

    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise PerturbError(f"scene {source}: invalid TOML: {exc}") from None
    body = data.pop("sweep", {})
    if not isinstance(body, dict):
        raise PerturbError(f"scene {source}: [sweep] must be a table")
    allowed = {"quantity", "solver", "params"} | _OPTION_KEYS
    for key in body:
        if key not in allowed:
            raise PerturbError(
                f"scene {source}: unknown key {key!r} in [sweep]: expected one of "
                + ", ".join(sorted(allowed))
            )
    # the rest is an ordinary scene: let perturb.apps.scene validate it
    scene = parse_scene(_dump_toml(data), source)
    quantity = body.get("quantity", "peak_amplitude")
    solver = body.get("solver", "approximation")
    grid_in = body.get("params", {})
    if not isinstance(grid_in, dict):
        raise PerturbError(f"scene {source}: [sweep] params must be a table NAME = range")
    grid = {}
    for name, value in grid_in.items():
        grid[name] = value
    try:
        grid_arr = _grid(grid) if grid else {}
        options = _check_options(quantity, solver, {k: body[k] for k in _OPTION_KEYS & set(body)})
    except ParameterError as exc:
        raise PerturbError(f"scene {source}: [sweep] {exc}") from None
    if scene.is_system and (solver != "simulation" or quantity == "bifurcation"):
        raise PerturbError(
            f"scene {source}: [sweep] a system of several coordinates is swept by stepped-sine "
            "simulation (solver = 'simulation', quantity 'peak_amplitude' or "
            f"'frequency_response'); got solver = {solver!r}, quantity = {quantity!r}"
        )
    if solver == "approximation":
        from perturb.methods.registry import spec as method_spec

        method = method_spec(scene.method)
        if method.kind != "symbolic":
            raise PerturbError(
                f"scene {source}: [sweep] solver = 'approximation' derives the scene's symbolic "
                f"[method] once for the whole grid; {scene.method!r} is {method.title}: give "
                "a symbolic method (hb1, shb, kb, ms, mlp) or solver = 'simulation'"
            )
    return SweepScene(
        scene=scene,
        quantity=quantity,
        solver=solver,
        grid=MappingProxyType(grid_arr),
        options=MappingProxyType(options),
    )


def load_sweep_scene(path: str | Path) -> SweepScene:
    """Read a scene file with an optional ``[sweep]`` section (see :class:`SweepScene`)."""
    p = Path(path)
    try:
        text = p.read_text()
    except OSError as exc:
        raise PerturbError(f"cannot read scene file {str(p)!r}: {exc.strerror}") from None
    return parse_sweep_scene(text, str(p))


def _check_options(quantity: Any, solver: Any, options: Mapping[str, Any]) -> dict[str, Any]:
    """Validated options with the defaults of ``quantity`` and ``solver`` filled in."""
    if quantity not in QUANTITIES:
        raise ParameterError(f"quantity = {quantity!r}: expected one of {', '.join(QUANTITIES)}")
    if solver not in SOLVERS:
        raise ParameterError(f"solver = {solver!r}: expected one of {', '.join(SOLVERS)}")
    unknown = sorted(set(options) - _OPTION_KEYS)
    if unknown:
        raise ParameterError(
            f"unknown option(s) {', '.join(unknown)}: expected " + ", ".join(sorted(_OPTION_KEYS))
        )

    def integer(name: str, default: int, lo: int, hi: int) -> int:
        v = options.get(name, default)
        if isinstance(v, bool) or not isinstance(v, int | np.integer) or not lo <= v <= hi:
            raise ParameterError(f"{name} = {v!r}: expected an integer from {lo} to {hi}")
        return int(v)

    out: dict[str, Any] = {}
    if quantity == "bifurcation":
        out["transient_periods"] = integer("transient_periods", 400, 0, 10**6)
        out["record_periods"] = integer("record_periods", 32, 1, 10**5)
    else:
        sim = solver == "simulation"
        if sim or quantity == "frequency_response":
            out["omega_points"] = integer("omega_points", 41 if sim else 101, 2, 10**5)
        if quantity == "frequency_response" and not sim:
            out["max_solutions"] = integer("max_solutions", 3, 1, 100)
        if sim:
            out["transient_periods"] = integer("transient_periods", 400, 0, 10**6)
            out["record_periods"] = integer("record_periods", 4, 1, 10**5)
            direction = options.get("direction", "up")
            if direction not in ("up", "down", "both"):
                raise ParameterError(f"direction = {direction!r}: expected up, down or both")
            out["direction"] = direction
    if quantity == "bifurcation" or solver == "simulation":
        y0 = options.get("y0", [0.0, 0.0])
        if (
            not isinstance(y0, list | tuple)
            or len(y0) != 2
            or not all(
                isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
                for v in y0
            )
        ):
            raise ParameterError(f"y0 = {y0!r}: expected two finite numbers [x, v]")
        out["y0"] = [float(v) for v in y0]
        tol = options.get("tol", 1e-8)
        if isinstance(tol, bool) or not isinstance(tol, int | float) or not 0 < tol < 1:
            raise ParameterError(f"tol = {tol!r}: expected a tolerance in (0, 1)")
        out["tol"] = float(tol)
    extra = sorted(set(options) - set(out))
    if extra:
        raise ParameterError(
            f"option(s) {', '.join(extra)} do not apply to quantity {quantity!r} with solver "
            f"{solver!r}"
        )
    return out


# --------------------------------------------------------------------------------------------
# compiled kernels: built once per process, cached by the task's specification
# --------------------------------------------------------------------------------------------
_KERNELS: dict[str, Any] = {}


def _scene_spec(ss: SweepScene, names: Sequence[str]) -> dict[str, Any]:
    """Everything a worker needs to rebuild the kernel, as plain JSON data."""
    sc = ss.scene
    return {
        "model": sc.model,
        "equation": sc.equation,
        "params": {k: float(v) for k, v in sorted(sc.params.items())},
        "omega": [float(sc.omega[0]), float(sc.omega[1])],
        "method": sc.method,
        "quantity": ss.quantity,
        "solver": ss.solver,
        "options": dict(sorted(ss.options.items())),
        "swept": list(names),
        # a system's scene only (an oscillator's spec, and so its sweep's hash, is unchanged)
        **(
            {
                "system": True,
                "equations": list(sc.equations) if sc.equations else None,
                "output": sc.output,
            }
            if sc.is_system
            else {}
        ),
    }


def _spec_oscillator(spec: Mapping[str, Any]):
    from perturb.model.builtins import builtin_model
    from perturb.model.oscillator import Oscillator

    if spec["equation"] is not None:
        return Oscillator.parse(spec["equation"], dict(spec["params"]), name=spec["model"])
    return builtin_model(spec["model"], **spec["params"])


def clear_kernel_cache() -> None:
    """Forget the compiled kernels of this process: the next sweep builds its own, as a fresh
    worker process would (for benchmarks)."""
    _KERNELS.clear()


def _kernel(spec_json: str) -> tuple[Any, bool]:
    kernel = _KERNELS.get(spec_json)
    if kernel is not None:
        return kernel, False
    spec = json.loads(spec_json)
    if spec.get("system"):
        kernel = _SystemSimulationKernel(spec)
    elif spec["quantity"] == "bifurcation":
        kernel = _BifurcationKernel(spec)
    elif spec["solver"] == "simulation":
        kernel = _SimulationKernel(spec)
    else:
        kernel = ApproximationKernel(spec)
    _KERNELS[spec_json] = kernel
    return kernel, True


def _check_swept(osc, names: Sequence[str], *, frequency_ok: bool) -> None:
    from perturb.simulate.flows.system import frequency_symbol

    for name in names:
        if name not in osc.params:
            known = ", ".join(osc.params) or "none"
            raise ParameterError(
                f"swept parameter {name!r} is not a parameter of model {osc.name!r}: expected "
                f"one of {known}"
            )
    w = frequency_symbol(osc)
    if not frequency_ok and w is not None and w.name in names:
        raise ParameterError(
            f"swept parameter {w.name!r} is the forcing frequency, which this quantity scans "
            "itself: sweep other parameters (or use quantity = 'bifurcation')"
        )


class _ForceRange:
    r"""``max |f(x)|`` over ``x`` in ``[lo, hi]`` for the restoring force ``f`` (compiled with
    the swept parameters as arguments); exact at the breakpoints of a PWL force."""

    def __init__(self, osc, names: Sequence[str]) -> None:
        import sympy as sp

        from perturb.errors import NonsmoothError
        from perturb.model.parsing import real_symbol
        from perturb.model.pwl import to_pwl
        from perturb.numeric.compile import lambdify

        syms = [real_symbol(n) for n in names]
        fixed = {s: v for s, v in osc.substitutions().items() if s.name not in names}
        f = osc.restoring_force.xreplace(fixed)
        free = sorted(s.name for s in f.free_symbols - {osc.x, *syms})
        if free:
            raise ParameterError(f"model {osc.name!r} needs values for {', '.join(free)}")
        mods = [{"Heaviside": lambda z, h0=0.5: np.heaviside(z, h0)}, "numpy"]
        self._f = sp.lambdify((osc.x, *syms), f, modules=mods)
        self._bps = None
        try:
            bps = list(to_pwl(f, osc.x).breakpoints)
        except (NonsmoothError, TypeError, ValueError):
            bps = []
        if bps:
            self._bps = lambdify(syms, bps) if syms else (lambda *a: [float(b) for b in bps])

    def __call__(self, lo: float, hi: float, values: Sequence[float]) -> float:
        xs = np.linspace(lo, hi, 1025)
        if self._bps is not None:
            b = np.array([float(v) for v in self._bps(*values)])
            xs = np.concatenate([xs, b[(b > lo) & (b < hi)]])
        with np.errstate(all="ignore"):
            fx = np.broadcast_to(np.asarray(self._f(xs, *values), dtype=float), xs.shape)
        return float(np.max(np.abs(fx)))


class ApproximationKernel:
    """Peaks and frequency responses of a scene's approximation over a parameter grid: one
    cell per call, ``kernel(values)`` with the values of the swept parameters.

    The method is derived once with the swept parameters left symbolic and compiled once by
    :func:`perturb.numeric.amplitude.compile_response` with them as free parameters; the
    amplitude parametrisation itself (amplitude equation, its roots in ``Omega**2``, roots at
    given frequencies, the orbit's extremes) is that solver's. What is specific to a sweep is
    here: the largest amplitude in the window (:meth:`peak`) and the fixed-size table of
    solutions per frequency (:meth:`frequency_response`).

    Parameters
    ----------
    spec : mapping
        The task specification of :func:`sweep` (model, parameter values, window, method,
        quantity, options and the names of the swept parameters).
    """

    #: the amplitude scan of a cell: logarithmic, 1e-8 to 1e8
    SCAN = np.geomspace(1e-8, 1e8, 2000)

    def __init__(self, spec: Mapping[str, Any]) -> None:
        from perturb.errors import NonsmoothError
        from perturb.methods.registry import spec as method_spec
        from perturb.model.parsing import real_symbol
        from perturb.simulate.flows.system import frequency_symbol

        self.spec = spec
        self.names = list(spec["swept"])
        osc = _spec_oscillator(spec)
        _check_swept(osc, self.names, frequency_ok=False)
        free = osc.with_params({n: None for n in self.names})
        self._free = free
        self._method = spec["method"]
        self._cells: dict[tuple[float, ...], Any] = {}
        try:
            approx = method_spec(self._method).resolve()(free)
        except NonsmoothError:
            # A swept breakpoint (a dead zone's d, a clearance): with the parameter left
            # symbolic the order of the breakpoints is undecidable, so the Fourier coefficients
            # cannot be written once for the whole grid. Each cell then derives and compiles
            # its own (slower, and still exact).
            sym = frequency_symbol(free)
            if sym is None:
                raise
            self.solver = None
            self.frequency_name = sym.name
        else:
            self.solver = self._compile(approx, [real_symbol(n) for n in self.names])
            self.frequency_name = approx.frequency.name
        self._force = _ForceRange(free, self.names)
        self.window = (float(spec["omega"][0]), float(spec["omega"][1]))
        self.quantity = spec["quantity"]
        self.options = spec["options"]
        if self.quantity == "frequency_response":
            self.omegas = np.linspace(*self.window, self.options["omega_points"])

    def _compile(self, approx: Any, syms: Sequence[Any]) -> Any:
        from perturb.numeric.amplitude import compile_response

        if (
            approx.frequency_polynomial is None
            or approx.amplitude is None
            or len(approx.unknowns) != 2
            or len(approx.frequency_polynomial) > 3
        ):
            raise PerturbError(
                f"method {self._method!r} gives no amplitude equation of degree <= 2 in "
                "Omega^2 with an amplitude and a phase: use hb1, shb, kb, ms or mlp, or "
                "solver = 'simulation'"
            )
        # no stability is computed: "slow_flow" only asks for a valid approximation
        return compile_response(approx, "slow_flow", parameters=list(syms))

    def _solver(self, p: Sequence[float]) -> tuple[Any, tuple[float, ...]]:
        """The compiled response for the swept values ``p`` and the arguments it takes."""
        if self.solver is not None:
            return self.solver, tuple(p)
        from perturb.methods.registry import spec as method_spec

        key = tuple(float(v) for v in p)
        solver = self._cells.get(key)
        if solver is None:
            cell = self._free.with_params(dict(zip(self.names, key, strict=True)))
            solver = self._compile(method_spec(self._method).resolve()(cell), [])
            if len(self._cells) >= 64:  # a worker sees one chunk of cells: keep a few
                self._cells.pop(next(iter(self._cells)))
            self._cells[key] = solver
        return solver, ()

    def schema(self) -> dict[str, tuple[tuple[str, ...], dict[str, np.ndarray]]]:
        """Per output: its dimensions beyond the grid's and their coordinates."""
        if self.quantity == "frequency_response":
            dims = (self.frequency_name, "solution")
            coords = {
                self.frequency_name: self.omegas,
                "solution": np.arange(self.options["max_solutions"]),
            }
            return {
                "amplitude": (dims, coords),
                "first_harmonic_amplitude": (dims, coords),
                "n_solutions": ((self.frequency_name,), {self.frequency_name: self.omegas}),
            }
        return {name: ((), {}) for name in _PEAK_VARS}

    def _in_window(self, a: np.ndarray, p: Sequence[float]) -> tuple[np.ndarray, ...]:
        solver, q = self._solver(p)
        wlo, whi, in_lo, in_hi = solver.window_roots(a, *self.window, *q)
        return in_lo, in_hi, wlo, whi

    def peak(self, p: Sequence[float]) -> dict[str, float]:
        """The resonance peak at the swept values ``p``: the largest amplitude with a solution
        in the window, its ``max |x|``, frequency and the largest restoring force over that
        orbit (NaN when the window has no solution).

        Raises
        ------
        PerturbError
            When the response grows past the scan (no damping).
        """
        nan = {k: math.nan for k in _PEAK_VARS}
        scan = self.SCAN
        in_lo, in_hi, _, _ = self._in_window(scan, p)
        hits = np.flatnonzero(in_lo | in_hi)
        if hits.size == 0:
            return nan  # no periodic solution in the window: not a failure
        i = int(hits[-1])
        if i == scan.size - 1:
            raise PerturbError(
                f"the response grows past amplitude {scan[-1]:.3g} in the window (no damping?)"
            )
        # nested grids: the largest amplitude with a solution in the window, to ~1e-14
        # relative (a call costs a fixed ~5 ms in the Fourier functions: few, wide rounds)
        a, b = scan[i], scan[i + 1]
        for _ in range(5):
            sub = np.linspace(a, b, 257)
            lo_ok, hi_ok, _, _ = self._in_window(sub, p)
            ok = np.flatnonzero(lo_ok | hi_ok)
            j = int(ok[-1]) if ok.size else 0
            a, b = sub[j], sub[min(j + 1, sub.size - 1)]
            if a == b:
                break
        arr = np.array([a])
        lo_ok, hi_ok, wlo, whi = self._in_window(arr, p)
        W = float(wlo[0] if lo_ok[0] else whi[0])
        w = math.sqrt(W)
        solver, q = self._solver(p)
        xmin, xmax = solver.extremes(arr, np.array([w]), *q)
        lo_x, hi_x = float(xmin[0]), float(xmax[0])
        return {
            "peak_amplitude": max(abs(lo_x), abs(hi_x)),
            "peak_omega": w,
            "peak_restoring_force": self._force(lo_x, hi_x, p),
        }

    def frequency_response(self, p: Sequence[float]) -> dict[str, np.ndarray]:
        """Every solution at the ``omega_points`` frequencies at the swept values ``p``: per
        frequency the ``max_solutions`` largest ``max |x|`` (NaN-padded), their first-harmonic
        amplitudes and the number of solutions."""
        nw, S = self.omegas.size, self.options["max_solutions"]
        # no search for root pairs between two scan points: it would cost several times the
        # rest of a cell
        solver, q = self._solver(p)
        iw, roots = solver.roots_at(self.omegas, *q, points=self.SCAN.size, pairs=False)
        amp = np.full((nw, S), np.nan)
        first = np.full((nw, S), np.nan)
        count = np.zeros(nw)
        if roots.size:
            xmin, xmax = solver.extremes(roots, self.omegas[iw], *q)
            size = np.maximum(np.abs(xmin), np.abs(xmax))
            for j in range(nw):
                sel = np.flatnonzero(iw == j)
                count[j] = sel.size
                order = sel[np.argsort(-size[sel], kind="stable")][:S]
                amp[j, : order.size] = size[order]
                first[j, : order.size] = roots[order]
        return {"amplitude": amp, "first_harmonic_amplitude": first, "n_solutions": count}

    def __call__(self, p: Sequence[float]) -> dict[str, Any]:
        if self.quantity == "frequency_response":
            return self.frequency_response(p)
        return self.peak(p)


class _SystemSimulationKernel:
    """Stepped-sine sweeps of a system of several coordinates
    (:func:`perturb.simulate.studies.system_frequency_sweep`): the scene's ``[model] output``
    is what ``amplitude`` measures; ``peak_restoring_force`` is NaN (a system has one force
    per element, not one restoring force)."""

    def __init__(self, spec: Mapping[str, Any]) -> None:
        from perturb.model.system import System
        from perturb.model.system_builtins import builtin_system

        self.spec = spec
        self.names = list(spec["swept"])
        params = dict(spec["params"])
        if spec.get("equations"):
            self.system = System.parse(list(spec["equations"]), params, name=spec["model"])
        else:
            self.system = builtin_system(spec["model"], **params)
        bad = [n for n in self.names if n not in self.system.params or n == "Omega"]
        if bad:
            raise PerturbError(
                f"swept parameter(s) {', '.join(bad)}: not parameters of system "
                f"{self.system.name!r} other than the forcing frequency Omega (its parameters: "
                f"{', '.join(k for k in self.system.params if k != 'Omega')})"
            )
        self.options = spec["options"]
        lo, hi = spec["omega"]
        self.omegas = np.linspace(lo, hi, self.options["omega_points"])
        self.directions = (
            ["up", "down"] if self.options["direction"] == "both" else [self.options["direction"]]
        )
        self.quantity = spec["quantity"]
        n = len(self.system.state_names)
        if any(self.options["y0"]) and len(self.options["y0"]) != n:
            raise PerturbError(
                f"[sweep] y0 = {self.options['y0']}: the system {self.system.name!r} has {n} "
                f"states ({', '.join(self.system.state_names)}); its sweeps start from rest"
            )

    def schema(self):
        if self.quantity == "frequency_response":
            dims = ("Omega", "direction")
            coords = {"Omega": self.omegas, "direction": np.array(self.directions)}
            return {"amplitude": (dims, coords), "first_harmonic_amplitude": (dims, coords)}
        return {name: ((), {}) for name in _PEAK_VARS}

    def __call__(self, p: Sequence[float]) -> dict[str, Any]:
        from perturb.simulate.studies import system_frequency_sweep

        o = self.options
        system = self.system.with_params(**dict(zip(self.names, map(float, p), strict=True)))
        y0 = o["y0"] if len(o["y0"]) == len(system.state_names) else None
        res = system_frequency_sweep(
            system,
            self.omegas,
            output=self.spec.get("output"),
            direction=o["direction"],
            y0=y0,
            transient_periods=o["transient_periods"],
            record_periods=o["record_periods"],
            tol=o["tol"],
        )
        if self.quantity == "frequency_response":
            amp = np.empty((self.omegas.size, len(self.directions)))
            first = np.empty_like(amp)
            for d, name in enumerate(self.directions):
                br = res.branch(name)
                order = np.argsort(br.omega)
                amp[:, d] = br.amplitude[order]
                first[:, d] = br.first_harmonic_amplitude[order]
            return {"amplitude": amp, "first_harmonic_amplitude": first}
        best = max(
            (s for b in res.branches for s in b.states), key=lambda s: (s.amplitude, -s.omega)
        )
        return {
            "peak_amplitude": best.amplitude,
            "peak_omega": best.omega,
            "peak_restoring_force": math.nan,
        }


class _SimulationKernel:
    """Stepped-sine sweeps of the equation of motion (exact PWL flow when it applies)."""

    def __init__(self, spec: Mapping[str, Any]) -> None:
        from perturb.simulate.flows.system import frequency_symbol

        self.spec = spec
        self.names = list(spec["swept"])
        self.osc = _spec_oscillator(spec)
        _check_swept(self.osc, self.names, frequency_ok=False)
        w = frequency_symbol(self.osc)
        if w is None:
            raise PerturbError(
                f"model {self.osc.name!r} has no forcing-frequency parameter to sweep"
            )
        self.frequency_name = w.name
        self.options = spec["options"]
        lo, hi = spec["omega"]
        self.omegas = np.linspace(lo, hi, self.options["omega_points"])
        self.directions = (
            ["up", "down"] if self.options["direction"] == "both" else [self.options["direction"]]
        )
        self.quantity = spec["quantity"]
        free = self.osc.with_params({n: None for n in self.names})
        self._force = _ForceRange(free, self.names)

    def schema(self):
        if self.quantity == "frequency_response":
            dims = (self.frequency_name, "direction")
            coords = {self.frequency_name: self.omegas, "direction": np.array(self.directions)}
            return {"amplitude": (dims, coords), "first_harmonic_amplitude": (dims, coords)}
        return {name: ((), {}) for name in _PEAK_VARS}

    def __call__(self, p: Sequence[float]) -> dict[str, Any]:
        from perturb.simulate.studies import frequency_sweep, make_flow

        o = self.options
        osc = self.osc.with_params(dict(zip(self.names, p, strict=True)))
        res = frequency_sweep(
            osc,
            self.omegas,
            direction=o["direction"],
            transient_periods=o["transient_periods"],
            record_periods=o["record_periods"],
            y0=o["y0"],
            tol=o["tol"],
            multipliers=False,
            progress=False,
        )
        if self.quantity == "frequency_response":
            amp = np.empty((self.omegas.size, len(self.directions)))
            first = np.empty_like(amp)
            for d, name in enumerate(self.directions):
                br = res.branch(name)
                order = np.argsort(br.omega)
                amp[:, d] = br.amplitude[order]
                first[:, d] = br.first_harmonic_amplitude[order]
            return {"amplitude": amp, "first_harmonic_amplitude": first}
        best = max(
            (s for b in res.branches for s in b.states), key=lambda s: (s.amplitude, -s.omega)
        )
        # the orbit at the peak again, sampled, for the range of x the force acts over
        flow = make_flow(osc, best.omega)
        T = 2 * math.pi / best.omega
        n = max(best.period, 1)
        t = np.linspace(0.0, n * T, 512 * n + 1)
        xs = flow(np.array(best.y_end), 0.0, n * T, t_eval=t).ys[:, 0]
        lo_x, hi_x = float(xs.min()), float(xs.max())
        # the sampled extremes are low by ~A (pi/512)^2/2; the sweep's amplitude is polished
        if abs(hi_x) >= abs(lo_x):
            hi_x = max(hi_x, best.amplitude)
        else:
            lo_x = min(lo_x, -best.amplitude)
        return {
            "peak_amplitude": best.amplitude,
            "peak_omega": best.omega,
            "peak_restoring_force": self._force(lo_x, hi_x, p),
        }


class _BifurcationKernel:
    """One bifurcation-diagram column per cell: the attractor reached from ``y0``."""

    def __init__(self, spec: Mapping[str, Any]) -> None:
        self.spec = spec
        self.names = list(spec["swept"])
        self.osc = _spec_oscillator(spec)
        _check_swept(self.osc, self.names, frequency_ok=True)
        self.options = spec["options"]

    def schema(self):
        R = self.options["record_periods"]
        coords = {"sample": np.arange(R)}
        return {
            "x_section": (("sample",), coords),
            "v_section": (("sample",), coords),
            "period": ((), {}),
            "residual": ((), {}),
        }

    def __call__(self, p: Sequence[float]) -> dict[str, Any]:
        from perturb.simulate.studies import bifurcation_diagram

        o = self.options
        osc = self.osc.with_params(dict(zip(self.names, p, strict=True)))
        d = bifurcation_diagram(
            osc,
            self.names[0],
            [p[0]],
            y0=o["y0"],
            transient_periods=o["transient_periods"],
            record_periods=o["record_periods"],
            tol=o["tol"],
            continuation=False,
            progress=False,
        )
        return {
            "x_section": d.x[0, 0],
            "v_section": d.v[0, 0],
            "period": float(d.period[0, 0]),
            "residual": float(d.residual[0, 0]),
        }


def _nan_like(schema) -> dict[str, Any]:
    out = {}
    for name, (dims, coords) in schema.items():
        out[name] = np.full(tuple(len(coords[d]) for d in dims), np.nan) if dims else math.nan
    return out


def _jsonable(value: Any) -> Any:
    arr = np.asarray(value, dtype=float)
    return arr.tolist() if arr.ndim else float(arr)


def _scene_chunk(spec_json: str, cells: Sequence[tuple[int, Sequence[float]]]) -> dict[str, Any]:
    """Worker task: evaluate a scene kernel at ``cells`` = [(flat index, values), ...]."""
    t0 = time.perf_counter()
    kernel, built = _kernel(spec_json)
    t1 = time.perf_counter()
    schema = kernel.schema()
    values: dict[str, list[Any]] = {name: [] for name in schema}
    failed, errors = [], []
    for _, p in cells:
        try:
            out = kernel(tuple(float(v) for v in p))
            failed.append(0)
        except PerturbError as exc:
            out = _nan_like(schema)
            failed.append(1)
            errors.append(f"at {dict(zip(kernel.names, p, strict=True))}: {exc}")
        for name in schema:
            values[name].append(_jsonable(out[name]))
    return {
        "cells": [int(i) for i, _ in cells],
        "values": values,
        "failed": failed,
        "errors": errors[:3],
        "seconds": time.perf_counter() - t1,
        "build_seconds": t1 - t0 if built else 0.0,
        "built": built,
        "pid": os.getpid(),
    }


def _function_chunk(
    fn: Callable[..., Any], names: Sequence[str], cells: Sequence[tuple[int, Sequence[float]]]
) -> dict[str, Any]:
    """Worker task: call a user function ``fn(**{name: value})`` at ``cells``."""
    t0 = time.perf_counter()
    values: dict[str, list[Any]] = {}
    for k, (_, p) in enumerate(cells):
        out = fn(**{n: float(v) for n, v in zip(names, p, strict=True)})
        if not isinstance(out, Mapping):
            out = {"value": out}
        if k == 0:
            values = {str(name): [] for name in out}
        if set(map(str, out)) != set(values):
            raise ParameterError(
                f"the function returned keys {sorted(map(str, out))} at "
                f"{dict(zip(names, p, strict=True))}, but {sorted(values)} before: every cell "
                "must return the same outputs"
            )
        for name, v in out.items():
            try:
                values[str(name)].append(_jsonable(v))
            except (TypeError, ValueError):
                raise ParameterError(
                    f"output {name!r} = {v!r} at {dict(zip(names, p, strict=True))}: expected a "
                    "number or an array of numbers"
                ) from None
    return {
        "cells": [int(i) for i, _ in cells],
        "values": values,
        "failed": None,
        "errors": [],
        "seconds": time.perf_counter() - t0,
        "build_seconds": 0.0,
        "built": False,
        "pid": os.getpid(),
    }


# --------------------------------------------------------------------------------------------
# executors
# --------------------------------------------------------------------------------------------
class _SerialExecutor(cf.Executor):
    """Runs each task when it is submitted, in this process (debugging, reference runs)."""

    def submit(self, fn, /, *args, **kwargs):  # type: ignore[override]
        fut: cf.Future = cf.Future()
        try:
            fut.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # delivered through the future, like a real executor
            if isinstance(exc, KeyboardInterrupt | SystemExit):
                raise
            fut.set_exception(exc)
        return fut


_PR_SET_PDEATHSIG = 1  # linux/prctl.h
_WATCH_SECONDS = 0.5


def _watch_parent(parent: int) -> None:
    """Exit this worker as soon as its parent is gone (reparented): the pool's own queues
    would keep an orphan waiting for ever. Ends with the process (capped at ~15 years)."""
    for _ in range(10**9):
        time.sleep(_WATCH_SECONDS)
        if os.getppid() != parent:
            os._exit(1)


def _worker_init(main_pid: int) -> None:
    """Initializer of the sweep's pool workers: they die with the process that owns the pool.

    On Linux the kernel sends SIGTERM when the parent dies (``prctl(PR_SET_PDEATHSIG)``); on
    every platform a daemon thread polls the parent's pid. SIGTERM gets its default action
    (an inherited handler must not keep an orphan alive).
    """
    with contextlib.suppress(ValueError, OSError):
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
    parent = os.getppid()
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
        except (OSError, AttributeError):
            pass  # the watchdog thread below still ends the worker
    # the owner may have died before prctl took effect
    try:
        os.kill(main_pid, 0)
    except ProcessLookupError:
        os._exit(1)
    except OSError:
        pass
    if parent == 1:
        os._exit(1)
    threading.Thread(
        target=_watch_parent, args=(parent,), daemon=True, name="perturb-watch-parent"
    ).start()


def _process_pool(n: int) -> cf.ProcessPoolExecutor:
    """A pool of ``n`` processes that die with this one (:func:`_worker_init`)."""
    return cf.ProcessPoolExecutor(n, initializer=_worker_init, initargs=(os.getpid(),))


def machine_workers() -> int:
    """The cores this process may run on (the default size of :func:`sweep`'s pool)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def _is_dask_client(obj: Any) -> bool:
    return type(obj).__module__.split(".")[0] == "distributed" and hasattr(obj, "get_executor")


def _open_executor(executor: Any) -> tuple[cf.Executor, int, bool, str]:
    """(executor, number of workers, whether we own it, description; "dask ..." for Dask)."""
    if executor is None:
        n = machine_workers()
        return _process_pool(n), n, True, f"process pool ({n} workers)"
    if isinstance(executor, str):
        if executor == "serial":
            return _SerialExecutor(), 1, True, "serial"
        raise ParameterError(
            f"executor = {executor!r}: expected None, 'serial', a number of processes, a "
            "concurrent.futures.Executor or a dask distributed.Client"
        )
    if isinstance(executor, int | np.integer) and not isinstance(executor, bool):
        if executor < 1:
            raise ParameterError(f"executor = {executor!r}: expected at least 1 process")
        n = int(executor)
        return _process_pool(n), n, True, f"process pool ({n} workers)"
    if _is_dask_client(executor):
        n = max(1, sum(executor.nthreads().values()))
        return executor.get_executor(pure=False), n, False, f"dask ({n} worker threads)"
    if isinstance(executor, cf.Executor):
        n = int(getattr(executor, "_max_workers", 0) or machine_workers())
        return executor, n, False, type(executor).__name__
    raise ParameterError(
        f"executor = {executor!r}: expected None, 'serial', a number of processes, a "
        "concurrent.futures.Executor or a dask distributed.Client"
    )


# --------------------------------------------------------------------------------------------
# checkpoints
# --------------------------------------------------------------------------------------------
class CheckpointWarning(UserWarning):
    """A checkpoint file was not trusted: its cells are computed again."""


class _BadPart(Exception):
    """A checkpoint part that is not used (the message says why)."""


def _json_number(name: str) -> float:
    # JSON's non-standard constants: NaN (a cell without a value) and the infinities of a user
    # function; their admissibility is checked per part
    return {"NaN": math.nan, "Infinity": math.inf, "-Infinity": -math.inf}[name]


class _Checkpoint:
    """Completed chunks as JSON files in a directory (see the module docstring).

    Every part is validated before its cells count as done: the sweep's fingerprint, cell
    indices within the grid and claimed by no other part, one value of the expected shape per
    cell and output (numbers; NaN; infinities only from a user function), ``failed`` flags,
    bounded texts — and, when this user has a cache key (:mod:`perturb.io.cache`), an HMAC over
    the part, so an edited number is detected. A part that fails is ignored with a
    :class:`CheckpointWarning` naming it, and its cells are computed again. Nothing in a
    checkpoint is executed (no pickle).
    """

    FORMAT = 2  # 2: parts carry an HMAC
    _KEYS = frozenset(
        {"fingerprint", "cells", "values", "failed", "errors", "seconds", "build_seconds"}
        | {"built", "pid"}
    )
    _MAX_BYTES = 1 << 30

    def __init__(
        self,
        path: str | Path,
        fingerprint: str,
        header: Mapping[str, Any],
        shapes: Mapping[str, tuple[int, ...]] | None = None,
    ) -> None:
        self.dir = Path(path)
        self.fingerprint = fingerprint
        self.n_cells = int(header["n_cells"])
        self.shapes = None if shapes is None else dict(shapes)  # None: a function sweep
        try:
            self.dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise PerturbError(
                f"checkpoint {str(self.dir)!r}: cannot create the directory ({exc.strerror})"
            ) from None
        head = self.dir / "sweep.json"
        expected = {"format": self.FORMAT, "fingerprint": fingerprint, **header}
        if head.exists():
            try:
                old = json.loads(head.read_text(), parse_constant=_json_number)
            except (OSError, ValueError):
                raise PerturbError(
                    f"checkpoint {str(head)!r} is unreadable: remove the directory to start over"
                ) from None
            if not isinstance(old, dict) or old.get("fingerprint") != fingerprint:
                raise PerturbError(
                    f"checkpoint {str(self.dir)!r} belongs to a different sweep (another scene, "
                    "grid or perturb version, or the compiled kernels switched on or off): "
                    "remove it or choose another directory"
                )
            same = {k: v for k, v in old.items() if k != "format"} == json.loads(
                json.dumps({k: v for k, v in expected.items() if k != "format"})
            )
            if old.get("format") not in (1, self.FORMAT) or not same:
                raise PerturbError(
                    f"checkpoint {str(head)!r} does not describe this sweep's grid (edited, or "
                    f"from another format than {self.FORMAT}): remove the directory to start over"
                )
        else:
            self._write(head, expected)

    @staticmethod
    def _write(path: Path, data: Any) -> None:
        # complete or absent: written aside, then renamed (a kill leaves a stray hidden file)
        write_text(path, json.dumps(data, allow_nan=True))

    @staticmethod
    def _canonical(data: Mapping[str, Any]) -> bytes:
        return json.dumps(data, sort_keys=True, allow_nan=True, separators=(",", ":")).encode()

    def _mac(self, data: Mapping[str, Any]) -> str | None:
        from perturb.io.cache import authenticate

        return authenticate(f"sweep-checkpoint/{self.fingerprint}", self._canonical(data))

    def _check(self, data: Any, shapes: dict[str, tuple[int, ...]], taken: set[int]) -> None:
        """Raise :class:`_BadPart` unless ``data`` is a valid part of this sweep."""
        if not isinstance(data, dict):
            raise _BadPart("not a JSON object")
        mac = data.pop("hmac", None)
        if set(data) != self._KEYS:
            raise _BadPart(f"unexpected fields {sorted(set(data) ^ self._KEYS)[:5]}")
        if data["fingerprint"] != self.fingerprint:
            raise _BadPart("it belongs to another sweep")
        want = self._mac(data)
        if want is not None and (type(mac) is not str or not hmac.compare_digest(mac, want)):
            raise _BadPart(
                "it failed authentication (edited, or written by another user or key)"
                if mac is not None
                else "it carries no authentication code"
            )
        cells = data["cells"]
        if (
            type(cells) is not list
            or not 0 < len(cells) <= self.n_cells
            or not all(type(i) is int and 0 <= i < self.n_cells for i in cells)
        ):
            raise _BadPart(f"cell indices outside the grid of {self.n_cells} cells")
        if len(set(cells)) != len(cells) or taken.intersection(cells):
            raise _BadPart("cells that another part already holds")
        n = len(cells)
        values = data["values"]
        if type(values) is not dict or not values:
            raise _BadPart("no values")
        if self.shapes is not None and set(values) != set(self.shapes):
            raise _BadPart(f"outputs {sorted(values)[:5]}, expected {sorted(self.shapes)}")
        for name, vals in values.items():
            if type(name) is not str or len(name) > 200 or type(vals) is not list:
                raise _BadPart(f"output {str(name)[:40]!r}")
            try:
                arr = np.asarray(vals, dtype=float)
            except (TypeError, ValueError):
                raise _BadPart(f"output {name!r} holds something other than numbers") from None
            if not all(_numbers(vals)):
                raise _BadPart(f"output {name!r} holds something other than numbers")
            if arr.ndim < 1 or arr.shape[0] != n:
                raise _BadPart(f"output {name!r} has {arr.shape[:1]} values for {n} cells")
            if name in shapes and arr.shape[1:] != shapes[name]:
                raise _BadPart(f"output {name!r} has shape {arr.shape[1:]}, not {shapes[name]}")
            if self.shapes is not None and np.isinf(arr).any():
                raise _BadPart(f"output {name!r} holds an infinite value")
        failed = data["failed"]
        if self.shapes is None:
            ok = failed is None
        else:
            ok = type(failed) is list and len(failed) == n and all(f in (0, 1) for f in failed)
            ok = ok and all(type(f) is int for f in failed)
        if not ok:
            raise _BadPart("invalid 'failed' flags")
        errors = data["errors"]
        if type(errors) is not list or len(errors) > 3:
            raise _BadPart("invalid error messages")
        if not all(type(e) is str and len(e) <= 10_000 for e in errors):
            raise _BadPart("invalid error messages")
        for key in ("seconds", "build_seconds"):
            v = data[key]
            if type(v) not in (int, float) or not (math.isfinite(v) and v >= 0):
                raise _BadPart(f"invalid {key}")
        if type(data["built"]) is not bool or type(data["pid"]) is not int:
            raise _BadPart("invalid 'built' or 'pid'")
        for name, vals in values.items():
            shapes.setdefault(name, np.asarray(vals, dtype=float).shape[1:])

    def load(self) -> list[dict[str, Any]]:
        """The valid parts (in file-name order); each invalid one is reported and skipped."""
        parts: list[dict[str, Any]] = []
        taken: set[int] = set()
        shapes: dict[str, tuple[int, ...]] = dict(self.shapes or {})
        for p in sorted(self.dir.glob("part-*.json")):
            try:
                try:
                    if p.stat().st_size > self._MAX_BYTES:
                        raise _BadPart(f"larger than {self._MAX_BYTES} bytes")
                    data = json.loads(p.read_text(), parse_constant=_json_number)
                except (OSError, ValueError, RecursionError) as exc:
                    raise _BadPart(f"unreadable ({type(exc).__name__})") from None
                self._check(data, shapes, taken)
            except _BadPart as exc:
                warnings.warn(
                    f"sweep checkpoint part {str(p)!r} ignored: {exc}; its cells are computed "
                    "again",
                    CheckpointWarning,
                    stacklevel=3,
                )
                continue
            taken.update(data["cells"])
            parts.append(data)
        return parts

    def save(self, result: Mapping[str, Any]) -> None:
        first = min(result["cells"])
        name = f"part-{first:09d}-{uuid.uuid4().hex[:8]}.json"
        data = {"fingerprint": self.fingerprint, **result}
        mac = self._mac(data)
        if mac is not None:
            data["hmac"] = mac
        self._write(self.dir / name, data)


def _numbers(values: list, depth: int = 0) -> Iterator[bool]:
    """Whether each leaf of nested lists is a number (``int`` or ``float``, not ``bool``)."""
    for v in values:
        if type(v) is list and depth < 32:
            yield from _numbers(v, depth + 1)
        else:
            yield type(v) in (int, float)


# --------------------------------------------------------------------------------------------
# the sweep
# --------------------------------------------------------------------------------------------
def _version() -> str:
    from perturb import __version__

    return __version__


def _function_id(fn: Callable[..., Any]) -> str:
    mod = getattr(fn, "__module__", None) or "?"
    name = getattr(fn, "__qualname__", None) or getattr(fn, "__name__", None) or repr(fn)
    return f"{mod}.{name}"


def _as_sweep_scene(obj: Any, quantity: str | None, solver: str | None) -> SweepScene:
    from perturb.apps.scene import Scene

    if isinstance(obj, str | Path):
        ss = load_sweep_scene(obj)
    elif isinstance(obj, SweepScene):
        ss = obj
    elif isinstance(obj, Scene):
        ss = SweepScene(scene=obj, quantity="frequency_response")
    else:
        raise ParameterError(
            f"scene_or_function = {obj!r}: expected a scene (file path, Scene or SweepScene) "
            "or a callable"
        )
    q = quantity or ss.quantity
    s = solver or ss.solver
    # options written for another quantity or solver would not apply: keep those that do
    opts = {
        k: v
        for k, v in ss.options.items()
        if (q, s) == (ss.quantity, ss.solver) or _applies(q, s, k)
    }
    return SweepScene(ss.scene, q, s, ss.grid, MappingProxyType(_check_options(q, s, opts)))


def _applies(quantity: str, solver: str, key: str) -> bool:
    return key in _check_options(quantity, solver, {})


def chunk_cells(per_cell: float | None, left: int, workers: int, target: float) -> int:
    """How many cells the next task of :func:`sweep` gets.

    Parameters
    ----------
    per_cell : float or None
        Measured seconds per cell so far; None before any task finished (then 1: probe
        tasks, whose timing sets the size of the rest).
    left : int
        Cells not yet submitted.
    workers : int
        Workers of the executor.
    target : float
        Seconds a task should take (``chunk_seconds``).

    Returns
    -------
    int
        ``target / per_cell`` cells, fewer when that leaves workers idle at the end (half a
        worker's share of the cells left), but never so few that a task lasts less than
        :data:`MIN_TASK_SECONDS` (unless a cell alone takes longer); between 1 and 100000.
    """
    if per_cell is None:
        return 1  # probe tasks: their timing sets the size of the rest
    per_cell = max(per_cell, 1e-6)
    n_target = math.ceil(target / per_cell)
    n_floor = math.ceil(MIN_TASK_SECONDS / per_cell)
    n_balance = math.ceil(left / (2 * workers))
    return max(1, min(n_target, max(n_floor, n_balance), 100_000))


def sweep(
    scene_or_function: Any,
    grid: Mapping[str, Any] | None = None,
    executor: Any = None,
    *,
    quantity: str | None = None,
    solver: str | None = None,
    checkpoint: str | Path | None = None,
    chunk_seconds: float | None = None,
    chunk_size: int | None = None,
    progress: bool | None = None,
    run_info: dict[str, Any] | None = None,
) -> Any:
    """Evaluate a scene's question or a function at every point of a parameter grid.

    Parameters
    ----------
    scene_or_function
        A scene: a TOML file path (read by :func:`load_sweep_scene`, its ``[sweep]`` section
        giving quantity, solver, grid and options), a :class:`SweepScene`, or a plain
        :class:`~perturb.apps.scene.Scene` (quantity ``frequency_response``).  Or a callable
        ``fn(**params)`` returning a number, an array, or a dict of them (it must be
        picklable — a module-level function — for process pools; Dask also takes lambdas).
    grid
        NAME -> values (a sequence, or text ``"start:stop:count"`` / ``"v1,v2"``), in the
        order of the dataset's dimensions.  For a scene it replaces the scene's grid
        entirely; default: the scene's ``[sweep] params``.
    executor
        ``None`` (a process pool with one process per core), ``"serial"``, a number of
        processes, a :class:`concurrent.futures.Executor`, or a Dask ``distributed.Client``.
    quantity, solver
        Override the scene's ``[sweep]`` quantity and solver (:data:`QUANTITIES`,
        :data:`SOLVERS`).
    checkpoint
        Directory for completed chunks; run the same sweep again to resume.
    chunk_seconds
        Target duration of a task (never below :data:`MIN_TASK_SECONDS` unless too few cells
        are left); default 0.25 s on processes, 1 s on Dask, whose scheduler adds tens of
        milliseconds a task.
    chunk_size
        Fixed number of cells per task instead of the timed choice.
    progress
        Progress line on stderr (default: on unless ``PERTURB_PROGRESS=0``).
    run_info
        A dict to fill with statistics of this run: ``tasks``, ``builds`` (kernels built by
        the workers), ``workers_seen``, ``task_cells`` (cells per task), ``computed_cells``,
        ``resumed_cells``, ``worker_seconds``.

    Returns
    -------
    xarray.Dataset
        Coordinates: the swept parameters (plus ``Omega``, ``solution``, ``sample`` ... for
        outputs with more dimensions); a variable per output, ``failed`` (int8) for scenes;
        attributes ``perturb_version``, ``scene`` (the scene as TOML) or ``function``,
        ``quantity``, ``solver``, ``method``, ``fingerprint``.  Save it with
        :func:`save_dataset`.

    Raises
    ------
    ParameterError
        Bad grid, executor, quantity or options (naming the value).
    PerturbError
        Bad scene, a checkpoint of another sweep.  An exception raised by a user function
        stops the sweep (completed chunks stay in the checkpoint).
    """
    import xarray as xr

    plan = _plan_sweep(scene_or_function, grid, quantity, solver)
    _check_chunking(chunk_seconds, chunk_size)
    ckpt, collected = _open_checkpoint(plan, checkpoint)
    done = set()
    for part in collected:
        done.update(part["cells"])
    pending = [i for i in range(plan.n_cells) if i not in done]
    stats = {"tasks": 0, "builds": 0, "pids": set(), "seconds": 0.0, "task_cells": []}
    if pending:
        _run_tasks(
            plan,
            pending,
            len(done),
            executor,
            chunk_seconds,
            chunk_size,
            progress,
            ckpt,
            collected,
            stats,
        )
    variables, coords = _assemble(plan, collected)
    ds = xr.Dataset(variables, coords=coords, attrs=plan.attrs)
    ds.attrs["swept"] = " ".join(plan.names)
    if run_info is not None:
        run_info.update(
            tasks=stats["tasks"],
            builds=stats["builds"],
            workers_seen=len(stats["pids"]),
            task_cells=list(stats["task_cells"]),
            computed_cells=len(pending),
            resumed_cells=len(done),
            worker_seconds=stats["seconds"],
        )
    return ds


@dataclass
class _SweepPlan:
    """What :func:`sweep` evaluates: the grid, the task run on chunks of cells, the output
    schema (None for a function: taken from its first results) and the dataset attributes."""

    grid: dict[str, np.ndarray]
    names: list[str]
    is_function: bool
    task: Callable[..., Any]
    task_args: tuple[Any, ...]
    schema: dict[str, Any] | None
    attrs: dict[str, Any]
    fingerprint: str

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(a.size for a in self.grid.values())

    @property
    def n_cells(self) -> int:
        return math.prod(self.shape)

    def cell(self, i: int) -> tuple[int, list[float]]:
        """Cell ``i`` (flat index) and its parameter values."""
        axes = list(self.grid.values())
        idx = np.unravel_index(i, self.shape)
        return i, [float(axes[d][k]) for d, k in enumerate(idx)]


def _plan_sweep(
    scene_or_function: Any,
    grid: Mapping[str, Any] | None,
    quantity: str | None,
    solver: str | None,
) -> _SweepPlan:
    """Step 1 of :func:`sweep`: check the grid and the scene or function, and fix what is
    run (task and its arguments), the output schema, the attributes and the fingerprint
    (the identity of the sweep, which a checkpoint must match)."""
    g = _grid(grid) if grid is not None else None
    is_function = callable(scene_or_function) and not isinstance(scene_or_function, str | Path)
    attrs: dict[str, Any] = {"perturb_version": _version(), "created_by": "perturb.sweep"}
    if is_function:
        if quantity is not None or solver is not None:
            raise ParameterError("quantity= and solver= apply to scenes, not to a function")
        if g is None:
            raise ParameterError("grid = None: a function sweep needs a grid")
        fn = scene_or_function
        names = list(g)
        task: Callable[..., Any] = _function_chunk
        task_args: tuple[Any, ...] = (fn, names)
        schema = None
        ident: dict[str, Any] = {"function": _function_id(fn)}
        attrs["function"] = ident["function"]
    else:
        ss = _as_sweep_scene(scene_or_function, quantity, solver)
        if g is None:
            g = dict(ss.grid)
        if not g:
            raise ParameterError(
                "grid: no parameters to sweep (give grid= or [sweep] params in the scene)"
            )
        names = list(g)
        spec = _scene_spec(ss, names)
        spec_json = json.dumps(spec, sort_keys=True)
        task, task_args = _scene_chunk, (spec_json,)
        # the kernel checks the scene here, where errors are easy to read, and gives the schema
        kernel, _ = _kernel(spec_json)
        schema = kernel.schema()
        ident = {"scene": spec}
        attrs.update(_scene_attrs(ss, spec, g))
    ident.update(
        grid={k: [float(v) for v in a] for k, a in g.items()},
        version=_version(),
    )
    if scan_kernel.wanted():
        # (results with the compiled kernels agree with numpy's to rounding, not bit for bit)
        ident["compiled"] = True
    fingerprint = hashlib.sha256(json.dumps(ident, sort_keys=True).encode()).hexdigest()
    attrs["fingerprint"] = fingerprint
    return _SweepPlan(g, names, is_function, task, task_args, schema, attrs, fingerprint)


def _scene_attrs(
    ss: SweepScene, spec: Mapping[str, Any], g: Mapping[str, np.ndarray]
) -> dict[str, Any]:
    """Step 1b of :func:`sweep`: the dataset attributes of a scene sweep, ``scene`` being a
    complete sweep scene (:func:`parse_sweep_scene` reads it back and reruns the map)."""
    scene_toml = _dump_toml(
        {
            "model": {"name": ss.scene.model}
            | ({"equation": ss.scene.equation} if ss.scene.equation else {}),
            "params": dict(spec["params"]),
            "ask": {"omega": spec["omega"]},
            "method": {"name": spec["method"]},
            "sweep": {"quantity": ss.quantity, "solver": ss.solver, **spec["options"]},
            "sweep.params": {k: [float(v) for v in a] for k, a in g.items()},
        }
    )
    return dict(
        scene=scene_toml,
        quantity=ss.quantity,
        solver=ss.solver,
        method=ss.scene.method if ss.solver == "approximation" else "simulation",
        model=ss.scene.model,
    )


def _check_chunking(chunk_seconds: Any, chunk_size: Any) -> None:
    """Step 2 of :func:`sweep`: ``chunk_seconds`` and ``chunk_size`` checked."""
    if chunk_seconds is not None and not (
        isinstance(chunk_seconds, int | float) and chunk_seconds > 0
    ):
        raise ParameterError(f"chunk_seconds = {chunk_seconds!r}: expected a positive number")
    if chunk_size is not None and (
        isinstance(chunk_size, bool) or not isinstance(chunk_size, int) or chunk_size < 1
    ):
        raise ParameterError(f"chunk_size = {chunk_size!r}: expected a positive integer")


def _open_checkpoint(
    plan: _SweepPlan, checkpoint: str | Path | None
) -> tuple[_Checkpoint | None, list[dict[str, Any]]]:
    """Step 3 of :func:`sweep`: the checkpoint (None without one) and the parts it holds
    already (a resumed sweep computes only the other cells)."""
    if checkpoint is None:
        return None, []
    schema = plan.schema
    shapes = (
        None
        if schema is None
        else {k: tuple(len(c[d]) for d in dims) for k, (dims, c) in schema.items()}
    )
    ckpt = _Checkpoint(
        checkpoint,
        plan.fingerprint,
        {"names": plan.names, "shape": list(plan.shape), "n_cells": plan.n_cells},
        shapes,
    )
    return ckpt, ckpt.load()


def _run_tasks(
    plan: _SweepPlan,
    pending: list[int],
    n_done: int,
    executor: Any,
    chunk_seconds: float | None,
    chunk_size: int | None,
    progress: bool | None,
    ckpt: _Checkpoint | None,
    collected: list[dict[str, Any]],
    stats: dict[str, Any],
) -> None:
    """Step 4 of :func:`sweep`: compute the ``pending`` cells on the executor in chunks
    (timed by :func:`chunk_cells` unless ``chunk_size``), appending each finished part to
    ``collected`` (and saving it in the checkpoint) and counting in ``stats``."""
    ex, workers, owned, how = _open_executor(executor)
    dask = how.startswith("dask")
    target = chunk_seconds or (1.0 if dask else 0.25)
    # Dask's round trip is long: queue more tasks so that no worker waits for the next
    max_inflight = (4 if dask else 2) * workers
    label = f"sweep {plan.n_cells} cells on {how}"
    if n_done:
        label += f" (resumed, {n_done} done)"
    queue = deque(pending)
    inflight: dict[cf.Future, list[int]] = {}
    per_cell: float | None = None
    t_sum, n_sum = 0.0, 0
    try:
        with Progress(plan.n_cells, label, enabled=progress) as bar:
            if n_done:
                bar.update(n_done)
            while queue or inflight:
                while queue and len(inflight) < max_inflight:
                    n = chunk_size or chunk_cells(per_cell, len(queue), workers, target)
                    chunk = [queue.popleft() for _ in range(min(n, len(queue)))]
                    fut = ex.submit(plan.task, *plan.task_args, [plan.cell(i) for i in chunk])
                    inflight[fut] = chunk
                finished, _ = cf.wait(list(inflight), return_when=cf.FIRST_COMPLETED)
                for fut in finished:
                    chunk = inflight.pop(fut)
                    res = fut.result()
                    if ckpt is not None:
                        ckpt.save(res)
                    collected.append(res)
                    t_sum += res["seconds"]
                    n_sum += len(chunk)
                    per_cell = t_sum / n_sum
                    stats["tasks"] += 1
                    stats["builds"] += int(res["built"])
                    stats["pids"].add(res["pid"])
                    stats["seconds"] += res["seconds"] + res["build_seconds"]
                    stats["task_cells"].append(len(chunk))
                    bar.update(len(chunk))
    except BaseException:
        for fut in inflight:
            fut.cancel()
        if owned:
            # an interrupt should not wait for running tasks: their cells are redone later
            ex.shutdown(wait=False, cancel_futures=True)
            owned = False
        raise
    finally:
        if owned:
            ex.shutdown(wait=True)


def _function_schema(collected: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Step 5a of :func:`sweep`: a function's output schema, from its first result (an
    output of ``ndim`` dimensions gets dimensions ``NAME_dim0`` ...)."""
    first = next((p for p in collected if p["cells"]), None)
    if first is None:
        raise ParameterError("the grid has no cells")
    schema = {}
    for name, vals in first["values"].items():
        arr = np.asarray(vals[0], dtype=float)
        dims = tuple(f"{name}_dim{k}" for k in range(arr.ndim))
        schema[name] = (dims, {d: np.arange(s) for d, s in zip(dims, arr.shape, strict=True)})
    return schema


def _assemble(
    plan: _SweepPlan, collected: Sequence[Mapping[str, Any]]
) -> tuple[dict[str, Any], dict[str, Any]]:
    """Step 5 of :func:`sweep`: the dataset's variables and coordinates from the collected
    parts (any order); adds ``failed_cells`` / ``first_error`` to ``plan.attrs`` for a
    scene."""
    schema = plan.schema if plan.schema is not None else _function_schema(collected)
    names, shape = plan.names, plan.shape
    clash = sorted((set(schema) | {d for dims, _ in schema.values() for d in dims}) & set(names))
    if clash:
        raise ParameterError(
            f"output or dimension name(s) {', '.join(clash)} are also swept parameters: rename "
            "the outputs"
        )
    data: dict[str, np.ndarray] = {}
    for name, (dims, coords) in schema.items():
        extra = tuple(len(coords[d]) for d in dims)
        data[name] = np.full(shape + extra, np.nan)
    failed = np.zeros(shape, np.int8)
    errors: list[str] = []
    for part in collected:
        if set(part["values"]) != set(schema):
            raise ParameterError(
                f"outputs {sorted(part['values'])} differ from {sorted(schema)} in part of the "
                "sweep: every cell must return the same outputs"
            )
        idx = np.unravel_index(np.asarray(part["cells"], dtype=np.int64), shape)
        for name, vals in part["values"].items():
            arr = np.asarray(vals, dtype=float)
            if arr.shape[1:] != data[name].shape[len(shape) :]:
                raise ParameterError(
                    f"output {name!r} has shape {arr.shape[1:]} in some cells and "
                    f"{data[name].shape[len(shape) :]} in others"
                )
            data[name][idx] = arr
        if part.get("failed") is not None:
            failed[idx] = np.asarray(part["failed"], dtype=np.int8)
            errors += part.get("errors", [])
    coords: dict[str, Any] = {k: (k, a) for k, a in plan.grid.items()}
    variables = {}
    for name, (dims, extra_coords) in schema.items():
        for d, c in extra_coords.items():
            coords.setdefault(d, (d, np.asarray(c)))
        variables[name] = (tuple(names) + tuple(dims), data[name])
    if not plan.is_function:
        variables["failed"] = (tuple(names), failed)
        plan.attrs["failed_cells"] = int(failed.sum())
        if errors:
            plan.attrs["first_error"] = errors[0]
    return variables, coords


# --------------------------------------------------------------------------------------------
# files and figures
# --------------------------------------------------------------------------------------------
def save_dataset(ds: Any, path: str | Path) -> Path:
    """Write ``ds`` to netCDF (``.nc``; the netCDF4 format when ``h5netcdf`` or ``netCDF4``
    is installed, else netCDF3 through scipy) or zarr (``.zarr``, needs the ``zarr``
    package); returns the path."""
    p = Path(path)
    ds = ds.copy()
    ds.encoding = {}
    if p.suffix == ".zarr":
        _save_zarr(ds, p)
        return p
    if p.suffix not in (".nc", ".nc4", ".netcdf"):
        raise ParameterError(f"output {str(p)!r}: expected a .nc or .zarr file name")
    # complete or absent: written beside the destination, renamed when complete
    with atomic_path(p) as tmp:
        ds.to_netcdf(tmp)
    return p


def _save_zarr(ds: Any, p: Path) -> None:
    """A zarr store (a folder) written beside ``p`` and swapped in when complete: ``p`` holds
    the old store or the new one, never a half-written one (between the two renames, for a
    moment, neither)."""
    folder = p.parent if str(p.parent) else Path(".")
    if not folder.is_dir():
        raise ParameterError(f"output {str(p)!r}: the folder {str(folder)!r} does not exist")
    if p.exists() and not p.is_dir():
        raise ParameterError(f"output {str(p)!r} exists and is not a zarr folder")
    tag = uuid.uuid4().hex[:8]
    tmp, old = folder / f".{p.name}.{tag}.tmp", folder / f".{p.name}.{tag}.old"
    try:
        ds.to_zarr(tmp, mode="w", consolidated=False)
    except ImportError as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        raise PerturbError(f"cannot write {str(p)!r}: {exc} (pip install zarr)") from None
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if p.exists():
        os.replace(p, old)
    os.replace(tmp, p)
    shutil.rmtree(old, ignore_errors=True)


def load_dataset(path: str | Path) -> Any:
    """Read a sweep written by :func:`save_dataset` (fully into memory, file closed)."""
    import xarray as xr

    p = Path(path)
    if not p.exists():
        raise PerturbError(f"no such sweep file: {str(p)!r}")
    if p.suffix == ".zarr":
        with xr.open_zarr(p, consolidated=False) as ds:
            out = ds.load()
    else:
        with xr.open_dataset(p) as ds:
            out = ds.load()
    return out


def plot_map(ds: Any, path: str | Path, variable: str | None = None) -> Path:
    """A heat map of ``variable`` over the first two swept parameters (a line for one).

    Further swept parameters are held at their first value; the output's own dimensions
    (``Omega``, ``solution`` ...) are reduced by their maximum (so a frequency-response
    sweep shows its peak).  Default variable: the one named by the ``quantity`` attribute,
    else the first.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = ds.attrs.get("swept", "").split() or list(ds.dims)[:2]
    if variable is None:
        q = ds.attrs.get("quantity")
        if q in ds.data_vars:
            variable = q
        elif q == "frequency_response":
            variable = "amplitude"
        elif q == "bifurcation":
            variable = "period"
        else:
            variable = next(v for v in ds.data_vars if v != "failed")
    if variable not in ds.data_vars:
        raise ParameterError(
            f"variable {variable!r}: expected one of {', '.join(map(str, ds.data_vars))}"
        )
    da = ds[variable]
    extra = [d for d in da.dims if d not in names]
    if extra:
        da = da.max(dim=extra, skipna=True)
    held = names[2:]
    if held:
        da = da.isel({d: 0 for d in held})
    fig, ax = plt.subplots(figsize=(6.4, 4.8))
    if len(names) == 1:
        ax.plot(da[names[0]].values, da.values, "-o", ms=3)
        ax.set_xlabel(names[0])
        ax.set_ylabel(variable)
    else:
        x, y = names[0], names[1]
        z = da.transpose(x, y).values
        finite = z[np.isfinite(z)]
        norm = None
        if finite.size and finite.min() > 0 and finite.max() > 10 * finite.min():
            from matplotlib.colors import LogNorm

            # resonance peaks span decades as the damping goes to zero
            norm = LogNorm(finite.min(), finite.max())
        mesh = ax.pcolormesh(da[y].values, da[x].values, z, shading="nearest", norm=norm)
        ax.set_xlabel(y)
        ax.set_ylabel(x)
        fig.colorbar(mesh, ax=ax, label=variable)
    title = f"{ds.attrs.get('model', '')} {variable}".strip()
    if held:
        title += " (" + ", ".join(f"{d}={float(ds[d][0]):g}" for d in held) + ")"
    ax.set_title(title)
    fig.tight_layout()
    p = Path(path)
    try:
        with atomic_path(p) as tmp:  # keeps the suffix: savefig picks the format by it
            fig.savefig(tmp, dpi=120)
    finally:
        plt.close(fig)
    return p
