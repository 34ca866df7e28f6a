"""From an :class:`~perturb.model.oscillator.Oscillator` to the numeric systems the integrators
take.

- :func:`to_pwl_system`: the data of the exact piecewise-analytic propagator
  (:class:`~perturb.simulate.flows.piecewise_exact.PWLSystem`) for oscillators with linear viscous
  damping, a piecewise-linear restoring force and harmonic forcing.
- :func:`first_order_rhs`: ``y' = F(t, y)`` with ``y = (x, x')`` and its Jacobian, for
  ``solve_ivp`` and shooting on any oscillator.

The forcing frequency can be overridden (``Omega=``) so a sweep reuses one oscillator.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import sympy as sp

from perturb.errors import ModelError, ParameterError
from perturb.model.oscillator import Forcing, Harmonic, Oscillator, validate_parameter_value
from perturb.simulate.flows.piecewise_exact import PWLSystem

__all__ = [
    "to_pwl_system",
    "first_order_rhs",
    "NumericRHS",
    "frequency_symbol",
    "parameter_values",
]


def frequency_symbol(osc: Oscillator) -> sp.Symbol | None:
    """The symbol of the (first) forcing frequency when it is a plain parameter, else None."""
    if osc.forcing.harmonics:
        w = osc.forcing.harmonics[0].frequency
        if isinstance(w, sp.Symbol):
            return w
    return None


def parameter_values(osc: Oscillator, Omega: float | None = None) -> dict[sp.Symbol, sp.Float]:
    """Parameter symbol -> value, with the forcing frequency overridden by ``Omega``."""
    subs = osc.substitutions()
    if Omega is not None:
        sym = frequency_symbol(osc)
        if sym is None:
            raise ModelError(
                f"model {osc.name!r} has no forcing-frequency parameter to set Omega = {Omega}"
            )
        subs[sym] = sp.Float(validate_parameter_value(sym.name, Omega))
    return subs


def _number(expr: sp.Expr, what: str, osc: Oscillator) -> float:
    free = sorted(s.name for s in expr.free_symbols)
    if free:
        raise ParameterError(f"model {osc.name!r} needs values for {', '.join(free)} ({what})")
    return float(expr)


def to_pwl_system(osc: Oscillator, Omega: float | None = None) -> PWLSystem:
    """The exact propagator's data for a PWL oscillator with all parameter values set.

    Raises
    ------
    ModelError
        If the oscillator is not ``x'' + mu x' + f(x) = c + sum F_j cos(w_j t + p_j)`` with a
        piecewise-linear ``f``.
    ParameterError
        If a parameter has no value.
    """
    if not osc.is_piecewise_linear:
        raise ModelError(
            f"model {osc.name!r} is not piecewise linear; use the event-driven integrator"
        )
    subs = parameter_values(osc, Omega)
    numeric = osc.with_params({s.name: float(v) for s, v in subs.items()})
    pwl = numeric.piecewise_linear().numeric()
    mu = _number(numeric.damping.xreplace(subs), "damping", osc)
    forcing = tuple(
        (
            _number(h.amplitude.xreplace(subs), "forcing amplitude", osc),
            _number(h.frequency.xreplace(subs), "forcing frequency", osc),
            _number(h.phase.xreplace(subs), "forcing phase", osc),
        )
        for h in osc.forcing.harmonics
    )
    # a negative frequency is the same harmonic with the phase reversed
    forcing = tuple((a, abs(w), p if w > 0 else -p) for a, w, p in forcing)
    static = _number(osc.forcing.constant.xreplace(subs), "static load", osc)
    return PWLSystem(
        breakpoints=np.asarray(pwl.breakpoints, float),
        slopes=np.asarray(pwl.slopes, float),
        offsets=np.asarray(pwl.offsets, float),
        damping=mu,
        forcing=tuple(f for f in forcing if f[0] != 0.0),
        static_force=static,
    )


@dataclass(frozen=True)
class NumericRHS:
    """``y' = fun(t, y)`` for ``y = (x, x')``, with ``jac(t, y)`` (2x2) and the forcing
    period (None when autonomous)."""

    fun: Callable[[float, np.ndarray], np.ndarray]
    jac: Callable[[float, np.ndarray], np.ndarray]
    period: float | None


def first_order_rhs(osc: Oscillator, Omega: float | None = None) -> NumericRHS:
    """The first-order system of ``osc`` with all parameter values substituted.

    Heaviside is evaluated with ``H(0) = 1/2``; the Jacobian drops Dirac terms (jumps are
    for event handling, not for the smooth Jacobian).
    """
    subs = parameter_values(osc, Omega)
    g = osc.g.xreplace(subs)
    f = osc.forcing.expr(osc.t).xreplace(subs)
    free = sorted(s.name for s in (g.free_symbols | f.free_symbols) - {osc.x, osc.v, osc.t})
    if free:
        raise ParameterError(f"model {osc.name!r} needs values for {', '.join(free)}")
    acc = f - g
    dx = sp.diff(acc, osc.x).replace(sp.DiracDelta, lambda *a: sp.Integer(0))
    dv = sp.diff(acc, osc.v).replace(sp.DiracDelta, lambda *a: sp.Integer(0))
    mods = [{"Heaviside": lambda z, h0=0.5: np.heaviside(z, h0)}, "numpy"]
    acc_fn = sp.lambdify((osc.t, osc.x, osc.v), acc, modules=mods)
    jac_fn = sp.lambdify((osc.t, osc.x, osc.v), [dx, dv], modules=mods)

    def fun(t: float, y: np.ndarray) -> np.ndarray:
        return np.array([y[1], acc_fn(t, y[0], y[1])], dtype=float)

    def jac(t: float, y: np.ndarray) -> np.ndarray:
        a, b = jac_fn(t, y[0], y[1])
        return np.array([[0.0, 1.0], [float(a), float(b)]])

    period = None
    expr = forcing_period_expr(osc)
    if expr is not None:
        period = 2 * np.pi / _number(2 * sp.pi / expr.xreplace(subs), "forcing frequency", osc)
    return NumericRHS(fun=fun, jac=jac, period=period)


def forcing_period_expr(osc: Oscillator) -> sp.Expr | None:
    """The period of the forcing (and of parametric terms) as an expression in the
    parameters: ``2 pi / |base frequency|``, or None when the system is autonomous."""
    base = osc.forcing.base_frequency
    if osc.parametric != 0:
        freqs = [sp.expand(a.args[0]).coeff(osc.t) for a in osc.parametric.atoms(sp.cos, sp.sin)]
        if base is not None:
            freqs.append(base)
        base = Forcing(tuple(Harmonic(sp.Integer(1), w) for w in freqs)).base_frequency
    if base is None:
        return None
    return 2 * sp.pi / sp.Abs(base)
