"""Hostile and erroneous input to the ``perturb`` command (issue 18, items 15, 16 and 18).

Every case must be answered within 20 s by exactly one line ``perturb: error: ...`` on standard
error, exit status 2 and no traceback. Cases that cannot hang run in-process
(``perturb.apps.cli.main``, fast); the few that could (hostile expressions, the requests that once
grew to 20 GB, signals) run in a subprocess with ``timeout=20``.
"""

from __future__ import annotations

import errno
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from perturb.apps.cli import MAX_PERIODS, main
from perturb.methods.registry import ORDER_LIMITS
from perturb.solve import MAX_HARMONICS

ROOT = Path(__file__).resolve().parents[1]
TIMEOUT = 20.0

#: wall time of each case, for the slowest-case report at the end of the module
TIMES: dict[str, float] = {}


def _one_error_line(err: str) -> str:
    lines = err.splitlines()
    assert "Traceback" not in err, err
    assert len(lines) == 1, f"expected one line on stderr, got {len(lines)}:\n{err}"
    assert lines[0].startswith("perturb: error: "), lines[0]
    return lines[0]


def _run_inprocess(argv, capsys, name: str | None = None) -> str:
    capsys.readouterr()
    t0 = time.perf_counter()
    code = main([str(a) for a in argv])
    TIMES[name or " ".join(map(str, argv))] = time.perf_counter() - t0
    err = capsys.readouterr().err
    assert code == 2, f"exit status {code}, stderr:\n{err}"
    return _one_error_line(err)


def _run_subprocess(argv, cwd: Path, name: str | None = None, **kw) -> str:
    env = dict(os.environ)
    env.pop("PERTURB_DEBUG", None)
    t0 = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-m", "perturb.apps.cli", *map(str, argv)],
        capture_output=True,
        text=True,
        timeout=TIMEOUT,
        cwd=cwd,
        env=env,
        **kw,
    )
    TIMES[name or " ".join(map(str, argv))] = time.perf_counter() - t0
    assert proc.returncode == 2, f"exit status {proc.returncode}, stderr:\n{proc.stderr}"
    return _one_error_line(proc.stderr)


