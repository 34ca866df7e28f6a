"""Flows: the time-t maps every periodic-orbit solver is built on.

A *flow* propagates a state ``y = (x, x')`` from ``t0`` to ``t1`` and, on request, returns the
sensitivity ``dy(t1)/dy(t0)`` (the monodromy matrix when ``t1 - t0`` is a period), including
saltation matrices where the vector field jumps. Shooting, continuation, Floquet analysis,
Poincaré sections and Lyapunov exponents take any object with this interface, so the exact
piecewise-analytic propagator, the event-driven integrator and a plain ODE solver are
interchangeable beneath them.

Interface (:class:`Flow`)::

    flow(y0, t0, t1, *, sensitivity=False, t_eval=None) -> FlowResult
    flow.vector_field(t, y) -> ndarray (2,)
    flow.period -> float | None          # forcing period; None for autonomous systems

:class:`ODEFlow` here is the smooth reference: ``solve_ivp`` (DOP853) on the state and its
variational equations. It is exact to the integration tolerance for smooth systems only; a
PWL or discontinuous system needs a flow that locates switches (exact or event-driven).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike
from scipy.integrate import solve_ivp

from ..errors import ParameterError, PerturbError
from ..model import Oscillator
from .system import NumericRHS, first_order_rhs

__all__ = ["Flow", "FlowResult", "ODEFlow"]


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


@runtime_checkable
class Flow(Protocol):
    """What periodic-orbit solvers need from an integrator; see the module docstring."""

    period: float | None

    def __call__(
        self,
        y0: ArrayLike,
        t0: float,
        t1: float,
        *,
        sensitivity: bool = False,
        t_eval: ArrayLike | None = None,
    ) -> FlowResult: ...

    def vector_field(self, t: float, y: ArrayLike) -> np.ndarray: ...


def _check_span(y0: ArrayLike, t0: float, t1: float) -> np.ndarray:
    y = np.asarray(y0, dtype=float).reshape(-1)
    if y.size != 2 or not np.all(np.isfinite(y)):
        raise ParameterError(f"y0 = {np.asarray(y0).tolist()!r}: expected two finite numbers")
    if not (np.isfinite(t0) and np.isfinite(t1) and t1 > t0):
        raise ParameterError(f"(t0, t1) = ({t0}, {t1}): expected finite t1 > t0")
    return y


class ODEFlow:
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
    ) -> None:
        self.oscillator = oscillator
        self.rhs: NumericRHS = first_order_rhs(oscillator, Omega)
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
        sol = solve_ivp(
            fun,
            (t0, t1),
            z0,
            method="DOP853",
            rtol=self.rtol,
            atol=self.atol,
            t_eval=None if t_eval is None else np.asarray(t_eval, float),
        )
        if sol.status != 0 or not np.all(np.isfinite(sol.y[:, -1])):
            raise PerturbError(
                f"integration of {self.oscillator.name!r} failed on [{t0}, {t1}]: {sol.message}"
            )
        if t_eval is not None:
            final = solve_ivp(fun, (t0, t1), z0, method="DOP853", rtol=self.rtol, atol=self.atol).y[
                :, -1
            ]
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
