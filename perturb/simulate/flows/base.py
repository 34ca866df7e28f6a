"""Flows: the time-t maps every periodic-orbit solver is built on.

A *flow* propagates a state ``y = (x, x')`` from ``t0`` to ``t1`` and, on request, returns the
sensitivity ``dy(t1)/dy(t0)`` (the monodromy matrix when ``t1 - t0`` is a period), including
saltation matrices where the vector field jumps. Shooting, continuation, Floquet analysis,
Poincaré sections and Lyapunov exponents take any object with this interface, so the exact
piecewise-analytic propagator, the event-driven integrator and a plain ODE solver are
interchangeable beneath them.

Interface (:class:`Flow`, the base class every flow derives from)::

    flow(y0, t0, t1, *, sensitivity=False, t_eval=None) -> FlowResult
    flow.vector_field(t, y) -> ndarray (2,)
    flow.period -> float | None          # forcing period; None for autonomous systems

plus the capabilities a flow declares (``system``, ``rhs``, ``surfaces``, ``rtol``,
``exact_dense_output``, ``sensitivity_determinant``; see :class:`Flow`).  Which flow a model
gets is decided in one place, :mod:`perturb.simulate.flows.factory` (:func:`make_flow`,
:class:`FlowFamily`); the concrete flows import this module only, never each other or the
factory.

:class:`ODEFlow` here is the smooth reference: ``solve_ivp`` (DOP853) on the state and its
variational equations. It is exact to the integration tolerance for smooth systems only; a
PWL or discontinuous system needs a flow that locates switches (exact or event-driven).
"""

from __future__ import annotations

import abc
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy.integrate import solve_ivp

from perturb.errors import ParameterError, PerturbError
from perturb.model.oscillator import Oscillator
from perturb.simulate.flows.system import NumericRHS, first_order_rhs

__all__ = ["Flow", "FlowResult", "ODEFlow", "as_flow", "step_budget"]


@dataclass(frozen=True, eq=False)
class FlowResult:
    """The outcome of one propagation.

    Attributes
    ----------
    t0, t1
        The interval.
    y
        State at ``t1``, shape (2,).
    sensitivity
        ``dy(t1)/dy(t0)``, shape (2, 2), or None when not requested.
    t, ys
        Output times and states (shape (n, 2)) when ``t_eval`` was given, else None.
    n_events
        Number of switching events met (0 for smooth flows).
    """

    t0: float
    t1: float
    y: np.ndarray
    sensitivity: np.ndarray | None = None
    t: np.ndarray | None = None
    ys: np.ndarray | None = None
    n_events: int = 0


class Flow(abc.ABC):
    """Base class of the flows: the interface periodic-orbit solvers need, and the
    capabilities a flow declares (read as attributes, never probed).

    Interface: ``flow(y0, t0, t1, *, sensitivity=False, t_eval=None) -> FlowResult`` and
    ``flow.vector_field(t, y)``; see the module docstring.

    Declared capabilities (class defaults; a concrete flow overrides those it has):

    ``period``
        Forcing period; None when autonomous (or incommensurate forcing frequencies).
    ``autonomous``
        No forcing at all (default: ``period is None``).
    ``system``
        The :class:`~perturb.simulate.flows.piecewise_exact.PWLSystem` of an exact flow
        (closed-form pieces, scalar field ``system.field1``), else None.
    ``rhs``
        The compiled :class:`~perturb.simulate.flows.system.NumericRHS` of an integrator that
        steps the smooth field (ODE flow), else None.
    ``surfaces``
        Switching surfaces located by an event-driven flow (empty otherwise); such a flow also
        has ``simulate(y0, t_span)`` returning a trajectory with its events.
    ``rtol``
        Relative tolerance of the integrator; 0.0 for a flow exact to rounding.
    ``exact_dense_output``
        True when ``trajectory(y0, t0, t1)`` returns an exact dense trajectory.

    :meth:`sensitivity_determinant` returns the exact determinant of the sensitivity when the
    flow knows it (Liouville), else None.

    ``isinstance(obj, Flow)`` also holds for an object that merely has ``__call__`` and
    ``vector_field`` (the structural interface of earlier versions); :func:`as_flow` gives
    such an object the declared defaults.
    """

    period: float | None = None
    system: Any = None
    rhs: NumericRHS | None = None
    surfaces: tuple = ()
    rtol: float = 0.0
    exact_dense_output: bool = False

    @property
    def autonomous(self) -> bool:
        """True for a flow without forcing."""
        return self.period is None

    @abc.abstractmethod
    def __call__(
        self,
        y0: ArrayLike,
        t0: float,
        t1: float,
        *,
        sensitivity: bool = False,
        t_eval: ArrayLike | None = None,
    ) -> FlowResult: ...

    @abc.abstractmethod
    def vector_field(self, t: float, y: ArrayLike) -> np.ndarray: ...

    def sensitivity_determinant(self, t0: float, t1: float) -> float | None:
        """Exact ``det dy(t1)/dy(t0)`` when known (None: compute it from the matrix)."""
        return None

    @classmethod
    def __subclasshook__(cls, other: type) -> bool:
        if cls is Flow:
            names = set().union(*(vars(k) for k in other.__mro__))
            if "__call__" in names and "vector_field" in names:
                return True
        return NotImplemented


