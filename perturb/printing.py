"""LaTeX printing in the notation of the seed papers.

SymPy prints ``Heaviside(x)`` as :math:`\\theta(x)`, which collides with the crossing angle
``theta = arccos(d/A)`` of every PWL derivation; here it is :math:`H(x)`.
"""

from __future__ import annotations

import sympy as sp
from sympy.printing.latex import LatexPrinter

__all__ = ["PerturbLatexPrinter", "latex"]


class PerturbLatexPrinter(LatexPrinter):
    """SymPy's LaTeX printer with ``H(x)`` for ``Heaviside(x)``; the base of the report's
    printer (:class:`perturb.report.layout.DocPrinter`)."""

    def _print_Heaviside(self, expr, exp=None):
        arg = self._print(expr.args[0])
        tex = f"H\\left({arg}\\right)"
        return f"{tex}^{{{exp}}}" if exp else tex


def latex(expr: sp.Basic, **settings) -> str:
    """LaTeX of ``expr`` with perturb's notation (``H`` for Heaviside)."""
    return PerturbLatexPrinter(settings).doprint(expr)
