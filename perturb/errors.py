"""Exceptions raised by :mod:`perturb`.

Every error a user can cause (bad equation text, bad parameter values, a request the
method cannot honour) is a :class:`PerturbError`, with a message that names the offending
value and says what was expected.
"""

from __future__ import annotations

__all__ = [
    "PerturbError",
    "ParseError",
    "ModelError",
    "ParameterError",
    "NonsmoothError",
    "FourierError",
]


class PerturbError(Exception):
    """Base class of every error raised deliberately by perturb."""


class ParseError(PerturbError, ValueError):
    """The text of an equation or expression is malformed or not allowed."""


class ModelError(PerturbError, ValueError):
    """The equation parses but is not an oscillator perturb can handle."""


class ParameterError(PerturbError, ValueError):
    """A parameter value is missing, unknown, not finite or out of range."""


class NonsmoothError(PerturbError, ValueError):
    """A nonsmooth expression cannot be brought to canonical piecewise-linear form."""


class FourierError(PerturbError, ValueError):
    """Fourier coefficients were requested for arguments outside their domain."""
