"""perturb: periodic responses of nonlinear and piecewise-linear oscillators.

The pipeline is ``Oscillator -> Approximation -> Solver -> Response``; see DESIGN.md.

>>> import perturb
>>> osc = perturb.builtin_model("nsd", k=-2.0)
>>> osc.piecewise_linear().breakpoints
(-1, 1)
"""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

from .errors import (
    FourierError,
    ModelError,
    NonsmoothError,
    ParameterError,
    ParseError,
    PerturbError,
)
from .model import BUILTIN_MODELS, Forcing, Harmonic, Oscillator, builtin_model
from .nonsmooth import PiecewiseLinear, to_pwl
from .parsing import parse_expression

try:
    __version__ = version("perturb")
except PackageNotFoundError:  # running from a source tree that was not installed
    __version__ = "0.1.0+source"

__all__ = [
    "__version__",
    "Oscillator",
    "Forcing",
    "Harmonic",
    "BUILTIN_MODELS",
    "builtin_model",
    "PiecewiseLinear",
    "to_pwl",
    "parse_expression",
    "PerturbError",
    "ParseError",
    "ModelError",
    "ParameterError",
    "NonsmoothError",
    "FourierError",
]
