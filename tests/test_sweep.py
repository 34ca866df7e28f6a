"""Parameter sweeps: grids, scenes, executors (serial, processes, Dask), files, resuming."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

xr = pytest.importorskip("xarray")

import perturb  # noqa: E402
import perturb.apps.grid as ps  # noqa: E402
from perturb.apps.scene import parse_scene  # noqa: E402
from perturb.errors import ParameterError, PerturbError  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
NSD = '[model]\nname = "nsd"\n[params]\nF = 2.0\nk = -2.0\nmu = 0.05\n[ask]\nomega = [0.2, 2.0]\n'


def _peak_scene(**options) -> ps.SweepScene:
    return ps.SweepScene(parse_scene(NSD), "peak_amplitude", "approximation", options=options)


SMALL_GRID = {"mu": [0.05, 0.2, 0.4], "k": [-3.0, -1.0, 1.0]}


def _assert_same(a, b) -> None:
    """Bit-identical values, coordinates and dimensions (attributes may differ)."""
    xr.testing.assert_equal(a, b)
    for name in a.data_vars:
        np.testing.assert_array_equal(a[name].values, b[name].values, strict=True)


# ------------------------------------------------------------------------------ grids --
def test_parse_range_forms():
    np.testing.assert_array_equal(ps.parse_range("0:1:5"), [0, 0.25, 0.5, 0.75, 1])
    np.testing.assert_array_equal(ps.parse_range("-4:1:50"), np.linspace(-4, 1, 50))
    np.testing.assert_array_equal(ps.parse_range("0.1, 0.3,0.2"), [0.1, 0.3, 0.2])
    np.testing.assert_array_equal(ps.parse_range("2"), [2.0])
    name, values = ps.parse_grid_item("mu=0.02:0.4:40")
    assert name == "mu" and values.size == 40 and values[0] == 0.02 and values[-1] == 0.4


@pytest.mark.parametrize(
    "text, fragment",
    [
        ("mu=0.02:0.4", "start:stop:count"),
        ("mu=0.02:0.4:2.5", "'2.5'"),
        ("mu=0.02:0.4:0", "'0'"),
        ("mu=a:1:3", "'a'"),
        ("mu=1:1:3", "start = stop"),
        ("mu=nan:1:3", "finite"),
        ("mu=1,,2", "v1,v2"),
        ("2mu=1:2:3", "NAME="),
        ("mu", "NAME="),
        ("mu=__import__('os')", "is not a number"),
    ],
)
def test_parse_grid_item_errors_name_the_value(text, fragment):
    with pytest.raises(ParameterError) as err:
        ps.parse_grid_item(text)
    assert fragment in str(err.value) and repr(text) in str(err.value)


def test_grid_validation():
    with pytest.raises(ParameterError, match="repeat"):
        ps.sweep(lambda a: a, {"a": [1.0, 1.0]}, "serial")
    with pytest.raises(ParameterError, match="finite"):
        ps.sweep(lambda a: a, {"a": [1.0, math.inf]}, "serial")
    with pytest.raises(ParameterError, match="grid = None"):
        ps.sweep(lambda a: a, None, "serial")
    with pytest.raises(ParameterError, match="executor = 'threads'"):
        ps.sweep(lambda a: a, {"a": [1.0]}, "threads")


def test_chunk_size_keeps_tasks_above_100ms():
    assert ps.chunk_cells(None, 1000, 2, 0.25) == 1  # probes
    n = ps.chunk_cells(0.003, 2000, 2, 0.25)
    assert n * 0.003 >= ps.MIN_TASK_SECONDS and n == 84
    # few cells left: smaller for balance, but not below 100 ms
    n = ps.chunk_cells(0.003, 100, 2, 0.25)
    assert n * 0.003 >= ps.MIN_TASK_SECONDS and n < 84
    assert ps.chunk_cells(5.0, 100, 2, 0.25) == 1  # an expensive cell is a task of its own


# ----------------------------------------------------------------------------- scenes --
def test_peak_map_scene_file():
    ss = ps.load_sweep_scene(ROOT / "scenes" / "peak_map.toml")
    assert (ss.quantity, ss.solver, ss.scene.model) == ("peak_amplitude", "approximation", "nsd")
    assert list(ss.grid) == ["mu", "k"]
    assert ss.grid["mu"].size == 40 and ss.grid["k"].size == 50
    assert ss.grid["mu"][0] == 0.02 and ss.grid["k"][-1] == 1.0
    assert ss.scene.params["F"] == 2.0


@pytest.mark.parametrize(
    "extra, fragment",
    [
        ("[sweep]\nquantity = 'peak'\n", "quantity = 'peak'"),
        ("[sweep]\nsolver = 'exact'\n", "solver = 'exact'"),
        ("[sweep]\nspeed = 3\n", "unknown key 'speed'"),
        ("[sweep]\ndirection = 'up'\n", "direction"),  # applies to the simulation only
        ("[sweep.params]\nmu = '0.1:0.2'\n", "start:stop:count"),
        ("[sweep]\nsolver = 'simulation'\ndirection = 'sideways'\n", "'sideways'"),
        # 'hb' is numeric harmonic balance (registry): the approximation solver derives a
        # symbolic method once for the grid, so it is refused with what applies
        ("[method]\nname = 'hb'\n[sweep]\nquantity = 'peak_amplitude'\n", "symbolic method"),
        ("[method]\nname = 'exact'\n[sweep]\nquantity = 'peak_amplitude'\n", "'simulation'"),
    ],
)
def test_sweep_section_errors(extra, fragment):
    with pytest.raises(PerturbError) as err:
        ps.parse_sweep_scene(NSD + extra, "s.toml")
    assert fragment in str(err.value) and "s.toml" in str(err.value)


def test_swept_parameter_must_exist_and_not_be_the_frequency():
    with pytest.raises(ParameterError, match="'zeta' is not a parameter"):
        ps.sweep(_peak_scene(), {"zeta": [0.1]}, "serial")
    with pytest.raises(ParameterError, match="'Omega' is the forcing frequency"):
        ps.sweep(_peak_scene(), {"Omega": [0.5, 1.0]}, "serial")


# ------------------------------------------------------------------ what a cell computes --
def test_peak_agrees_with_the_frequency_response_front_door():
    from perturb.methods import METHODS
    from perturb.numeric.amplitude import approximation_response

    ds = ps.sweep(_peak_scene(), {"mu": [0.1], "k": [-2.0, -0.5]}, "serial")
    for k in (-2.0, -0.5):
        osc = perturb.builtin_model("nsd", F=2.0, k=k, mu=0.1)
        resp = approximation_response(METHODS["hb1"](osc), (0.2, 2.0), stability="slow_flow")
        ref = max(float(b.amplitude.max()) for b in resp.branches)
        got = float(ds.peak_amplitude.sel(mu=0.1, k=k))
        assert got == pytest.approx(ref, rel=1e-11)
        # beyond |x| = 1 the force of nsd is x - (1 - k): the peak force is A - (1 - k)
        force = float(ds.peak_restoring_force.sel(mu=0.1, k=k))
        assert force == pytest.approx(got - (1 - k), rel=1e-12)
    assert not ds.failed.any()


def test_linear_case_matches_the_closed_form_peak():
    # k = 1: x'' + mu x' + x = F cos(Omega t), peak F / (mu sqrt(1 - mu^2/4)) at
    # Omega = sqrt(1 - mu^2/2); single-harmonic balance is exact here
    ds = ps.sweep(_peak_scene(), {"mu": [0.1, 0.4], "k": [1.0]}, "serial")
    for mu in (0.1, 0.4):
        cell = ds.sel(mu=mu, k=1.0)
        assert float(cell.peak_amplitude) == pytest.approx(
            2.0 / (mu * math.sqrt(1 - mu * mu / 4)), rel=1e-12
        )
        assert float(cell.peak_omega) == pytest.approx(math.sqrt(1 - mu * mu / 2), rel=1e-6)
        assert float(cell.peak_restoring_force) == pytest.approx(float(cell.peak_amplitude))


def test_hb1_peak_verified_against_simulation():
    # the cheap path (hb1) against the equation of motion integrated exactly (PWL flow), in a
    # stepped-sine sweep on a grid 0.02 apart around the resonance
    grid = {"mu": [0.3], "k": [-1.0]}
    approx = ps.sweep(_peak_scene(), grid, "serial")
    scene = ps.SweepScene(
        parse_scene(NSD.replace("[0.2, 2.0]", "[0.7, 0.9]")),
        "peak_amplitude",
        "simulation",
        options={"omega_points": 11, "transient_periods": 300, "tol": 1e-6},
    )
    sim = ps.sweep(scene, grid, "serial")
    a_hb1, a_sim = float(approx.peak_amplitude[0, 0]), float(sim.peak_amplitude[0, 0])
    # the simulated peak lies on a 0.02 grid below the true one: hb1 within 3 %
    assert a_sim == pytest.approx(a_hb1, rel=0.03)
    assert float(sim.peak_omega[0, 0]) == pytest.approx(float(approx.peak_omega[0, 0]), abs=0.05)
    f_sim = float(sim.peak_restoring_force[0, 0])
    assert f_sim == pytest.approx(float(approx.peak_restoring_force[0, 0]), rel=0.05)


def test_frequency_response_cells_match_solutions_at():
    from perturb.methods import METHODS
    from perturb.numeric.amplitude import solutions_at

    scene = ps.SweepScene(
        parse_scene(NSD), "frequency_response", "approximation", options={"omega_points": 10}
    )
    ds = ps.sweep(scene, {"mu": [0.1], "k": [-2.0]}, "serial")
    assert ds.amplitude.dims == ("mu", "k", "Omega", "solution")
    osc = perturb.builtin_model("nsd", F=2.0, k=-2.0, mu=0.1)
    ref = solutions_at(METHODS["hb1"](osc), ds.Omega.values, stability="slow_flow")
    for j, w in enumerate(ds.Omega.values):
        want = sorted(
            (
                float(a)
                for b in ref.branches
                for o, a in zip(b.omega, b.amplitude, strict=True)
                if o == w
            ),
            reverse=True,
        )
        got = ds.amplitude[0, 0, j].values
        assert int(ds.n_solutions[0, 0, j]) == len(want)
        np.testing.assert_allclose(got[: len(want)], want, rtol=1e-10)
        assert np.all(np.isnan(got[len(want) :]))


def test_bifurcation_columns():
    scene = ps.SweepScene(
        parse_scene(NSD),
        "bifurcation",
        "approximation",
        options={"transient_periods": 150, "record_periods": 6},
    )
    # k = 1 is linear: a period-1 orbit, whose section repeats
    ds = ps.sweep(scene, {"mu": [0.4], "k": [1.0], "Omega": [0.8]}, "serial")
    assert ds.x_section.dims == ("mu", "k", "Omega", "sample") and ds.sizes["sample"] == 6
    assert int(ds.period.item()) == 1
    x = ds.x_section.values.ravel()
    np.testing.assert_allclose(x, x[0], atol=1e-6)


def test_cell_errors_become_nan_and_failed(monkeypatch):
    scene = _peak_scene()
    ds0 = ps.sweep(scene, {"mu": [0.1, 0.2]}, "serial")  # builds and caches the kernel
    real = ps.ApproximationKernel.peak

    def flaky(self, p):
        if p[0] == 0.2:
            raise PerturbError("unbounded")
        return real(self, p)

    # patched on the class: the second sweep reuses the kernel the first one cached
    monkeypatch.setattr(ps.ApproximationKernel, "peak", flaky)
    ds = ps.sweep(scene, {"mu": [0.1, 0.2]}, "serial")
    assert ds.failed.values.tolist() == [0, 1] and ds.attrs["failed_cells"] == 1
    assert "unbounded" in ds.attrs["first_error"]
    assert np.isnan(ds.peak_amplitude.values[1])
    assert ds.peak_amplitude.values[0] == ds0.peak_amplitude.values[0]


# -------------------------------------------------------------------------- functions --
def _user_fn(a, b):
    return {"total": a + b, "vec": [a, b, a * b]}


def test_function_sweep_outputs_and_labels():
    ds = ps.sweep(_user_fn, {"a": "0:1:3", "b": [10.0, 20.0]}, "serial")
    assert ds.total.dims == ("a", "b") and ds.vec.dims == ("a", "b", "vec_dim0")
    np.testing.assert_array_equal(ds.total.values, [[10, 20], [10.5, 20.5], [11, 21]])
    assert ds.vec.sel(a=1.0, b=20.0).values.tolist() == [1.0, 20.0, 20.0]
    assert ds.attrs["function"].endswith("_user_fn") and "perturb_version" in ds.attrs
    scalar = ps.sweep(lambda a: a * a, {"a": [1.0, 2.0]}, "serial")
    assert scalar.value.values.tolist() == [1.0, 4.0]


def test_function_must_return_the_same_outputs():
    with pytest.raises(ParameterError, match="same outputs"):
        ps.sweep(lambda a: {"x": a} if a < 1 else {"y": a}, {"a": [0.0, 2.0]}, "serial")
    with pytest.raises(ParameterError, match="expected a number"):
        ps.sweep(lambda a: {"x": "big"}, {"a": [0.0]}, "serial")
    with pytest.raises(ParameterError, match="also swept parameters"):
        ps.sweep(lambda a: {"a": a}, {"a": [0.0]}, "serial")


# ------------------------------------------------------------------------- executors --
def test_process_pool_identical_to_serial_and_builds_once_per_worker():
    scene = _peak_scene()
    ref = ps.sweep(scene, SMALL_GRID, "serial")
    info: dict = {}
    got = ps.sweep(scene, SMALL_GRID, 2, run_info=info)
    _assert_same(ref, got)
    assert info["tasks"] >= 2 and info["computed_cells"] == 9
    # a worker builds the kernel at most once (a forked one inherits the parent's)
    assert info["builds"] <= info["workers_seen"] <= 2
    # other chunkings, an executor passed in, a user function: same numbers
    import concurrent.futures as cf

    with cf.ProcessPoolExecutor(2) as ex:
        _assert_same(ref, ps.sweep(scene, SMALL_GRID, ex, chunk_size=4))
        f1 = ps.sweep(_user_fn, {"a": "0:1:7", "b": [1.0, 2.0]}, ex)
    _assert_same(f1, ps.sweep(_user_fn, {"a": "0:1:7", "b": [1.0, 2.0]}, "serial"))


@pytest.fixture(scope="module")
def dask_client():
    distributed = pytest.importorskip("distributed")
    import dask

    # loopback only, no dashboard, no profiler (it slows pure-Python tasks); stopped below
    with dask.config.set({"distributed.worker.profile.enabled": False}):
        cluster = distributed.LocalCluster(
            n_workers=2,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            dashboard_address=None,
            silence_logs=50,
        )
    client = distributed.Client(cluster)
    yield client
    client.close()
    cluster.close()


def test_dask_local_cluster_identical_to_serial(dask_client):
    scene = _peak_scene()
    ref = ps.sweep(scene, SMALL_GRID, "serial")
    info: dict = {}
    got = ps.sweep(scene, SMALL_GRID, dask_client, run_info=info)
    _assert_same(ref, got)
    # fresh worker processes: each built the kernel exactly once, then reused it
    assert info["builds"] == info["workers_seen"] >= 1
    assert info["tasks"] > info["builds"]
    again: dict = {}
    _assert_same(ref, ps.sweep(scene, SMALL_GRID, dask_client, chunk_size=2, run_info=again))
    assert again["builds"] == 0
    # a lambda travels to Dask workers (cloudpickle)
    fn = ps.sweep(lambda a, b: a * b, {"a": [1.0, 2.0], "b": [3.0]}, dask_client)
    assert fn.value.values.tolist() == [[3.0], [6.0]]


def test_cli_scheduler_option_uses_the_cluster(dask_client, tmp_path):
    from perturb.apps.cli import main as cli_main

    def main(argv):
        return cli_main(["sweep", *argv])

    out = tmp_path / "m.nc"
    argv = [str(ROOT / "scenes" / "peak_map.toml"), "--param", "mu=0.1,0.3", "--param", "k=1"]
    assert (
        main(
            [*argv, "--out", str(out), "--no-plot"] + ["--scheduler", dask_client.scheduler.address]
        )
        == 0
    )
    assert main([*argv, "--out", str(tmp_path / "s.nc"), "--no-plot", "--serial"]) == 0
    _assert_same(ps.load_dataset(out), ps.load_dataset(tmp_path / "s.nc"))


# ------------------------------------------------------------------------------ files --
@pytest.mark.parametrize("suffix", [".nc", ".zarr"])
def test_save_and_load_round_trip(tmp_path, suffix):
    if suffix == ".zarr":
        pytest.importorskip("zarr")
    ds = ps.sweep(_peak_scene(), {"mu": [0.1, 0.3], "k": [-1.0]}, "serial")
    path = ps.save_dataset(ds, tmp_path / f"map{suffix}")
    back = ps.load_dataset(path)
    _assert_same(ds, back)
    assert back.attrs["scene"] == ds.attrs["scene"]
    assert back.attrs["perturb_version"] == perturb.__version__
    # the stored scene is a complete sweep scene: reading it back gives the same sweep
    again = ps.parse_sweep_scene(back.attrs["scene"])
    np.testing.assert_array_equal(again.grid["mu"], [0.1, 0.3])
    _assert_same(ds, ps.sweep(again, None, "serial"))


def test_simulation_frequency_response_labels_survive_netcdf(tmp_path):
    scene = ps.SweepScene(
        parse_scene(NSD),
        "frequency_response",
        "simulation",
        options={"omega_points": 3, "direction": "both", "transient_periods": 60},
    )
    ds = ps.sweep(scene, {"mu": [0.4], "k": [1.0]}, "serial")
    assert ds.amplitude.dims == ("mu", "k", "Omega", "direction")
    back = ps.load_dataset(ps.save_dataset(ds, tmp_path / "frc.nc"))
    assert [str(d) for d in back.direction.values] == ["up", "down"]
    np.testing.assert_array_equal(back.amplitude.values, ds.amplitude.values)


# ------------------------------------------------------------------ checkpoints, resume --
def test_checkpoint_resume_skips_completed_cells(tmp_path):
    calls = []

    def f(a, b):
        calls.append((a, b))
        return a - b

    grid = {"a": "0:1:4", "b": "0:1:3"}
    ckpt = tmp_path / "ckpt"
    ref = ps.sweep(f, grid, "serial", checkpoint=ckpt, chunk_size=5)
    assert len(calls) == 12
    parts = sorted(ckpt.glob("part-*.json"))
    assert len(parts) == 3
    # lose one chunk (as if killed before it finished): only its cells are redone
    lost = json.loads(parts[1].read_text())["cells"]
    parts[1].unlink()
    calls.clear()
    info: dict = {}
    again = ps.sweep(f, grid, "serial", checkpoint=ckpt, run_info=info)
    assert len(calls) == len(lost) == info["computed_cells"] and info["resumed_cells"] == 7
    _assert_same(ref, again)
    # checkpoints are JSON data, never pickles
    for p in ckpt.iterdir():
        json.loads(p.read_text())


def test_checkpoint_of_another_sweep_is_refused(tmp_path):
    ps.sweep(_user_fn, {"a": [1.0], "b": [2.0]}, "serial", checkpoint=tmp_path / "c")
    with pytest.raises(PerturbError, match="different sweep"):
        ps.sweep(_user_fn, {"a": [1.0, 2.0], "b": [2.0]}, "serial", checkpoint=tmp_path / "c")


_KILL_SCRIPT = textwrap.dedent(
    """
    import sys, time
    import perturb.apps.grid as ps

    def cell(a, b):
        time.sleep(0.04)
        with open(sys.argv[3], "a") as log:
            log.write(f"{a!r},{b!r}\\n")
        return {"s": a * b + 0.1 * a, "w": [a, b]}

    if __name__ == "__main__":
        ex = int(sys.argv[4]) if sys.argv[4].isdigit() else sys.argv[4]
        ds = ps.sweep(cell, KILL_GRID, ex, checkpoint=sys.argv[1], chunk_size=2, progress=False)
        ps.save_dataset(ds, sys.argv[2])
    """
).replace("KILL_GRID", repr({"a": "0:1:8", "b": "-1:1:5"}))


def _kill_cell_reference(a, b):
    return {"s": a * b + 0.1 * a, "w": [a, b]}


@pytest.mark.parametrize("executor", [pytest.param("serial", marks=pytest.mark.slow), "2"])
def test_killed_sweep_resumes_with_the_same_result(tmp_path, executor):
    script = tmp_path / "job.py"
    script.write_text(_KILL_SCRIPT)
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    ckpt, log = tmp_path / "ckpt", tmp_path / "log.txt"

    def run(*args, **kw):
        return subprocess.Popen([sys.executable, str(script), *map(str, args)], env=env, **kw)

    job = run(ckpt, tmp_path / "out.nc", log, executor, start_new_session=True)
    deadline = time.monotonic() + 60
    while len(list(ckpt.glob("part-*.json"))) < 6 and time.monotonic() < deadline:
        assert job.poll() is None, "the sweep finished before it could be killed"
        time.sleep(0.02)
    os.killpg(job.pid, signal.SIGKILL)  # the whole session: pool workers too
    job.wait()
    done_before = set()
    for p in ckpt.glob("part-*.json"):
        done_before.update(json.loads(p.read_text())["cells"])
    assert 12 <= len(done_before) < 40
    n_first = len(log.read_text().splitlines())
    assert not (tmp_path / "out.nc").exists()

    assert run(ckpt, tmp_path / "out.nc", log, executor).wait(timeout=120) == 0
    second = log.read_text().splitlines()[n_first:]
    redone = {tuple(map(float, line.split(","))) for line in second}
    axes = (np.linspace(0, 1, 8), np.linspace(-1, 1, 5))
    done_values = {(float(axes[0][i // 5]), float(axes[1][i % 5])) for i in done_before}
    assert not (redone & done_values), "completed cells were computed again"
    assert len(second) == 40 - len(done_before)

    ref = ps.sweep(_kill_cell_reference, {"a": "0:1:8", "b": "-1:1:5"}, "serial")
    _assert_same(ref, ps.load_dataset(tmp_path / "out.nc"))


# -------------------------------------------------------------------------------- CLI --
def test_cli_sweep_writes_map_and_png(tmp_path, capsys):
    from perturb.apps.cli import main as cli_main

    def main(argv):
        return cli_main(["sweep", *argv])

    out = tmp_path / "map.nc"
    code = main(
        [
            str(ROOT / "scenes" / "peak_map.toml"),
            "--param",
            "mu=0.1:0.4:3",
            "--param",
            "k=-2,1",
            "--param",
            "F=1.5",
            "--out",
            str(out),
            "--serial",
        ]
    )
    assert code == 0
    assert out.exists() and (tmp_path / "map.png").stat().st_size > 1000
    assert not (tmp_path / "map.nc.partial").exists()
    ds = ps.load_dataset(out)
    assert dict(ds.sizes) == {"mu": 3, "k": 2}
    # F = 1.5 and the linear cell: peak F / (mu sqrt(1 - mu^2/4))
    assert float(ds.peak_amplitude.sel(mu=0.4, k=1.0)) == pytest.approx(
        1.5 / (0.4 * math.sqrt(0.96)), rel=1e-12
    )
    assert "F = 1.5" in ds.attrs["scene"]
    assert "wrote" in capsys.readouterr().err


@pytest.mark.parametrize(
    "argv, fragment",
    [
        (["--param", "mu=0.1:0.4"], "start:stop:count"),
        (["--param", "zeta=1:2:3", "--serial"], "'zeta' is not a parameter"),
        (["--out", "map.csv"], "'map.csv'"),
        (["--quantity", "peak", "--serial"], "quantity = 'peak'"),
        (["--workers", "0"], "--workers 0"),
    ],
)
def test_cli_errors(tmp_path, capsys, argv, fragment):
    from perturb.apps.cli import main as cli_main

    def main(argv):
        return cli_main(["sweep", *argv])

    code = main([str(ROOT / "scenes" / "peak_map.toml"), "--out", str(tmp_path / "m.nc"), *argv])
    assert code == 2
    assert fragment in capsys.readouterr().err


def test_module_is_callable():
    ds = perturb.sweep(lambda a: 2 * a, {"a": [1.0]}, "serial")
    assert ds.value.values.tolist() == [2.0]


# ------------------------------------------ hostile checkpoints, atomic outputs, orphans --
@pytest.fixture
def private_key(tmp_path, monkeypatch):
    """This test's own cache key (checkpoint parts are authenticated with it)."""
    import perturb.io.cache as pc

    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    monkeypatch.delenv("PERTURB_CACHE_KEY", raising=False)
    monkeypatch.setattr(pc, "_KEYS", {})


