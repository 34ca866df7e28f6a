"""One front door for time histories: exact, event-driven, LCP or plain ODE integration.

:func:`time_history` picks the integrator a model needs (``method="auto"``): the exact
piecewise-analytic propagator for piecewise-linear oscillators, the event-driven integrator
for other nonsmooth ones, ``solve_ivp`` for smooth ones; ``"lcp"`` runs the fixed-step LCP
scheme (step ``h``). All return the same :class:`TimeHistory`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from perturb.errors import ParameterError
from perturb.model.oscillator import Oscillator

__all__ = ["TimeHistory", "time_history", "METHODS"]

METHODS = ("auto", "exact", "event", "lcp", "ode")


@dataclass(frozen=True, eq=False)
class TimeHistory:
    """Samples ``t, x, v`` of one run and the integrator that made them."""

    t: np.ndarray
    x: np.ndarray
    v: np.ndarray
    method: str
    n_events: int = 0

    def __repr__(self) -> str:
        return (
            f"TimeHistory({self.t.size} samples, t {self.t[0]:.4g}..{self.t[-1]:.4g}, "
            f"max|x| {np.max(np.abs(self.x)):.4g}, method {self.method}, {self.n_events} events)"
        )

    def to_csv(self, path=None) -> str:
        """The CSV text ``t,x,v``; with ``path`` also written there (atomically: a temporary
        file in the same folder renamed over ``path`` once complete)."""
        lines = ["t,x,v"] + [
            f"{t!r},{x!r},{v!r}"
            for t, x, v in zip(self.t.tolist(), self.x.tolist(), self.v.tolist(), strict=True)
        ]
        text = "\n".join(lines) + "\n"
        if path is not None:
            from perturb.atomic import write_text

            write_text(path, text)  # complete or absent, also when killed or the disk is full
        return text


def time_history(
    oscillator: Oscillator,
    y0: ArrayLike,
    t_span: Sequence[float],
    *,
    method: str = "auto",
    samples: int = 2001,
    h: float | None = None,
    Omega: float | None = None,
) -> TimeHistory:
    """Integrate ``oscillator`` from ``y0`` over ``t_span`` and sample ``samples`` instants.

    Parameters
    ----------
    method
        ``"auto"``, ``"exact"`` (PWL only), ``"event"``, ``"lcp"`` (continuous PWL; fixed
        step ``h``, default a 200th of the forcing period) or ``"ode"``.

    Raises
    ------
    ParameterError
        Unknown method, bad span or sample count.
    """
    if method not in METHODS:
        raise ParameterError(f"method = {method!r}: expected one of {', '.join(METHODS)}")
    t0, t1 = (float(t) for t in t_span)
    if not (np.isfinite(t0) and np.isfinite(t1) and t1 > t0):
        raise ParameterError(f"t_span = {tuple(t_span)!r}: expected finite (t0, t1), t1 > t0")
    if int(samples) < 2:
        raise ParameterError(f"samples = {samples}: expected at least 2")
    t_eval = np.linspace(t0, t1, int(samples))
    osc = oscillator
    if method == "auto":
        if osc.is_piecewise_linear:
            method = "exact"
        elif not osc.is_smooth:
            method = "event"
        else:
            method = "ode"
    if method == "exact":
        from perturb.simulate.flows.piecewise_exact import propagate
        from perturb.simulate.flows.system import to_pwl_system

        traj = propagate(to_pwl_system(osc, Omega), y0, (t0, t1), t_eval=t_eval)
        return TimeHistory(traj.t, traj.x, traj.v, "exact", len(traj.events))
    if method == "event":
        from perturb.simulate.flows.event_driven import simulate

        traj = simulate(osc, y0, (t0, t1), Omega=Omega, t_eval=t_eval)
        return TimeHistory(traj.t, traj.x, traj.v, "event", len(traj.events))
    if method == "lcp":
        from perturb.simulate.flows.lcp import simulate_lcp
        from perturb.simulate.flows.system import first_order_rhs

        if h is None:
            period = first_order_rhs(osc, Omega).period or 2 * np.pi
            h = period / 200
        traj = simulate_lcp(osc, y0, (t0, t1), h, Omega=Omega)
        x = np.interp(t_eval, traj.t, traj.x)
        v = np.interp(t_eval, traj.t, traj.v)
        # the step actually taken: simulate_lcp shortens it on a stiff contact
        return TimeHistory(t_eval, x, v, f"lcp(h={traj.h:.3g})", 0)
    from perturb.simulate.flows.factory import make_flow

    # the ODE flow at its own default tolerances (the flow factory's are looser)
    res = make_flow(osc, Omega, method="ode", rtol=1e-11, atol=1e-12)(y0, t0, t1, t_eval=t_eval)
    assert res.ys is not None and res.t is not None
    return TimeHistory(res.t, res.ys[:, 0], res.ys[:, 1], "ode", 0)