# ---------------------------------------------------------------------------------------------
# in-process: argument checks that answer before any work
FRC = ["frc", "nsd"]
CASES = [
    # outputs
    ([*FRC, "--out", "{tmp}/missing/frc.csv"], "does not exist"),
    ([*FRC, "--out", "{tmp}/f.csv", "--plot", "{tmp}/f.csv"], "same file"),
    ([*FRC, "--out", "{tmp}/f.csv", "--plot", "{tmp}/./f.csv"], "same file"),
    ([*FRC, "--out", "{tmp}"], "is a folder"),
    ([*FRC, "--out", "{tmp}/afile/x.csv"], "does not exist"),
    (["simulate", "nsd", "--out", "{tmp}/nope/t.csv"], "does not exist"),
    (["simulate", "nsd", "--out", "{tmp}/t.png", "--plot", "{tmp}/t.png"], "same file"),
    (["periodic", "nsd", "--omega", "1", "--out", "{tmp}/nope/p.csv"], "does not exist"),
    (["derive", "hb1", "duffing", "--latex", "{tmp}/d.tex", "--json", "{tmp}/d.tex"], "same"),
    (["derive", "hb1", "duffing", "--latex", "{tmp}/nope/d.tex"], "does not exist"),
    (["run", "--out", "{tmp}/afile"], "is a file"),
    (["sweep", str(ROOT / "scenes" / "peak_map.toml"), "--out", "{tmp}/nope/m.nc"], "not exist"),
    (["sweep", str(ROOT / "scenes" / "peak_map.toml"), "--out", "{tmp}/m.csv"], ".nc or .zarr"),
    (
        [
            "sweep",
            str(ROOT / "scenes" / "peak_map.toml"),
            "--out",
            "{tmp}/m.nc",
            "--plot",
            "{tmp}/m.nc",
        ],
        "m.nc",
    ),
    (
        [
            "sweep",
            str(ROOT / "scenes" / "peak_map.toml"),
            "--param",
            "mu=1e-5000:1:3",
            "--out",
            "{tmp}/m.nc",
        ],
        "underflows",
    ),
    (
        [
            "sweep",
            str(ROOT / "scenes" / "peak_map.toml"),
            "--param",
            "mu=nan:1:3",
            "--out",
            "{tmp}/m.nc",
        ],
        "finite",
    ),
    (
        ["sweep", str(ROOT / "scenes" / "peak_map.toml"), "--workers", "0", "--out", "{tmp}/m.nc"],
        "--workers 0",
    ),
    # unbounded work
    ([*FRC, "--method", "hb", "--harmonics", "10000"], f"at most {MAX_HARMONICS}"),
    ([*FRC, "--method", "hb", "--harmonics", "0"], "at least 1"),
    ([*FRC, "--method", "hb", "--harmonics", "-5"], "at least 1"),
    ([*FRC, "--method", "mlp", "--order", "1000"], f"at most {ORDER_LIMITS['mlp']}"),
    ([*FRC, "--method", "ms", "--order", "50"], f"at most {ORDER_LIMITS['ms']}"),
    ([*FRC, "--method", "mms", "--order", "9"], f"at most {ORDER_LIMITS['ms']}"),
    ([*FRC, "--method", "mlp", "--order", "0"], "at least 1"),
    (["derive", "ms", "duffing", "--order", "1000"], f"at most {ORDER_LIMITS['ms']}"),
    ([*FRC, "--points", "1000000000"], "at most"),
    ([*FRC, "--points", "1"], "at least 2"),
    ([*FRC, "--omega", "0.2:2:1e9"], "count"),
    (["simulate", "nsd", "--t", "0:1e12"], f"at most {MAX_PERIODS}"),
    (["simulate", "nsd", "--samples", "1000000000"], "at most"),
    (["simulate", "nsd", "--samples", "1"], "at least 2"),
    (["simulate", "nsd", "--method", "lcp", "--h", "1e-12"], "steps"),
    (["simulate", "nsd", "--h", "0"], "step > 0"),
    (["periodic", "nsd", "--omega", "1", "--m", "1000"], "at most"),
    (["periodic", "nsd", "--omega", "1", "--m", "0"], "at least 1"),
    (["fourier", "x", "--A", "1", "--n", "1000000000"], "at most"),
    (["fourier", "x", "--A", "1", "--n", "-1"], "at least 0"),
    # windows and numbers
    ([*FRC, "--omega", "2:0.2"], "0 < start < stop"),
    ([*FRC, "--omega", "1:1"], "0 < start < stop"),
    ([*FRC, "--omega", "0:1"], "0 < start < stop"),
    ([*FRC, "--omega=-1:1"], "0 < start < stop"),
    ([*FRC, "--omega", "-1:1"], "expected one argument"),
    ([*FRC, "--omega", "1e-5000:1"], "underflows"),
    ([*FRC, "--omega", "1:1e5000"], "finite"),
    ([*FRC, "--omega", "nan:1"], "finite"),
    ([*FRC, "--omega", "1:inf"], "finite"),
    ([*FRC, "--omega", "a:b"], "expected start:stop"),
    ([*FRC, "--omega", "1:2:3:4"], "expected start:stop"),
    ([*FRC, "--omega", "0.6,-1"], "positive"),
    ([*FRC, "--omega", "0.6,,0.9"], "expected start:stop"),
    ([*FRC, "--param", "k=nan"], "finite"),
    ([*FRC, "--param", "k=inf"], "finite"),
    ([*FRC, "--param", "k=-inf"], "finite"),
    ([*FRC, "--param", "mu=1e-5000"], "underflows"),
    ([*FRC, "--param", "mu=1e5000"], "finite"),
    ([*FRC, "--param", "mu=1e-320"], "smallest normal"),
    ([*FRC, "--param", "k"], "NAME=VALUE"),
    ([*FRC, "--param", "=2"], "NAME=VALUE"),
    ([*FRC, "--param", "1k=2"], "NAME=VALUE"),
    ([*FRC, "--param", "k=two"], "not a number"),
    ([*FRC, "--param", "Omega=2", "--omega", "1,1.5"], "give its values with --omega"),
    (["simulate", "nsd", "--t", "5:1"], "t1 > t0"),
    (["simulate", "nsd", "--t", "nan:1"], "finite"),
    (["simulate", "nsd", "--y0", "1"], "two"),
    (["simulate", "nsd", "--y0", "a,b"], "two numbers"),
    (["simulate", "nsd", "--y0", "1e999,0"], "finite"),
    (["periodic", "nsd", "--omega", "0"], "> 0"),
    (["periodic", "nsd", "--omega", "1e-300"], "outside the forcing frequencies"),
    (["periodic", "nsd", "--omega", "1e300"], "outside the forcing frequencies"),
    ([*FRC, "--omega", "1e-300:1e-299"], "outside the forcing frequencies"),
    ([*FRC, "--omega", "1e300:1e301"], "outside the forcing frequencies"),
    ([*FRC, "--omega", "0.5,1e9"], "outside the forcing frequencies"),
    (["periodic", "nsd", "--omega", "nan"], "finite"),
    (["fourier", "x", "--A", "nan"], "finite"),
    (["fourier", "x", "--A", "1e-5000"], "underflows"),
    (["fourier", "x", "--A", "-1"], "--A -1"),
    (["fourier", "k*x**3", "--A", "1", "--param", "k=1e305"], "parameter 'k'"),
    # methods, models, equations
    ([*FRC, "--method", "magic"], "--method 'magic'"),
    (["frc", "nosuch"], "builtin name"),
    (["frc", "x'' + = 0"], "x''"),
    (["frc", "x'' + (x = cos(Omega*t)"], "x''"),
    (["frc", "x'' + foo(x) = cos(Omega*t)"], "foo"),
    (["frc", "x'' + __import__('os') = 0"], "not allowed"),
    (["frc", "x'' + mu*x' + x = 0", "--omega", "1:2"], "mu"),
    (["derive", "magic", "duffing"], "method 'magic'"),
    (["derive", "hb1", "duffing", "--order", "2"], "takes no order"),
    (["derive", "hb", "duffing"], "not a derivation"),
    (["simulate", "nsd", "--method", "magic"], "--method 'magic'"),
    ([*FRC, "--method", "hb1", "--harmonics", "99"], "takes no harmonics"),
    ([*FRC, "--method", "hb1", "--order", "2"], "takes no order"),
    ([*FRC, "--method", "exact", "--harmonics", "9"], "takes no harmonics"),
    ([*FRC, "--method", "hb1", "--one-branch"], "--one-branch"),
    ([*FRC, "--method", "auto", "--order", "2"], "--method auto"),
    # scenes
    (["run", "{tmp}/missing.toml"], "cannot read scene file"),
    (["run", "{tmp}/bad.toml"], "scene"),
    (["run", "{tmp}/harmonics.toml"], f"at most {MAX_HARMONICS}"),
    (["run", "{tmp}/order.toml"], f"at most {ORDER_LIMITS['mlp']}"),
    (["run", "{tmp}/reversed.toml"], "omega"),
    # argparse
    ([*FRC, "--bogus"], "unrecognized arguments"),
    (["frc"], "required"),
    ([*FRC, "--points", "abc"], "invalid int"),
    ([*FRC, "--compare", "magic"], "invalid choice"),
    (["nosuch"], "invalid choice"),
    (["fourier", "x"], "--A"),
]

