"""perturb: periodic responses of nonlinear and piecewise-linear oscillators.

The pipeline is ``Oscillator -> Approximation -> Solver -> Response``; see docs/architecture.md.
Every public name loads on first use (module ``__getattr__``), so ``import perturb`` and the
command line's start-up do not import SymPy, SciPy or matplotlib.

>>> import perturb
>>> osc = perturb.builtin_model("nsd", k=-2.0)
>>> osc.piecewise_linear().breakpoints
(-1, 1)
"""

from __future__ import annotations

import importlib
from importlib.metadata import PackageNotFoundError, version

from perturb.errors import (
    FourierError,
    ModelError,
    NonsmoothError,
    ParameterError,
    ParseError,
    PerturbError,
)

#: Public name -> the module that defines it (imported on first use).
_LAZY = {
    "Oscillator": "perturb.model.oscillator",
    "Forcing": "perturb.model.oscillator",
    "Harmonic": "perturb.model.oscillator",
    "BUILTIN_MODELS": "perturb.model.builtins",
    "builtin_model": "perturb.model.builtins",
    "PiecewiseLinear": "perturb.model.pwl",
    "to_pwl": "perturb.model.pwl",
    "parse_expression": "perturb.model.parsing",
    "frequency_response": "perturb.solve",
    "periodic_orbits": "perturb.solve",
    "Response": "perturb.response",
    "Branch": "perturb.response",
    "time_history": "perturb.simulate.time_history",
    "compare": "perturb.comparison",
    "relative_errors": "perturb.comparison",
    "plot": "perturb.report.figures",
    "sweep": "perturb.apps.grid",
}


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'perturb' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # loaded once
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))


try:
    __version__ = version("perturb")
except PackageNotFoundError:  # running from a source tree that was not installed
    __version__ = "0.1.0+source"

__all__ = [
    "__version__",
    *_LAZY,
    "PerturbError",
    "ParseError",
    "ModelError",
    "ParameterError",
    "NonsmoothError",
    "FourierError",
]