_CK_GRID = {"a": "0:1:4", "b": "0:1:3"}
_CK_CALLS: list[tuple[float, float]] = []


def _ck_cell(a, b):
    _CK_CALLS.append((a, b))
    return {"s": a * b + 0.25, "v": [a, b]}


def _edit(path, change):
    data = json.loads(path.read_text())
    change(data)
    path.write_text(json.dumps(data))
    return data["cells"]


def _resign(path):
    from perturb.io.cache import authenticate

    data = json.loads(path.read_text())
    data.pop("hmac", None)
    text = json.dumps(data, sort_keys=True, allow_nan=True, separators=(",", ":"))
    data["hmac"] = authenticate(f"sweep-checkpoint/{data['fingerprint']}", text.encode())
    path.write_text(json.dumps(data))


def _tamper_number(parts, marker):
    return _edit(parts[0], lambda d: d["values"]["s"].__setitem__(0, d["values"]["s"][0] + 1.0))


def _tamper_code(parts, marker):
    payload = f"__import__('os').system('touch {marker}')"
    cells = _edit(parts[1], lambda d: d["values"]["s"].__setitem__(0, payload))
    _resign(parts[1])
    return cells


def _tamper_cells_outside_the_grid(parts, marker):
    cells = json.loads(parts[2].read_text())["cells"]
    _edit(parts[2], lambda d: d["cells"].__setitem__(0, 10**6))
    _resign(parts[2])
    return cells


