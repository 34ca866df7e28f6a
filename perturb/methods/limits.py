"""The measured limits of the symbolic engines (imports nothing heavy).

Shared by :mod:`perturb.methods.applicability` (the engines' own checks) and
:mod:`perturb.methods.registry` (the front ends' checks, before SymPy is loaded).
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType

__all__ = ["ORDER_LIMITS"]

#: Largest expansion order (``lp``, ``mlp``, ``ms``) or number of harmonics in the set
#: (symbolic ``shb``, keyed ``"hb"`` as the engine's own checks name it) accepted, so that no
#: request runs unbounded. Cold derivation times measured on the shared two-core machine
#: (2026-11-27, loaded by other jobs; times vary by ~2x with the load): forced Duffing mLP
#: order 12 2.6 s, 16 15 s, 20 56 s (50 ran past 120 s before this bound); forced Duffing
#: multiple scales order 8 2.4 s, 10 36 s; free quadratic-cubic L-P order 12 3.2 s, 14 15 s,
#: 16 34 s, 20 over 100 s; forced Duffing harmonic balance with the odd harmonics 1..15
#: (8 harmonics) 8.7 s, 1..21 (11) 7.2-13.8 s. Piecewise-linear forces are bounded further by
#: :data:`perturb.methods.lindstedt.PWL_MAX_ORDER` (lp, mlp), order 1 (ms) and one harmonic
#: (shb).
ORDER_LIMITS: Mapping[str, int] = MappingProxyType({"lp": 12, "mlp": 12, "ms": 8, "hb": 11})