class _ForeignFlow(Flow):
    """A structural flow (``__call__`` and ``vector_field``, not derived from :class:`Flow`)
    with the declared capabilities it has, read once here; the rest take the defaults."""

    def __init__(self, flow: Any) -> None:
        self.flow = flow
        self.period = getattr(flow, "period", None)
        for name in ("system", "rhs", "rtol", "surfaces"):
            if hasattr(flow, name):
                setattr(self, name, getattr(flow, name))
        self._autonomous = getattr(flow, "autonomous", None)

    @property
    def autonomous(self) -> bool:
        return self.period is None if self._autonomous is None else bool(self._autonomous)

    def __call__(self, y0, t0, t1, *, sensitivity=False, t_eval=None) -> FlowResult:
        return self.flow(y0, t0, t1, sensitivity=sensitivity, t_eval=t_eval)

    def vector_field(self, t: float, y: ArrayLike) -> np.ndarray:
        return self.flow.vector_field(t, y)

    def sensitivity_determinant(self, t0: float, t1: float) -> float | None:
        fn = getattr(self.flow, "sensitivity_determinant", None)
        return float(fn(t0, t1)) if callable(fn) else None

    def __getattr__(self, name: str) -> Any:  # anything else the wrapped flow offers
        flow = self.__dict__.get("flow")
        if flow is None:  # not initialised (copy, unpickling): no recursion into __getattr__
            raise AttributeError(name)
        return getattr(flow, name)

    def __repr__(self) -> str:
        return repr(self.flow)


def as_flow(obj: Any) -> Flow:
    """``obj`` as a :class:`Flow` with its declared capabilities: itself when it derives from
    :class:`Flow`, a thin wrapper when it only has the structural interface.

    Raises
    ------
    ParameterError
        ``obj`` is not callable or has no ``vector_field`` method.
    """
    if Flow in type(obj).__mro__:
        return obj
    if not callable(obj) or not callable(getattr(obj, "vector_field", None)):
        raise ParameterError(
            f"flow = {obj!r}: expected a Flow (callable with a vector_field method), e.g. "
            "ExactPWLFlow(osc) or ODEFlow(osc)"
        )
    return _ForeignFlow(obj)


def _check_span(y0: ArrayLike, t0: float, t1: float) -> np.ndarray:
    y = np.asarray(y0, dtype=float).reshape(-1)
    if y.size != 2 or not np.all(np.isfinite(y)):
        raise ParameterError(f"y0 = {np.asarray(y0).tolist()!r}: expected two finite numbers")
    if not (np.isfinite(t0) and np.isfinite(t1) and t1 > t0):
        raise ParameterError(f"(t0, t1) = ({t0}, {t1}): expected finite t1 > t0")
    return y


