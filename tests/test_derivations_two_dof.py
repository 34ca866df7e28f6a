"""The two derivation scripts of several coordinates run as a reader runs them (``--fast``),
and their sections compile with the other studies' build script.

* ``derivations/two_dof_nnm_backbone.py``: L-P / mLP backbones of nonlinear normal modes
  against shooting written in the script; every check it states must pass.
* ``derivations/two_dof_internal_resonance.py``: the 1:3 and 1:1 internal-resonance slow flows
  against shooting; the fixed points it checks must agree in stability and lie within the
  first-order error the script reports (``rel_error`` column, O(eps)).

The engines themselves are tested against independent oracles in
``tests/test_system_lindstedt.py`` and ``tests/test_system_averaging.py``; this test keeps the
scripts from rotting (they run nowhere else in CI).
"""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import pytest

DERIVATIONS = Path(__file__).resolve().parents[1] / "derivations"
SCRIPTS = ("two_dof_nnm_backbone", "two_dof_internal_resonance")


def _run(args: list[str]) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, *args], capture_output=True, text=True, timeout=600, check=False
    )


@pytest.mark.slow
def test_scripts_run_their_checks_pass_and_the_document_builds(tmp_path, request):
    for name in SCRIPTS:
        proc = _run([str(DERIVATIONS / f"{name}.py"), "--fast", "--out", str(tmp_path / name)])
        assert proc.returncode == 0, proc.stdout + proc.stderr
        assert (tmp_path / name / "section.tex").is_file()

    summary = json.loads((tmp_path / "two_dof_nnm_backbone" / "summary.json").read_text())
    assert summary["checks"] and all(summary["checks"].values()), summary["checks"]

    for table in ("checks_1_3.csv", "checks_1_1.csv"):
        rows = list(csv.DictReader((tmp_path / "two_dof_internal_resonance" / table).open()))
        assert rows, table
        for r in rows:
            assert r["stable_slow"] == r["stable_orbit"], (table, r)
            # first order in eps = 0.02: a few per cent, worst at a fold (script's own bound)
            assert float(r["rel_error"]) < 0.1, (table, r)

    request.getfixturevalue("pdflatex")  # skips without pdflatex (fails under CI)
    proc = _run([str(DERIVATIONS / "build.py"), "--root", str(tmp_path)])
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert (tmp_path / "derivations.pdf").read_bytes()[:5] == b"%PDF-"
