"""The model layer: what the equation is.

- :mod:`perturb.model.oscillator`: :class:`Oscillator` (``x'' + g(x, x', t) = f(t)``), its
  forcing and parameters;
- :mod:`perturb.model.parsing`: the safe parser of equation strings (no ``eval``);
- :mod:`perturb.model.pwl`: the canonical piecewise-linear form of nonsmooth terms;
- :mod:`perturb.model.builtins`: the builtin models as data (no SymPy);
- :mod:`perturb.model.segments`: the closed-form forced steady state of each linear segment;
- :mod:`perturb.model.symmetry`: odd symmetry ``(x, v, t) -> (-x, -v, t + T/2)``;
- :mod:`perturb.model.system`: systems of several coordinates and first-order states
  (builtins in :mod:`perturb.model.system_builtins`);
- :mod:`perturb.model.affine`: piecewise-affine systems of several states.
"""

import importlib

_LAZY = {
    "BUILTIN_MODELS": "perturb.model.builtins",
    "Forcing": "perturb.model.oscillator",
    "Harmonic": "perturb.model.oscillator",
    "Oscillator": "perturb.model.oscillator",
    "builtin_model": "perturb.model.builtins",
    "parse_expression": "perturb.model.parsing",
    "PiecewiseLinear": "perturb.model.pwl",
    "to_pwl": "perturb.model.pwl",
}


def __getattr__(name):
    if name not in _LAZY:
        raise AttributeError(f"module 'perturb.model' has no attribute {name!r}")
    return getattr(importlib.import_module(_LAZY[name]), name)


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
