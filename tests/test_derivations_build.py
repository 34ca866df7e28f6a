"""The combined document: all four derivation scripts in ``--fast`` mode into one root, then
``derivations/build.py --root ROOT`` (as a reader runs it), the ``.tex`` it writes and the PDF
that ``pdflatex`` makes of it.

The scripts run once per session (the ``derivations_fast`` fixture of conftest.py), shared
with the tests of each script; together they take minutes, so this test is marked slow. The
PDF step is skipped without ``pdflatex``, except under CI, where it fails.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

BUILD = Path(__file__).resolve().parents[1] / "derivations" / "build.py"

#: script name -> how its section starts
STUDIES = {
    "course": r"\section{",
    "hydraulic_mount": r"\section{",
    "periodic_solutions": r"\section{",
    "zou_nagarajaiah": r"\section{Zou \& Nagarajaiah",
}


def _build(root: Path, *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, str(BUILD), "--root", str(root), *extra],
        capture_output=True,
        text=True,
        timeout=900,
    )


@pytest.mark.slow
def test_all_four_studies_build_into_one_document(derivations_fast, derivation_module, request):
    for name in STUDIES:
        root = derivations_fast(name)
    proc = _build(root, "--no-pdf")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    tex = (root / "derivations.tex").read_text()
    inputs = re.findall(r"\\input\{([^}]+)\}", tex)
    assert inputs == [f"{name}/section.tex" for name in sorted(STUDIES)]
    for name, start in STUDIES.items():
        section = (root / name / "section.tex").read_text()
        assert section.lstrip().startswith(start), name
        # every file a section names is there, relative to the document
        for rel in re.findall(r"\\(?:includegraphics(?:\[[^]]*\])?|input)\{([^}]+)\}", section):
            assert (root / rel).is_file() or (root / name / rel).is_file(), (name, rel)

    request.getfixturevalue("pdflatex")  # skips without pdflatex (fails under CI)
    proc = _build(root)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    pdf = root / "derivations.pdf"
    assert pdf.read_bytes()[:5] == b"%PDF-"
    assert pdf.stat().st_size > 200_000  # the figures are in it
    # the table of contents lists the four sections, so all four were typeset
    toc = (root / "derivations.toc").read_text(errors="replace")
    assert len(re.findall(r"\\contentsline \{section\}", toc)) == len(STUDIES)
    # the Zou section's own text (not the engine's generated derivation it inputs) fits
    build = derivation_module("build")
    boxes = build.overfull_boxes((root / "derivations.log").read_text(errors="replace"))
    assert not [b for b in boxes if b[0] == "zou_nagarajaiah/section.tex" and b[1] > 5], boxes


def test_overfull_boxes_are_read_from_the_log_per_file(derivation_module):
    """A pdflatex log written by hand: each box is charged to the last .tex file opened
    before it, with its width; boxes before any section belong to the document."""
    build = derivation_module("build")
    log = (
        "Overfull \\hbox (3.5pt too wide) in paragraph at lines 1--2\n"
        "(./course/section.tex [1] <./course/fig.png>\n"
        "Overfull \\hbox (12.25pt too wide) in paragraph at lines 40--41\n"
        ") (./zou_nagarajaiah/section.tex (./zou_nagarajaiah/mlp_order1.tex\n"
        "Overfull \\hbox (5.98412pt too wide) detected at line 78\n"
    )
    boxes = build.overfull_boxes(log)
    assert [(f, w) for f, w, _ in boxes] == [
        ("", 3.5),
        ("course/section.tex", 12.25),
        ("zou_nagarajaiah/mlp_order1.tex", 5.98412),
    ]
    assert boxes[2][2].startswith("Overfull \\hbox (5.98412pt too wide) detected at line 78")


def test_the_document_numbers_its_figures_within_sections(derivation_module):
    """Own figures are "Figure 4.12", never a bare number that reads as a paper's figure."""
    build = derivation_module("build")
    assert "\\numberwithin{figure}{section}" in build.PREAMBLE
