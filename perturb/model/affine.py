r"""Piecewise-affine first-order systems: the data the exact n-dimensional propagator takes.

A system of several coordinates whose nonlinear elements are piecewise linear (springs and
dampers with breakpoints, gaps, dead zones, steps) is, in each region of its state space, a
linear ODE with harmonic input,

.. math::

    y' = A_r\, y + b_r + \sum_k \big(u_k \cos \omega_k t + v_k \sin \omega_k t\big),

where the region :math:`r` is fixed by the signs of the switching functions
:math:`s_j(y) = c_j \cdot y - d_j` (a relative displacement past a gap edge, a pressure
below the vacuum level, ...). This module holds only that data, validated; the model layer
builds it from an n-coordinate model, the reference solvers propagate it in closed form.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from types import MappingProxyType

import numpy as np

from perturb.errors import ModelError

__all__ = ["Surface", "HarmonicInput", "AffineRegion", "PiecewiseAffineSystem"]


def _vector(values: Sequence[float], n: int, what: str) -> np.ndarray:
    v = np.array(values, dtype=float)
    if v.shape != (n,):
        raise ModelError(f"{what} has shape {v.shape}, expected ({n},) (one entry per state)")
    if not np.all(np.isfinite(v)):
        raise ModelError(f"{what} = {v.tolist()}: expected finite numbers")
    v.setflags(write=False)
    return v


@dataclass(frozen=True)
class Surface:
    """A switching surface ``s(y) = normal . y - offset = 0``.

    Parameters
    ----------
    normal
        The combination of states the element acts on (``x1 - x2`` is ``(1, -1, 0, 0)`` in
        the state ``(x1, x2, x1', x2')``).
    offset
        Where it switches (a gap's half-width, a breakpoint).
    label
        What it is, for messages (``"gap x1 - x2 = 0.1"``).
    """

    normal: np.ndarray
    offset: float
    label: str = ""

    def value(self, y: np.ndarray) -> np.ndarray:
        """``s(y)`` for one state ``(n,)`` or many ``(m, n)``."""
        return np.asarray(y, dtype=float) @ self.normal - self.offset


@dataclass(frozen=True)
class HarmonicInput:
    """One harmonic input ``u cos(omega t) + v sin(omega t)`` (vectors of length ``n``)."""

    omega: float
    u: np.ndarray
    v: np.ndarray


@dataclass(frozen=True)
class AffineRegion:
    """``y' = A y + b`` (plus the system's harmonic inputs) in one region."""

    A: np.ndarray
    b: np.ndarray


@dataclass(frozen=True)
class PiecewiseAffineSystem:
    """A piecewise-affine first-order system with harmonic inputs.

    Parameters
    ----------
    state_names
        One name per state (``("x1", "x2", "x1'", "x2'")``, ``("p1", "q_i")``).
    surfaces
        The switching surfaces; a region is named by the signs of ``s_j(y)`` (``+1`` for
        ``s_j >= 0``, ``-1`` below), in the order of ``surfaces``.
    regions
        Sign pattern -> :class:`AffineRegion`. Patterns that cannot occur (both edges of one
        gap crossed the same way) may be missing; reaching one is an error.
    inputs
        The harmonic inputs, shared by every region.
    period
        The forcing period (``None`` for an autonomous system).
    continuous
        Whether the vector field is continuous across each surface (no saltation needed).
    """

    state_names: tuple[str, ...]
    surfaces: tuple[Surface, ...]
    regions: Mapping[tuple[int, ...], AffineRegion]
    inputs: tuple[HarmonicInput, ...] = ()
    period: float | None = None
    continuous: tuple[bool, ...] = ()

    @property
    def n(self) -> int:
        """Number of states."""
        return len(self.state_names)

    @classmethod
    def build(
        cls,
        state_names: Sequence[str],
        surfaces: Sequence[tuple[Sequence[float], float] | tuple[Sequence[float], float, str]],
        regions: Mapping[Sequence[int], tuple[Sequence[Sequence[float]], Sequence[float]]],
        inputs: Sequence[tuple[float, Sequence[float], Sequence[float]]] = (),
        period: float | None = None,
    ) -> PiecewiseAffineSystem:
        """Validate plain arrays and build the system (arrays become read-only).

        Raises
        ------
        ModelError
            Mismatched dimensions, non-finite entries, a sign pattern of the wrong length or
            with entries other than +-1, a zero surface normal, or a non-positive period.
        """
        names = tuple(str(s) for s in state_names)
        n = len(names)
        if n == 0:
            raise ModelError("state_names is empty: expected at least one state")
        if len(set(names)) != n:
            raise ModelError(f"state_names = {names}: expected distinct names")
        surf = []
        for j, entry in enumerate(surfaces):
            normal, offset, *rest = entry
            c = _vector(normal, n, f"surface {j} normal")
            if not np.any(c):
                raise ModelError(
                    f"surface {j}: normal is zero, expected a combination of states "
                    "that is not identically zero"
                )
            if not math.isfinite(float(offset)):
                raise ModelError(f"surface {j}: offset = {offset!r}, expected a finite number")
            surf.append(Surface(c, float(offset), str(rest[0]) if rest else f"surface {j}"))
        regs: dict[tuple[int, ...], AffineRegion] = {}
        for pattern, (A, b) in regions.items():
            key = tuple(int(p) for p in pattern)
            if len(key) != len(surf) or any(p not in (-1, 1) for p in key):
                raise ModelError(
                    f"region {tuple(pattern)}: expected a pattern of {len(surf)} signs (+1/-1)"
                )
            Am = np.array(A, dtype=float)
            if Am.shape != (n, n) or not np.all(np.isfinite(Am)):
                raise ModelError(
                    f"region {key}: A has shape {Am.shape}, expected finite ({n}, {n})"
                )
            Am.setflags(write=False)
            regs[key] = AffineRegion(Am, _vector(b, n, f"region {key} b"))
        if not regs:
            raise ModelError("regions is empty: expected at least one region")
        ins = []
        for k, (omega, u, v) in enumerate(inputs):
            if not (math.isfinite(float(omega)) and float(omega) > 0):
                raise ModelError(f"input {k}: omega = {omega!r}, expected a positive frequency")
            ins.append(
                HarmonicInput(
                    float(omega), _vector(u, n, f"input {k} u"), _vector(v, n, f"input {k} v")
                )
            )
        if period is not None and not (math.isfinite(float(period)) and float(period) > 0):
            raise ModelError(f"period = {period!r}: expected a positive number or None")
        cont = []
        for j in range(len(surf)):
            # continuous across surface j when every pair of regions differing only in sign j
            # has the same field on the surface (A_+ y + b_+ = A_- y + b_- for s_j(y) = 0)
            ok = True
            for key, reg in regs.items():
                if key[j] != 1:
                    continue
                other = regs.get(key[:j] + (-1,) + key[j + 1 :])
                if other is None:
                    continue
                dA, db = reg.A - other.A, reg.b - other.b
                c, d = surf[j].normal, surf[j].offset
                # on the surface, y = d c/|c|^2 + (component orthogonal to c): dA must be a
                # multiple of c^T (rank one along c) and dA (d c/|c|^2) + db = 0
                cc = c / float(c @ c)
                along = np.outer(dA @ cc, c)
                scale = max(1.0, float(np.abs(reg.A).max()), float(np.abs(other.A).max()))
                if np.abs(dA - along).max() > 1e-12 * scale or np.abs(
                    dA @ (d * cc) + db
                ).max() > 1e-12 * max(1.0, float(np.abs(reg.b).max())):
                    ok = False
                    break
            cont.append(ok)
        return cls(
            names,
            tuple(surf),
            MappingProxyType(regs),
            tuple(ins),
            None if period is None else float(period),
            tuple(cont),
        )

    def pattern(self, y: np.ndarray) -> tuple[int, ...]:
        """The sign pattern of the region holding state ``y`` (``s_j = 0`` counts as +1)."""
        return tuple(1 if s.value(y) >= 0.0 else -1 for s in self.surfaces)

    def region(self, pattern: tuple[int, ...]) -> AffineRegion:
        """The region of a sign pattern.

        Raises
        ------
        ModelError
            If the pattern names no region of this system.
        """
        try:
            return self.regions[pattern]
        except KeyError:
            raise ModelError(
                f"sign pattern {pattern} of the surfaces "
                f"({', '.join(s.label for s in self.surfaces)}) names no region; expected one "
                f"of {sorted(self.regions)}"
            ) from None

    def field(self, t: float, y: np.ndarray) -> np.ndarray:
        """The vector field ``y'`` at time ``t`` and state ``y`` (for reference integrators)."""
        reg = self.region(self.pattern(y))
        out = reg.A @ y + reg.b
        for h in self.inputs:
            out = out + h.u * math.cos(h.omega * t) + h.v * math.sin(h.omega * t)
        return out
