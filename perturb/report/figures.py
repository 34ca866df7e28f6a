"""Figures: frequency responses with stable branches solid and unstable ones dashed.

:func:`plot` overlays any number of :class:`~perturb.response.Response` objects on one
Axes (also :meth:`Response.plot <perturb.response.Response.plot>`): one colour per response,
labelled in words (:func:`method_label`), stable points solid, unstable dashed, folds as
dots, and a legend of proxy entries — one per response plus the "stable" / "unstable" line
styles — so that no legend entry copies the style of whichever segment happened to come
first. :func:`plot_frequency_response` does the same and saves the figure.

matplotlib is imported inside the functions: ``import perturb`` does not need it.
"""

from __future__ import annotations

import re
import textwrap
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

#: A :class:`~perturb.response.Response` (or anything with its ``branches``, ``method``,
#: ``model`` and ``params``).  Not imported: ``Response.plot`` imports this module (the
#: response layer's one upward import, listed in pyproject's ``ignore_imports``), and importing
#: Response here would close a circle; figures recognise a response by its fields instead.
Response = Any


def _is_response(obj: object) -> bool:
    """Whether ``obj`` is one response (not a sequence of them)."""
    return hasattr(obj, "branches") and hasattr(obj, "method")


__all__ = [
    "plot",
    "plot_frequency_response",
    "frequency_response_figure",
    "plot_time_history",
    "method_label",
    "equation_title",
    "mathtext_safe",
]

#: Parameter names printed as Greek letters in titles.
_GREEK = {
    "mu": r"\mu",
    "Omega": r"\Omega",
    "omega": r"\omega",
    "omega0": r"\omega_0",
    "alpha": r"\alpha",
    "alpha2": r"\alpha_2",
    "alpha3": r"\alpha_3",
    "eps": r"\varepsilon",
    "epsilon": r"\varepsilon",
    "delta": r"\delta",
    "zeta": r"\zeta",
    "gamma": r"\gamma",
    "beta": r"\beta",
    "lambda": r"\lambda",
    "lam": r"\lambda",
    "k1": "k_1",
    "k2": "k_2",
}

_SYMBOLIC = {
    "hb1": "single-harmonic balance",
    "hb": "harmonic balance (symbolic)",
    "kb": "Krylov–Bogoliubov averaging",
    "vdp": "van der Pol averaging",
    "multiple_scales": "multiple scales",
    "ms": "multiple scales",
    "mlp": "modified Lindstedt–Poincaré",
    "lp": "Lindstedt–Poincaré",
}


def method_label(method: str) -> str:
    """``Response.method`` in words, for legends.

    >>> method_label("numeric HB H=15 exact")
    'numeric harmonic balance, 15 harmonics (exact Galerkin projection)'
    >>> method_label("hb1(harmonics=1)")
    'single-harmonic balance'
    >>> method_label("exact")
    'exact periodic orbits'
    """
    m = method.strip()
    if m == "exact" or m.startswith("exact "):
        return "exact periodic orbits"
    hb = re.fullmatch(r"numeric HB H=(\d+)( odd)?(?: m=(\d+))? (exact|AFT\d*)", m)
    if hb:
        h, odd, sub, proj = hb.groups()
        text = f"numeric harmonic balance, {h} harmonic{'s' if h != '1' else ''}"
        if odd:
            text += " (odd only)"
        if sub:
            text += f", period {sub}T"
        if proj == "exact":
            text += " (exact Galerkin projection)"
        else:
            n = proj[3:]
            text += f" (AFT, {n} samples)" if n else " (AFT)"
        return text
    sym = re.fullmatch(r"([A-Za-z_0-9]+)(?:\((.*)\))?", m)
    if sym and sym.group(1) in _SYMBOLIC:
        name, opts = sym.group(1), sym.group(2) or ""
        text = _SYMBOLIC[name]
        order = re.search(r"\border=(\d+)", opts)
        if order and name not in ("hb1", "hb"):
            text += f", order {order.group(1)}"
        if name == "hb":
            harm = re.search(r"\bharmonics=(\d+)", opts)
            if harm:
                text = f"symbolic harmonic balance, {harm.group(1)} harmonics"
            if "bias=True" in opts:
                text += " with bias"
        return text
    return m


def mathtext_safe(text: str) -> str:
    """Plain text that matplotlib prints as is (``$`` would start mathtext)."""
    return text.replace("\\", "/").replace("$", r"\$")


