"""The :class:`Approximation`: what every symbolic method returns.

A method (``perturb/methods/<name>.py``) turns an :class:`~perturb.model.oscillator.Oscillator`
into an
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
- ``steps``: the derivation as (title, expression or text) pairs;
- ``notes``: what the method says about this approximation that the numbers do not (e.g. a
  zero-mean ansatz on a force with an even polynomial part), written by the method when it
  derives it (:mod:`perturb.methods.caveats`); every response computed from the
  approximation repeats them in its ``notes``.  Saved with it (JSON and the derivation
  cache, :mod:`perturb.io.serialize`) when there are any.
"""

from __future__ import annotations

import shutil
import textwrap
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import sympy as sp

from perturb.model.oscillator import Oscillator
from perturb.printing import latex

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
    notes: tuple[str, ...] = ()

    @property
    def label(self) -> str:
        opts = ", ".join(f"{k}={v}" for k, v in self.options.items())
        return f"{self.method}({opts})" if opts else self.method

    def __str__(self) -> str:
        return self.summary()

    def summary(self, width: int | None = None, *, limit: int = 4) -> str:
        """A terminal summary: wrapped to ``width`` columns (the terminal's, at most 100)
        and abbreviated.

        An equation that prints in at most ``limit`` lines is shown in full, with the Fourier
        coefficient functions by their short names (``aR_3`` for ``a^R_3``); a longer one
        as one summary line — its number of terms, its symbols, the coefficient functions it
        uses and its harmonics. The full expressions are what ``perturb derive --latex`` and
        ``--json`` write.
        """
        if width is None:
            width = min(shutil.get_terminal_size((100, 24)).columns, 100)
        width = max(int(width), 40)
        printer = _ShortStr(_coefficient_keys(self.residuals + (self.waveform,)))
        lines = _wrap(f"Approximation by {self.label} of {self.oscillator}", width, "    ")
        lines += _wrap("unknowns: " + ", ".join(map(str, self.unknowns)), width, "    ", "  ")
        abbreviated = False
        rows = [(f"equation {k}: 0 = ", r) for k, r in enumerate(self.residuals, 1)]
        rows.append((f"x({self.tau}) = ", self.waveform))
        for label, expr in rows:
            text = printer.doprint(expr)
            wrapped = _wrap(label + text, width, "      ", "  ")
            if len(wrapped) > limit:
                abbreviated = True
                wrapped = _wrap(label + _describe(expr, self.tau), width, "      ", "  ")
            lines += wrapped
        if printer.used:
            lines += _wrap(
                "Fourier coefficients: " + "; ".join(sorted(printer.used)),
                width,
                "    ",
                "  ",
            )
        if abbreviated:
            lines.append("  (abbreviated: --latex FILE or --json FILE writes the full expressions)")
        return "\n".join(lines)

    def _repr_latex_(self) -> str:
        # The residuals and waveform only; perturb.report.latex writes whole documents.
        rows = [latex(r) + " = 0" for r in self.residuals]
        rows.append(f"x({latex(self.tau)}) = {latex(self.waveform)}")
        return "$\\begin{aligned}" + " \\\\ ".join(rows) + "\\end{aligned}$"


# ------------------------------------------------------------------------------------------
# terminal summary
# ------------------------------------------------------------------------------------------
_TAGS = {"StepCoefficient": "aH", "RampCoefficient": "aR", "DiracCoefficient": "adelta"}
_WHAT = {"aH": "H(x - d)", "aR": "(x - d)H(x - d)", "adelta": "delta(x - d)"}


def _coefficient_keys(exprs: tuple[sp.Expr, ...]) -> set[tuple]:
    keys = set()
    for e in exprs:
        for f in e.atoms(sp.Function):
            if type(f).__name__ in _TAGS:
                keys.add(tuple(f.args[1:]))
    return keys


class _ShortStr(sp.printing.str.StrPrinter):
    """SymPy's text printer with the Fourier coefficient functions as ``aR_3`` when the
    expression uses one argument triple ``(A, b, d)``, ``aR_3(d)`` when the triples share
    the orbit ``(A, b)``, ``aR_3(A, b, d)`` otherwise."""

    def __init__(self, keys: set[tuple]) -> None:
        super().__init__()
        self._one = len(keys) == 1
        self._by_d = len(keys) > 1 and len({k[:2] for k in keys}) == 1
        self.used: set[str] = set()

    def _print_Function(self, expr) -> str:
        tag = _TAGS.get(type(expr).__name__)
        if tag is None:
            return super()._print_Function(expr)
        n, A, b, d = (self._print(a) for a in expr.args)
        shift = A + "*cos(psi)" + ("" if expr.args[2] == 0 else f" + {b}")
        of = _WHAT[tag].replace("d", d) if self._one else _WHAT[tag]
        if self._one:
            self.used.add(f"{tag}_n = {tag}_n({shift}; {d}), of {of}")
            return f"{tag}_{n}"
        if self._by_d:
            self.used.add(f"{tag}_n(d) = {tag}_n({shift}; d), of {of}")
            return f"{tag}_{n}({d})"
        self.used.add(f"{tag}_n(A, b, d) of {of} along x = A cos(psi) + b")
        return f"{tag}_{n}({A}, {b}, {d})"


def _wrap(text: str, width: int, indent: str, first: str = "") -> list[str]:
    return textwrap.wrap(
        text,
        width=width,
        initial_indent=first,
        subsequent_indent=indent,
        break_on_hyphens=False,
    ) or [first]


def _describe(expr: sp.Expr, tau: sp.Symbol) -> str:
    """One line about a long expression: terms, symbols, coefficient functions, harmonics."""
    terms = len(sp.Add.make_args(expr))
    names = sorted({s.name for s in expr.free_symbols}, key=str.lower)
    parts = [f"{terms} term" + ("s" if terms != 1 else "")]
    parts.append("in " + ", ".join(names))
    funcs: dict[str, list[int]] = {}
    for f in expr.atoms(sp.Function):
        tag = _TAGS.get(type(f).__name__)
        if tag is not None and f.args[0].is_Integer:
            funcs.setdefault(tag, []).append(int(f.args[0]))
    for tag, ns in sorted(funcs.items()):
        ns = sorted(set(ns))
        parts.append(f"{tag}_n for n = {ns[0]}..{ns[-1]} ({len(ns)} of them)")
    harmonics = set()
    for f in expr.atoms(sp.cos, sp.sin):
        c = f.args[0].as_coefficient(tau) if tau in f.args[0].free_symbols else None
        if c is None:
            for s in f.args[0].free_symbols:
                if s.name in ("psi", "theta", "tau"):
                    c = f.args[0].coeff(s)
        if c is not None and c.is_Integer:
            harmonics.add(abs(int(c)))
    if harmonics:
        hs = sorted(harmonics)
        parts.append(f"harmonics {hs[0]}..{hs[-1]}" if len(hs) > 3 else f"harmonics {hs}")
    parts.append(f"{len(sp.sstr(expr))} characters")
    return "; ".join(parts)
