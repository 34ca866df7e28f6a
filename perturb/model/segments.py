"""Closed-form forced steady state of each linear segment of a piecewise-linear oscillator.

On segment ``i`` of a piecewise-linear restoring force ``f(x) = s_i x + o_i`` the equation

    x'' + mu x' + s_i x + o_i = c + sum_j F_j cos(w_j t + p_j)

is linear; for ``s_i != 0`` and ``s_i - w_j^2 + i mu w_j != 0`` its unique periodic (forced)
solution is

    x(t) = x_c + Re sum_j Z_j e^{i w_j t},   x_c = (c - o_i) / s_i,
    Z_j = F_j e^{i p_j} / (s_i - w_j^2 + i mu w_j).

It is an orbit of the whole piecewise-linear system exactly when it never leaves the segment
(:attr:`SegmentSteadyState.inside`).  Such orbits are exact periodic solutions, found without
integration: seeds for shooting (:mod:`perturb.simulate.orbits.search`), for numeric harmonic
balance (:mod:`perturb.seeds`), and closed-form points of exact continuation.

Pure numpy (no SymPy): this is the one place the formula is written.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["SegmentSteadyState", "segment_steady_states"]


@dataclass(frozen=True)
class SegmentSteadyState:
    """The forced steady state of one linear segment, as if the segment extended everywhere.

    Attributes
    ----------
    segment
        Index ``i`` of the segment (between ``breakpoints[i-1]`` and ``breakpoints[i]``).
    slope, offset
        ``s_i`` and ``o_i`` of the force ``s_i x + o_i`` on the segment.
    centre
        ``x_c = (c - o_i) / s_i``, the static equilibrium of the segment's force.
    forcing
        The harmonic loads ``(F_j, w_j, p_j)``.
    denominators
        ``s_i - w_j^2 + i mu w_j`` per load (the segment's dynamic stiffness at ``w_j``).
    lower, upper
        The segment's edges (``-inf`` / ``inf`` for the outer segments).
    """

    segment: int
    slope: float
    offset: float
    centre: float
    forcing: tuple[tuple[float, float, float], ...]
    denominators: tuple[complex, ...]
    lower: float
    upper: float

    @property
    def responses(self) -> tuple[complex, ...]:
        """``F_j / (s_i - w_j^2 + i mu w_j)`` per load: the complex amplitude without the
        load's phase (``x = x_c + Re sum_j R_j e^{i (w_j t + p_j)}``)."""
        return tuple(
            F / den for (F, _, _), den in zip(self.forcing, self.denominators, strict=True)
        )

    @property
    def amplitudes(self) -> tuple[complex, ...]:
        """``Z_j = F_j e^{i p_j} / (s_i - w_j^2 + i mu w_j)`` per load: the complex amplitude
        of harmonic ``e^{i w_j t}`` (``x = x_c + Re sum_j Z_j e^{i w_j t}``), i.e. the
        cosine and minus the sine coefficient ``(Re Z_j, -Im Z_j)``."""
        return tuple(
            complex(F * np.exp(1j * ph) / den)
            for (F, _, ph), den in zip(self.forcing, self.denominators, strict=True)
        )

    @property
    def amplitude(self) -> complex:
        """The complex amplitude ``Z`` of a single harmonic load (see :attr:`amplitudes`).

        Raises
        ------
        ValueError
            The system has no or several harmonic loads.
        """
        if len(self.forcing) != 1:
            raise ValueError(
                f"amplitude needs exactly one harmonic load, the system has {len(self.forcing)}"
                ": use amplitudes"
            )
        return self.amplitudes[0]

    @property
    def half_range(self) -> float:
        """Bound on ``|x(t) - x_c|``: ``sum_j |F_j / (s_i - w_j^2 + i mu w_j)|``, exact for one
        load (a bound for several, whose peaks need not coincide)."""
        return float(sum(abs(r) for r in self.responses))

    @property
    def xmin(self) -> float:
        """``x_c - half_range``: the lowest position (a lower bound for several loads)."""
        return self.centre - self.half_range

    @property
    def xmax(self) -> float:
        """``x_c + half_range``: the highest position (an upper bound for several loads)."""
        return self.centre + self.half_range

    @property
    def inside(self) -> bool:
        """True when the steady state stays strictly inside the segment, i.e. it is a periodic
        orbit of the whole piecewise-linear system (for several loads: certainly inside; an
        orbit touching the edges only by the bound's slack is reported as not inside)."""
        return bool(self.lower < self.xmin and self.xmax < self.upper)

    @property
    def margin(self) -> float:
        """Distance from the orbit's range to the nearer segment edge (``> 0``: inside)."""
        return min(self.upper - self.xmax, self.xmin - self.lower)

    def states(self, t: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Position and velocity ``(x, v)`` of the steady state at times ``t``."""
        t = np.asarray(t, dtype=float)
        x = np.full(t.shape, self.centre, dtype=float)
        v = np.zeros(t.shape)
        for (_, w, ph), r in zip(self.forcing, self.responses, strict=True):
            e = r * np.exp(1j * (w * t + ph))
            x = x + e.real
            v = v + (1j * w * e).real
        return x, v


def segment_steady_states(
    breakpoints: ArrayLike,
    slopes: ArrayLike,
    offsets: ArrayLike,
    damping: float,
    forcing: Sequence[tuple[float, float, float]],
    static_force: float = 0.0,
) -> tuple[SegmentSteadyState | None, ...]:
    """The forced steady state of every linear segment of a piecewise-linear oscillator
    ``x'' + mu x' + f(x) = c + sum_j F_j cos(w_j t + p_j)``, ``f(x) = s_i x + o_i`` on
    segment ``i``.

    Parameters
    ----------
    breakpoints : array_like, shape (m,)
        Increasing breakpoints; segment ``i`` lies between ``breakpoints[i-1]`` and
        ``breakpoints[i]``.
    slopes, offsets : array_like, shape (m + 1,)
        ``s_i`` and ``o_i``.
    damping
        ``mu``.
    forcing
        Harmonic loads ``(F_j, w_j, p_j)``.
    static_force
        Constant load ``c``.

    Returns
    -------
    tuple of SegmentSteadyState or None
        One entry per segment; None where the segment has no unique steady state (zero slope,
        or an undamped resonance ``s_i = w_j^2`` with ``mu = 0``).

    Examples
    --------
    The central segment of the negative-stiffness device (``k = -2``) has a saddle orbit
    inside ``|x| < 1``:

    >>> st = segment_steady_states([-1.0, 1.0], [1.0, -2.0, 1.0], [3.0, 0.0, -3.0], 0.05,
    ...                            [(0.5, 0.6, 0.0)])
    >>> st[1].inside, round(abs(st[1].amplitude), 4)
    (True, 0.2118)
    """
    bps = np.asarray(breakpoints, dtype=float).reshape(-1)
    sl = np.asarray(slopes, dtype=float).reshape(-1)
    of = np.asarray(offsets, dtype=float).reshape(-1)
    if sl.size != bps.size + 1 or of.size != bps.size + 1:
        raise ValueError(
            f"{sl.size} slopes and {of.size} offsets for {bps.size} breakpoints: expected "
            f"{bps.size + 1} of each"
        )
    loads = tuple((float(F), float(w), float(ph)) for F, w, ph in forcing)
    mu = float(damping)
    out: list[SegmentSteadyState | None] = []
    for i, (s, o) in enumerate(zip(sl, of, strict=True)):
        s, o = float(s), float(o)
        if s == 0.0:
            out.append(None)
            continue
        dens = tuple(complex(s - w * w, mu * w) for _, w, _ in loads)
        if any(den == 0 for den in dens):
            out.append(None)
            continue
        out.append(
            SegmentSteadyState(
                segment=i,
                slope=s,
                offset=o,
                centre=(float(static_force) - o) / s,
                forcing=loads,
                denominators=dens,
                lower=-math.inf if i == 0 else float(bps[i - 1]),
                upper=math.inf if i == bps.size else float(bps[i]),
            )
        )
    return tuple(out)
