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

:func:`make_flow` also takes a system of several coordinates
(:class:`~perturb.model.system.System`, or its
:class:`~perturb.model.affine.PiecewiseAffineSystem`): the exact n-dimensional flow
(:class:`~perturb.simulate.flows.affine_exact.AffineExactFlow`) when it is piecewise affine, else
:class:`SystemODEFlow` (DOP853 on ``System.field`` with variational equations; defined here
because :class:`ODEFlow` takes the two states of an oscillator only).

This module imports the concrete flows; they import only :mod:`perturb.simulate.flows.base`
(and the model helpers), so the flow modules form no import circle.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import replace
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike
from scipy.integrate import solve_ivp

from perturb.errors import ModelError, ParameterError, PerturbError
from perturb.model.affine import HarmonicInput, PiecewiseAffineSystem
from perturb.model.oscillator import Oscillator, validate_parameter_value
from perturb.model.system import System
from perturb.simulate.flows.affine_exact import AffineExactFlow
from perturb.simulate.flows.base import Flow, FlowResult, ODEFlow, step_budget
from perturb.simulate.flows.event_driven import EventFlow
from perturb.simulate.flows.exact import ExactPWLFlow
from perturb.simulate.flows.piecewise_exact import PWLSystem
from perturb.simulate.flows.system import NumericRHS, frequency_symbol

__all__ = ["FlowFamily", "FlowMethod", "SystemFlowFamily", "SystemODEFlow", "make_flow"]

FlowMethod = Literal["auto", "exact", "ode", "events", "lcp"]
_METHODS = ("auto", "exact", "ode", "events", "lcp")


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
    osc: Oscillator | System | PiecewiseAffineSystem,
    Omega: float | None = None,
    *,
    method: FlowMethod = "auto",
    rtol: float = 1e-10,
    atol: float = 1e-12,
    active: Mapping[str, int | None] | None = None,
    h: float | None = None,
) -> Flow:
    """One flow of ``osc``: exact for piecewise-linear models, event-driven for systems with
    contacts, else DOP853.

    Parameters
    ----------
    osc
        Oscillator or :class:`~perturb.model.system.System` with all parameter values set
        (``Omega`` may override the frequency), or a
        :class:`~perturb.model.affine.PiecewiseAffineSystem`.
    Omega
        Forcing frequency override (an oscillator's forcing frequency; a system's parameter
        named ``Omega``; not for a ``PiecewiseAffineSystem``, whose data are numbers).
    method
        ``"auto"``: the exact flow when the model is piecewise linear (:class:`ExactPWLFlow`
        for an oscillator, :class:`AffineExactFlow` for a system; falling back to the ODE flow
        when the exact flow rejects a feature of it), else the ODE flow (:class:`ODEFlow`,
        :class:`SystemODEFlow`). A system with stops or friction contacts and no ``active``
        gets the event-driven flow (:class:`~perturb.simulate.flows.system_events.
        SystemEventFlow`): impacts, resting and sticking are events that neither the exact
        nor the ODE flow switches on its own. ``"exact"``: require the exact flow; ``"ode"``:
        always the ODE flow; ``"events"``: the event-driven flow
        (:class:`~perturb.simulate.flows.event_driven.EventFlow` for an oscillator);
        ``"lcp"``: systems only, the Moreau–Jean time-stepper
        (:class:`~perturb.simulate.flows.system_lcp.SystemLCPFlow`, step ``h``; first order,
        no sensitivity).
    rtol, atol
        Tolerances of the ODE and event-driven flows (the exact flows have none).
    active
        Systems only: the mode of every stop (and sticking friction contact), as
        :meth:`System.piecewise_affine <perturb.model.system.System.piecewise_affine>` takes
        it (``None`` free, ``-1``/``+1`` resting on the lower/upper limit): the exact and ODE
        flows then keep these modes for the whole run.
    h
        The step of ``method="lcp"`` (required there, refused elsewhere).

    Raises
    ------
    ParameterError
        Unknown ``method``, bad tolerances, a model of another type, ``Omega`` for a system
        without such a parameter or for a ``PiecewiseAffineSystem``, ``active`` for an
        oscillator.
    ModelError
        ``method="exact"`` and the model is not piecewise linear, or it has stops or friction
        contacts and no ``active``.
    """
    if method not in _METHODS:
        raise ParameterError(
            f"method = {method!r}: expected one of {', '.join(map(repr, _METHODS))}"
        )
    if method == "lcp" and h is None:
        raise ParameterError("h = None: method='lcp' needs its step h (a positive number)")
    if method != "lcp" and h is not None:
        raise ParameterError(f"h = {h!r}: the step is for method='lcp', not method={method!r}")
    if active is not None and not isinstance(active, Mapping):
        raise ParameterError(f"active = {active!r}: expected a mapping stop name -> None, -1 or +1")
    if isinstance(osc, System | PiecewiseAffineSystem):
        return _make_system_flow(osc, Omega, method, rtol, atol, active, h)
    if not isinstance(osc, Oscillator):
        raise ParameterError(
            f"osc = {osc!r}: expected an Oscillator, a System or a PiecewiseAffineSystem"
        )
    if active is not None:
        raise ParameterError(
            f"active = {active!r}: stops are for systems (System), not oscillators"
        )
    if method == "lcp":
        raise ParameterError(
            "method = 'lcp': the Moreau flow is for systems (System); for an oscillator use "
            "perturb.simulate.flows.lcp"
        )
    if _real_positive("rtol", rtol) >= 1.0:
        raise ParameterError(f"rtol = {rtol!r}: expected a relative tolerance in (0, 1)")
    rtol = float(rtol)
    atol = _real_positive("atol", atol)
    if method == "events":
        return EventFlow(osc, Omega, rtol=rtol, atol=atol)
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


