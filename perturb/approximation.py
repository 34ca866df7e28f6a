"""The :class:`Approximation`: what every symbolic method returns.

A method (``perturb/methods/<name>.py``) turns an :class:`~perturb.model.Oscillator` into an
Approximation; the numeric layer compiles it without knowing which method made it. The
contract (docs/architecture.md, "the method contract"):

- ``unknowns``: the symbols solved for (amplitude, phase, bias, ...);
- ``residuals``: algebraic steady-state equations ``residuals == 0`` in the unknowns, the
  forcing frequency and the parameters;
- ``slow_flow``: optional ODEs ``d unknowns / dt = slow_flow`` whose fixed points are the
  steady states (their Jacobian gives stability);
- ``frequency_polynomial``: optional coefficients ``c_0(A), c_1(A), ...`` of
  ``sum_j c_j(A) W**j = 0`` with ``W = Omega**2`` — the phase-eliminated amplitude equation,
  which lets the numeric layer trace every branch by amplitude parametrisation;
- ``waveform``: ``x`` as an expression of the phase variable ``tau = Omega*t`` and the
  unknowns;
- ``backbone``: optional frequency-amplitude relation ``omega(a)`` of the free undamped
  system (Lindstedt–Poincaré, multiple scales, averaging), in the amplitude symbol;
- ``fourier``: the Fourier coefficients the method used, by label;
- ``steps``: the derivation as (title, expression or text) pairs.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import sympy as sp

from .model import Oscillator
from .printing import latex

__all__ = ["Approximation", "Step"]


@dataclass(frozen=True)
class Step:
    """One step of a derivation: a title, an optional sentence, and the mathematics."""

    title: str
    math: tuple[sp.Basic, ...] = ()
    text: str = ""

    def __str__(self) -> str:
        body = "\n".join(f"    {sp.sstr(m)}" for m in self.math)
        return f"{self.title}\n{('  ' + self.text + chr(10)) if self.text else ''}{body}"


@dataclass(frozen=True)
class Approximation:
    """A method's result; see the module docstring for the meaning of each field."""

    oscillator: Oscillator
    method: str
    options: Mapping[str, Any]
    unknowns: tuple[sp.Symbol, ...]
    residuals: tuple[sp.Expr, ...]
    waveform: sp.Expr
    tau: sp.Symbol
    frequency: sp.Symbol
    slow_flow: tuple[sp.Expr, ...] | None = None
    amplitude: sp.Symbol | None = None
    frequency_polynomial: tuple[sp.Expr, ...] | None = None
    phase_from: tuple[sp.Expr, sp.Expr] | None = None
    backbone: sp.Expr | None = None
    fourier: Mapping[str, sp.Expr] = field(default_factory=lambda: MappingProxyType({}))
    steps: tuple[Step, ...] = ()

    @property
    def label(self) -> str:
        opts = ", ".join(f"{k}={v}" for k, v in self.options.items())
        return f"{self.method}({opts})" if opts else self.method

    def __str__(self) -> str:
        lines = [f"Approximation by {self.label} of {self.oscillator}"]
        lines.append("  unknowns: " + ", ".join(map(str, self.unknowns)))
        for r in self.residuals:
            lines.append(f"  0 = {sp.sstr(r)}")
        lines.append(f"  x({self.tau}) = {sp.sstr(self.waveform)}")
        return "\n".join(lines)

    def _repr_latex_(self) -> str:
        # The residuals and waveform only; perturb.report.latex writes whole documents.
        rows = [latex(r) + " = 0" for r in self.residuals]
        rows.append(f"x({latex(self.tau)}) = {latex(self.waveform)}")
        return "$\\begin{aligned}" + " \\\\ ".join(rows) + "\\end{aligned}$"
