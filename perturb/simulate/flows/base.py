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

from perturb.errors import ModelError, ParameterError, PerturbError
from perturb.model.oscillator import Oscillator, validate_parameter_value
from perturb.simulate.flows.system import NumericRHS, first_order_rhs, frequency_symbol

__all__ = ["Flow", "FlowResult", "ODEFlow", "FlowFamily"]


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
        budget = _step_budget(t0, t1, self.period)
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
                events=[_step_budget(t0, t1, self.period)],
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


def _step_budget(t0: float, t1: float, period: float | None):
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


class FlowFamily:
    """Flows of one oscillator over the values of one parameter, compiled once.

    Continuation and sweeps ask for thousands of flows that differ in one number; rebuilding
    the canonical PWL form or re-lambdifying per value would dominate their cost. Piecewise-
    linear oscillators get the exact flow (:class:`~perturb.simulate.flows.exact.ExactPWLFlow`,
    breakpoints, slopes and offsets compiled as functions of the parameter); other models with
    switch functions (``sign(x')`` friction, a Heaviside step on a nonlinear force, ...) the
    event-driven flow (:class:`~perturb.simulate.flows.event_driven.EventFlow`, one template whose
    compiled modes take the parameter as an argument; ``event`` is True), whose sensitivity
    carries the saltation matrices at the switches and the sliding projections; smooth
    models the :class:`ODEFlow`.

    Parameters
    ----------
    oscillator
        All parameters but ``parameter`` need values.
    parameter
        Name of the parameter that varies; default: the forcing frequency.
    exact
        ``None`` (default) chooses the exact flow when the model is piecewise linear, else
        the event-driven flow when it has switch functions the event-driven integrator
        takes, else the ODE flow; ``False`` forces the ODE flow (which steps over switches:
        its monodromy misses the saltation).
    """

    def __init__(
        self,
        oscillator: Oscillator,
        parameter: str | None = None,
        *,
        exact: bool | None = None,
        rtol: float = 1e-11,
        atol: float = 1e-12,
    ) -> None:
        osc = oscillator
        if parameter is None:
            sym = frequency_symbol(osc)
            if sym is None:
                raise ModelError(
                    f"model {osc.name!r} has no forcing-frequency parameter; name the parameter"
                )
            parameter = sym.name
        if parameter not in osc.params:
            raise ParameterError(
                f"parameter {parameter!r} is not in model {osc.name!r}: expected one of "
                + ", ".join(osc.params)
            )
        self.oscillator = osc
        self.parameter = parameter
        self.rtol, self.atol = rtol, atol
        use_exact = osc.is_piecewise_linear if exact is None else bool(exact)
        if use_exact and not osc.is_piecewise_linear:
            raise ModelError(f"model {osc.name!r} is not piecewise linear: no exact flow")
        self.exact = use_exact
        self._pwl = _compile_pwl(osc, parameter) if use_exact else None
        # a field with switches (sign(x'), Heaviside of a non-PWL force, ...) that is not
        # piecewise linear: the event-driven flow, which locates the switches and applies the
        # saltation matrices and sliding projections to the sensitivity (the ODE flow steps
        # over the jumps: its monodromy misses them, and sticking makes it chatter)
        self._event = None
        self.event = False
        if not use_exact and exact is None and _has_switches(osc):
            self._event = _event_template(osc, parameter, rtol, atol)
            self.event = self._event is not None
        self._rhs = None if (use_exact or self.event) else _compile_rhs(osc, parameter)
        self._recent: dict[float, Flow] = {}

    def __repr__(self) -> str:
        kind = "exact" if self.exact else ("event" if self.event else "ode")
        return f"FlowFamily({self.oscillator.name}, {self.parameter}, {kind})"

    def at(self, value: float) -> Flow:
        """The flow at ``parameter = value``."""
        value = validate_parameter_value(self.parameter, value)
        if self.exact:
            from perturb.simulate.flows.exact import ExactPWLFlow

            if self._pwl is None:  # breakpoints could not be ordered symbolically
                return ExactPWLFlow(self.oscillator.with_params({self.parameter: value}))
            # continuation asks for the same few parameter values over and over (corrector
            # iterations, statistics, branch checks): building and validating a system costs
            # as much as propagating it over a period, so recent flows are kept
            flow = self._recent.get(value)
            if flow is None:
                flow = ExactPWLFlow(self._pwl(value))
                if len(self._recent) >= _RECENT_FLOWS:
                    self._recent.pop(next(iter(self._recent)))
                self._recent[value] = flow
            return flow
        if self._event is not None:
            if self._event == "per value":
                # the parameter moves a switching surface: one event-driven flow per value
                from perturb.simulate.flows.event_driven import EventFlow

                flow = self._recent.get(value)
                if flow is None:
                    flow = EventFlow(
                        self.oscillator.with_params({self.parameter: value}),
                        rtol=self.rtol,
                        atol=self.atol,
                    )
                    if len(self._recent) >= _RECENT_FLOWS:
                        self._recent.pop(next(iter(self._recent)))
                    self._recent[value] = flow
                return flow
            return self._event.at(value)
        assert self._rhs is not None
        return ODEFlow(self.oscillator, rhs=self._rhs(value), rtol=self.rtol, atol=self.atol)


_RECENT_FLOWS = 64