def _make_system_flow(
    model: System | PiecewiseAffineSystem,
    Omega: float | None,
    method: str,
    rtol: float,
    atol: float,
    active: Mapping[str, int | None] | None,
    h: float | None,
) -> Flow:
    """:func:`make_flow` for a system of several coordinates (the same checks and choice)."""
    if _real_positive("rtol", rtol) >= 1.0:
        raise ParameterError(f"rtol = {rtol!r}: expected a relative tolerance in (0, 1)")
    rtol = float(rtol)
    atol = _real_positive("atol", atol)
    if isinstance(model, PiecewiseAffineSystem):
        if Omega is not None:
            raise ParameterError(
                f"Omega = {Omega!r}: a PiecewiseAffineSystem holds numbers; build it again from "
                "its System with the new frequency"
            )
        if active is not None:
            raise ParameterError(
                f"active = {active!r}: a PiecewiseAffineSystem has its stop modes built in"
            )
        if method in ("events", "lcp"):
            raise ParameterError(
                f"method = {method!r}: a PiecewiseAffineSystem has fixed contact modes; pass "
                "its System"
            )
        if method == "ode":
            return SystemODEFlow(model, rtol=rtol, atol=atol)
        return AffineExactFlow(model)
    if Omega is not None:
        if "Omega" not in model.params:
            raise ParameterError(
                f"Omega = {Omega!r}: system {model.name!r} has no parameter 'Omega' (expected "
                f"one of {', '.join(model.params) or 'none'}); use with_params"
            )
        model = model.with_params(Omega=Omega)
    if method == "lcp":
        from perturb.simulate.flows.system_lcp import SystemLCPFlow

        if active is not None:
            raise ParameterError(f"active = {active!r}: the Moreau flow switches contacts itself")
        return SystemLCPFlow(model, _real_positive("h", h))
    contacts = [e.name for e in model.elements if e.kind in ("stop", "friction")]
    if method == "events" or (method == "auto" and contacts and active is None):
        from perturb.simulate.flows.system_events import SystemEventFlow

        if active is not None:
            raise ParameterError(
                f"active = {active!r}: the event-driven flow switches contacts itself"
            )
        return SystemEventFlow(model, rtol=rtol, atol=atol)
    stops = [e.name for e in model.elements if e.kind == "stop"]
    missing = [s for s in stops if s not in dict(active or {})]
    if missing:
        raise ModelError(
            f"system {model.name!r} has the stop(s) {missing}: pass active={{name: None "
            "(free), -1 or +1 (resting on the lower/upper limit)}} for each (a stop is a "
            "constraint: its impacts need the event-driven solver)"
        )
    if method == "exact":
        if not model.is_piecewise_linear:
            raise ModelError(
                f"method = 'exact': system {model.name!r} is not piecewise linear; use method='ode'"
            )
        return AffineExactFlow(model.piecewise_affine(active))
    if method == "auto" and model.is_piecewise_linear:
        try:
            return AffineExactFlow(model.piecewise_affine(active))
        except ModelError:
            pass  # e.g. more regions than MAX_REGIONS: the ODE flow takes it
    return SystemODEFlow(model, active=active, rtol=rtol, atol=atol)


