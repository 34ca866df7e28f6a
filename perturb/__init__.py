"""perturb: periodic responses of nonlinear and piecewise-linear oscillators.

The pipeline is ``Oscillator -> Approximation -> Solver -> Response``; see docs/architecture.md.

>>> import perturb
>>> osc = perturb.builtin_model("nsd", k=-2.0)
>>> osc.piecewise_linear().breakpoints
(-1, 1)
"""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

from perturb.errors import (
    FourierError,
    ModelError,
    NonsmoothError,
    ParameterError,
    ParseError,
    PerturbError,
)
from perturb.model.oscillator import BUILTIN_MODELS, Forcing, Harmonic, Oscillator, builtin_model
from perturb.model.parsing import parse_expression
from perturb.model.pwl import PiecewiseLinear, to_pwl
from perturb.response import Branch, Response
from perturb.solve import frequency_response


def __getattr__(name: str):
    # the reference solvers pull in scipy.integrate; load them on first use (the front
    # door: the search started also from approximations' solutions, perturb.seeds)
    if name == "periodic_orbits":
        from perturb.solve import periodic_orbits

        return periodic_orbits
    if name in ("compare", "relative_errors"):
        from perturb import comparison as _compare

        return getattr(_compare, name)
    if name == "sweep":
        from perturb.apps.grid import sweep

        return sweep
    if name == "time_history":
        from perturb.simulate.time_history import time_history

        return time_history
    if name == "plot":  # matplotlib only when a figure is asked for
        from perturb.report.figures import plot

        return plot
    raise AttributeError(f"module 'perturb' has no attribute {name!r}")


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
    "frequency_response",
    "Response",
    "Branch",
    "periodic_orbits",
    "time_history",
    "compare",
    "relative_errors",
    "plot",
    "sweep",
    "PerturbError",
    "ParseError",
    "ModelError",
    "ParameterError",
    "NonsmoothError",
    "FourierError",
]
