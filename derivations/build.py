"""Assemble every ``out/*/section.tex`` into ``out/derivations.tex`` and compile it.

Run the derivation scripts first (each writes ``out/<name>/section.tex``), then::

    python derivations/build.py            # writes and compiles out/derivations.tex
    python derivations/build.py --no-pdf   # only writes the .tex

Exits non-zero when there is no section, when ``pdflatex`` is missing (unless ``--no-pdf``)
or when ``pdflatex`` fails (the end of its log is printed). After a successful compile it
prints the overfull boxes of the log, per study; ``--max-overfull PT`` makes any box wider
than PT points an error (exit 4).

Figures and tables are numbered within sections ("Figure 4.12"), so the document's own
numbers cannot be read as the numbers of the papers it reproduces, which the sections cite
by author ("Zou Fig. 12").
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

DEFAULT_ROOT = Path(__file__).resolve().parent / "out"
DOCUMENT = "derivations.tex"

PREAMBLE = r"""\documentclass[11pt]{article}
\usepackage[T1]{fontenc}
\usepackage{lmodern}
\usepackage{amsmath,amssymb}
\usepackage{graphicx}
\usepackage{booktabs}
\usepackage[margin=2.2cm]{geometry}
\allowdisplaybreaks
\setlength{\emergencystretch}{2em}
\numberwithin{figure}{section}
\numberwithin{table}{section}
\title{perturb: derivations checked against the literature}
\author{}
\date{\today}
\begin{document}
\maketitle
\tableofcontents
"""


def sections(root: Path) -> list[Path]:
    """The section fragments under ``root``, in a stable (alphabetical) order."""
    return sorted(root.glob("*/section.tex"))


def document(root: Path, parts: Sequence[Path]) -> str:
    r"""The document text; each part is ``\input`` relative to the document.

    ``\graphicspath`` is set to the part's folder before it is read, so a section may name
    its figures either relative to the document (``name/fig.png``) or by bare file name.
    """
    body = []
    for part in parts:
        rel = part.relative_to(root).as_posix()
        folder = part.parent.relative_to(root).as_posix()
        body.append(f"\\graphicspath{{{{{folder}/}}}}\n\\input{{{rel}}}\n\\clearpage")
    return PREAMBLE + "\n".join(body) + "\n\\end{document}\n"


def compile_pdf(tex: Path, *, max_runs: int = 3, timeout: float = 300.0) -> Path:
    """Run ``pdflatex`` in the document's folder until cross-references settle."""
    exe = shutil.which("pdflatex")
    if exe is None:
        raise FileNotFoundError("pdflatex not found on PATH")
    for run in range(max_runs):
        proc = subprocess.run(
            [exe, "-interaction=nonstopmode", "-halt-on-error", tex.name],
            cwd=tex.parent,
            capture_output=True,
            text=True,
            errors="replace",  # TeX writes file names and messages in its own 8-bit encoding
            timeout=timeout,
        )
        if proc.returncode != 0:
            tail = "\n".join(proc.stdout.splitlines()[-40:])
            raise RuntimeError(f"pdflatex failed on {tex}:\n{tail}")
        # the first run writes the .toc and .aux the later ones read
        if run > 0 and "Rerun to get" not in proc.stdout:
            break
    return tex.with_suffix(".pdf")


_OVERFULL = re.compile(r"Overfull \\hbox \(([0-9.]+)pt too wide\)[^\n]*")
_OPENED = re.compile(r"\(\./([^\s()]+\.tex)")


def overfull_boxes(log: str) -> list[tuple[str, float, str]]:
    """``(file, width in pt, message)`` of every overfull \\hbox in a pdflatex log.

    The file is the last ``.tex`` file the log shows opened (``(./<folder>/<file>.tex``)
    before the message, relative to the document (its first component is the study);
    ``""`` when none was opened yet (the preamble, the title)."""
    out = []
    for m in _OVERFULL.finditer(log):
        opened = _OPENED.findall(log, 0, m.start())
        out.append((opened[-1] if opened else "", float(m.group(1)), m.group(0)))
    return out


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, default=DEFAULT_ROOT, help="folder of the studies")
    parser.add_argument("--no-pdf", action="store_true", help="write the .tex only")
    parser.add_argument(
        "--max-overfull",
        type=float,
        default=None,
        metavar="PT",
        help="fail (exit 4) when a box runs more than PT points into the margin",
    )
    args = parser.parse_args(argv)
    root = args.root.resolve()
    parts = sections(root)
    if not parts:
        print(f"no {root}/*/section.tex: run the derivation scripts first", file=sys.stderr)
        return 1
    tex = root / DOCUMENT
    tex.write_text(document(root, parts))
    print(f"wrote {tex} ({len(parts)} sections: {', '.join(p.parent.name for p in parts)})")
    if args.no_pdf:
        return 0
    if shutil.which("pdflatex") is None:
        print("pdflatex is not installed: cannot build the PDF (use --no-pdf)", file=sys.stderr)
        return 2
    try:
        pdf = compile_pdf(tex)
    except RuntimeError as exc:
        print(exc, file=sys.stderr)
        return 3
    print(f"wrote {pdf}")
    boxes = overfull_boxes(tex.with_suffix(".log").read_text(errors="replace"))
    # pdflatex runs up to three times; the log is the last run's
    by_study: dict[str, list[float]] = {}
    for name, width, _ in boxes:
        by_study.setdefault(name.split("/")[0] if "/" in name else "(document)", []).append(width)
    print(
        f"overfull boxes: {len(boxes)}"
        + "".join(
            f"; {study}: {len(w)} (widest {max(w):.1f} pt)" for study, w in sorted(by_study.items())
        )
    )
    if args.max_overfull is not None:
        wide = [b for b in boxes if b[1] > args.max_overfull]
        if wide:
            for name, _, msg in wide:
                print(f"  {name or '(document)'}: {msg}", file=sys.stderr)
            print(f"{len(wide)} boxes wider than {args.max_overfull:g} pt", file=sys.stderr)
            return 4
    return 0


if __name__ == "__main__":
    sys.exit(main())
