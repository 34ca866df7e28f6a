"""Symbolic methods: each turns an Oscillator into an Approximation (docs/architecture.md,
the method contract).

:data:`METHODS` maps the short names of the symbolic engines to them; it is derived from the
method registry (:mod:`perturb.methods.registry`, the one home of method names, options and
capabilities), so the two cannot disagree. The engines load on first use (module
``__getattr__``): importing :mod:`perturb.methods` or the registry does not import SymPy.
"""

from __future__ import annotations

import importlib
import sys
from types import MappingProxyType, ModuleType
from typing import Any

__all__ = [
    "METHODS",
    "single_harmonic_balance",
    "harmonic_balance",
    "krylov_bogoliubov",
    "van_der_pol_averaging",
    "multiple_scales",
    "lindstedt_poincare",
    "modified_lindstedt",
]

#: Public engine name -> its module (loaded on first use).
_ENGINES = {
    "single_harmonic_balance": "perturb.methods.harmonic_balance",
    "harmonic_balance": "perturb.methods.harmonic_balance",
    "krylov_bogoliubov": "perturb.methods.averaging",
    "van_der_pol_averaging": "perturb.methods.averaging",
    "multiple_scales": "perturb.methods.multiple_scales",
    "lindstedt_poincare": "perturb.methods.lindstedt",
    "modified_lindstedt": "perturb.methods.modified_lindstedt",
}


def _methods() -> MappingProxyType:
    """Short name -> engine, for every symbolic method of the registry (``exact`` and numeric
    ``hb`` are solvers, not approximations: they are not here)."""
    from perturb.methods.registry import REGISTRY

    return MappingProxyType(
        {name: s.resolve() for name, s in REGISTRY.items() if s.kind == "symbolic"}
    )


def __getattr__(name: str) -> Any:
    if name == "METHODS":
        value = _methods()
    elif name in _ENGINES:
        value = getattr(importlib.import_module(_ENGINES[name]), name)
    else:
        raise AttributeError(f"module 'perturb.methods' has no attribute {name!r}")
    globals()[name] = value  # loaded once
    return value


class _Package(ModuleType):
    """This package, keeping each engine's name for the function: importing the submodule
    ``perturb.methods.harmonic_balance`` (or ``multiple_scales``, ``modified_lindstedt``)
    would otherwise bind the package attribute of the same name to the module, where callers
    expect the function (as when the engines were imported eagerly)."""

    def __setattr__(self, name: str, value: Any) -> None:
        if name in _ENGINES and isinstance(value, ModuleType):
            return
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package