def _has_switches(osc: Oscillator) -> bool:
    import sympy as sp

    return bool(osc.g.atoms(sp.Heaviside, sp.sign, sp.Abs, sp.Max, sp.Min, sp.Piecewise))


def _event_template(osc: Oscillator, parameter: str, rtol: float, atol: float):
    """An event-driven flow with ``parameter`` kept as an argument, or None when the model is
    outside the event-driven integrator's reach (switching arguments that depend on the
    parameter or on time, Dirac terms): the ODE flow is used then."""
    from perturb.simulate.flows.event_driven import EventFlow

    if osc.params.get(parameter) is None:
        osc = osc.with_params({parameter: 1.0})  # a placeholder: at() sets the value
    try:
        return EventFlow(osc, rtol=rtol, atol=atol, parameter=parameter)
    except (ModelError, ParameterError):
        pass
    try:
        EventFlow(osc, rtol=rtol, atol=atol)  # the parameter in a switching argument?
    except (ModelError, ParameterError):
        return None
    return "per value"


def _others(osc: Oscillator, parameter: str) -> dict:
    subs = {s: v for s, v in osc.substitutions().items() if s.name != parameter}
    return subs


def _compile_pwl(osc: Oscillator, parameter: str):
    """value -> PWLSystem, with the canonical form computed once symbolically in the
    parameter; None when its breakpoints cannot be ordered without a value."""
    import sympy as sp

    from perturb.errors import NonsmoothError
    from perturb.model.parsing import real_symbol
    from perturb.model.pwl import to_pwl
    from perturb.simulate.flows.piecewise_exact import PWLSystem

    p = real_symbol(parameter)
    subs = _others(osc, parameter)
    try:
        pwl = to_pwl(osc.restoring_force.xreplace(subs), osc.x)
    except NonsmoothError:
        return None
    exprs = [
        *pwl.breakpoints,
        *pwl.slopes,
        *pwl.offsets,
        osc.damping.xreplace(subs),
        osc.forcing.constant.xreplace(subs),
    ]
    for h in osc.forcing.harmonics:
        exprs += [h.amplitude.xreplace(subs), h.frequency.xreplace(subs), h.phase.xreplace(subs)]
    free = sorted({s.name for e in exprs for s in sp.sympify(e).free_symbols} - {parameter})
    if free:
        raise ParameterError(f"model {osc.name!r} needs values for {', '.join(free)}")
    fn = sp.lambdify(p, exprs, modules="math")
    m = len(pwl.breakpoints)
    # the last system built: when the parameter enters only the forcing (the frequency), the
    # next one shares its validated force arrays
    last: list[tuple[list[float], PWLSystem]] = []

    def build(value: float) -> PWLSystem:
        vals = [float(v) for v in fn(value)]
        bps, rest = vals[:m], vals[m:]
        slopes, offsets = rest[: m + 1], rest[m + 1 : 2 * m + 2]
        mu, static = rest[2 * m + 2], rest[2 * m + 3]
        harm = rest[2 * m + 4 :]
        forcing = []
        for j in range(0, len(harm), 3):
            amp, w, ph = harm[j : j + 3]
            if amp != 0.0:
                forcing.append((amp, abs(w), ph if w > 0 else -ph))
        head = vals[: 2 * m + 4]
        if last and last[0][0] == head:
            return last[0][1].with_forcing(forcing)
        system = PWLSystem(
            bps, slopes, offsets, damping=mu, forcing=tuple(forcing), static_force=static
        )
        last[:] = [(head, system)]
        return system

    return build


def _compile_rhs(osc: Oscillator, parameter: str):
    """value -> NumericRHS, lambdified once with the parameter as an argument."""
    import sympy as sp

    from perturb.model.parsing import real_symbol

    p = real_symbol(parameter)
    subs = _others(osc, parameter)
    acc = (osc.forcing.expr(osc.t) - osc.g).xreplace(subs)
    free = sorted(s.name for s in acc.free_symbols - {osc.x, osc.v, osc.t, p})
    if free:
        raise ParameterError(f"model {osc.name!r} needs values for {', '.join(free)}")
    dx = sp.diff(acc, osc.x).replace(sp.DiracDelta, lambda *a: sp.Integer(0))
    dv = sp.diff(acc, osc.v).replace(sp.DiracDelta, lambda *a: sp.Integer(0))
    mods = [{"Heaviside": lambda z, h0=0.5: np.heaviside(z, h0)}, "numpy"]
    acc_fn = sp.lambdify((osc.t, osc.x, osc.v, p), acc, modules=mods)
    jac_fn = sp.lambdify((osc.t, osc.x, osc.v, p), [dx, dv], modules=mods)
    base = osc.forcing.base_frequency
    period_fn = None
    if base is not None:
        period_fn = sp.lambdify(p, 2 * sp.pi / sp.Abs(base.xreplace(subs)), modules="math")

    def build(value: float) -> NumericRHS:
        def fun(t: float, y: np.ndarray) -> np.ndarray:
            return np.array([y[1], acc_fn(t, y[0], y[1], value)], dtype=float)

        def jac(t: float, y: np.ndarray) -> np.ndarray:
            a, b = jac_fn(t, y[0], y[1], value)
            return np.array([[0.0, 1.0], [float(a), float(b)]])

        return NumericRHS(fun=fun, jac=jac, period=None if period_fn is None else period_fn(value))

    return build
