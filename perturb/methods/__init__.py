"""Symbolic methods: each turns an Oscillator into an Approximation (docs/architecture.md,
the method contract). :data:`METHODS` maps the short names used by scenes and the command
line to them."""

from __future__ import annotations

from collections.abc import Callable
from types import MappingProxyType

from perturb.approximation import Approximation
from perturb.methods.averaging import krylov_bogoliubov, van_der_pol_averaging
from perturb.methods.harmonic_balance import harmonic_balance, single_harmonic_balance
from perturb.methods.lindstedt import lindstedt_poincare
from perturb.methods.modified_lindstedt import modified_lindstedt
from perturb.methods.multiple_scales import multiple_scales

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

#: Short name -> method. ``exact`` is not here: it is a solver, not an approximation.
METHODS: MappingProxyType[str, Callable[..., Approximation]] = MappingProxyType(
    {
        "hb1": single_harmonic_balance,
        "hb": harmonic_balance,
        "kb": krylov_bogoliubov,
        "vdp": van_der_pol_averaging,
        "ms": multiple_scales,
        "lp": lindstedt_poincare,
        "mlp": modified_lindstedt,
    }
)
