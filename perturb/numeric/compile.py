"""Compile SymPy expressions of an :class:`~perturb.approximation.Approximation` to numpy.

The Fourier-coefficient functions of :mod:`perturb.fourier.symbols` are evaluated with the
stable vectorised forms of :mod:`perturb.fourier.coefficients`; common subexpressions are shared.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
import sympy as sp

from perturb.approximation import Approximation
from perturb.errors import ParameterError
from perturb.fourier.symbols import NUMERIC_IMPLEMENTATIONS

__all__ = ["lambdify", "bind_parameters"]


def lambdify(args: Sequence[sp.Symbol], exprs: Sequence[sp.Expr] | sp.Expr) -> Callable[..., Any]:
    """``sympy.lambdify`` with perturb's Fourier functions and common-subexpression
    elimination. Each output is broadcast to the shape of the inputs."""
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
