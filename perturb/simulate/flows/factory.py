"""The one place where a model gets its flow: :func:`make_flow` (one flow) and
:class:`FlowFamily` (the flows of one model over the values of a parameter, compiled once).

The choice, in one place instead of one per caller:

* piecewise-linear models get the exact flow (:class:`~perturb.simulate.flows.exact.
  ExactPWLFlow`: closed-form pieces, exact sensitivity);
* (:class:`FlowFamily`) other models with switch functions the event-driven flow
  (:class:`~perturb.simulate.flows.event_driven.EventFlow`: located switches, saltation
  matrices, sliding);
* smooth models (and whatever the others do not take) the ODE flow
  (:class:`~perturb.simulate.flows.base.ODEFlow`).

This module imports the concrete flows; they import only :mod:`perturb.simulate.flows.base`
(and the model helpers), so the flow modules form no import circle.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np

from perturb.errors import ModelError, ParameterError
from perturb.model.oscillator import Oscillator, validate_parameter_value
from perturb.simulate.flows.base import Flow, ODEFlow
from perturb.simulate.flows.event_driven import EventFlow
from perturb.simulate.flows.exact import ExactPWLFlow
from perturb.simulate.flows.piecewise_exact import PWLSystem
from perturb.simulate.flows.system import NumericRHS, frequency_symbol

__all__ = ["FlowFamily", "FlowMethod", "make_flow"]

FlowMethod = Literal["auto", "exact", "ode"]


def _real_positive(name: str, value: object) -> float:
    try:
        out = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise ParameterError(f"{name} = {value!r}: expected a finite real number") from None
    if not math.isfinite(out):
        raise ParameterError(f"{name} = {value!r}: expected a finite real number")
    if out <= 0.0:
        raise ParameterError(f"{name} = {value!r}: expected a positive number")
    return out


def make_flow(
    osc: Oscillator,
    Omega: float | None = None,
    *,
    method: FlowMethod = "auto",
    rtol: float = 1e-10,
    atol: float = 1e-12,
) -> Flow:
    """One flow of ``osc``: exact for piecewise-linear models, else DOP853 (:class:`ODEFlow`).

    Parameters
    ----------
    osc
        Oscillator with all parameter values set (``Omega`` may override the frequency).
    Omega
        Forcing frequency override.
    method
        ``"auto"``: :class:`ExactPWLFlow` when the model is piecewise linear (falling back to
        the ODE flow when the exact flow rejects a feature of it), else :class:`ODEFlow`;
        ``"exact"``: require the exact flow; ``"ode"``: always :class:`ODEFlow`.
    rtol, atol
        Tolerances of :class:`ODEFlow` (the exact flow has none).

    Raises
    ------
    ParameterError
        Unknown ``method`` or bad tolerances.
    ModelError
        ``method="exact"`` and the model is not piecewise linear.
    """
    if not isinstance(osc, Oscillator):
        raise ParameterError(f"osc = {osc!r}: expected an Oscillator")
    if method not in ("auto", "exact", "ode"):
        raise ParameterError(f"method = {method!r}: expected 'auto', 'exact' or 'ode'")
    if _real_positive("rtol", rtol) >= 1.0:
        raise ParameterError(f"rtol = {rtol!r}: expected a relative tolerance in (0, 1)")
    rtol = float(rtol)
    atol = _real_positive("atol", atol)
    if method == "exact":
        if not osc.is_piecewise_linear:
            raise ModelError(
                f"method = 'exact': model {osc.name!r} is not piecewise linear; use method='ode'"
            )
        return ExactPWLFlow(osc, Omega=Omega)
    if method == "auto" and osc.is_piecewise_linear:
        try:
            return ExactPWLFlow(osc, Omega=Omega)
        except ModelError:
            # e.g. a PWL force with a feature the exact flow does not take: fall back
            pass
    return ODEFlow(osc, Omega, rtol=rtol, atol=atol)


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
