"""What a method says about its approximation that the numbers do not.

A symbolic engine decorated with :func:`states_caveats` returns its
:class:`~perturb.approximation.Approximation` with ``notes`` filled by :func:`caveats`; the
numeric layer copies them into every response it computes from the approximation
(:func:`perturb.numeric.amplitude.response_notes`) without knowing which method wrote them.
One caveat today:

Even polynomial part under a zero-mean ansatz
    ``kb``, ``vdp``, ``hb1``, the symbolic ``hb`` without bias, and the first order of ``lp``,
    ``mlp`` and ``ms`` assume an orbit centred on ``x = 0``.  They accept a force with an even
    polynomial part (:func:`perturb.methods.applicability.require_centred`), but leave out the
    mean it causes and its effect on the frequency (second order in the amplitude): the note
    says so and names what applies instead.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import replace
from typing import Any

from perturb.approximation import Approximation
from perturb.errors import PerturbError
from perturb.methods.applicability import APPLIES_OFF_CENTRE, even_part

__all__ = ["caveats", "states_caveats"]

#: Methods whose ansatz is centred on x = 0 at every order (without a ``bias`` option).
_ZERO_MEAN_METHODS = ("kb", "vdp", "hb", "hb1")


def caveats(approx: Approximation) -> tuple[str, ...]:
    """The caveats of ``approx`` (module docstring); empty when there is none."""
    zero_mean = not approx.options.get("bias", False) and (
        approx.method in _ZERO_MEAN_METHODS or approx.options.get("order", 1) == 1
    )
    osc = approx.oscillator
    try:
        kinds = even_part(osc) if zero_mean else frozenset()
    except PerturbError:  # pragma: no cover - the method already accepted the model
        kinds = frozenset()
    if "polynomial" not in kinds:
        return ()
    return (
        f"the force of model {osc.name!r} has an even polynomial part: {approx.label} (an "
        "orbit centred on x = 0, to first order) leaves out the mean it causes and its "
        "effect on the frequency (second order in the amplitude); for a strong even part "
        f"use {APPLIES_OFF_CENTRE}",
    )


def states_caveats(engine: Callable[..., Approximation]) -> Callable[..., Approximation]:
    """Decorate a symbolic engine so that its approximation carries :func:`caveats` in
    ``notes`` (after any notes the engine wrote itself).  Signature, name and docstring are
    the engine's (:func:`functools.wraps`)."""

    @functools.wraps(engine)
    def derive(*args: Any, **kwargs: Any) -> Approximation:
        approx = engine(*args, **kwargs)
        extra = caveats(approx)
        return replace(approx, notes=approx.notes + extra) if extra else approx

    return derive
