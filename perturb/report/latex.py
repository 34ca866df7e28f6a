r"""LaTeX documents of derivations: one writer for every engine.

:func:`latex_document` renders an :class:`~perturb.approximation.Approximation` as a standalone
document that reads like the derivation in a methods paper: a title in words, the settings in a
sentence, the closed forms of the Fourier coefficients it uses (defined before their first
use), then one titled step at a time — the step's sentence (plain text, with mathematics
between ``$`` signs) and its equations, whose terms come in the order a person writes them,
grouped by harmonic and broken over lines to fit the page (:mod:`perturb.report.layout`).
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import sympy as sp
from sympy.core.function import AppliedUndef

from perturb.approximation import Approximation, Step
from perturb.report.layout import TEXT_WIDTH, DocPrinter, equation_rows, tex_width
from perturb.report.notation import (
    coefficient_calls,
    coefficient_definitions,
    document_title,
    escape,
    escape_text,
    settings_sentence,
)

__all__ = [
    "latex_document",
    "derivation_body",
    "step_latex",
    "escape",
    "escape_text",
    "math_latex",
]


def _printer_for(items: Iterable[sp.Basic]) -> tuple[DocPrinter, str]:
    calls = coefficient_calls(items)
    short = len(calls) == 1
    centres = {k[:2] for k in calls}
    by_switch = len(calls) > 1 and len(centres) == 1  # one orbit, several switching points
    printer = DocPrinter(
        {"inv_trig_style": "full"},
        short_coefficients=calls.keys() if short else (),
        by_switch=centres if by_switch else (),
    )
    mode = "short" if short else ("by_switch" if by_switch else "full")
    return printer, coefficient_definitions(calls, printer.doprint, mode)


def _continued(m: sp.Basic) -> bool:
    """A continuation row of an equation split by an older engine (``_Continued(terms)`` or
    the undefined function ``+(terms)``)."""
    if type(m).__name__ == "_Continued":
        return True
    return isinstance(m, AppliedUndef) and type(m).__name__ == "+" and len(m.args) == 1


def math_latex(math: Iterable[sp.Basic], printer: DocPrinter | None = None) -> str:
    """Equations as ``align*`` blocks that fit the page: each equation broken at its
    top-level ``+``/``-`` after collecting its terms by harmonic."""
    items = list(math)
    if printer is None:  # no definitions paragraph: coefficient functions with their argument
        printer = DocPrinter({"inv_trig_style": "full"})
    # rejoin the continuation rows older engines split equations into
    merged: list[sp.Basic] = []
    for m in items:
        if _continued(m) and merged and isinstance(merged[-1], sp.Equality):
            last = merged[-1]
            merged[-1] = sp.Eq(last.lhs, sp.Add(last.rhs, m.args[0]), evaluate=False)
        elif _continued(m):
            merged.append(m.args[0])
        else:
            merged.append(m)
    lefts = [tex_width(printer.doprint(m.lhs)) + 14.8 for m in merged if isinstance(m, sp.Equality)]
    column = max((w for w in lefts if w <= 0.4 * TEXT_WIDTH), default=0.0)
    blocks: list[list[str]] = [[]]
    for m in merged:
        if isinstance(m, sp.Equality):
            rows, own = equation_rows(printer, m.lhs, m.rhs, TEXT_WIDTH, column=column)
        elif isinstance(m, sp.Expr):
            rows, own = equation_rows(printer, None, m, TEXT_WIDTH)
        else:
            rows, own = [f"&{printer.doprint(m)}"], False
        if own:
            blocks.append(rows)
            blocks.append([])
        else:
            blocks[-1].extend(rows)
    return "\n".join(
        "\\begin{align*}\n" + " \\\\\n".join(b) + "\n\\end{align*}" for b in blocks if b
    )


def step_latex(step: Step, printer: DocPrinter | None = None) -> str:
    """One step as a ``\\subsection*`` with its sentence and its equations."""
    out = [f"\\subsection*{{{escape_text(step.title)}}}"]
    if step.text:
        out.append(escape_text(step.text))
    if step.math:
        out.append(math_latex(step.math, printer))
    return "\n".join(out)


def derivation_body(steps: Iterable[Step]) -> str:
    """The steps of a derivation as LaTeX for inclusion in a larger document: the closed
    forms of the Fourier coefficients it uses first, then every step, all printed with one
    :class:`~perturb.report.layout.DocPrinter` (so ``a^R_n`` is written without its argument
    where the derivation uses one argument only and the definitions say so).

    Needs the packages amsmath and amssymb.
    """
    steps = tuple(steps)
    printer, definitions = _printer_for([m for s in steps for m in s.math])
    body = "\n\n".join(step_latex(s, printer) for s in steps)
    return f"{definitions}\n{body}" if definitions else body


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
        Defaults to the method and model in words, e.g. "Second-order modified
        Lindstedt–Poincaré expansion of the negative-stiffness oscillator".

    Returns
    -------
    str
        The document text (compiles with ``pdflatex``; packages: fontenc, lmodern,
        amsmath, amssymb, geometry); written atomically when ``path`` is given.
    """
    osc = approximation.oscillator
    title = title or document_title(approximation.method, approximation.options, osc.name)
    everything = [m for s in approximation.steps for m in s.math]
    printer, _ = _printer_for(everything)
    values = ", ".join(
        f"${printer.doprint(sp.Symbol(n))} = {val:g}$"
        for n, val in osc.params.items()
        if val is not None
    )
    settings = settings_sentence(approximation.options, printer.doprint)
    body = derivation_body(approximation.steps)
    intro = "Derived by perturb."
    if settings:
        intro += " " + settings
    if values:
        intro += f" Parameter values used for numbers: {values}."
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
            # long words and formulas in the text break lines rather than run into the margin;
            # the loose lines that makes are not reported (TeX would print their text, in
            # its own encoding, to the terminal)
            r"\sloppy\hbadness=10000",
            f"\\section*{{{escape_text(title)}}}",
            intro,
            body,
            r"\end{document}",
            "",
        ]
    )
    if path is not None:
        from perturb.atomic import write_text

        write_text(path, doc)  # complete or absent
    return doc
