"""Symbolic methods: each turns an Oscillator into an Approximation (DESIGN.md, the method
contract). :data:`METHODS` maps the short names used by scenes and the command line to them."""

from __future__ import annotations

from collections.abc import Callable
from types import MappingProxyType

from ..approximation import Approximation
from ..model import Oscillator
from .harmonic_balance import single_harmonic_balance

__all__ = ["METHODS", "single_harmonic_balance"]

#: Short name -> method. ``exact`` is not here: it is a solver, not an approximation.
METHODS: MappingProxyType[str, Callable[[Oscillator], Approximation]] = MappingProxyType(
    {"hb1": single_harmonic_balance}
)