def _tamper_duplicate(parts, marker):
    # a copy of a valid part (its HMAC too) claiming cells another part holds: dropped
    (parts[0].parent / "part-999999999-copy.json").write_bytes(parts[0].read_bytes())
    return []


def _tamper_garbage(parts, marker):
    cells = json.loads(parts[1].read_text())["cells"]
    parts[1].write_bytes(b"\x80\x04\x95 not json: a pickle would be refused too")
    return cells


def _tamper_shape(parts, marker):
    cells = _edit(parts[3], lambda d: d["values"]["v"].__setitem__(0, [1.0]))
    _resign(parts[3])
    return cells


def _tamper_no_hmac(parts, marker):
    return _edit(parts[0], lambda d: d.pop("hmac"))


@pytest.mark.parametrize(
    "tamper",
    [
        _tamper_number,
        _tamper_code,
        _tamper_cells_outside_the_grid,
        _tamper_duplicate,
        _tamper_garbage,
        _tamper_shape,
        _tamper_no_hmac,
    ],
)
def test_tampered_checkpoint_parts_are_ignored_and_recomputed(tmp_path, private_key, tamper):
    ckpt = tmp_path / "ckpt"
    ref = ps.sweep(_ck_cell, _CK_GRID, "serial", checkpoint=ckpt, chunk_size=3)
    parts = sorted(ckpt.glob("part-*.json"))
    assert len(parts) == 4
    marker = tmp_path / "pwned"
    redo = tamper(parts, marker)
    _CK_CALLS.clear()
    with pytest.warns(ps.CheckpointWarning, match="ignored"):
        again = ps.sweep(_ck_cell, _CK_GRID, "serial", checkpoint=ckpt)
    axes = (np.linspace(0, 1, 4), np.linspace(0, 1, 3))
    assert sorted(_CK_CALLS) == sorted((axes[0][i // 3], axes[1][i % 3]) for i in redo)
    _assert_same(ref, again)
    assert not marker.exists()


def test_a_checkpoint_header_that_does_not_describe_the_sweep_is_an_error(tmp_path, private_key):
    ckpt = tmp_path / "ckpt"
    ps.sweep(_ck_cell, _CK_GRID, "serial", checkpoint=ckpt, chunk_size=3)
    head = ckpt / "sweep.json"
    data = json.loads(head.read_text())
    data["n_cells"] = 10**9
    head.write_text(json.dumps(data))
    with pytest.raises(PerturbError, match="does not describe this sweep"):
        ps.sweep(_ck_cell, _CK_GRID, "serial", checkpoint=ckpt)


def test_scene_checkpoint_values_must_have_the_schema(tmp_path, private_key):
    ckpt = tmp_path / "ckpt"
    grid = {"mu": [0.1, 0.3], "k": [1.0]}
    ref = ps.sweep(_peak_scene(), grid, "serial", checkpoint=ckpt, chunk_size=1)
    part = sorted(ckpt.glob("part-*.json"))[0]
    _edit(part, lambda d: d["values"].update(extra=[1.0]))
    _resign(part)  # as if the key had leaked: validation still refuses the part
    with pytest.warns(ps.CheckpointWarning, match="outputs"):
        again = ps.sweep(_peak_scene(), grid, "serial", checkpoint=ckpt)
    _assert_same(ref, again)


def test_outputs_are_complete_or_absent(tmp_path, monkeypatch):
    import matplotlib.figure

    ds = ps.sweep(_user_fn, {"a": [1.0, 2.0], "b": [2.0, 3.0]}, "serial")
    out, png = tmp_path / "map.nc", tmp_path / "map.png"
    ps.save_dataset(ds, out)
    ps.plot_map(ds, png)
    good_nc, good_png = out.read_bytes(), png.read_bytes()

    def full_disk(self, path, *args, **kwargs):
        Path(path).write_bytes(b"half a file")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(xr.Dataset, "to_netcdf", full_disk)
    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", full_disk)
    with pytest.raises(OSError):
        ps.save_dataset(ds, out)
    with pytest.raises(OSError):
        ps.plot_map(ds, png)
    assert out.read_bytes() == good_nc and png.read_bytes() == good_png
    assert sorted(p.name for p in tmp_path.iterdir()) == ["map.nc", "map.png"]


_ORPHAN_SCRIPT = textwrap.dedent(
    """
    import os, sys, time
    import perturb.apps.grid as ps

    def cell(a):
        with open(sys.argv[1], "a") as log:
            log.write(f"{os.getpid()}\\n")
        time.sleep(60)
        return a

    if __name__ == "__main__":
        ps.sweep(cell, {"a": "0:1:4"}, 2, chunk_size=1, progress=False)
    """
)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    try:  # a zombie (dead, not yet reaped by a container's init) is gone
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return True


@pytest.mark.skipif(os.name != "posix", reason="POSIX signals")
def test_pool_workers_die_with_a_killed_parent(tmp_path):
    script, log = tmp_path / "job.py", tmp_path / "pids.txt"
    script.write_text(_ORPHAN_SCRIPT)
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    job = subprocess.Popen([sys.executable, str(script), str(log)], env=env, start_new_session=True)
    try:
        pids: set[int] = set()
        deadline = time.monotonic() + 60
        while len(pids) < 2 and time.monotonic() < deadline:
            assert job.poll() is None, "the sweep ended early"
            time.sleep(0.05)
            if log.exists():
                pids = {int(p) for p in log.read_text().split()}
        assert len(pids) == 2, "the workers did not start"
        os.kill(job.pid, signal.SIGKILL)  # the parent only, as the OOM killer would
        job.wait(timeout=10)
        deadline = time.monotonic() + 10
        while any(_alive(p) for p in pids) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not [p for p in pids if _alive(p)], "pool workers outlived their parent"
    finally:
        try:
            os.killpg(job.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass


def test_swept_dead_zone_breakpoint_matches_the_closed_form_peak():
    # Sweeping a breakpoint (d) leaves its order against the other breakpoint undecidable
    # with d symbolic, so each cell derives its own balance. The single-harmonic balance of
    # x'' + mu x' + k1 x + k2 (x - sat_d(x)) = F cos(Omega t) has, for A > d, the equivalent
    # stiffness k_eq(A) = k1 + k2 [1 - (2/pi)(asin(d/A) + (d/A) sqrt(1 - (d/A)^2))], and
    # the amplitude equation [(k_eq - W)^2 + mu^2 W] A^2 = F^2 (W = Omega^2) peaks at
    # W = k_eq - mu^2/2, where A^2 mu^2 (k_eq - mu^2/4) = F^2 (derived here, not by perturb)
    from scipy.optimize import brentq

    text = '[model]\nname = "deadzone"\n[ask]\nomega = [0.5, 2.0]\n'
    scene = ps.SweepScene(parse_scene(text), "peak_amplitude", "approximation")
    ds = ps.sweep(scene, {"d": [0.5, 1.0]}, "serial")
    assert not ds.failed.any()
    k1, k2, mu, F = 0.1, 1.0, 0.05, 0.5
    for d in (0.5, 1.0):

        def k_eq(A, d=d):
            r = d / A
            return k1 + k2 * (1 - (2 / math.pi) * (math.asin(r) + r * math.sqrt(1 - r * r)))

        A = brentq(lambda A: A * A * mu * mu * (k_eq(A) - mu * mu / 4) - F * F, d, 1e3, xtol=1e-14)
        cell = ds.sel(d=d)
        assert float(cell.peak_amplitude) == pytest.approx(A, rel=1e-9)
        assert float(cell.peak_omega) == pytest.approx(math.sqrt(k_eq(A) - mu * mu / 2), rel=1e-6)
