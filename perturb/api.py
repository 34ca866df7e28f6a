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

__all__ = ["frequency_response", "ALIASES"]


#: Names the command line also accepts (issue 5 spells them this way).
ALIASES = {"mms": "ms", "avg": "kb"}


def frequency_response(
    oscillator: Oscillator,
    method: str = "hb1",
    Omega: Sequence[float] = (0.2, 2.0),
    *,
    frequencies: Sequence[float] | None = None,
    order: int | None = None,
    harmonics: int | None = None,
    **options: Any,
) -> Response:
    """The frequency response of ``oscillator`` by ``method``.

    Parameters
    ----------
    method
        ``"exact"`` (continuation of exact periodic orbits), ``"hb"`` (numeric multi-harmonic
        balance, ``harmonics`` harmonics, exact Galerkin projection for PWL forces),
        ``"auto"`` (the cheapest method that meets ``rtol`` at exact spot checks,
        :func:`perturb.adaptive.auto_frequency_response`; the choice, its estimate and the
        spot-check errors are the first ``notes`` of the response) or a
        symbolic method of :data:`perturb.methods.METHODS` (``"mms"`` and ``"avg"`` are
        accepted for ``"ms"`` and ``"kb"``).
    Omega
        ``(low, high)``.
    frequencies
        Exact frequencies to report instead of a traced curve: every solution found at
        each of them, and no other frequency (not with ``"hb"``).
    order
        Expansion order of the symbolic method (``mlp``, ``ms``, ``lp``).
    harmonics
        Harmonics of ``"hb"`` (default 15).
    options
        Passed to the solver. With ``"auto"``: ``rtol`` (relative amplitude tolerance in
        ``(0, 1)``, default ``1e-3``), ``spots`` / ``n_spots`` (spot-check frequencies),
        ``points``.

    Notes
    -----
    A symbolic approximation whose amplitude equation is a polynomial of degree <= 2 in
    ``Omega**2`` is traced by amplitude parametrisation; any other (second-order modified
    L-P, for instance) by seeding and continuation of its residuals
    (:func:`perturb.numeric.residual_response.residual_response`).
    """
    method = ALIASES.get(method, method)
    if method == "auto":
        from .adaptive import auto_frequency_response, check_rtol

        rtol = check_rtol(options.pop("rtol", 1e-3))
        if frequencies is not None or order is not None or harmonics is not None:
            raise ParameterError(
                "method 'auto' chooses order and harmonics itself over a window Omega=(lo, hi): "
                "give neither frequencies=, order= nor harmonics="
            )
        return auto_frequency_response(oscillator, Omega, rtol, **options)[0]
    if method == "exact":
        from .simulate.continuation import exact_frequency_response, exact_solutions_at

        if frequencies is not None:
            return exact_solutions_at(oscillator, frequencies, **options)
        return exact_frequency_response(oscillator, Omega, **options)
    if method == "hb" and order is None:
        from .numeric.harmonic_balance import harmonic_balance_response

        if frequencies is not None:
            raise ParameterError(
                "method 'hb' traces a branch by continuation: give a window Omega=(lo, hi), "
                "not frequencies="
            )
        return harmonic_balance_response(
            oscillator, Omega, harmonics=15 if harmonics is None else int(harmonics), **options
        )
    if method not in METHODS:
        raise ParameterError(
            f"method = {method!r}: expected 'exact', 'hb' or one of {', '.join(METHODS)} "
            f"(aliases {', '.join(ALIASES)})"
        )
    from .numeric.frequency_response import frequency_response as traced
    from .numeric.frequency_response import solutions_at
    from .numeric.residual_response import residual_response

    method_options: dict[str, Any] = {}
    if order is not None:
        import inspect

        if "order" not in inspect.signature(METHODS[method]).parameters:
            raise ParameterError(f"order = {order!r}: method {method!r} has no expansion order")
        method_options["order"] = int(order)
    approx = METHODS[method](oscillator, **method_options)
    poly = approx.frequency_polynomial
    if poly is None or len(poly) > 3 or approx.slow_flow is None:
        if frequencies is not None:
            raise ParameterError(
                f"{approx.label} is traced by continuation of its residuals: give a window "
                "Omega=(lo, hi), not frequencies="
            )
        # the curve's resolution is set by the continuation step, not by a point count
        options.pop("points", None)
        return residual_response(approx, Omega, **options)
    if frequencies is not None:
        return solutions_at(approx, frequencies, **options)
    return traced(approx, Omega, **options)