def _renders(tex: str) -> bool:
    """Whether matplotlib's mathtext parses ``tex`` (one ``$...$`` span)."""
    try:
        from matplotlib.mathtext import MathTextParser

        MathTextParser("path").parse(tex)
    except Exception:  # any parse failure: use the plain fallback
        return False
    return True


def param_tex(name: str) -> str:
    """Matplotlib mathtext of a parameter name: Greek names as letters, a trailing number as
    a subscript (``zeta1`` -> ``\\zeta_{1}``), any other name upright with ``_`` escaped."""
    if name in _GREEK:
        return _GREEK[name]
    if re.fullmatch(r"[A-Za-z]", name):
        return name
    head = re.fullmatch(r"([A-Za-z]+)(\d+)", name)
    if head and head.group(1) in _GREEK:
        return f"{_GREEK[head.group(1)]}_{{{head.group(2)}}}"
    if head:
        return f"{head.group(1)}_{{{head.group(2)}}}"
    return r"\mathrm{" + name.replace("_", r"\_") + "}"


def _params_text(params: Mapping[str, float], skip=("Omega",)) -> str:
    parts = []
    for n, v in params.items():
        if n in skip or v is None:
            continue
        try:
            val = f"{float(v):g}"
        except (TypeError, ValueError):
            continue
        parts.append(f"{param_tex(n)} = {val}")
    if not parts:
        return ""
    tex = "$" + r",\ ".join(parts) + "$"
    if _renders(tex):
        return tex
    return mathtext_safe(", ".join(f"{n}={v:g}" for n, v in params.items() if n not in skip))


def _equation_tex(oscillator) -> str | None:
    """The equation of motion as mathtext (``\\ddot x``, ``\\mu``, ``H(\\cdot)``), or None."""
    import sympy as sp

    from perturb.printing import latex

    try:
        eq = oscillator.equation
        x, v = oscillator.x, oscillator.v
        acc = next(
            (s for s in eq.lhs.free_symbols if getattr(s, "name", "") == f"{x.name}''"), None
        )
        names = {s: param_tex(s.name) for s in eq.free_symbols if s.name in _GREEK}
        names[x] = "x"
        names[v] = r"\dot{x}"
        if acc is not None:
            names[acc] = r"\ddot{x}"
        terms = list(sp.Add.make_args(eq.lhs))

        def rank(term) -> int:
            syms = term.free_symbols
            if acc is not None and acc in syms:
                return 0
            if v in syms:
                return 1
            return 2

        terms.sort(key=rank)
        parts = []
        for i, term in enumerate(terms):
            tex = latex(term, symbol_names=names)
            if i and not tex.startswith("-"):
                tex = "+ " + tex
            parts.append(tex)
        lhs = " ".join(parts)
        rhs = latex(eq.rhs, symbol_names=names)
    except Exception:  # an equation the printer cannot take apart: plain text instead
        return None
    tex = f"${lhs} = {rhs}$".replace(r"\left(", "(").replace(r"\right)", ")")
    tex = tex.replace(r"\cos{(", r"\cos(").replace(r"\sin{(", r"\sin(")
    tex = re.sub(r"\\(cos|sin)\((.*?) \)}", r"\\\1(\2)", tex)
    return tex if _renders(tex) else None


def equation_title(
    oscillator=None,
    params: Mapping[str, float] | None = None,
    *,
    model: str = "",
    width: int = 95,
    skip: Sequence[str] = ("Omega",),
) -> str:
    """A figure title: the equation of motion (mathtext) and the parameter values.

    Falls back to the model name, then to shortened plain text, when the equation is too
    long for one line or does not parse as mathtext; never a bare ``custom:``. Parameters
    named in ``skip`` (default the forcing frequency, the axis of a frequency response) are
    left out.
    """
    lines: list[str] = []
    if oscillator is not None:
        tex = _equation_tex(oscillator)
        # mathtext cannot be wrapped: a long equation is shown as shortened plain text
        plain_len = len(re.sub(r"\\[A-Za-z]+|[{}$^_]", "", tex or ""))
        if tex is not None and plain_len <= width + 20:
            lines.append(tex)
        else:
            eq = str(oscillator.equation.lhs) + " = " + str(oscillator.equation.rhs)
            eq = textwrap.shorten(eq, width=width, placeholder=" …")
            lines.append(mathtext_safe(eq))
        if params is None:
            params = {k: v for k, v in oscillator.params.items() if v is not None}
        if not model:
            model = oscillator.name
    elif model:
        lines.append(mathtext_safe(model))
    p = _params_text(params or {}, skip=tuple(skip))
    if p:
        head = model if oscillator is not None and not model.startswith("custom") else ""
        lines.append(f"{mathtext_safe(head)}: {p}" if head else p)
    return "\n".join(lines)


