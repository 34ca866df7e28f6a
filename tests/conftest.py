"""Test-wide settings: the derivation cache lives in a temporary folder, never in ~/.cache.

Shared fixtures: ``compile_tex`` (pdflatex), ``derivation_module`` (a derivation script
imported as a module) and ``derivations_fast`` (the scripts run in ``--fast`` mode, once per
session).
"""

from __future__ import annotations

import importlib.util
import os
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from types import ModuleType

import pytest

# One BLAS thread per test process, set before anything imports numpy: pytest-xdist already
# runs one worker per core, and OpenBLAS threads spinning beside the other worker made a test
# file cost 3x its CPU on a loaded two-core machine (28 s vs 8.2 s for
# tests/test_autonomous_balance.py). Subprocesses of the tests inherit it.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")


@pytest.fixture(autouse=True, scope="session")
def _isolated_cache(tmp_path_factory):
    mp = pytest.MonkeyPatch()
    mp.setenv("PERTURB_CACHE_DIR", str(tmp_path_factory.mktemp("perturb-cache")))
    # the cache's HMAC key lives in the user's config folder: keep the test run out of $HOME
    mp.setenv("XDG_CONFIG_HOME", str(tmp_path_factory.mktemp("perturb-config")))
    mp.setenv("PERTURB_PROGRESS", "0")
    yield
    mp.undo()


# ------------------------------------------------------------------------------------------
# LaTeX and the derivation scripts, shared by tests/test_latex.py and test_derivations_*.py
# ------------------------------------------------------------------------------------------
DERIVATIONS = Path(__file__).resolve().parents[1] / "derivations"


def _pdflatex() -> str:
    exe = shutil.which("pdflatex")
    if exe is None:
        if os.environ.get("CI"):
            pytest.fail("pdflatex is missing in CI: .ci/run must install texlive")
        pytest.skip("pdflatex not installed")
    return exe


@pytest.fixture
def pdflatex() -> str:
    """The ``pdflatex`` executable; skips the test without it, except under CI (``CI`` set),
    where the test fails."""
    return _pdflatex()


@pytest.fixture(scope="session")
def compile_tex() -> Callable[..., Path]:
    """``compile_tex(tex, runs=1)``: run ``pdflatex`` on ``tex`` in its folder and return the
    PDF; the test fails with the end of the log when pdflatex does. Without pdflatex the test
    is skipped, except under CI (``CI`` set), where it fails."""

    def run(tex: Path, runs: int = 1, timeout: float = 300.0) -> Path:
        exe = _pdflatex()
        for _ in range(runs):
            proc = subprocess.run(
                [exe, "-interaction=nonstopmode", "-halt-on-error", tex.name],
                cwd=tex.parent,
                capture_output=True,
                text=True,
                errors="replace",  # TeX writes file names and messages in its own encoding
                timeout=timeout,
            )
            assert proc.returncode == 0, proc.stdout[-3000:]
        pdf = tex.with_suffix(".pdf")
        assert pdf.stat().st_size > 1000
        return pdf

    return run


@pytest.fixture(scope="session")
def derivation_module() -> Callable[[str], ModuleType]:
    """``derivation_module(name)``: ``derivations/<name>.py`` imported (once per session) as
    the module ``derivations_<name>``."""
    loaded: dict[str, ModuleType] = {}

    def load(name: str) -> ModuleType:
        if name not in loaded:
            spec = importlib.util.spec_from_file_location(
                f"derivations_{name}", DERIVATIONS / f"{name}.py"
            )
            module = importlib.util.module_from_spec(spec)
            sys.modules[spec.name] = module  # dataclasses look their module up while built
            spec.loader.exec_module(module)
            loaded[name] = module
        return loaded[name]

    return load


@pytest.fixture(scope="session")
def derivations_fast(tmp_path_factory) -> Callable[[str], Path]:
    """``derivations_fast(name)``: run ``derivations/<name>.py --fast`` once per session (in
    a subprocess) into ``ROOT/<name>/`` and return ROOT, the one folder all studies share, so
    ``derivations/build.py --root ROOT`` assembles every study run so far."""
    root = tmp_path_factory.mktemp("derivations-fast")
    runs: dict[str, subprocess.CompletedProcess] = {}

    def run(name: str) -> Path:
        if name not in runs:
            runs[name] = subprocess.run(
                [sys.executable, str(DERIVATIONS / f"{name}.py"), "--fast"]
                + ["--out", str(root / name)],
                capture_output=True,
                text=True,
                timeout=1800,
            )
        proc = runs[name]
        assert proc.returncode == 0, f"{name}.py --fast failed:\n" + (
            proc.stdout[-2000:] + proc.stderr[-4000:]
        )
        return root

    return run


def pytest_collection_modifyitems(config, items):
    # The suite runs on pytest-xdist workers (pyproject: -n auto --dist loadgroup). A session
    # fixture runs once per worker, so every test that needs the derivation scripts' --fast
    # outputs goes to one worker: the scripts (minutes of CPU) run once, not once per worker.
    for item in items:
        if "derivations_fast" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.xdist_group("derivations"))
