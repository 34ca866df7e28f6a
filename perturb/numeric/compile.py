"""Compile SymPy expressions to numpy: those of an
:class:`~perturb.approximation.Approximation` (:func:`lambdify`), and polynomial forces as
numeric monomial tables (:class:`PolynomialTable`).

The Fourier-coefficient functions of :mod:`perturb.fourier.symbols` are evaluated with the
stable vectorised forms of :mod:`perturb.fourier.coefficients`; common subexpressions are shared.
A polynomial needs no code generation at all: its table of coefficients and exponents is
evaluated by numpy directly (no ``sympy.lambdify``, whose first call in a process also
imports SymPy's code printers: tens of milliseconds per cold process).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import sympy as sp

from perturb.errors import ParameterError

if TYPE_CHECKING:
    from perturb.approximation import Approximation

__all__ = ["lambdify", "bind_parameters", "PolynomialTable", "polynomial_table"]


def lambdify(args: Sequence[sp.Symbol], exprs: Sequence[sp.Expr] | sp.Expr) -> Callable[..., Any]:
    """``sympy.lambdify`` with perturb's Fourier functions and common-subexpression
    elimination. Each output is broadcast to the shape of the inputs."""
    # imported here: the numeric Fourier forms cost a cold process ~20 ms, and the polynomial
    # tables below (numeric harmonic balance) do not need them
    from perturb.fourier.symbols import NUMERIC_IMPLEMENTATIONS

    single = isinstance(exprs, sp.Basic)
    items = [exprs] if single else list(exprs)
    fn = sp.lambdify(args, items, modules=[NUMERIC_IMPLEMENTATIONS, "numpy"], cse=True)

    def call(*values: Any) -> Any:
        shape = np.broadcast_shapes(*(np.shape(v) for v in values)) if values else ()
        with np.errstate(all="ignore"):
            out = [np.broadcast_to(np.asarray(o, dtype=float), shape) for o in fn(*values)]
        return out[0] if single else out

    return call


def bind_parameters(
    approximation: Approximation, exprs: Sequence[sp.Expr], keep: Sequence[sp.Symbol]
) -> list[sp.Expr]:
    """Substitute the oscillator's parameter values into ``exprs``.

    Every parameter other than the symbols in ``keep`` must have a value.

    Raises
    ------
    ParameterError
        Naming the parameters that are still free.
    """
    osc = approximation.oscillator
    keep_set = set(keep)
    values: Mapping[sp.Symbol, Any] = {
        s: val for s, val in osc.substitutions().items() if s not in keep_set
    }
    out = [sp.sympify(e).xreplace(values) for e in exprs]
    free = sorted({s.name for e in out for s in e.free_symbols} - {s.name for s in keep_set})
    if free:
        raise ParameterError(
            f"model {osc.name!r} needs values for {', '.join(free)} to be solved numerically: "
            "pass them as params or --param NAME=VALUE"
        )
    return out


@dataclass(frozen=True)
class PolynomialTable:
    """A polynomial ``p(z_1, ..., z_n) = sum_i c_i prod_j z_j**e_ij`` as numbers.

    Attributes
    ----------
    coefficients : numpy.ndarray, shape (terms,)
    exponents : numpy.ndarray of int, shape (terms, n)
    """

    coefficients: np.ndarray
    exponents: np.ndarray

    def __post_init__(self) -> None:
        c = np.array(self.coefficients, dtype=float).reshape(-1)
        e = np.array(self.exponents, dtype=int).reshape(c.size, -1)
        if not np.all(np.isfinite(c)) or np.any(e < 0):
            raise ParameterError(
                "PolynomialTable: expected finite coefficients and exponents >= 0, got "
                f"{c.tolist()} and {e.tolist()}"
            )
        c.flags.writeable = False
        e.flags.writeable = False
        object.__setattr__(self, "coefficients", c)
        object.__setattr__(self, "exponents", e)

    def __repr__(self) -> str:
        terms = " + ".join(
            f"{c:g}*" + "*".join(f"z{j}**{int(k)}" for j, k in enumerate(row) if k)
            if np.any(row)
            else f"{c:g}"
            for c, row in zip(self.coefficients, self.exponents, strict=True)
        )
        return f"PolynomialTable({terms or '0'})"

    def __call__(self, *values: Any) -> np.ndarray:
        """The polynomial at ``values`` (broadcast together), as a float array."""
        if len(values) != self.exponents.shape[1]:
            raise ParameterError(
                f"PolynomialTable of {self.exponents.shape[1]} variables called with "
                f"{len(values)} values"
            )
        z = [np.asarray(v, dtype=float) for v in values]
        out = np.zeros(np.broadcast_shapes(*(a.shape for a in z)))
        with np.errstate(all="ignore"):
            for c, row in zip(self.coefficients, self.exponents, strict=True):
                term = np.full(out.shape, c)
                for a, k in zip(z, row, strict=True):
                    if k == 1:
                        term = term * a
                    elif k > 1:
                        term = term * a**k
                out = out + term
        return out

    def derivative(self, j: int) -> PolynomialTable:
        """``dp/dz_j`` (exact: exponents and coefficients)."""
        e = self.exponents
        keep = e[:, j] > 0
        new_e = e[keep].copy()
        new_c = self.coefficients[keep] * new_e[:, j]
        new_e[:, j] -= 1
        if not new_c.size:
            return PolynomialTable(np.zeros(1), np.zeros((1, e.shape[1]), dtype=int))
        return PolynomialTable(new_c, new_e)


def polynomial_table(expr: sp.Expr, variables: Sequence[sp.Symbol]) -> PolynomialTable | None:
    """The :class:`PolynomialTable` of ``expr`` in ``variables``, or None when ``expr`` is not
    a polynomial in them with numeric coefficients (a PWL, ``sign`` or any other function of
    them, another free symbol, a coefficient that is not a finite real number)."""
    expr = sp.sympify(expr)
    if expr.free_symbols - set(variables):
        return None
    try:
        poly = sp.Poly(expr, *variables)
    except (sp.PolynomialError, sp.GeneratorsError, sp.CoercionFailed):
        return None
    terms = poly.terms()
    coefficients, exponents = [], []
    for powers, c in terms:
        if not c.is_number:
            return None
        value = complex(c)
        if value.imag != 0.0 or not np.isfinite(value.real):
            return None
        coefficients.append(value.real)
        exponents.append(powers)
    if not coefficients:
        return PolynomialTable(np.zeros(1), np.zeros((1, len(variables)), dtype=int))
    return PolynomialTable(np.array(coefficients), np.array(exponents, dtype=int))
