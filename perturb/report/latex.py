"""LaTeX documents of derivations.

:func:`latex_document` renders an :class:`~perturb.approximation.Approximation` as a standalone
document that reads like the derivation in a paper: the equation, the ansatz, the Fourier
coefficients, the balance equations and the result, one titled step at a time.
"""

from __future__ import annotations

from pathlib import Path

import sympy as sp

from ..approximation import Approximation, Step
from ..printing import latex

__all__ = ["latex_document", "step_latex", "escape"]

_SPECIAL = {
    "\\": r"\textbackslash{}",
    "&": r"\&",
    "%": r"\%",
    "$": r"\$",
    "#": r"\#",
    "_": r"\_",
    "{": r"\{",
    "}": r"\}",
    "~": r"\textasciitilde{}",
    "^": r"\textasciicircum{}",
}


def escape(text: str) -> str:
    """Escape LaTeX's special characters in plain text."""
    return "".join(_SPECIAL.get(c, c) for c in text)


def step_latex(step: Step) -> str:
    """One step as a ``\\subsection*`` with its sentence and an ``align*`` block."""
    out = [f"\\subsection*{{{escape(step.title)}}}"]
    if step.text:
        out.append(escape(step.text))
    if step.math:
        rows = []
        for m in step.math:
            if isinstance(m, sp.Equality):
                rows.append(f"{latex(m.lhs)} &= {latex(m.rhs)}")
            else:
                rows.append(f"&{latex(m)}")
        out.append("\\begin{align*}\n" + " \\\\\n".join(rows) + "\n\\end{align*}")
    return "\n".join(out)


def latex_document(
    approximation: Approximation, path: str | Path | None = None, *, title: str | None = None
) -> str:
    """A standalone LaTeX document of ``approximation``'s derivation.

    Parameters
    ----------
    approximation
        Any method's result.
    path
        If given, the document is also written there.
    title
        Defaults to the method and model names.

    Returns
    -------
    str
        The document text (compiles with ``pdflatex``; packages: fontenc, lmodern,
        amsmath, amssymb, geometry); written atomically when ``path`` is given..
    """
    osc = approximation.oscillator
    title = title or f"{approximation.label} of the {osc.name} oscillator"
    values = ", ".join(
        f"${latex(sp.Symbol(n))} = {val:g}$" for n, val in osc.params.items() if val is not None
    )
    body = "\n\n".join(step_latex(s) for s in approximation.steps)
    doc = "\n".join(
        [
            r"\documentclass[11pt]{article}",
            r"\usepackage[T1]{fontenc}",
            # scalable Type 1 text fonts: T1 with the default Computer Modern falls back to
            # bitmap (Type 3) EC fonts in the PDF
            r"\usepackage{lmodern}",
            r"\usepackage{amsmath,amssymb}",
            r"\usepackage[margin=2cm]{geometry}",
            r"\allowdisplaybreaks",
            r"\begin{document}",
            f"\\section*{{{escape(title)}}}",
            "Derived by perturb."
            + (f" Parameter values used for numbers: {values}." if values else ""),
            body,
            r"\end{document}",
            "",
        ]
    )
    if path is not None:
        from ..atomic import write_text

        write_text(path, doc)  # complete or absent
    return doc
