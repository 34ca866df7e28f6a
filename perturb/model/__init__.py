"""The model layer: what the equation is.

- :mod:`perturb.model.oscillator`: :class:`Oscillator` (``x'' + g(x, x', t) = f(t)``), its
  forcing, parameters and the builtin models;
- :mod:`perturb.model.parsing`: the safe parser of equation strings (no ``eval``);
- :mod:`perturb.model.pwl`: the canonical piecewise-linear form of nonsmooth terms.
"""

from perturb.model.oscillator import (
    BUILTIN_MODELS,
    Forcing,
    Harmonic,
    Oscillator,
    builtin_model,
)
from perturb.model.parsing import parse_expression
from perturb.model.pwl import PiecewiseLinear, to_pwl

__all__ = [
    "BUILTIN_MODELS",
    "Forcing",
    "Harmonic",
    "Oscillator",
    "builtin_model",
    "parse_expression",
    "PiecewiseLinear",
    "to_pwl",
]
