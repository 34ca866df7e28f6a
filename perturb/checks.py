"""Argument validation: one helper per kind of value, for the Python API, the command line,
scenes and grid sweeps.

Each helper returns the value in its canonical type or raises
:class:`~perturb.errors.ParameterError` with a message that names the value (``what``) and
says what was expected. The module sits in the base layer (it imports only the standard
library and :mod:`perturb.errors`), so the command line can validate its flags before any
heavy import.

``parse_number``
    Text typed by a user -> a finite float, refusing literals that silently underflow
    (``1e-5000`` -> 0) or land below the smallest normal double.
``finite``
    A number -> a finite float.
``whole``
    A whole number within ``[low, high]`` (limits of bounded work).
``window``
    ``(low, high)`` with ``0 < low < high`` (frequency windows).
``frequencies``
    A non-empty list of positive finite frequencies, at most ``limit`` of them.
"""

from __future__ import annotations

import dataclasses
import math
import re
import sys
from collections.abc import Sequence
from typing import Any

from perturb.errors import ParameterError

__all__ = ["parse_number", "finite", "whole", "window", "frequencies"]


def parse_number(text: str, what: str) -> float:
    """``text`` as a finite float that is not an underflow of a nonzero literal to 0 or to a
    subnormal value (``1e-5000`` would otherwise silently become 0).

    Parameters
    ----------
    text
        The typed text (nothing is evaluated: only :func:`float` reads it).
    what
        How the message names the value, e.g. ``"--omega '1e-5000:1'"``.

    Raises
    ------
    ParameterError
        Naming ``what``.
    """
    text = str(text).strip()
    try:
        value = float(text)
    except ValueError:
        raise ParameterError(f"{what}: {text!r} is not a number; expected a number") from None
    if not math.isfinite(value):
        raise ParameterError(f"{what}: expected a finite number, got {text!r}")
    mantissa = re.split(r"[eE]", text)[0]
    if value == 0.0 and re.search(r"[1-9]", mantissa):
        raise ParameterError(
            f"{what}: {text!r} underflows to 0 in double precision; expected 0 or a number of "
            f"magnitude >= {sys.float_info.min:.3g}"
        )
    if value != 0.0 and abs(value) < sys.float_info.min:
        raise ParameterError(
            f"{what}: {text!r} is below the smallest normal double {sys.float_info.min:.3g}"
        )
    return value


def finite(value: Any, what: str) -> float:
    """``value`` (a real number, not a bool and not text) as a finite float.

    Raises
    ------
    ParameterError
        Naming ``what``.
    """
    if isinstance(value, bool | str):
        raise ParameterError(f"{what} = {value!r}: expected a finite real number")
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise ParameterError(f"{what} = {value!r}: expected a finite real number") from None
    if not math.isfinite(out):
        raise ParameterError(f"{what} = {value!r}: expected a finite real number")
    return out


def whole(value: Any, what: str, low: int, high: int, why: str = "") -> int:
    """``value`` as an int in ``[low, high]`` (a float that is a whole number is accepted).

    Parameters
    ----------
    why
        The reason for ``high``, added to the message when the value exceeds it.

    Raises
    ------
    ParameterError
        Naming ``what`` and the limit.
    """
    ok = not isinstance(value, bool) and _is_real(value)
    if not ok or not math.isfinite(float(value)) or float(value) != int(value):
        raise ParameterError(f"{what} = {value!r}: expected a whole number from {low} to {high}")
    value = int(value)
    if value < low:
        raise ParameterError(f"{what} = {value}: expected at least {low}")
    if value > high:
        reason = f" ({why})" if why else ""
        raise ParameterError(f"{what} = {value}: expected at most {high}{reason}")
    return value


def window(value: Any, what: str = "Omega", *, positive: bool = True) -> tuple[float, float]:
    """``value`` as a window ``(low, high)`` of finite numbers with ``low < high`` (and
    ``0 < low`` unless ``positive=False``: a frequency window is positive, a continuation
    parameter's need not be).

    Raises
    ------
    ParameterError
        Naming ``what`` and the bad value.
    """
    if isinstance(value, str | bytes):
        raise ParameterError(f"{what} = {value!r}: expected two numbers (low, high)")
    try:
        lo, hi = (float(w) for w in value)
    except (TypeError, ValueError):
        raise ParameterError(f"{what} = {value!r}: expected two numbers (low, high)") from None
    if positive and not (math.isfinite(lo) and math.isfinite(hi) and 0.0 < lo < hi):
        raise ParameterError(f"{what} = ({lo}, {hi}): expected 0 < low < high, both finite")
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise ParameterError(f"{what} = ({lo}, {hi}): expected finite low < high")
    return lo, hi


