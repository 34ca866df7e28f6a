"""Assemble every ``out/*/section.tex`` into ``out/derivations.tex`` and compile it.

Run the derivation scripts first (each writes ``out/<name>/section.tex``), then::

    python derivations/build.py            # writes and compiles out/derivations.tex
    python derivations/build.py --no-pdf   # only writes the .tex

Exits non-zero when there is no section, when ``pdflatex`` is missing (unless ``--no-pdf``)
or when ``pdflatex`` fails (the end of its log is printed).
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

DEFAULT_ROOT = Path(__file__).resolve().parent / "out"
DOCUMENT = "derivations.tex"

PREAMBLE = r"""\documentclass[11pt]{article}
\usepackage[T1]{fontenc}
\usepackage{amsmath,amssymb}
\usepackage{graphicx}
\usepackage{booktabs}
\usepackage[margin=2.2cm]{geometry}
\allowdisplaybreaks
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


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, default=DEFAULT_ROOT, help="folder of the studies")
    parser.add_argument("--no-pdf", action="store_true", help="write the .tex only")
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
    return 0


if __name__ == "__main__":
    sys.exit(main())