class ODEFlow(Flow):
    """Smooth flow of an oscillator by ``solve_ivp`` with variational equations.

    Parameters
    ----------
    oscillator
        Any oscillator with all parameter values set.
    Omega
        Override of the forcing frequency.
    rtol, atol
        Tolerances of DOP853.
    """

    def __init__(
        self,
        oscillator: Oscillator,
        Omega: float | None = None,
        *,
        rtol: float = 1e-11,
        atol: float = 1e-12,
        rhs: NumericRHS | None = None,
    ) -> None:
        self.oscillator = oscillator
        self.rhs: NumericRHS = rhs if rhs is not None else first_order_rhs(oscillator, Omega)
        self.period = self.rhs.period
        self.rtol, self.atol = float(rtol), float(atol)

    def __repr__(self) -> str:
        return f"ODEFlow({self.oscillator.name}, period={self.period}, rtol={self.rtol:g})"

    def vector_field(self, t: float, y: ArrayLike) -> np.ndarray:
        return self.rhs.fun(t, np.asarray(y, float))

    def _augmented(self, t: float, z: np.ndarray) -> np.ndarray:
        y = z[:2]
        phi = z[2:].reshape(2, 2)
        return np.concatenate([self.rhs.fun(t, y), (self.rhs.jac(t, y) @ phi).ravel()])

    def __call__(
        self,
        y0: ArrayLike,
        t0: float,
        t1: float,
        *,
        sensitivity: bool = False,
        t_eval: ArrayLike | None = None,
    ) -> FlowResult:
        y = _check_span(y0, t0, t1)
        z0 = np.concatenate([y, np.eye(2).ravel()]) if sensitivity else y
        fun = self._augmented if sensitivity else self.rhs.fun
        budget = step_budget(t0, t1, self.period)
        sol = solve_ivp(
            fun,
            (t0, t1),
            z0,
            method="DOP853",
            rtol=self.rtol,
            atol=self.atol,
            t_eval=None if t_eval is None else np.asarray(t_eval, float),
            events=[budget],
        )
        if sol.status == 1:
            raise PerturbError(
                f"integration of {self.oscillator.name!r} on [{t0}, {t1}] stopped at "
                f"t = {float(sol.t[-1])!r} after {budget.max_steps} steps (about "
                f"{_STEPS_PER_PERIOD} per forcing period allowed): the step size collapsed. A "
                "force that jumps (e.g. sign(x') friction) makes DOP853 chatter: the "
                "event-driven flow locates the switches (FlowFamily, EventFlow); or the motion "
                "is far faster than the forcing (extreme parameters)"
            )
        if sol.status != 0 or not np.all(np.isfinite(sol.y[:, -1])):
            raise PerturbError(
                f"integration of {self.oscillator.name!r} failed on [{t0}, {t1}]: {sol.message}"
            )
        # (solve_ivp integrates across switches of a nonsmooth force without locating them:
        # accuracy there is the step control's, which is why PWL models use ExactPWLFlow)
        if t_eval is not None:
            final = solve_ivp(
                fun,
                (t0, t1),
                z0,
                method="DOP853",
                rtol=self.rtol,
                atol=self.atol,
                events=[step_budget(t0, t1, self.period)],
            ).y[:, -1]
        else:
            final = sol.y[:, -1]
        return FlowResult(
            t0=float(t0),
            t1=float(t1),
            y=final[:2].copy(),
            sensitivity=final[2:].reshape(2, 2).copy() if sensitivity else None,
            t=None if t_eval is None else sol.t.copy(),
            ys=None if t_eval is None else sol.y[:2].T.copy(),
        )


#: steps of DOP853 allowed per forcing period of the span (a smooth orbit takes a few hundred
#: at rtol 1e-11; a jump in the field that DOP853 steps across, e.g. sticking under sign(x'),
#: takes millions), and on top of that
_STEPS_PER_PERIOD, _STEPS_BASE = 5_000, 20_000


def step_budget(t0: float, t1: float, period: float | None):
    """A terminal event of ``solve_ivp`` that fires after a budget of steps (solve_ivp calls
    it once per step; it changes sign only then, so no root finding happens before)."""
    span_periods = abs(t1 - t0) / (period if period else 2.0 * np.pi)
    max_steps = int(_STEPS_BASE + _STEPS_PER_PERIOD * min(span_periods, 1e7))
    count = [0]
    last = [t0]
    stop: list[float] = []

    def event(t: float, z: np.ndarray) -> float:
        if stop:  # fired: a function of t with its root between the last two steps
            return (stop[0] - t) * (1.0 if t1 >= t0 else -1.0)
        count[0] += 1
        if count[0] <= max_steps:
            last[0] = t
            return 1.0
        stop.append(0.5 * (last[0] + t))
        return (stop[0] - t) * (1.0 if t1 >= t0 else -1.0)

    event.terminal = True  # type: ignore[attr-defined]
    event.max_steps = max_steps  # type: ignore[attr-defined]
    return event