SCENES = {
    "bad.toml": "[model\nname = 'nsd'\n",
    "harmonics.toml": "[model]\nname = 'nsd'\n[ask]\nomega = [0.2, 2.0]\n"
    "[method]\nname = 'hb'\nharmonics = 1000\n",
    "order.toml": "[model]\nname = 'nsd'\n[ask]\nomega = [0.2, 2.0]\n"
    "[method]\nname = 'mlp'\norder = 1000\n",
    "reversed.toml": "[model]\nname = 'nsd'\n[ask]\nomega = [2.0, 0.2]\n",
}


@pytest.fixture
def hostile_dir(tmp_path):
    (tmp_path / "afile").write_text("not a folder")
    for name, text in SCENES.items():
        (tmp_path / name).write_text(text)
    return tmp_path


@pytest.mark.parametrize("argv, fragment", CASES, ids=[" ".join(a) for a, _ in CASES])
def test_error_is_one_line_exit_2(argv, fragment, hostile_dir, capsys):
    argv = [a.replace("{tmp}", str(hostile_dir)) for a in argv]
    line = _run_inprocess(argv, capsys)
    assert fragment in line
    # nothing was written where a refused output pointed
    leftovers = {p.name for p in hostile_dir.iterdir()} - set(SCENES) - {"afile"}
    assert not leftovers, leftovers