def _runs(mask: np.ndarray) -> list[slice]:
    """Contiguous runs of equal values, overlapping by one point so lines join."""
    edges = np.nonzero(np.diff(mask.astype(int)))[0] + 1
    starts = np.concatenate([[0], edges])
    ends = np.concatenate([edges + 1, [mask.size]])
    return [slice(s, min(e, mask.size)) for s, e in zip(starts, ends, strict=True)]


def _default_title(items: Sequence[Response]) -> str:
    if not items:
        return ""
    r = items[0]
    model = r.model or ""
    try:
        from perturb.model.builtins import BUILTIN_MODELS, builtin_model

        if model in BUILTIN_MODELS:
            params = {k: v for k, v in r.params.items() if k != "Omega"}
            return equation_title(builtin_model(model, **params), params)
    except Exception:  # unknown parameter names and the like: the plain title below
        pass
    custom = not model or model.startswith("custom")
    head = "frequency response" if custom else mathtext_safe(model)
    p = _params_text(r.params)
    return f"{head}: {p}" if p else head


def plot(
    *responses: Response,
    ax=None,
    labels: Sequence[str | None] | None = None,
    colors: Sequence[str | None] | None = None,
    linewidths: Sequence[float | None] | None = None,
    title: str | None = None,
    oscillator=None,
    log_amplitude: bool = False,
    quantity: str = "amplitude",
    legend: bool = True,
    legend_kw: Mapping | None = None,
):
    """Overlay frequency responses on one Axes and return the Axes.

    Parameters
    ----------
    *responses : Response
        Each gets one colour; stable points solid, unstable dashed, folds as dots.
    ax : matplotlib Axes, optional
        Drawn into; a new figure otherwise.
    labels : sequence of str, optional
        Legend text per response (default :func:`method_label` of its ``method``).
    colors, linewidths : sequence, optional
        Per response (``None`` entries take the default).
    title : str, optional
        Default: the equation of motion (with ``oscillator``) or the model and its
        parameters; ``""`` for none.
    oscillator : Oscillator, optional
        Used for the title.
    log_amplitude : bool
        Logarithmic amplitude axis (responses spanning decades).
    quantity : {'amplitude', 'first_harmonic_amplitude', 'mean'}
        The plotted column.
    legend : bool
        Draw the legend: one entry per response, then the "stable" / "unstable" keys.
    """
    import matplotlib

    if ax is None:
        matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    items: list[Response] = []
    for r in responses:
        if _is_response(r):
            items.append(r)
        else:  # a list of responses passed as one argument
            items.extend(r)
    if quantity not in ("amplitude", "first_harmonic_amplitude", "mean"):
        raise ValueError(f"quantity = {quantity!r}: expected amplitude, first_harmonic_amplitude")
    if ax is None:
        _fig, ax = plt.subplots(figsize=(8, 5.2), dpi=120, layout="constrained")
    palette = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    handles = []
    for k, resp in enumerate(items):
        color = (colors[k] if colors and k < len(colors) else None) or palette[k % len(palette)]
        lw = (linewidths[k] if linewidths and k < len(linewidths) else None) or 1.4
        label = labels[k] if labels and k < len(labels) and labels[k] else None
        label = label or method_label(resp.method)
        for br in resp.branches:
            y = getattr(br, quantity)
            for sl in _runs(br.stable):
                stable = bool(br.stable[sl.start])
                ax.plot(
                    br.omega[sl],
                    y[sl],
                    ls="-" if stable else (0, (4, 2.5)),
                    color=color,
                    lw=lw if stable else 0.75 * lw,
                )
        if quantity == "amplitude":
            for w, a in resp.folds:
                ax.plot([w], [a], "o", color=color, ms=3.5, mew=0)
        handles.append(Line2D([], [], color=color, lw=lw, label=label))
    if items:
        handles.append(Line2D([], [], color="0.25", lw=1.4, ls="-", label="stable"))
        handles.append(Line2D([], [], color="0.25", lw=1.0, ls=(0, (4, 2.5)), label="unstable"))
        if quantity == "amplitude" and any(r.folds for r in items):
            handles.append(
                Line2D([], [], color="0.25", ls="", marker="o", ms=3.5, mew=0, label="fold")
            )
    ax.set_xlabel(r"forcing frequency $\Omega$")
    ylabel = {
        "amplitude": r"amplitude $\max\,|x|$",
        "first_harmonic_amplitude": r"first-harmonic amplitude",
        "mean": r"mean $\bar{x}$",
    }[quantity]
    ax.set_ylabel(ylabel)
    if log_amplitude and quantity != "mean":
        ax.set_yscale("log")
    if title is None:
        title = (
            equation_title(oscillator, items[0].params if items else None)
            if oscillator is not None
            else _default_title(items)
        )
    if title:
        ax.set_title(title, fontsize=9)
    ax.grid(alpha=0.3, which="both" if log_amplitude else "major")
    if legend and handles:
        kw = {"fontsize": 7.5, "loc": "best", "framealpha": 0.9}
        kw.update(legend_kw or {})
        ax.legend(handles=handles, **kw)
    return ax


