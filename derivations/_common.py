"""Small helpers shared by the derivation scripts (output folder, ``--fast``, CSV and TeX files).

A study writes into its own folder, ``derivations/out/<name>/`` unless ``--out DIR`` says
otherwise. ``build.py`` puts ``derivations.tex`` in the folder above (``--root``), so a section
refers to its own files as ``<folder>/<file>``; :meth:`Study.tex_path` returns that string.
"""

from __future__ import annotations

import argparse
import csv
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

HERE = Path(__file__).resolve().parent
DEFAULT_ROOT = HERE / "out"

__all__ = ["DEFAULT_ROOT", "Study", "study"]


@dataclass(frozen=True)
class Study:
    """Where one study writes, and whether it runs on coarse grids."""

    name: str
    dir: Path
    fast: bool

    def path(self, filename: str) -> Path:
        """A file in this study's folder (the folder is created on first use)."""
        self.dir.mkdir(parents=True, exist_ok=True)
        return self.dir / filename

    def tex_path(self, filename: str) -> str:
        """How ``section.tex`` names one of its files: relative to the assembled document."""
        return f"{self.dir.name}/{filename}"

    def write_csv(
        self, filename: str, header: Sequence[str], rows: Iterable[Sequence[object]]
    ) -> Path:
        """Write a CSV file; floats are written with 17 significant digits (round-trip)."""
        out = self.path(filename)
        with out.open("w", newline="") as fh:
            writer = csv.writer(fh)
            writer.writerow(header)
            for row in rows:
                writer.writerow([f"{v:.17g}" if isinstance(v, float) else v for v in row])
        return out

    def write_section(self, text: str) -> Path:
        """Write ``section.tex`` (a fragment starting with ``\\section{...}``)."""
        out = self.path("section.tex")
        out.write_text(text.strip() + "\n")
        return out


def study(name: str, description: str, argv: Sequence[str] | None = None) -> Study:
    """Parse the common command line (``--fast``, ``--out DIR``) of a derivation script."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument(
        "--fast", action="store_true", help="coarser grids, for tests and quick checks"
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=DEFAULT_ROOT / name,
        help=f"output folder (default: {DEFAULT_ROOT / name}); build.py reads its parent",
    )
    args = parser.parse_args(argv)
    return Study(name=name, dir=args.out.resolve(), fast=args.fast)
