"""The :class:`Response`: branches of periodic solutions over a frequency range.

Every solver, approximate or exact, returns one, so two responses can be compared point by
point. The CSV columns are fixed (other tools read them)::

    branch, omega, amplitude, first_harmonic_amplitude, mean, stable, max_multiplier, method

``amplitude`` is max over one period of ``|x(t)|``; ``first_harmonic_amplitude`` and ``mean``
(the bias) are reported separately; ``max_multiplier`` is the largest ``|exp(lambda T)|``
over the stability exponents, so it means the same thing for every method.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from perturb.errors import PerturbError

__all__ = ["Branch", "Response", "CSV_COLUMNS", "responses_to_csv"]

#: Column names of :meth:`Response.to_csv`, in order.
CSV_COLUMNS = (
    "branch",
    "omega",
    "amplitude",
    "first_harmonic_amplitude",
    "mean",
    "stable",
    "max_multiplier",
    "method",
)


def _frozen(a: Any, name: str) -> np.ndarray:
    arr = np.array(a, dtype=float if name != "stable" else bool)
    if arr.ndim != 1:
        raise PerturbError(f"branch field {name!r} must be one-dimensional, got shape {arr.shape}")
    if name != "stable" and not np.all(np.isfinite(arr)):
        raise PerturbError(f"branch field {name!r} has non-finite values")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class Branch:
    """One continuous branch of periodic solutions, ordered along the curve."""

    omega: np.ndarray
    amplitude: np.ndarray
    first_harmonic_amplitude: np.ndarray
    mean: np.ndarray
    stable: np.ndarray
    max_multiplier: np.ndarray

    def __post_init__(self) -> None:
        n = None
        for name in (
            "omega",
            "amplitude",
            "first_harmonic_amplitude",
            "mean",
            "stable",
            "max_multiplier",
        ):
            arr = _frozen(getattr(self, name), name)
            if n is None:
                n = arr.size
            elif arr.size != n:
                raise PerturbError(f"branch field {name!r} has {arr.size} points, expected {n}")
            object.__setattr__(self, name, arr)

    def __len__(self) -> int:
        return int(self.omega.size)

    def __repr__(self) -> str:
        if len(self) == 0:
            return "Branch(empty)"
        return (
            f"Branch({len(self)} points, omega {self.omega.min():.4g}..{self.omega.max():.4g}, "
            f"amplitude {self.amplitude.min():.4g}..{self.amplitude.max():.4g}, "
            f"{int(self.stable.sum())} stable)"
        )


@dataclass(frozen=True, eq=False)
class Response:
    """A frequency response: branches plus what produced them."""

    branches: tuple[Branch, ...]
    method: str
    model: str = ""
    params: Mapping[str, float] = field(default_factory=lambda: MappingProxyType({}))
    folds: tuple[tuple[float, float], ...] = ()
    notes: tuple[str, ...] = ()

    def __repr__(self) -> str:
        lines = [
            f"Response of {self.model or 'model'} by {self.method}: {len(self.branches)} branches"
        ]
        lines += [f"  {i}: {b!r}" for i, b in enumerate(self.branches)]
        if self.folds:
            lines.append(
                "  folds at omega = " + ", ".join(f"{w:.6g} (A={a:.6g})" for w, a in self.folds)
            )
        return "\n".join(lines)

    def rows(self) -> list[dict[str, Any]]:
        """One dict per point, keys :data:`CSV_COLUMNS`."""
        out = []
        for i, b in enumerate(self.branches):
            for j in range(len(b)):
                out.append(
                    {
                        "branch": i,
                        "omega": float(b.omega[j]),
                        "amplitude": float(b.amplitude[j]),
                        "first_harmonic_amplitude": float(b.first_harmonic_amplitude[j]),
                        "mean": float(b.mean[j]),
                        "stable": bool(b.stable[j]),
                        "max_multiplier": float(b.max_multiplier[j]),
                        "method": self.method,
                    }
                )
        return out

    def to_csv(
        self, path: str | Path | None = None, extra: Mapping[str, Sequence] | None = None
    ) -> str:
        """Write (and return) the CSV text; ``extra`` adds columns after the standard ones.

        The file is written atomically (:mod:`perturb.atomic`): complete or absent.
        """
        return responses_to_csv((self,), path, extra=extra)

    def plot(self, ax=None, **options):
        """Draw this response (stable solid, unstable dashed) and return the matplotlib Axes.

        Same options as :func:`perturb.report.figures.plot` (``labels``, ``colors``,
        ``title``, ``oscillator``, ``log_amplitude``, ``quantity``, ``legend``); several
        responses on one Axes: :func:`perturb.report.figures.plot` or call ``plot(ax=ax)`` on
        each. matplotlib is imported here, not by ``import perturb``.
        """
        from perturb.report.figures import plot

        return plot(self, ax=ax, **options)


def responses_to_csv(
    responses: Sequence[Response],
    path: str | Path | None = None,
    extra: Mapping[str, Sequence] | None = None,
) -> str:
    """One CSV (columns :data:`CSV_COLUMNS`, then ``extra``) of several responses.

    Branches are numbered through all responses (the second response's first branch follows
    the first's last), and each row's ``method`` says which response it belongs to. ``extra``
    columns have one value per row, in row order. With ``path`` the text is also written, to
    a temporary file renamed onto ``path`` (complete or absent).
    """
    buf = io.StringIO()
    cols = list(CSV_COLUMNS) + list(extra or {})
    writer = csv.DictWriter(buf, fieldnames=cols, lineterminator="\n")
    writer.writeheader()
    k = 0
    offset = 0
    for resp in responses:
        for row in resp.rows():
            for name, values in (extra or {}).items():
                row[name] = values[k]
            row["branch"] = int(row["branch"]) + offset
            row["stable"] = int(row["stable"])
            for key in ("omega", "amplitude", "first_harmonic_amplitude", "mean", "max_multiplier"):
                row[key] = repr(row[key])
            writer.writerow(row)
            k += 1
        offset += len(resp.branches)
    text = buf.getvalue()
    if path is not None:
        from perturb.atomic import write_text

        write_text(path, text)
    return text


def covering_window(targets: Sequence[float]) -> tuple[float, float]:
    """A window 2 % wider than the requested frequencies ``targets`` on both sides, so that a
    branch crossing the extreme ones is traced through them, not stopped on them."""
    lo, hi = min(targets), max(targets)
    return lo * (1 - 0.02), hi * (1 + 0.02)


def polyline_crossings(omega: Sequence[float], targets: Sequence[float]) -> list[tuple[float, int]]:
    """``(target, j)`` for every segment ``j`` of a branch's polyline in Omega that a target
    frequency lies on (a frequency hit exactly by a point counts once)."""
    out = []
    n = len(omega)
    for j in range(max(n - 1, 0)):
        lo, hi = sorted((float(omega[j]), float(omega[j + 1])))
        for w in targets:
            if lo <= w <= hi and not (w == float(omega[j + 1]) and j + 1 < n - 1):
                out.append((w, j))
    return out