def plot_frequency_response(
    responses: Response | Sequence[Response],
    path: str | Path | None = None,
    *,
    title: str | None = None,
    ax=None,
    **options,
):
    """Plot one or more responses (:func:`plot`) and save to ``path``; returns the figure.

    The file is written atomically (:mod:`perturb.atomic`): complete or absent.
    """
    items = [responses] if _is_response(responses) else list(responses)
    ax = plot(*items, ax=ax, title=title, **options)
    fig = ax.figure
    if path is not None:
        save_figure(fig, path)
    return fig


def frequency_response_figure(
    responses: Sequence[Response],
    path: str | Path | None = None,
    *,
    title: str | None = None,
    zoom: Sequence[float] | None = None,
    mean: bool = False,
    **options,
):
    """The frequency response with optional side panels; saved to ``path``, returns the figure.

    Parameters
    ----------
    responses : sequence of Response
    zoom : (omega_lo, omega_hi, amplitude_lo, amplitude_hi), optional
        A panel below enlarging this rectangle (where many branches crowd).
    mean : bool
        A panel below with the mean ``x̄`` of each orbit, which tells asymmetric orbits (and
        their mirror images) from symmetric ones, whose amplitudes coincide.
    options
        Of :func:`plot` (``labels``, ``colors``, ``linewidths``, ``log_amplitude``,
        ``legend_kw``, ``oscillator``).
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    items = list(responses)
    lower = [name for name, on in (("zoom", zoom is not None), ("mean", mean)) if on]
    if not lower:
        return plot_frequency_response(items, path, title=title, **options)
    fig, axes = plt.subplot_mosaic(
        [["main"] * len(lower), lower],
        figsize=(8.5, 8.0),
        dpi=120,
        height_ratios=[1.75, 1.0],
        layout="constrained",
    )
    plot(*items, ax=axes["main"], title=title, **options)
    quiet = {k: v for k, v in options.items() if k not in ("legend_kw", "log_amplitude")}
    if zoom is not None:
        w0, w1, a0, a1 = (float(v) for v in zoom)
        az = axes["zoom"]
        plot(*items, ax=az, title="", legend=False, **quiet)
        az.set_xlim(w0, w1)
        az.set_ylim(a0, a1)
        az.set_title(f"enlarged: $\\Omega$ in [{w0:g}, {w1:g}]", fontsize=8)
        axes["main"].indicate_inset((w0, a0, w1 - w0, a1 - a0), edgecolor="0.4", alpha=0.8)
    if mean:
        am = axes["mean"]
        plot(*items, ax=am, title="", legend=False, quantity="mean", **quiet)
        am.set_title(
            "mean: 0 for symmetric orbits, $\\pm$ for an asymmetric pair",
            fontsize=8,
        )
    if path is not None:
        save_figure(fig, path)
    return fig


def save_figure(fig, path: str | Path) -> None:
    """``fig.savefig(path)`` through a temporary file renamed onto ``path``."""
    from perturb.atomic import atomic_path

    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=Path(path).suffix.lstrip(".").lower() or "png")


def plot_time_history(history, path=None, *, title: str | None = None):
    """Time history ``x(t)`` and the phase portrait ``(x, x')`` side by side."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4), dpi=110, layout="constrained")
    ax1.plot(history.t, history.x, lw=0.8)
    ax1.set_xlabel("$t$")
    ax1.set_ylabel("$x$")
    ax1.grid(alpha=0.3)
    ax2.plot(history.x, history.v, lw=0.6)
    ax2.set_xlabel("$x$")
    ax2.set_ylabel(r"$\dot{x}$")
    ax2.grid(alpha=0.3)
    if title is None:
        title = f"time history ({history.method})"
    elif "$" not in title:
        title = "\n".join(textwrap.wrap(mathtext_safe(title), 130))
    fig.suptitle(title, fontsize=8)
    if path is not None:
        save_figure(fig, path)
    return fig
