"""Step control of the pseudo-arclength core: the corrector's work sets the pace.

One object for every continuation in the package: :func:`~perturb.numeric.continuation.
continue_curve` uses it with its ``growth`` and the exact frequency response
(:mod:`perturb.simulate.exact_response`) with its own pace table and an output-spacing cap
(a subclass there), so "halve after a failure, grow after an easy correction, stay within
``[ds_min, ds_max]``" is written once.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

__all__ = ["StepControl"]


class StepControl:
    """Step length along the curve, paced by the corrector's iterations.

    Parameters
    ----------
    step : float
        The first step.
    ds_min, ds_max : float
        Smallest step (a failure below it is an underflow) and the largest one an accepted
        step grows to (unless :meth:`accepted` is given another ``limit``).
    pace : sequence of (int, float or None)
        ``(most iterations, factor)`` rows in increasing order: after an accepted point
        whose correction took ``k`` iterations the step is multiplied by the factor of the
        first row with ``k <= most`` (``None``: left as it is), then kept within
        ``[ds_min, limit]``; beyond the last row it is left as it is.

    Attributes
    ----------
    step : float
        The step to try next.
    """

    def __init__(
        self,
        step: float,
        ds_min: float,
        ds_max: float,
        pace: Sequence[tuple[float, float | None]],
    ) -> None:
        self.step = float(step)
        self.ds_min = float(ds_min)
        self.ds_max = float(ds_max)
        self.pace = tuple(pace)

    @classmethod
    def growing(cls, step: float, ds_min: float, ds_max: float, growth: float) -> StepControl:
        """The pace of :func:`continue_curve`: grow by ``growth`` after at most two
        iterations, keep after three, shrink by 0.7 after more."""
        return cls(step, ds_min, ds_max, ((2, growth), (3, None), (math.inf, 0.7)))

    def factor(self, iterations: int) -> float | None:
        """The pace factor after a correction of ``iterations`` iterations."""
        for most, factor in self.pace:
            if iterations <= most:
                return factor
        return None

    def accepted(self, iterations: int, limit: float | None = None) -> float:
        """Pace the next step after an accepted point; return it.

        ``limit`` caps the grown step (default ``ds_max``); the result is at least
        ``ds_min``."""
        factor = self.factor(iterations)
        if factor is not None:
            cap = self.ds_max if limit is None else limit
            self.step = max(self.ds_min, min(self.step * factor, cap))
        return self.step

    def failed(self) -> bool:
        """Halve the step after a failed or rejected step; False when it fell below
        ``ds_min`` (the continuation cannot go on)."""
        self.step *= 0.5
        return self.step >= self.ds_min
