"""The front doors of the pipeline for an :class:`~perturb.model.Oscillator`.

``frequency_response(osc, method=..., Omega=...)`` answers with any approximation method
(``"hb1"``, ...) or with ``"exact"`` (shooting + continuation on the exact flow); the other
functions are re-exported from the layers that own them.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from .errors import ParameterError
from .methods import METHODS
from .model import Oscillator
from .response import Response

__all__ = ["frequency_response"]


def frequency_response(
    oscillator: Oscillator,
    method: str = "hb1",
    Omega: Sequence[float] = (0.2, 2.0),
    *,
    frequencies: Sequence[float] | None = None,
    **options: Any,
) -> Response:
    """The frequency response of ``oscillator`` by ``method``.

    Parameters
    ----------
    method
        ``"exact"`` or a name in :data:`perturb.methods.METHODS`.
    Omega
        ``(low, high)``.
    frequencies
        Exact frequencies to report instead of a traced curve: every solution found at
        each of them, and no other frequency.
    options
        Passed to the solver.
    """
    if method == "exact":
        from .simulate.continuation import exact_frequency_response, exact_solutions_at

        if frequencies is not None:
            return exact_solutions_at(oscillator, frequencies, **options)
        return exact_frequency_response(oscillator, Omega, **options)
    if method not in METHODS:
        raise ParameterError(
            f"method = {method!r}: expected 'exact' or one of {', '.join(METHODS)}"
        )
    from .numeric.frequency_response import frequency_response as traced
    from .numeric.frequency_response import solutions_at

    approx = METHODS[method](oscillator)
    if frequencies is not None:
        return solutions_at(approx, frequencies, **options)
    return traced(approx, Omega, **options)