def test_every_refusal_is_instant(capsys, tmp_path):
    """The limits answer before the model is built: well under a second each, even the
    request that once grew to 20 GB."""
    for argv in (
        [*FRC, "--method", "hb", "--harmonics", "10000"],
        [*FRC, "--method", "mlp", "--order", "1000"],
        ["simulate", "nsd", "--t", "0:1e12"],
    ):
        t0 = time.perf_counter()
        assert main(argv) == 2
        assert time.perf_counter() - t0 < 1.0
    capsys.readouterr()


# ---------------------------------------------------------------------------------------------
# the Python front door refuses the same requests
def test_api_limits_and_options_a_method_does_not_take():
    import perturb
    from perturb.errors import ParameterError

    osc = perturb.builtin_model("duffing")
    for method, kw, fragment in (
        ("hb", {"harmonics": 10000}, f"at most {MAX_HARMONICS}"),
        ("hb", {"harmonics": 0}, "at least 1"),
        ("hb", {"harmonics": 2.5}, "whole number"),
        ("hb", {"harmonics": True}, "whole number"),
        ("mlp", {"order": 1000}, f"at most {ORDER_LIMITS['mlp']}"),
        ("ms", {"order": 9}, f"at most {ORDER_LIMITS['ms']}"),
        ("hb1", {"points": 10**9}, "at most"),
        # an option the method does not take is named, with what the method accepts
        ("hb", {"order": 2}, "'hb' takes no order .*accepts: harmonics"),
        ("hb", {"points": 100}, "'hb' takes no points"),
        ("hb1", {"harmonics": 99}, "'hb1' takes no harmonics"),
        ("exact", {"harmonics": 9}, "'exact' takes no harmonics"),
        ("kb", {"order": 2}, "'kb' takes no order"),
        ("auto", {"order": 2}, "'auto' takes no order"),
        ("mlp", {"bias": True}, "'mlp' takes no bias .*accepts: order"),
    ):
        with pytest.raises(ParameterError, match=fragment):
            t0 = time.perf_counter()
            perturb.frequency_response(osc, method, (0.5, 2.0), **kw)
        assert time.perf_counter() - t0 < 1.0
    with pytest.raises(ParameterError, match="frequencies"):
        perturb.frequency_response(osc, "hb1", frequencies=[0.5, float("nan")])


# ---------------------------------------------------------------------------------------------
# failures while writing, unexpected errors, interrupts (in-process, monkeypatched)
def test_full_disk_while_writing_is_one_line_and_leaves_no_file(tmp_path, monkeypatch, capsys):
    import perturb.atomic

    real_fsync = os.fsync

    def full(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(perturb.atomic.os, "fsync", full)
    out = tmp_path / "frc.csv"
    line = _run_inprocess([*FRC, "--omega", "0.6,0.9", "--out", out], capsys, "full disk")
    monkeypatch.setattr(perturb.atomic.os, "fsync", real_fsync)
    assert "No space left on device" in line
    assert list(tmp_path.iterdir()) == []  # neither the output nor its temporary file


def test_permission_denied_while_writing(tmp_path, monkeypatch, capsys):
    import perturb.atomic

    def denied(*args, **kwargs):
        raise PermissionError(errno.EACCES, os.strerror(errno.EACCES))

    monkeypatch.setattr(perturb.atomic.tempfile, "mkstemp", denied)
    line = _run_inprocess(
        [*FRC, "--omega", "0.6,0.9", "--out", tmp_path / "x.csv"], capsys, "EACCES"
    )
    assert "Permission denied" in line and "x.csv" in line


@pytest.mark.skipif(os.geteuid() == 0 if hasattr(os, "geteuid") else True, reason="root")
def test_read_only_folder(tmp_path, capsys):
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o500)
    try:
        line = _run_inprocess([*FRC, "--out", folder / "x.csv"], capsys, "read-only folder")
    finally:
        folder.chmod(0o700)
    assert "not writable" in line


def test_unexpected_error_names_it_and_the_debug_switch(monkeypatch, capsys):
    import perturb.apps.cli

    def broken(*args, **kwargs):
        raise ZeroDivisionError("complex division by zero")

    monkeypatch.setattr(perturb.apps.cli, "_model_from_arg", broken)
    monkeypatch.delenv("PERTURB_DEBUG", raising=False)
    line = _run_inprocess([*FRC, "--omega", "0.6"], capsys, "internal error")
    assert "ZeroDivisionError" in line and "PERTURB_DEBUG=1" in line
    monkeypatch.setenv("PERTURB_DEBUG", "1")
    with pytest.raises(ZeroDivisionError):
        main([*FRC, "--omega", "0.6"])


