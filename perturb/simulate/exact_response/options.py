"""Options of the exact frequency response: the public ``ExactResponseOptions``, their
validation and merge with keyword arguments (``exact_options``), the parameter window, the
march settings (``Settings``) and the flow family of an oscillator.

Part of :mod:`perturb.simulate.exact_response` (the method is described there).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from perturb import checks
from perturb.errors import ParameterError
from perturb.model.oscillator import Oscillator
from perturb.model.system import System
from perturb.simulate.flows.factory import FlowFamily


# =============================================================================================
# the corrector and the march
# =============================================================================================
@dataclass
class Settings:
    ds_max: float
    ds_min: float
    tol: float
    max_points: int
    max_periods: float
    max_iter: int = 6
    #: time.monotonic() after which marches stop ("time budget"); the same clock in forked
    #: workers
    deadline: float = math.inf


# =============================================================================================
# public: continue_orbits
# =============================================================================================
@dataclass(frozen=True)
class ExactResponseOptions:
    """Tuning knobs of the exact frequency response (:func:`exact_branches`,
    :func:`continue_orbits`; :func:`exact_frequency_response` and :func:`exact_solutions_at`
    pass them on).

    Each function also takes the fields as keyword arguments, which replace those of
    ``options`` (so ``exact_branches(osc, w, tol=1e-9)`` and
    ``exact_branches(osc, w, options=ExactResponseOptions(tol=1e-9))`` are the same call); a
    keyword the function does not use is a :class:`~perturb.errors.ParameterError` naming it.
    :func:`continue_orbits` uses the first six fields, :func:`exact_branches` all of them.
    Values are checked by the functions.  The defaults are those the functions had before
    the options object existed.

    Attributes
    ----------
    ds_max : float
        Output spacing: consecutive points differ by at most ``ds_max`` of the window in the
        parameter and ``ds_max`` relative (to ``max(1, amplitude)``) in amplitude; 0.005 =
        0.5 %.  (The corrector's step in the scaled state may be up to 8 times longer where
        the orbit's phase turns at nearly constant parameter and amplitude.)
    ds_min : float
        Smallest step before giving up (after one jump attempt).
    tol : float
        Newton tolerance in scaled coordinates (estimated error of the stored point).
    max_points : int
        Points per march (per direction) at most.
    max_periods : float, optional
        Budget of propagated time in forcing periods (the cost measure: one Newton iteration
        propagates ``m`` forcing periods): per direction for :func:`continue_orbits`
        (None: 1e6), for all stages of :func:`exact_branches` (None: 2e5).
    closed_form : bool
        Trace orbits that stay inside one linear segment of a PWL force from the exact
        formula (no propagation).  ``False`` shoots everywhere (for checks).
    sweep_points : int
        Frequencies of the virtual sweeps (0: none).
    transient_periods : int
        Periods integrated per attempt where a sweep jumps (up to three attempts).
    branch_points, period_doubling, symmetry : bool
        Switches of the stages of :func:`exact_branches`: the other branch at branch points,
        period-2 branches, mirror images of odd systems.
    attractors : bool
        Stage of :func:`exact_branches` after the sweeps: the stable orbits a vectorised
        simulation settles on from a grid of states and from beside every unstable traced
        orbit, and Newton from the traced orbits at the window edges shifted
        (:mod:`perturb.simulate.exact_response.attractors`).
    max_branches : int
        Budget of branches.
    max_seconds : float, optional
        Wall-clock budget of :func:`exact_branches` (None: none).
    progress : bool, optional
        Progress line (None: on unless ``PERTURB_PROGRESS=0``).
    workers : int, optional
        Processes that trace (None: ``PERTURB_WORKERS``, else 2 on a machine with two or
        more CPUs); see :func:`exact_branches`.
    """

    ds_max: float = 0.005
    ds_min: float = 1e-7
    tol: float = 1e-10
    max_points: int = 20000
    max_periods: float | None = None
    closed_form: bool = True
    sweep_points: int = 60
    transient_periods: int = 40
    branch_points: bool = True
    period_doubling: bool = False
    symmetry: bool = True
    max_branches: int = 40
    max_seconds: float | None = 300.0
    progress: bool | None = None
    workers: int | None = None
    attractors: bool = True


#: The fields of :class:`ExactResponseOptions` that shape one march (:func:`continue_orbits`).
ORBIT_FIELDS = frozenset(("ds_max", "ds_min", "tol", "max_points", "max_periods", "closed_form"))


ALL_FIELDS = frozenset(ExactResponseOptions.__dataclass_fields__)


def exact_options(
    options: ExactResponseOptions | None,
    knobs: dict[str, Any],
    allowed: frozenset[str],
    where: str,
) -> ExactResponseOptions:
    """``options`` with the keywords ``knobs`` of ``where`` in place of its fields
    (:func:`perturb.checks.options_with`); only the fields ``allowed`` may be keywords."""
    return checks.options_with(ExactResponseOptions, options, knobs, where, allowed)


def parameter_window(window: Sequence[float]) -> tuple[float, float]:
    return checks.window(window, "window", positive=False)


def settings(ds_max: float, ds_min: float, tol: float, max_points: int, max_periods: float):
    for name, v in (("ds_max", ds_max), ("ds_min", ds_min), ("tol", tol)):
        if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
            raise ParameterError(f"{name} = {v!r}: expected a positive number")
    if ds_min > ds_max:
        raise ParameterError(f"ds_min = {ds_min} > ds_max = {ds_max}")
    if isinstance(max_points, bool) or not isinstance(max_points, int) or max_points < 2:
        raise ParameterError(f"max_points = {max_points!r}: expected an integer >= 2")
    max_periods = checks.finite(max_periods, "max_periods")
    if not max_periods > 0:
        raise ParameterError(f"max_periods = {max_periods!r}: expected a positive number")
    return Settings(float(ds_max), float(ds_min), float(tol), int(max_points), float(max_periods))


def flow_family(oscillator: Oscillator | System | FlowFamily, parameter: str | None) -> FlowFamily:
    if isinstance(oscillator, FlowFamily):
        if parameter is not None and parameter != oscillator.parameter:
            raise ParameterError(
                f"parameter = {parameter!r} but the FlowFamily varies {oscillator.parameter!r}"
            )
        return oscillator
    if not isinstance(oscillator, Oscillator | System):
        raise ParameterError(
            f"oscillator = {oscillator!r}: expected an Oscillator, a System or a FlowFamily"
        )
    return FlowFamily(oscillator, parameter)
