"""Figures: frequency responses with stable branches solid and unstable ones dashed."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..response import Response

__all__ = ["plot_frequency_response"]


def _runs(mask: np.ndarray) -> list[slice]:
    """Contiguous runs of equal values, overlapping by one point so lines join."""
    edges = np.nonzero(np.diff(mask.astype(int)))[0] + 1
    starts = np.concatenate([[0], edges])
    ends = np.concatenate([edges + 1, [mask.size]])
    return [slice(s, min(e, mask.size)) for s, e in zip(starts, ends, strict=True)]


def plot_frequency_response(
    responses: Response | Sequence[Response],
    path: str | Path | None = None,
    *,
    title: str | None = None,
    ax=None,
):
    """Plot one or more responses: amplitude against forcing frequency.

    Stable points are drawn solid, unstable dashed, folds as dots. Returns the figure.
    """
    import matplotlib

    if ax is None:
        matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    items = [responses] if isinstance(responses, Response) else list(responses)
    if ax is None:
        fig, ax = plt.subplots(figsize=(7, 4.5), dpi=120)
    else:
        fig = ax.figure
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for k, resp in enumerate(items):
        color = colors[k % len(colors)]
        first = True
        for br in resp.branches:
            for sl in _runs(br.stable):
                stable = bool(br.stable[sl.start])
                ax.plot(
                    br.omega[sl],
                    br.amplitude[sl],
                    "-" if stable else "--",
                    color=color,
                    lw=1.6 if stable else 1.0,
                    label=resp.method if first else None,
                )
                first = False
        for w, a in resp.folds:
            ax.plot([w], [a], "o", color=color, ms=3)
    ax.set_xlabel(r"forcing frequency $\Omega$")
    ax.set_ylabel(r"amplitude $\max|x|$")
    if title is None and items:
        params = ", ".join(f"{n}={v:g}" for n, v in items[0].params.items() if n != "Omega")
        title = f"{items[0].model}: {params}  (solid stable, dashed unstable)"
    if title:
        ax.set_title(title, fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    if path is not None:
        fig.savefig(path)
    return fig


def plot_time_history(history, path=None, *, title: str | None = None):
    """Time history ``x(t)`` and the phase portrait ``(x, x')`` side by side."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4), dpi=110)
    ax1.plot(history.t, history.x, lw=0.8)
    ax1.set_xlabel("t")
    ax1.set_ylabel("x")
    ax1.grid(alpha=0.3)
    ax2.plot(history.x, history.v, lw=0.6)
    ax2.set_xlabel("x")
    ax2.set_ylabel("x'")
    ax2.grid(alpha=0.3)
    fig.suptitle(title or f"time history ({history.method})", fontsize=8)
    fig.tight_layout()
    if path is not None:
        fig.savefig(path)
    return fig