def test_ctrl_c_is_one_line_and_status_130(monkeypatch, capsys, tmp_path):
    import perturb.apps.cli

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(perturb.apps.cli, "_model_from_arg", interrupted)
    assert main([*FRC, "--out", str(tmp_path / "x.csv")]) == 130
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("perturb: error: interrupted")
    assert "Traceback" not in err and list(tmp_path.iterdir()) == []


def test_signal_handlers_are_restored_after_main(capsys):
    before = signal.getsignal(signal.SIGTERM)
    assert main(["frc", "nosuch"]) == 2
    assert signal.getsignal(signal.SIGTERM) is before
    capsys.readouterr()


# ---------------------------------------------------------------------------------------------
# subprocess + timeout: inputs that once hung or ran away
PARSE_CASES = [
    pytest.param(["fourier", "1e-9999999*x", "--A", "1", "--n", "2"], id="fourier 1e-9999999"),
    pytest.param(
        ["frc", "x'' + 0.1*x' + x + 1e-9999999*x**3 = 0.5*cos(Omega*t)", "--omega", "0.5,1.0"],
        id="frc 1e-9999999 literal",
    ),
    pytest.param(
        ["simulate", "x'' + 0.1*x' + x + x**x**x**x = 0.5*cos(Omega*t)"]
        + ["--param", "Omega=1", "--t", "0:5"],
        id="simulate tower of powers",
    ),
    pytest.param(["fourier", "x**(10**10**10)", "--A", "1", "--n", "2"], id="fourier huge power"),
    pytest.param(["fourier", "(" * 5000 + "x" + ")" * 5000, "--A", "1"], id="deep nesting"),
]


@pytest.mark.parametrize("argv", PARSE_CASES)
def test_hostile_expressions_answered_within_20_s(argv, tmp_path):
    _run_subprocess(argv, tmp_path)


def test_harmonics_10000_and_absurd_scene_refused_in_a_fresh_process(tmp_path):
    # the request that grew to 20.5 GB, and the scene that ran for 33 min
    _run_subprocess([*FRC, "--method", "hb", "--harmonics", "10000"], tmp_path, "H=10000")
    (tmp_path / "s.toml").write_text(SCENES["harmonics.toml"])
    line = _run_subprocess(["run", "s.toml", "--out", "o"], tmp_path, "scene harmonics 1000")
    assert f"at most {MAX_HARMONICS}" in line and not (tmp_path / "o").exists()


@pytest.mark.parametrize(
    "sig, status, word",
    [(signal.SIGTERM, 143, "terminated"), (signal.SIGINT, 130, "interrupted")],
    ids=["SIGTERM", "SIGINT"],
)
def test_signal_exits_promptly_and_leaves_no_partial_output(sig, status, word, tmp_path):
    out = tmp_path / "frc.csv"
    env = dict(os.environ)  # the exact continuation's default: a pool of 2 forked workers
    proc = subprocess.Popen(
        [sys.executable, "-m", "perturb.apps.cli", *FRC, "--method", "exact", "--out", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=tmp_path,
        env=env,
    )
    try:
        time.sleep(4.0)  # imports done, the exact continuation running
        t0 = time.perf_counter()
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=TIMEOUT)
        TIMES[f"{sig.name} to exit"] = time.perf_counter() - t0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == status, err
    lines = [ln for ln in err.splitlines() if not ln.startswith("[perturb]")]
    assert (
        "Traceback" not in err
        and len(lines) == 1
        and lines[0].startswith(f"perturb: error: {word}")
    ), err
    assert TIMES[f"{sig.name} to exit"] < 10.0
    assert list(tmp_path.iterdir()) == []  # neither the CSV nor a temporary file


def test_zz_report_slowest_case():
    """Not a check: prints the slowest case of this module (``pytest -s`` shows it)."""
    if TIMES:
        name, t = max(TIMES.items(), key=lambda kv: kv[1])
        print(f"\n{len(TIMES)} timed hostile cases; slowest {t:.2f} s: {name}")