class SystemODEFlow(Flow):
    r"""Smooth flow of a system of ``n`` states by DOP853, with variational equations.

    The right-hand side is :meth:`System.field <perturb.model.system.System.field>` (any
    elements; stops in the modes ``active``) or
    :meth:`PiecewiseAffineSystem.field <perturb.model.affine.PiecewiseAffineSystem.field>`; the
    sensitivity integrates :math:`\Phi' = J(t, y)\Phi`: for a ``System`` with the exact
    Jacobian of its elements (``f_e'`` differentiated symbolically once, Dirac terms dropped),
    for a ``PiecewiseAffineSystem`` the ``A`` of the region. Like :class:`ODEFlow` it steps across
    switches without locating them: exact to the tolerances for smooth fields only, and its
    sensitivity misses saltation; piecewise-affine systems have
    :class:`~perturb.simulate.flows.affine_exact.AffineExactFlow`.

    Parameters
    ----------
    system
        A :class:`~perturb.model.system.System` with all parameter values set, or a
        :class:`~perturb.model.affine.PiecewiseAffineSystem`.
    active
        Stop / sticking modes for a ``System`` (see :meth:`System.field`).
    rtol, atol
        Tolerances of DOP853.

    Attributes
    ----------
    n_states : int
        Number of states (declared for the orbit solvers).
    period : float or None
        The forcing period.
    """

    def __init__(
        self,
        system: System | PiecewiseAffineSystem,
        *,
        active: Mapping[str, int | None] | None = None,
        rtol: float = 1e-11,
        atol: float = 1e-12,
    ) -> None:
        if isinstance(system, PiecewiseAffineSystem):
            if active is not None:
                raise ParameterError(
                    f"active = {active!r}: a PiecewiseAffineSystem has its stop modes built in"
                )
            self._field: Callable[[float, np.ndarray], np.ndarray] = system.field
            self._jac = lambda t, y: system.region(system.pattern(y)).A
            self.period = system.period
            self.name = "piecewise-affine system"
        elif isinstance(system, System):
            act = dict(active or {})
            self._field = lambda t, y: np.asarray(system.field(t, y, act), dtype=float)
            self._jac = _system_jacobian(system, act)
            self.period = _system_period(system)
            self.name = system.name
        else:
            raise ParameterError(
                f"system = {system!r}: expected a System or a PiecewiseAffineSystem"
            )
        self.system_model = system
        self.n_states = int(system.n)
        self.rtol, self.atol = float(rtol), float(atol)
        self._forced = self.period is not None

    @property
    def autonomous(self) -> bool:
        """No harmonic forcing."""
        return not self._forced

    def __repr__(self) -> str:
        return (
            f"SystemODEFlow({self.name}, n={self.n_states}, period={self.period}, "
            f"rtol={self.rtol:g})"
        )

    def vector_field(self, t: float, y: ArrayLike) -> np.ndarray:
        return self._field(float(t), np.asarray(y, dtype=float))

    def jacobian(self, t: float, y: ArrayLike) -> np.ndarray:
        """``df/dy`` at ``(t, y)`` (exact; jumps of the field contribute nothing)."""
        return self._jac(float(t), np.asarray(y, dtype=float))

    def _augmented(self, t: float, z: np.ndarray) -> np.ndarray:
        n = self.n_states
        y = z[:n]
        phi = z[n:].reshape(n, n)
        return np.concatenate([self._field(t, y), (self.jacobian(t, y) @ phi).ravel()])

    def __call__(
        self,
        y0: ArrayLike,
        t0: float,
        t1: float,
        *,
        sensitivity: bool = False,
        t_eval: ArrayLike | None = None,
    ) -> FlowResult:
        """Propagate ``y0`` (``n`` states) from ``t0`` to ``t1 > t0``; see
        :class:`~perturb.simulate.flows.base.Flow`.

        Raises
        ------
        ParameterError
            Bad ``y0`` or interval.
        PerturbError
            The integration failed or its step budget ran out (see :class:`ODEFlow`).
        """
        n = self.n_states
        try:
            y = np.array(y0, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            raise ParameterError(f"y0 = {y0!r}: expected {n} finite numbers") from None
        if y.size != n or not np.all(np.isfinite(y)):
            raise ParameterError(f"y0 = {y.tolist()!r}: expected {n} finite numbers")
        if not (math.isfinite(t0) and math.isfinite(t1) and t1 > t0):
            raise ParameterError(f"(t0, t1) = ({t0}, {t1}): expected finite t1 > t0")
        z0 = np.concatenate([y, np.eye(n).ravel()]) if sensitivity else y
        fun = self._augmented if sensitivity else self._field
        budget = step_budget(t0, t1, self.period)
        sol = solve_ivp(
            fun,
            (t0, t1),
            z0,
            method="DOP853",
            rtol=self.rtol,
            atol=self.atol,
            dense_output=t_eval is not None,
            events=[budget],
        )
        if sol.status == 1:
            raise PerturbError(
                f"integration of {self.name!r} on [{t0}, {t1}] stopped at t = "
                f"{float(sol.t[-1])!r} after {budget.max_steps} steps: the step size collapsed "
                "(a jump in the field, or motion far faster than the forcing)"
            )
        if sol.status != 0 or not np.all(np.isfinite(sol.y[:, -1])):
            raise PerturbError(
                f"integration of {self.name!r} failed on [{t0}, {t1}]: {sol.message}"
            )
        final = sol.y[:, -1]
        t_out = ys = None
        if t_eval is not None:
            t_out = np.asarray(t_eval, dtype=float).reshape(-1)
            ys = sol.sol(t_out)[:n].T.copy() if t_out.size else np.empty((0, n))
        return FlowResult(
            t0=float(t0),
            t1=float(t1),
            y=final[:n].copy(),
            sensitivity=final[n:].reshape(n, n).copy() if sensitivity else None,
            t=t_out,
            ys=ys,
        )


def _system_jacobian(system: System, active: Mapping[str, int | None]):
    """``(t, y) -> df/dy`` of :meth:`System.field` in the modes ``active``: the linear part and
    ``w_e f_e'(c_e . y) c_e^T`` of every element (``f_e'`` by SymPy, Dirac terms dropped),
    through the same mass-matrix inverse and constraint projections as the field."""
    import sympy as sp

    from perturb.model.system import S

    num = system.numeric_form()
    act = {k: v for k, v in dict(active).items() if v is not None}
    P, Pv = system.constraint_projection(act)
    PB = P @ num["Binv"]
    n, n2 = system.n, num["n2"]
    mods = [{"Heaviside": lambda z, h0=0.5: np.heaviside(z, h0)}, "numpy"]

    def no_dirac(expr):
        return expr.replace(sp.DiracDelta, lambda *a: sp.Integer(0))

    terms = []
    for e in system.elements:
        if e.kind == "stop" or e.name in act:
            continue
        c, w = num["comb"][e.name]
        f = e.function.xreplace(num["vals"])
        if c is not None:
            fn = sp.lambdify([S], no_dirac(sp.diff(f, S)), modules=mods)
        else:
            grads = [no_dirac(sp.diff(f, s)) for s in system.states]
            fn = sp.lambdify(list(system.states), grads, modules=mods)
        terms.append((c, PB @ w, fn))
    base = np.zeros((n, n))
    base[:n2, n2 : 2 * n2] = Pv
    base[n2:, :] = -PB @ num["L"]

    def jac(t: float, y: np.ndarray) -> np.ndarray:
        J = base.copy()
        for c, pw, fn in terms:
            if c is not None:
                J[n2:, :] -= np.outer(pw, float(fn(float(c @ y))) * c)
            else:
                J[n2:, :] -= np.outer(pw, np.asarray(fn(*y), dtype=float))
        return J

    return jac


def _system_period(system: System) -> float | None:
    """The forcing period of a system (its harmonic inputs' common period), None without."""
    from perturb.model.system import common_period  # the model's own rule for a common period

    omegas = [om for om, _, _ in system.numeric_form()["harmonics"] if om != 0.0]
    return common_period(omegas)


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

    #: the model the family was built from (an Oscillator here; a System for
    #: :class:`SystemFlowFamily`)
    model: Oscillator | System
    #: number of states of every flow (2: ``(x, v)``)
    n_states: int = 2

    def __new__(cls, oscillator: Oscillator | System, *args: Any, **kwargs: Any) -> FlowFamily:
        # FlowFamily(system, ...) is the family of a system of several coordinates
        if cls is FlowFamily and isinstance(oscillator, System):
            return super().__new__(SystemFlowFamily)
        return super().__new__(cls)

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
        if not isinstance(osc, Oscillator):
            raise ParameterError(f"oscillator = {osc!r}: expected an Oscillator or a System")
        self.model = osc
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


class SystemFlowFamily(FlowFamily):
    """Flows of one :class:`~perturb.model.system.System` over the values of one parameter
    (``FlowFamily(system, parameter)`` builds one).

    Piecewise-affine systems get :class:`~perturb.simulate.flows.affine_exact.AffineExactFlow`
    of ``system.with_params({parameter: value}).piecewise_affine()``; when the parameter enters
    only the forcing frequencies, proportionally (the forcing frequency ``Omega`` of every
    builtin), the regions, surfaces and input vectors are built once and every value only
    rescales the input frequencies and the period (building them costs ~4 ms, as much as a
    dozen forcing periods of propagation). Other systems get :class:`SystemODEFlow` per value.
    Recent flows are kept, as for an oscillator.

    Parameters
    ----------
    system
        All parameters but ``parameter`` need values; no stops (their impacts need the
        event-driven solver).
    parameter
        Name of the parameter that varies; default ``'Omega'``.
    exact
        ``None``: the exact flow when the system is piecewise linear; ``False``: always
        :class:`SystemODEFlow`; ``True``: require the exact flow.

    Attributes
    ----------
    system : System
        The model (``model`` too; ``oscillator`` is None).
    n_states : int
    exact : bool
    event : bool
        Always False (no event-driven n-dimensional family yet).
    """

    def __init__(
        self,
        system: System,
        parameter: str | None = None,
        *,
        exact: bool | None = None,
        rtol: float = 1e-11,
        atol: float = 1e-12,
    ) -> None:
        if not isinstance(system, System):
            raise ParameterError(f"system = {system!r}: expected a System")
        if parameter is None:
            if "Omega" not in system.params:
                raise ModelError(
                    f"system {system.name!r} has no parameter 'Omega' (the forcing frequency): "
                    f"name the parameter (one of {', '.join(system.params) or 'none'})"
                )
            parameter = "Omega"
        if parameter not in system.params:
            raise ParameterError(
                f"parameter {parameter!r} is not in system {system.name!r}: expected one of "
                + (", ".join(system.params) or "none")
            )
        stops = [e.name for e in system.elements if e.kind == "stop"]
        if stops:
            raise ModelError(
                f"system {system.name!r} has the stop(s) {stops}: a family of flows over a "
                "parameter takes systems without stops (impacts need the event-driven solver)"
            )
        others = [k for k, v in system.params.items() if v is None and k != parameter]
        if others:
            raise ParameterError(f"system {system.name!r} needs values for {', '.join(others)}")
        self.model = self.system = system
        self.oscillator = None  # type: ignore[assignment]
        self.parameter = parameter
        self.rtol, self.atol = rtol, atol
        self.n_states = int(system.n)
        self.event = False
        self._event = None
        self._rhs = None
        self._pwl = None
        pwl = system.is_piecewise_linear
        use_exact = pwl if exact is None else bool(exact)
        if use_exact and not pwl:
            raise ModelError(f"system {system.name!r} is not piecewise linear: no exact flow")
        self.exact = use_exact
        self._recent: dict[float, Flow] = {}
        # the frequency-only fast path: (reference system, frequency rates, period * value)
        self._scaled: tuple[PiecewiseAffineSystem, np.ndarray, float] | None = None
        if use_exact:
            self._scaled = self._frequency_scaling()

    def __repr__(self) -> str:
        # (also for a half-built family: repr is called when __init__ raises)
        name = getattr(getattr(self, "system", None), "name", "?")
        kind = "exact" if getattr(self, "exact", False) else "ode"
        return f"FlowFamily({name}, {getattr(self, 'parameter', '?')}, {kind})"

    def _affine(self, value: float) -> PiecewiseAffineSystem:
        return self.system.with_params({self.parameter: value}).piecewise_affine()

    def _frequency_scaling(self) -> tuple[PiecewiseAffineSystem, np.ndarray, float] | None:
        """The reference system and ``d omega_k / d value`` when the parameter enters only the
        input frequencies, proportionally (checked at two values), else None."""
        v0 = self.system.params.get(self.parameter) or 1.0
        v1 = 1.37 * v0 + 0.11
        try:
            a, b = self._affine(v0), self._affine(v1)
        except (ModelError, ParameterError):
            return None
        if a.period is None or b.period is None or not a.inputs:
            return None
        if (
            len(a.inputs) != len(b.inputs)
            or len(a.surfaces) != len(b.surfaces)
            or not all(
                np.array_equal(sa.normal, sb.normal) and sa.offset == sb.offset
                for sa, sb in zip(a.surfaces, b.surfaces, strict=True)
            )
        ):
            return None
        if set(a.regions) != set(b.regions) or any(
            not (np.array_equal(a.regions[k].A, b.regions[k].A))
            or not np.array_equal(a.regions[k].b, b.regions[k].b)
            for k in a.regions
        ):
            return None
        rates = np.array([h.omega / v0 for h in a.inputs])
        for ha, hb, r in zip(a.inputs, b.inputs, rates, strict=True):
            if not (np.array_equal(ha.u, hb.u) and np.array_equal(ha.v, hb.v)):
                return None
            if not math.isclose(r * v1, hb.omega, rel_tol=1e-13, abs_tol=0.0):
                return None
        if not math.isclose(a.period * v0, b.period * v1, rel_tol=1e-12, abs_tol=0.0):
            return None
        return a, rates, a.period * v0

    def at(self, value: float) -> Flow:
        """The flow at ``parameter = value``."""
        value = validate_parameter_value(self.parameter, value)
        flow = self._recent.get(value)
        if flow is not None:
            return flow
        if self._scaled is not None:
            ref, rates, pv = self._scaled
            if value <= 0.0:
                raise ParameterError(
                    f"{self.parameter} = {value!r}: expected a positive forcing frequency"
                )
            inputs = tuple(
                HarmonicInput(float(r * value), h.u, h.v)
                for r, h in zip(rates, ref.inputs, strict=True)
            )
            flow = AffineExactFlow(replace(ref, inputs=inputs, period=pv / value))
        elif self.exact:
            flow = AffineExactFlow(self._affine(value))
        else:
            flow = SystemODEFlow(
                self.system.with_params({self.parameter: value}), rtol=self.rtol, atol=self.atol
            )
        if len(self._recent) >= _RECENT_FLOWS:
            self._recent.pop(next(iter(self._recent)))
        self._recent[value] = flow
        return flow


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