def frequencies(values: Any, limit: int, what: str = "frequencies") -> list[float]:
    """``values`` as a non-empty list of positive finite frequencies, at most ``limit``.

    Raises
    ------
    ParameterError
        Naming ``what``.
    """
    if isinstance(values, str | bytes):
        raise ParameterError(f"{what} = {values!r}: expected a sequence of positive numbers")
    try:
        out = [float(w) for w in values]
    except (TypeError, ValueError):
        raise ParameterError(
            f"{what} = {values!r}: expected a sequence of positive numbers"
        ) from None
    if not out or not all(math.isfinite(w) and w > 0 for w in out):
        raise ParameterError(f"{what} = {out!r}: expected positive finite forcing frequencies")
    if len(out) > limit:
        raise ParameterError(f"{what}: {len(out)} values, expected at most {limit}")
    return out


def flag(value: Any, what: str) -> bool:
    """``value`` as a truth value, refusing anything that is not ``True`` or ``False`` (a
    NumPy bool included): text such as ``"no"`` would otherwise count as true.

    Raises
    ------
    ParameterError
        Naming ``what``.
    """
    if isinstance(value, bool) or type(value).__name__ == "bool_":
        return bool(value)
    raise ParameterError(f"{what} = {value!r}: expected True or False")


def state(
    value: Any,
    n: int,
    what: str = "y0",
    names: Sequence[str] | None = None,
    *,
    require_finite: bool = True,
) -> Any:
    """``value`` as a float array of ``n`` entries (a state of ``n`` states).

    ``names`` (the states' names) are quoted in the message; ``require_finite=False`` lets
    non-finite entries pass (a vector field evaluated by an integrator that diverges: the
    integrator reports that, with its time).

    Raises
    ------
    ParameterError
        Naming ``what`` and the number expected.
    """
    import numpy as np  # here, not at the top: the command line imports this module early

    kind = "finite numbers" if require_finite else "numbers"
    listed = f" ({', '.join(names)})" if names else ""
    try:
        y = np.array(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ParameterError(f"{what} = {value!r}: expected {n} {kind}{listed}") from None
    if y.size != n or (require_finite and not np.all(np.isfinite(y))):
        raise ParameterError(f"{what} = {y.tolist()!r}: expected {n} {kind}{listed}")
    return y


def _is_real(value: Any) -> bool:
    """A real number of any numeric type (int, float, numpy scalars), without importing
    numpy."""
    try:
        return float(value) == value and not isinstance(value, str | bytes | complex)
    except (TypeError, ValueError, OverflowError):
        return False


def options_with(
    cls: type,
    options: Any,
    knobs: dict[str, Any],
    where: str,
    allowed: frozenset[str] | None = None,
    default: Any = None,
    hint: str = "",
) -> Any:
    """An options dataclass ``cls`` with the keyword arguments ``knobs`` in place of its
    fields: the one rule of every options object (``options=`` or its fields as keywords,
    a keyword overriding the object's field).

    Parameters
    ----------
    options
        A ``cls`` instance, or None for ``default`` (``cls()`` when not given).
    allowed
        The fields ``where`` takes as keywords (default: all of them).
    hint
        Appended to the message about an unknown keyword (other arguments ``where`` takes).

    Raises
    ------
    ParameterError
        ``options`` not a ``cls``, or a keyword that is no allowed field, naming it.
    """
    if options is None:
        options = cls() if default is None else default
    elif not isinstance(options, cls):
        raise ParameterError(
            f"{where}: options = {options!r}: expected a {cls.__name__} (or its fields as keywords)"
        )
    if not knobs:
        return options
    fields = frozenset(cls.__dataclass_fields__) if allowed is None else allowed
    unknown = sorted(set(knobs) - fields)
    if unknown:
        raise ParameterError(
            f"{where}: unknown option(s) {', '.join(unknown)}; expected "
            f"{', '.join(sorted(fields))}{hint}"
        )
    return dataclasses.replace(options, **knobs)
