r"""Limit cycling and periodic solutions: the tools of the literature study, measured.

The literature study on limit cycling (docs/references.md section 3, its chapters 3 and 4)
reviews the nonsmooth causes of self-excited oscillation (dead zone,
saturation, backlash, relay, hysteresis) and the tools that predict periodic solutions:
describing functions for a Lur'e loop (1 + N(A) W(j omega) = 0), single shooting with a phase
condition, periodic finite differences and multiple shooting.  Its claims are qualitative
("finite differences are computationally more efficient than shooting", "shooting is very
vulnerable to bad initial guesses", "the finite difference method can only be applied to smooth
systems", "the describing function gives the limit cycle probably and approximately").  This
script puts numbers on them.

1. *Periodic-orbit solvers on the same orbits.*  perturb's single shooting (``periodic_orbit``,
   ``limit_cycle``), multiple shooting (``multiple_shooting``, all in
   :mod:`perturb.simulate.orbits.shooting`) and periodic finite differences
   (:func:`~perturb.simulate.orbits.collocation.collocation_orbit`) on the forced Duffing
   oscillator, the van der Pol limit cycle at eps = 1 and 5, and the Zou-Nagarajaiah (nsd)
   orbits (exact PWL flow, event-driven flow, plain ODE flow).  Cost: wall time, Newton
   iterations, right-hand-side and Jacobian evaluations (counted by wrapping the
   :class:`~perturb.simulate.flows.system.NumericRHS` that
   :class:`~perturb.simulate.flows.base.ODEFlow`
   integrates) or flow calls and linear pieces (PWL flows).  Accuracy: against references
   computed here with ``solve_ivp`` (DOP853, rtol 1e-13) -- a long run to the attracting cycle
   for van der Pol, Newton shooting on the variational equations for Duffing, the same with
   switches located by events for the nsd orbit, and the closed-form linear response for the
   nsd saddle orbit.  A work-precision sweep (ODE tolerance for shooting, grid size and order
   for finite differences) gives the figure.
2. *Describing functions* of the dead zone, saturation, ideal relay, relay with hysteresis and
   backlash.  The single-valued ones come from perturb's Fourier engine
   (``deadzone_coefficients``, ``saturation_coefficients``, ``sign_coefficients`` of
   :mod:`perturb.fourier.coefficients`, and symbolically
   :func:`~perturb.methods.averaging.equivalent_linearisation`); perturb has none for
   nonlinearities with memory (its Fourier engine takes static g(x), and averaging rejects
   ``M*sign(x - h*sign(x'))``), so the hysteretic relay and the backlash are derived here with
   SymPy by integrating their steady output waveform.  Every closed form is checked against the
   FFT of that waveform.
3. *Lur'e loops.*  Each nonlinearity in feedback with a third-order plant chosen so that the
   describing function predicts a stable limit cycle; amplitude and frequency from
   1 + N(a) G(i omega) = 0, stability by the Loeb criterion (the quasi-linear loop is stable
   just above the predicted amplitude and unstable just below), against an event-driven
   ``solve_ivp`` simulation written here (every mode of these loops is affine; switches are
   located as events), measured on its steady oscillation (period from upward zero crossings,
   first-harmonic amplitude by FFT over the last period).

4. *Dry friction, an event map, continuation at a fold.*  Stick-slip limit cycles of a mass on
   a moving belt: Coulomb friction with a static coefficient above the kinetic one (which
   perturb's Filippov sticking cannot hold; event-located ``solve_ivp`` written here, against
   the closed-form cycle) and Stribeck friction (perturb's event-driven integrator); the
   return map of van der Pol on x' = 0, x > 0, whose fixed point is the limit-cycle amplitude
   and whose slope is the Floquet multiplier (the determinant of perturb's monodromy matrix);
   sequential (natural-parameter) continuation of the one-harmonic forced Duffing response,
   which loses its branch one step past each fold, against perturb's pseudo-arclength core
   (:func:`perturb.numeric.continuation.continue_curve`), which passes both.

All parameter values are representative choices (the seed gives no numbers), except the nsd
parameters k = -2, mu = 0.05, F = 2, Omega = 0.6, which are the Zou-Nagarajaiah Fig. 5 values
reconstructed in docs/references.md section 1.

Run ``python derivations/periodic_solutions.py [--fast] [--out DIR]``; outputs go to ``DIR``
(default ``derivations/out/periodic_solutions/``): section.tex, PNG figures, CSV tables.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path

import numpy as np
import sympy as sp
from scipy.integrate import quad, solve_ivp
from scipy.optimize import brentq

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:  # imported by path (tests) rather than run as a script
    sys.path.insert(0, str(HERE))

from _common import Study, study  # noqa: E402

from perturb.errors import ModelError, PerturbError  # noqa: E402
from perturb.fourier.coefficients import (  # noqa: E402
    deadzone_coefficients,
    saturation_coefficients,
    sign_coefficients,
)
from perturb.methods.averaging import equivalent_linearisation  # noqa: E402
from perturb.model.builtins import builtin_model  # noqa: E402
from perturb.model.oscillator import Oscillator  # noqa: E402
from perturb.model.parsing import real_symbol  # noqa: E402
from perturb.numeric.continuation import (  # noqa: E402
    ContinuationError,
    continue_curve,
    newton_fixed,
)
from perturb.printing import latex  # noqa: E402
from perturb.report.latex import escape  # noqa: E402
from perturb.simulate.flows.base import ODEFlow  # noqa: E402
from perturb.simulate.flows.event_driven import EventFlow  # noqa: E402
from perturb.simulate.flows.event_driven import simulate as event_driven_simulate  # noqa: E402
from perturb.simulate.flows.exact import ExactPWLFlow  # noqa: E402
from perturb.simulate.flows.system import NumericRHS, first_order_rhs  # noqa: E402
from perturb.simulate.orbits.collocation import collocation_orbit  # noqa: E402
from perturb.simulate.orbits.shooting import (  # noqa: E402
    PeriodicOrbit,
    ShootingError,
    limit_cycle,
    multiple_shooting,
    periodic_orbit,
)

NAME = "periodic_solutions"
TWO_PI = 2.0 * math.pi

#: tolerances of the references written here (DOP853)
REF_RTOL, REF_ATOL = 1e-13, 1e-14
#: phase samples on which two orbits are compared
N_COMPARE = 64


# ============================================================================================
# 1. periodic-orbit solvers
# ============================================================================================
@dataclass(frozen=True)
class OrbitCase:
    """One periodic orbit that every solver is asked for.

    ``fun``/``jac`` are the equations of motion written out here, independently of perturb's
    parser, for the reference; ``switches`` are the positions where the force has a kink (the
    reference integrator stops and restarts there).
    """

    key: str
    title: str
    model: Oscillator
    autonomous: bool
    fun: Callable[..., np.ndarray]
    jac: Callable[..., np.ndarray]
    switches: tuple[float, ...] = ()
    #: (x, v) -> the segment of a PWL force that the motion is in or enters (``fun`` and
    #: ``jac`` take it as a third argument and then keep that segment's linear force)
    segment: Callable[[float, float], int] | None = None
    #: guess of the period for an autonomous case (forced: the forcing period)
    period_hint: float = 0.0


def _duffing(mu=0.1, w0=1.0, alpha=1.0, F=0.5, W=1.2) -> OrbitCase:
    def fun(t, y):
        x, v = y
        return np.array([v, F * math.cos(W * t) - mu * v - w0 * w0 * x - alpha * x**3])

    def jac(t, y):
        return np.array([[0.0, 1.0], [-w0 * w0 - 3.0 * alpha * y[0] ** 2, -mu]])

    return OrbitCase(
        "duffing",
        r"Duffing, $\mu=0.1$, $\alpha=1$, $F=0.5$, $\Omega=1.2$",
        builtin_model("duffing", mu=mu, omega0=w0, alpha=alpha, F=F, Omega=W),
        autonomous=False,
        fun=fun,
        jac=jac,
        period_hint=TWO_PI / W,
    )


def _vanderpol(eps: float) -> OrbitCase:
    def fun(t, y):
        x, v = y
        return np.array([v, eps * (1.0 - x * x) * v - x])

    def jac(t, y):
        x, v = y
        return np.array([[0.0, 1.0], [-2.0 * eps * x * v - 1.0, eps * (1.0 - x * x)]])

    # the classical relaxation-oscillation estimate (3 - 2 ln 2) eps + 7.014 eps^(-1/3) for
    # large eps, 2 pi for small: only a hint for the reference run, never given to perturb
    hint = TWO_PI if eps < 2 else (3.0 - 2.0 * math.log(2.0)) * eps + 7.014 * eps ** (-1 / 3)
    return OrbitCase(
        f"vdp{eps:g}",
        rf"van der Pol, $\varepsilon={eps:g}$",
        builtin_model("vanderpol", eps=eps),
        autonomous=True,
        fun=fun,
        jac=jac,
        period_hint=hint,
    )


NSD = {"k": -2.0, "mu": 0.05, "F": 2.0, "Omega": 0.6}  # Zou-Nagarajaiah Fig. 5 (docs/references.md)


def _nsd_segment(x: float, v: float) -> int:
    """-1, 0, 1 for x < -1, |x| < 1, x > 1; on a breakpoint, the side the velocity enters."""
    for d, above in ((1.0, 1), (-1.0, 0)):
        if x > d or (x == d and v > 0):
            return above
        if x == d:
            return above - 1
    return -1


def _nsd_force(x: float, k: float, seg: int | None = None) -> tuple[float, float]:
    """f(x) and f'(x) of kx + (1-k)[(x-1)H(x-1) + (x+1)H(-x-1)], written out by segment
    (``seg`` given: that segment's line, continued beyond its breakpoints)."""
    if seg is None:
        seg = 1 if x > 1.0 else (-1 if x < -1.0 else 0)
    if seg == 1:
        return x + (k - 1.0), 1.0
    if seg == -1:
        return x + (1.0 - k), 1.0
    return k * x, k


def _nsd(saddle: bool) -> OrbitCase:
    k, mu, F, W = NSD["k"], NSD["mu"], NSD["F"], NSD["Omega"]

    def fun(t, y, seg=None):
        f, _ = _nsd_force(y[0], k, seg)
        return np.array([y[1], F * math.cos(W * t) - mu * y[1] - f])

    def jac(t, y, seg=None):
        _, s = _nsd_force(y[0], k, seg)
        return np.array([[0.0, 1.0], [-s, -mu]])

    title = "nsd, small saddle orbit" if saddle else "nsd, large orbit"
    return OrbitCase(
        "nsd_saddle" if saddle else "nsd",
        title + r" ($k=-2$, $\mu=0.05$, $F=2$, $\Omega=0.6$)",
        builtin_model("nsd", **NSD),
        autonomous=False,
        fun=fun,
        jac=jac,
        switches=(-1.0, 1.0),
        period_hint=TWO_PI / W,
        segment=_nsd_segment,
    )


def orbit_cases() -> list[OrbitCase]:
    return [_duffing(), _vanderpol(1.0), _vanderpol(5.0), _nsd(False), _nsd(True)]


# -- the reference integrator (written here) ---------------------------------------------------
def _augmented(fun, jac):
    def rhs(t, z):
        y = z[:2]
        phi = z[2:].reshape(2, 2)
        return np.concatenate([fun(t, y), (jac(t, y) @ phi).ravel()])

    return rhs


def propagate(
    case: OrbitCase,
    y0: np.ndarray,
    t0: float,
    t1: float,
    *,
    variational: bool = False,
    t_eval: np.ndarray | None = None,
    turning: bool = False,
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None, list[float]]:
    """State at ``t1``, its sensitivity, states at ``t_eval`` and the x-values where v = 0.

    The integration stops at every kink of the force (``case.switches``) and restarts; within
    a segment the force is that segment's line, continued past the breakpoints, so no step
    ever sees the kink (the event is located on the smooth continuation).  The nsd force is
    continuous, so the variational state passes the switch unchanged (the saltation matrix is
    the identity).
    """
    z = np.concatenate([y0, np.eye(2).ravel()]) if variational else np.array(y0, float)
    t = t0
    outs = [] if t_eval is None else [None] * len(t_eval)
    turns: list[float] = []
    last_switch = None  # (index, direction to arm) of the boundary just crossed
    while True:
        if case.segment is None:
            f_seg, j_seg = case.fun, case.jac
        else:
            seg = case.segment(float(z[0]), float(z[1]))

            def f_seg(tt, y, seg=seg):
                return case.fun(tt, y, seg)

            def j_seg(tt, y, seg=seg):
                return case.jac(tt, y, seg)

        fun = _augmented(f_seg, j_seg) if variational else f_seg
        events = []
        for i, d in enumerate(case.switches):

            def ev(tt, zz, d=d):
                return zz[0] - d

            ev.terminal = True
            ev.direction = 0.0 if last_switch is None or last_switch[0] != i else last_switch[1]
            events.append(ev)

        def turn(tt, zz):
            return zz[1]

        events.append(turn)
        sol = solve_ivp(
            fun,
            (t, t1),
            z,
            method="DOP853",
            rtol=REF_RTOL,
            atol=REF_ATOL,
            events=events,
            dense_output=t_eval is not None,
        )
        if sol.status < 0:
            raise RuntimeError(f"reference integration failed: {sol.message}")
        t_end = sol.t[-1]
        if t_eval is not None:
            for j, te in enumerate(t_eval):
                if outs[j] is None and t - 1e-15 <= te <= t_end + 1e-15:
                    outs[j] = sol.sol(min(max(te, t), t_end))[:2]
        if turning:
            turns.extend(float(yy[0]) for yy in sol.y_events[-1])
        if sol.status == 0:
            z = sol.y[:, -1]
            break
        i = next(i for i in range(len(case.switches)) if sol.t_events[i].size)
        t = float(sol.t_events[i][0])
        z = sol.y_events[i][0].copy()
        # on the breakpoint exactly (moves x by rounding only), so that the velocity picks
        # the segment entered, not the rounding of the located event
        z[0] = case.switches[i]
        # the next crossing of this boundary goes back the other way
        last_switch = (i, -math.copysign(1.0, z[1]))
    sens = z[2:].reshape(2, 2) if variational else None
    ys = None if t_eval is None else np.array(outs)
    return z[:2].copy(), sens, ys, turns


@dataclass(frozen=True)
class Reference:
    """A converged periodic orbit computed here: ``y0`` at ``t0 = 0``, period, amplitude."""

    case: OrbitCase
    y0: np.ndarray
    period: float
    amplitude: float
    how: str
    seconds: float
    #: t -> states (n, 2) in closed form, where there is one
    closed: Callable[[np.ndarray], np.ndarray] | None = None

    def states(self, phases: np.ndarray) -> np.ndarray:
        """States at ``t = period * phases`` (``0 <= phases < 1``), shape (n, 2)."""
        t = self.period * np.asarray(phases, float)
        if self.closed is not None:
            # an unstable orbit cannot be sampled by integrating it: its multiplier (2e6 for
            # the nsd saddle) amplifies the integration error across the period
            return self.closed(t)
        _, _, ys, _ = propagate(self.case, self.y0, 0.0, self.period, t_eval=t)
        return ys


def _newton_forced(case: OrbitCase, y: np.ndarray, T: float, tol: float = 1e-13) -> np.ndarray:
    """phi_T(y) = y by Newton on the variational equations (no line search: the guesses
    handed in are close)."""
    for _ in range(40):
        yT, M, _, _ = propagate(case, y, 0.0, T, variational=True)
        dy = np.linalg.solve(M - np.eye(2), -(yT - y))
        y = y + dy
        if np.max(np.abs(dy)) <= tol * max(1.0, np.max(np.abs(y))):
            return y
    raise RuntimeError(f"reference Newton did not converge for {case.key}")


def _long_run_cycle(case: OrbitCase, y: np.ndarray) -> tuple[np.ndarray, float]:
    """An attracting limit cycle by integrating until successive maxima of x repeat: the
    period is the time between two maxima, y0 = (x_max, 0)."""

    def top(t, z):
        return z[1]

    top.direction = -1.0  # v falls through 0 at a maximum of x
    t, T_prev, x_prev = 0.0, math.nan, math.nan
    chunk = 4.0 * case.period_hint
    for _ in range(60):
        sol = solve_ivp(
            case.fun, (t, t + chunk), y, method="DOP853", rtol=REF_RTOL, atol=REF_ATOL, events=top
        )
        tops, xs = sol.t_events[0], sol.y_events[0][:, 0] if sol.t_events[0].size else []
        if len(tops) >= 2:
            T, x = float(tops[-1] - tops[-2]), float(xs[-1])
            if abs(T - T_prev) < 1e-11 * T and abs(x - x_prev) < 1e-11 * abs(x):
                return np.array([x, 0.0]), T
            T_prev, x_prev = T, x
        t, y = sol.t[-1], sol.y[:, -1]
    raise RuntimeError(f"the long run for {case.key} did not settle")


def linear_steady_state(k: float, mu: float, F: float, W: float):
    """``(states, amplitude)`` of the steady response of x'' + mu x' + k x = F cos(W t):
    x = Re(X e^{iWt}), X = F/(k - W^2 + i mu W); ``states(t)`` has shape (n, 2)."""
    X = F / (k - W * W + 1j * mu * W)

    def states(t: np.ndarray) -> np.ndarray:
        z = X * np.exp(1j * W * np.asarray(t, float))
        return np.column_stack([z.real, (1j * W * z).real])

    return states, abs(X)


def reference_orbit(case: OrbitCase) -> Reference:
    start = time.perf_counter()
    closed = None
    if case.key == "nsd_saddle":
        # |x| < 1 on the whole orbit (checked below): a linear oscillator, solved in closed form
        closed, amp = linear_steady_state(NSD["k"], NSD["mu"], NSD["F"], NSD["Omega"])
        y0 = closed(np.zeros(1))[0]
        T, how = case.period_hint, "closed-form linear response"
    elif case.autonomous:
        y0, T = _long_run_cycle(case, np.array([2.0, 0.0]))
        how = "long solve\\_ivp run, maxima repeat to $10^{-11}$"
    else:
        start_guess = {"duffing": np.array([1.0, 0.0]), "nsd": np.array([9.4, 1.0])}[case.key]
        T = case.period_hint
        y0 = _newton_forced(case, start_guess, T)
        how = "Newton shooting, variational equations" + (
            ", switches as events" if case.switches else ""
        )
    if closed is not None:
        if amp >= 1.0:
            raise RuntimeError("the nsd saddle orbit leaves |x| < 1: not the linear response")
    else:
        _, _, _, turns = propagate(case, y0, 0.0, T, turning=True)
        amp = max(abs(y0[0]), *(abs(x) for x in turns))
    return Reference(case, y0, T, amp, how, time.perf_counter() - start, closed)


# -- counting the cost ---------------------------------------------------------------------------
class Runaway(RuntimeError):
    """An iterate left the region of the orbit (raised by the guards below)."""


#: a solver whose iterate reaches |x| > RUNAWAY x (reference amplitude) is stopped.  Newton on
#: van der Pol at eps = 5 can walk towards the trivial solution T -> 0 with |x| doubling per
#: step (perturb does not stop it), and every step then costs more (stiffness ~ eps x^2)
RUNAWAY = 20.0


class CountingRHS:
    """A NumericRHS whose ``fun``/``jac`` calls are counted (ODEFlow and collocation use it);
    it raises :class:`Runaway` beyond ``|x| > bound``."""

    def __init__(self, base: NumericRHS, bound: float = math.inf) -> None:
        self.nfev = 0
        self.njev = 0

        def fun(t, y):
            self.nfev += 1
            if abs(y[0]) > bound:
                raise Runaway(f"|x| = {abs(y[0]):.3g} > {bound:.3g}")
            return base.fun(t, y)

        def jac(t, y):
            self.njev += 1
            return base.jac(t, y)

        self.rhs = NumericRHS(fun=fun, jac=jac, period=base.period)


class CountingExactFlow(ExactPWLFlow):
    """ExactPWLFlow counting its calls and the linear pieces they propagate (the dense output
    used for the orbit statistics goes through ``trajectory`` and is not counted)."""

    def __init__(self, osc: Oscillator, bound: float = math.inf) -> None:
        super().__init__(osc)
        self.calls = 0
        self.pieces = 0
        self.bound = bound

    def __call__(self, y0, t0, t1, *, sensitivity=False, t_eval=None):
        if abs(float(np.asarray(y0, float)[0])) > self.bound:
            raise Runaway(f"|x| > {self.bound:.3g}")
        res = super().__call__(y0, t0, t1, sensitivity=sensitivity, t_eval=t_eval)
        self.calls += 1
        self.pieces += res.n_events + 1
        return res


class CountingEventFlow(EventFlow):
    """EventFlow counting its calls and the smooth segments they integrate."""

    def __init__(self, osc: Oscillator, bound: float = math.inf, **kw) -> None:
        super().__init__(osc, **kw)
        self.calls = 0
        self.pieces = 0
        self.bound = bound

    def __call__(self, y0, t0, t1, *, sensitivity=False, t_eval=None):
        if abs(float(np.asarray(y0, float)[0])) > self.bound:
            raise Runaway(f"|x| > {self.bound:.3g}")
        res = super().__call__(y0, t0, t1, sensitivity=sensitivity, t_eval=t_eval)
        self.calls += 1
        self.pieces += res.n_events + 1
        return res


@dataclass(frozen=True)
class MethodSpec:
    """One solver configuration: ``method`` in single/multiple/collocation, on ``flow``."""

    method: str
    flow: str = "ode"  # 'ode', 'exact', 'event'
    nodes: int = 1
    n_points: int = 0
    order: int = 0
    rtol: float = 1e-11
    max_iter: int = 50
    #: 'perturbed': the reference orbit perturbed (every method gets the same orbit guess);
    #: 'crude': a state and a period from a formula (single shooting only)
    guess: str = "perturbed"

    @property
    def label(self) -> str:
        flow = {"ode": "ODEFlow", "exact": "ExactPWLFlow", "event": "EventFlow"}[self.flow]
        if self.method == "single":
            crude = ", crude guess" if self.guess == "crude" else ""
            return f"single shooting, {flow}{crude}"
        if self.method == "multiple":
            return f"multiple shooting ({self.nodes} nodes), {flow}"
        return f"finite differences N={self.n_points}, order {self.order}"

    @property
    def tex(self) -> str:
        flow = {"ode": "ODE", "exact": "exact PWL", "event": "event-driven"}[self.flow]
        tol = "" if self.flow == "exact" else f", rtol ${_num(self.rtol, 1)}$"
        if self.method == "single":
            crude = ", crude guess$^c$" if self.guess == "crude" else ""
            return f"single shooting ({flow}{tol}{crude})"
        if self.method == "multiple":
            return f"multiple shooting, {self.nodes} nodes ({flow}{tol})"
        return f"finite differences, $N={self.n_points}$, order {self.order}"


@dataclass(frozen=True)
class MethodRun:
    """Cost and accuracy of one solver on one case (``ok`` False: it failed; ``error`` says
    why)."""

    case: str
    spec: MethodSpec
    ok: bool
    seconds: float
    iterations: int
    nfev: int  # right-hand-side calls (ODE flows, collocation) or linear pieces (PWL flows)
    njev: int  # Jacobian calls, or flow calls for PWL flows
    period: float = math.nan
    period_error: float = math.nan
    state_error: float = math.nan
    amplitude_error: float = math.nan
    stability: str = ""
    max_multiplier: float = math.nan
    message: str = ""
    orbit: PeriodicOrbit | None = field(default=None, repr=False, compare=False)

    @property
    def error(self) -> float:
        """max(|Delta T|, max |Delta y| over the orbit): the accuracy of the whole answer
        (infinite for a failed run)."""
        if not self.ok:
            return math.inf
        pe = 0.0 if math.isnan(self.period_error) else self.period_error
        return max(pe, self.state_error)


def _guess_states(ref: Reference, n: int, saddle: bool) -> np.ndarray:
    y = ref.states(np.arange(n) / n)
    if saddle:
        return y + np.array([0.05, -0.05])
    return 1.02 * y + 0.02


def run_method(case: OrbitCase, ref: Reference, spec: MethodSpec) -> MethodRun:
    """Solve ``case`` with ``spec`` from the common perturbed guess; measure against ``ref``."""
    osc = case.model
    counter = None
    bound = RUNAWAY * max(1.0, ref.amplitude)
    if spec.flow == "exact":
        flow = CountingExactFlow(osc, bound)
    elif spec.flow == "event":
        flow = CountingEventFlow(osc, bound, rtol=spec.rtol, atol=spec.rtol / 10)
    else:
        counter = CountingRHS(first_order_rhs(osc), bound)
        flow = ODEFlow(osc, rhs=counter.rhs, rtol=spec.rtol, atol=spec.rtol / 10)
    saddle = case.key == "nsd_saddle"
    if spec.guess == "crude":
        guess = np.array([[2.0, 0.0]])
        T_guess = case.period_hint
    else:
        T_guess = 0.98 * ref.period if case.autonomous else None
        n_guess = {"single": 1, "multiple": spec.nodes, "collocation": spec.n_points}[spec.method]
        guess = _guess_states(ref, n_guess, saddle)
    start = time.perf_counter()
    try:
        if spec.method == "single":
            if case.autonomous:
                orb = limit_cycle(flow, guess[0], T_guess, max_iter=spec.max_iter)
            else:
                orb = periodic_orbit(flow, guess[0], max_iter=spec.max_iter)
        elif spec.method == "multiple":
            kw = {"period_guess": T_guess} if case.autonomous else {}
            orb = multiple_shooting(flow, guess, max_iter=spec.max_iter, **kw)
        else:
            kw = {"period_guess": T_guess} if case.autonomous else {}
            orb = collocation_orbit(
                flow, guess, n_points=spec.n_points, order=spec.order, max_iter=spec.max_iter, **kw
            )
    except (ShootingError, PerturbError, Runaway) as exc:
        seconds = time.perf_counter() - start
        nf, nj = _counts(flow, counter)
        it = getattr(exc, "iterations", 0)
        return MethodRun(case.key, spec, False, seconds, it, nf, nj, message=str(exc))
    seconds = time.perf_counter() - start
    nf, nj = _counts(flow, counter)
    phases = np.arange(N_COMPARE) / N_COMPARE
    _, x, v = orb.sample(N_COMPARE)
    y_ref = ref.states(phases)
    state_err = float(np.max(np.abs(np.column_stack([x, v]) - y_ref)))
    return MethodRun(
        case.key,
        spec,
        True,
        seconds,
        orb.iterations,
        nf,
        nj,
        period=orb.period,
        period_error=abs(orb.period - ref.period) if case.autonomous else math.nan,
        state_error=state_err,
        amplitude_error=abs(orb.amplitude - ref.amplitude),
        stability=orb.stability,
        max_multiplier=orb.max_multiplier,
        orbit=orb,
    )


def _counts(flow, counter: CountingRHS | None) -> tuple[int, int]:
    if counter is not None:
        return counter.nfev, counter.njev
    return flow.pieces, flow.calls


def method_specs(case: OrbitCase, fast: bool) -> list[MethodSpec]:
    """The solvers of the comparison table, per case."""
    if case.key == "nsd":
        return [
            MethodSpec("single", "exact"),
            MethodSpec("multiple", "exact", nodes=8),
            MethodSpec("single", "event"),
            MethodSpec("single", "ode"),
            MethodSpec("collocation", n_points=256 if fast else 1024, order=8),
        ]
    if case.key == "nsd_saddle":
        return [
            MethodSpec("single", "exact", max_iter=15),
            MethodSpec("multiple", "exact", nodes=16),
            MethodSpec("multiple", "event", nodes=16),
            MethodSpec("collocation", n_points=128, order=8),
        ]
    rtol = 1e-9 if (fast and case.key == "vdp5") else 1e-11
    grid = {"duffing": (64, 128), "vdp1": (128, 256), "vdp5": (512, 512)}[case.key]
    specs = [
        MethodSpec("single", rtol=rtol),
        MethodSpec("multiple", nodes=8, rtol=rtol),
        MethodSpec("collocation", n_points=grid[0], order=4),
        MethodSpec("collocation", n_points=grid[1], order=8),
    ]
    if case.key == "vdp5":
        specs.insert(1, MethodSpec("single", rtol=rtol, guess="crude"))
    return specs


def work_precision_specs(fast: bool) -> list[MethodSpec]:
    rtols = (1e-5, 1e-8, 1e-11) if fast else (1e-5, 1e-7, 1e-9, 1e-11, 1e-13)
    grids = (32, 64, 128) if fast else (32, 64, 128, 256, 512)
    specs = [MethodSpec("single", rtol=r) for r in rtols]
    specs += [MethodSpec("multiple", nodes=8, rtol=r) for r in rtols]
    specs += [MethodSpec("collocation", n_points=n, order=p) for p in (4, 8) for n in grids]
    return specs


def _num(x: float, digits: int = 3) -> str:
    """A number for LaTeX math: 1.23\\times10^{-5}."""
    if x == 0 or not math.isfinite(x):
        return "0" if x == 0 else r"\mathrm{n/a}"
    mant, exp = f"{x:.{digits - 1}e}".split("e")
    exp = int(exp)
    if -2 <= exp <= 3:
        return f"{x:.{max(digits - 1 - exp, 0)}f}"
    if mant in ("1", "1.0", "1.00"):
        return rf"10^{{{exp}}}"
    return rf"{mant}\times10^{{{exp}}}"


# ============================================================================================
# 2. describing functions
# ============================================================================================
@dataclass(frozen=True)
class Mode:
    """One affine mode of a nonlinearity: u = ke e + kz z + u0, and z' = e' when ``follows``
    (backlash engaged), else z' = 0 (z is the backlash output; unused otherwise)."""

    ke: float = 0.0
    kz: float = 0.0
    u0: float = 0.0
    follows: bool = False


@dataclass(frozen=True)
class Switch:
    """Leave the mode when g = ce e + ced e' + cz z + c0 crosses 0 in ``direction``."""

    ce: float
    ced: float
    cz: float
    c0: float
    direction: float
    to: int


@cache
def memory_describing_functions() -> dict[str, tuple[sp.Expr, sp.Expr]]:
    r"""(Re N, Im N) of the hysteretic relay and the backlash, derived here with SymPy.

    Input :math:`e = a\sin\theta`; the steady output :math:`u(\theta)` is integrated piece by
    piece, :math:`N = (b_1 + i a_1)/a` with :math:`b_1 = \frac1\pi\int u\sin\theta`,
    :math:`a_1 = \frac1\pi\int u\cos\theta` over one period (so that
    :math:`u_1 = \operatorname{Im}(N a e^{i\theta})`).

    * relay, output :math:`\pm M`, switching up at :math:`e = h` (rising) and down at
      :math:`e = -h` (falling): :math:`u = M` for :math:`\alpha < \theta < \pi + \alpha`,
      :math:`\sin\alpha = h/a`;
    * backlash of half-gap :math:`b` (unit slope): from the top of the input
      (:math:`\theta = \pi/2`) the output rests at :math:`a - b` until the input has come
      down by :math:`2b` (:math:`\theta_1 = \pi - \beta`, :math:`\sin\beta = 1 - 2b/a`), follows
      :math:`e + b` to the bottom, rests at :math:`-a + b` until :math:`\theta_2 = 2\pi -
      \beta`, then follows :math:`e - b`.
    """
    a, b, M, h = sp.symbols("a b M h", positive=True)
    th = sp.Symbol("theta", real=True)

    def first_harmonic(pieces):
        b1 = sum(sp.integrate(u * sp.sin(th), (th, lo, hi)) for u, lo, hi in pieces) / sp.pi
        a1 = sum(sp.integrate(u * sp.cos(th), (th, lo, hi)) for u, lo, hi in pieces) / sp.pi
        # expand + factor_terms gives the textbook shape in 1/20 of simplify's time
        return sp.factor_terms(sp.expand(b1 / a)), sp.factor_terms(sp.expand(a1 / a))

    alpha = sp.asin(h / a)
    relay = first_harmonic([(M, alpha, sp.pi + alpha), (-M, sp.pi + alpha, 2 * sp.pi + alpha)])
    beta = sp.asin(1 - 2 * b / a)
    t1, t2 = sp.pi - beta, 2 * sp.pi - beta
    backlash = first_harmonic(
        [
            (a - b, sp.pi / 2, t1),
            (a * sp.sin(th) + b, t1, 3 * sp.pi / 2),
            (-a + b, 3 * sp.pi / 2, t2),
            (a * sp.sin(th) - b, t2, 5 * sp.pi / 2),
        ]
    )
    return {"relay_hysteresis": relay, "backlash": backlash}


@cache
def _memory_numeric(key: str) -> Callable:
    re_n, im_n = memory_describing_functions()[key]
    syms = sorted(re_n.free_symbols | im_n.free_symbols, key=lambda s: s.name)
    f_re = sp.lambdify(syms, re_n, "numpy")
    f_im = sp.lambdify(syms, im_n, "numpy")
    names = [s.name for s in syms]

    def N(**kw):
        args = [kw[n] for n in names]
        return f_re(*args) + 1j * f_im(*args)

    return N


class Nonlinearity:
    """A nonlinearity u = n(e) of a Lur'e loop: its describing function, its steady output
    under e = a sin(theta), and its affine modes for the event-driven simulation."""

    key: str = ""
    title: str = ""
    threshold: float = 0.0  # N(a) = 0 (or undefined) for a <= threshold
    source: str = ""  # where N comes from (TeX)
    modes: dict[int, Mode]
    switches: dict[int, tuple[Switch, ...]]

    def describing(self, a: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def waveform(self, a: float, theta: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def kinks(self, a: float) -> list[float]:
        """Angles in [0, 2 pi) where the steady output under e = a sin(theta) has a kink or a
        jump (the quadrature below splits there)."""
        raise NotImplementedError

    def initial_mode(self, e: float, z: float) -> int:
        raise NotImplementedError

    def enter(self, mode: int, e: float, z: float) -> float:
        """z on entering ``mode`` (the backlash output snaps to e -+ b when it engages)."""
        return z

    def formula(self) -> str:
        """N(a) as TeX."""
        raise NotImplementedError


def _symmetric_kinks(level: float, a: float) -> list[float]:
    if a <= level:
        return []
    s = math.asin(level / a)
    return [s, math.pi - s, math.pi + s, TWO_PI - s]


def _switch_at(level: float, direction: float, to: int) -> Switch:
    """Leave when e crosses ``level`` in ``direction``."""
    return Switch(1.0, 0.0, 0.0, -level, direction, to)


class DeadZone(Nonlinearity):
    """u = e - sat(e): zero for |e| < delta, slope 1 outside."""

    key, title = "dead_zone", "dead zone"

    def __init__(self, delta: float = 1.0) -> None:
        self.delta = self.threshold = delta
        self.source = (
            r"perturb: \texttt{deadzone\_coefficients}, \texttt{equivalent\_linearisation}"
        )
        self.modes = {-1: Mode(ke=1.0, u0=delta), 0: Mode(), 1: Mode(ke=1.0, u0=-delta)}
        self.switches = {
            0: (_switch_at(delta, 1.0, 1), _switch_at(-delta, -1.0, -1)),
            1: (_switch_at(delta, -1.0, 0),),
            -1: (_switch_at(-delta, 1.0, 0),),
        }

    def describing(self, a):
        a = np.asarray(a, float)
        return deadzone_coefficients(1, a, 0.0, -self.delta, self.delta) / a + 0j

    def waveform(self, a, theta):
        e = a * np.sin(theta)
        return e - np.clip(e, -self.delta, self.delta)

    def kinks(self, a):
        return _symmetric_kinks(self.delta, a)

    def initial_mode(self, e, z):
        return int(np.sign(e)) if abs(e) > self.delta else 0

    def formula(self):
        return (
            r"1 - \frac{2}{\pi}\Big(\arcsin\frac{\delta}{a} + \frac{\delta}{a}"
            r"\sqrt{1 - \frac{\delta^2}{a^2}}\Big)"
        )


class Saturation(Nonlinearity):
    """u = clip(e, -L, L)."""

    key, title = "saturation", "saturation"

    def __init__(self, level: float = 1.0) -> None:
        self.level = level
        self.threshold = 0.0
        self.source = (
            r"perturb: \texttt{saturation\_coefficients}, \texttt{equivalent\_linearisation}"
        )
        self.modes = {-1: Mode(u0=-level), 0: Mode(ke=1.0), 1: Mode(u0=level)}
        self.switches = {
            0: (_switch_at(level, 1.0, 1), _switch_at(-level, -1.0, -1)),
            1: (_switch_at(level, -1.0, 0),),
            -1: (_switch_at(-level, 1.0, 0),),
        }

    def describing(self, a):
        a = np.asarray(a, float)
        return saturation_coefficients(1, a, 0.0, -self.level, self.level) / a + 0j

    def waveform(self, a, theta):
        return np.clip(a * np.sin(theta), -self.level, self.level)

    def kinks(self, a):
        return _symmetric_kinks(self.level, a)

    def initial_mode(self, e, z):
        return int(np.sign(e)) if abs(e) > self.level else 0

    def formula(self):
        return r"\frac{2}{\pi}\Big(\arcsin\frac{L}{a} + \frac{L}{a}\sqrt{1 - \frac{L^2}{a^2}}\Big)"


class Relay(Nonlinearity):
    """u = +-M, switching to +M when e rises through h and to -M when it falls through -h."""

    def __init__(self, M: float = 1.0, h: float = 0.0) -> None:
        self.M, self.h = M, h
        self.threshold = h
        self.key = "relay_hysteresis" if h > 0 else "relay"
        self.title = f"relay with hysteresis ($h={h:g}$)" if h > 0 else "ideal relay"
        self.source = (
            r"SymPy, derived here (perturb: none for memory nonlinearities)"
            if h > 0
            else r"perturb: \texttt{sign\_coefficients}, \texttt{equivalent\_linearisation}"
        )
        self.modes = {1: Mode(u0=M), -1: Mode(u0=-M)}
        self.switches = {1: (_switch_at(-h, -1.0, -1),), -1: (_switch_at(h, 1.0, 1),)}

    def describing(self, a):
        a = np.asarray(a, float)
        if self.h > 0:
            return _memory_numeric("relay_hysteresis")(a=a, M=self.M, h=self.h)
        return self.M * sign_coefficients(1, a, 0.0, 0.0) / a + 0j

    def waveform(self, a, theta):
        alpha = math.asin(self.h / a)
        on = np.mod(np.asarray(theta) - alpha, TWO_PI) < math.pi
        return np.where(on, self.M, -self.M)

    def kinks(self, a):
        alpha = math.asin(self.h / a)
        return [alpha, math.pi + alpha]

    def initial_mode(self, e, z):
        return 1 if e >= 0 else -1

    def formula(self):
        if self.h > 0:
            return r"\frac{4M}{\pi a}\Big(\sqrt{1 - \frac{h^2}{a^2}} - i\,\frac{h}{a}\Big)"
        return r"\frac{4M}{\pi a}"


class Backlash(Nonlinearity):
    """Play of half-gap b: the output z follows e - b (driven up), e + b (driven down), or
    rests while the input crosses the gap."""

    key, title = "backlash", "backlash"

    def __init__(self, b: float = 0.5) -> None:
        self.b = self.threshold = b
        self.source = r"SymPy, derived here (perturb: none for memory nonlinearities)"
        self.modes = {1: Mode(kz=1.0, follows=True), -1: Mode(kz=1.0, follows=True), 0: Mode(kz=1)}
        self.switches = {
            1: (Switch(0.0, 1.0, 0.0, 0.0, -1.0, 0),),  # the input turns down: disengage
            -1: (Switch(0.0, 1.0, 0.0, 0.0, 1.0, 0),),
            0: (Switch(1.0, 0.0, -1.0, -b, 1.0, 1), Switch(1.0, 0.0, -1.0, b, -1.0, -1)),
        }

    def describing(self, a):
        return _memory_numeric("backlash")(a=np.asarray(a, float), b=self.b)

    def waveform(self, a, theta):
        b = self.b
        beta = math.asin(1.0 - 2.0 * b / a)
        phi = np.mod(np.asarray(theta) - math.pi / 2, TWO_PI) + math.pi / 2
        t1, t2 = math.pi - beta, TWO_PI - beta
        return np.select(
            [phi < t1, phi < 1.5 * math.pi, phi < t2],
            [a - b + 0 * phi, a * np.sin(phi) + b, -a + b + 0 * phi],
            a * np.sin(phi) - b,
        )

    def kinks(self, a):
        beta = math.asin(1.0 - 2.0 * self.b / a)
        return [math.pi / 2, math.pi - beta, 1.5 * math.pi, TWO_PI - beta]

    def initial_mode(self, e, z):
        return 0

    def enter(self, mode, e, z):
        return e - mode * self.b if mode else z

    def formula(self):
        return (
            r"\frac12 + \frac1\pi\Big(\arcsin\big(1-\tfrac{2b}{a}\big) + 2\big(1-\tfrac{2b}{a}\big)"
            r"\sqrt{\tfrac{b}{a}\big(1-\tfrac{b}{a}\big)}\Big) - i\,\frac{4b}{\pi a}"
            r"\Big(1-\frac{b}{a}\Big)"
        )


def nonlinearities() -> list[Nonlinearity]:
    return [DeadZone(1.0), Saturation(1.0), Relay(1.0, 0.0), Relay(1.0, 0.2), Backlash(0.5)]


def harmonics_of(nl: Nonlinearity, a: float, n: int = 4096) -> np.ndarray:
    """Complex harmonics c_k of the steady output under e = a sin(theta): u = sum
    Im(c_k e^{ik theta}) (so c_1/a is N(a)); from the FFT of the waveform."""
    theta = TWO_PI * np.arange(n) / n
    U = np.fft.rfft(nl.waveform(a, theta)) / n
    # u = sum 2 Re(U_k e^{ik theta}) = sum Im(2i U_k e^{ik theta})
    return 2j * U


def describing_by_quadrature(nl: Nonlinearity, a: float) -> complex:
    """N(a) = (b_1 + i a_1)/a from adaptive quadrature of the steady waveform, split at its
    kinks and jumps (an independent check of every closed form)."""
    cuts = sorted({0.0, TWO_PI, *(k % TWO_PI for k in nl.kinks(a))})
    b1 = a1 = 0.0
    for lo, hi in zip(cuts[:-1], cuts[1:], strict=True):
        if hi - lo < 1e-15:
            continue

        # the waveform's value on (lo, hi), never evaluated on a jump
        def u(th, lo=lo, hi=hi):
            return float(nl.waveform(a, np.array([min(max(th, lo + 1e-14), hi - 1e-14)]))[0])

        kw = {"epsabs": 1e-12, "epsrel": 1e-11, "limit": 200}
        b1 += quad(lambda th: u(th) * math.sin(th), lo, hi, **kw)[0]
        a1 += quad(lambda th: u(th) * math.cos(th), lo, hi, **kw)[0]
    return complex(b1, a1) / (math.pi * a)


def perturb_symbolic_describing() -> dict[str, sp.Expr]:
    """N(a) of the single-valued nonlinearities from perturb's equivalent linearisation (its
    theta-form, with the switching angles substituted), for the numeric cross-check and TeX."""
    x, v = real_symbol("x"), real_symbol("x'")
    delta = sp.Symbol("delta", positive=True)
    L, M = sp.Symbol("L", positive=True), sp.Symbol("M", positive=True)
    exprs = {
        "dead_zone": (x - sp.Max(-delta, sp.Min(delta, x)), {"delta": 1.0}),
        "saturation": (sp.Max(-L, sp.Min(L, x)), {"L": 1.0}),
        "relay": (M * sp.sign(x), None),
    }
    out = {}
    for key, (expr, values) in exprs.items():
        eq = equivalent_linearisation(expr, x=x, v=v, values=values)
        k_eq, _, defs = eq.closed()
        out[key] = k_eq.subs(dict(defs))
    return out


def perturb_rejects_hysteresis() -> str:
    """perturb's message for the hysteretic relay (it has no describing function for it)."""
    x, v = real_symbol("x"), real_symbol("x'")
    M, h = sp.symbols("M h", positive=True)
    try:
        equivalent_linearisation(M * sp.sign(x - h * sp.sign(v)), x=x, v=v)
    except ModelError as exc:
        return str(exc)
    return ""


# ============================================================================================
# 3. Lur'e loops: prediction by the describing function, and simulation
# ============================================================================================
@dataclass(frozen=True)
class Plant:
    """G(s) = K num(s)/den(s), den monic of degree 3; polynomials highest power first.

    State space in controllable companion form (x1' = x2, x2' = x3, x3' = -den . x + u,
    y = K num . x), so y' does not see u when the relative degree is >= 2.
    """

    key: str
    tex: str
    K: float
    num: tuple[float, ...]
    den: tuple[float, ...]

    @property
    def A(self) -> np.ndarray:
        n = len(self.den) - 1
        A = np.zeros((n, n))
        A[:-1, 1:] = np.eye(n - 1)
        A[-1, :] = -np.array(self.den[::-1][:-1])
        return A

    @property
    def B(self) -> np.ndarray:
        B = np.zeros(len(self.den) - 1)
        B[-1] = 1.0
        return B

    @property
    def C(self) -> np.ndarray:
        C = np.zeros(len(self.den) - 1)
        C[: len(self.num)] = self.K * np.array(self.num[::-1])
        return C

    def G(self, w: np.ndarray) -> np.ndarray:
        s = 1j * np.asarray(w, float)
        return self.K * np.polyval(self.num, s) / np.polyval(self.den, s)

    def closed_loop_roots(self, gain: complex) -> np.ndarray:
        """Roots of den(s) + gain K num(s) (complex gain: the quasi-linear loop)."""
        num = np.zeros(len(self.den), complex)
        num[len(self.den) - len(self.num) :] = self.K * np.array(self.num)
        return np.roots(np.array(self.den, complex) + gain * num)


#: G1: a type-1 servo; the linear loop (N = 1) is unstable for K > 6 (phase crossover at
#: omega = sqrt 2, |G1| = K/6 there)
def plant_servo(K: float) -> Plant:
    return Plant(f"servo{K:g}", rf"\frac{{{K:g}}}{{s(s+1)(s+2)}}", K, (1.0,), (1.0, 3.0, 2.0, 0.0))


#: G2: an open-loop unstable plant (poles 0.177 +- 1.203i, -1.353) that the loop stabilises for
#: 2 < NK: the conditionally stable loop a dead zone needs for a *stable* limit cycle (with G1
#: the dead-zone cycle is the unstable threshold between decay and divergence)
def plant_unstable(K: float) -> Plant:
    return Plant(
        f"unstable{K:g}",
        rf"\frac{{{K:g}(s+0.5)}}{{s^3+s^2+s+2}}",
        K,
        (1.0, 0.5),
        (1.0, 1.0, 1.0, 2.0),
    )


@dataclass(frozen=True)
class LureCase:
    nl: Nonlinearity
    plant: Plant

    @property
    def key(self) -> str:
        return self.nl.key


def lure_cases() -> list[LureCase]:
    nls = {nl.key: nl for nl in nonlinearities()}
    return [
        LureCase(nls["dead_zone"], plant_unstable(4.0)),
        LureCase(nls["saturation"], plant_servo(10.0)),
        LureCase(nls["relay"], plant_servo(4.0)),
        LureCase(nls["relay_hysteresis"], plant_servo(4.0)),
        LureCase(nls["backlash"], plant_servo(4.0)),
    ]


@dataclass(frozen=True)
class Prediction:
    """A solution of 1 + N(a) G(i omega) = 0 and its describing-function stability."""

    a: float
    omega: float
    stable: bool
    N: complex


def _omega_of(case: LureCase, N: complex, grid: np.ndarray, G_grid: np.ndarray) -> float:
    """The omega with N G(i omega) real and negative (nan if none)."""
    H = N * G_grid
    hit = np.flatnonzero(
        (H.imag[:-1] * H.imag[1:] <= 0.0) & (H.real[:-1] < 0.0) & (H.real[1:] < 0.0)
    )
    if hit.size == 0:
        return math.nan
    i = int(hit[0])
    return brentq(lambda w: (N * case.plant.G(np.array([w]))[0]).imag, grid[i], grid[i + 1],
                  xtol=1e-15, rtol=1e-15)  # fmt: skip


def predict_cycles(case: LureCase, n_grid: int = 240) -> list[Prediction]:
    """All amplitudes with |N(a) G(i omega(a))| = 1 on a log grid of a, refined by brentq.

    Stability (Loeb): the quasi-linear loop den + N(a) K num has its root near i omega in the
    left half-plane just above the predicted amplitude and in the right half-plane just below.
    """
    w_grid = np.geomspace(1e-2, 1e2, 800)
    G_grid = case.plant.G(w_grid)
    lo = case.nl.threshold * (1.0 + 1e-7) if case.nl.threshold > 0 else 1e-3
    a_grid = np.geomspace(lo, 1e3 * max(lo, 1.0), n_grid)

    def residual(N: complex) -> tuple[float, float]:
        w = _omega_of(case, N, w_grid, G_grid)
        if math.isnan(w):
            return math.nan, w
        return -(N * case.plant.G(np.array([w]))[0]).real - 1.0, w

    def r(a: float) -> float:
        return residual(complex(case.nl.describing(np.array([a]))[0]))[0]

    rs = np.array([residual(complex(N))[0] for N in case.nl.describing(a_grid)])
    out = []
    for i in range(n_grid - 1):
        if np.isfinite(rs[i]) and np.isfinite(rs[i + 1]) and rs[i] * rs[i + 1] < 0.0:
            a = brentq(r, a_grid[i], a_grid[i + 1], xtol=1e-15, rtol=1e-15)
            N = complex(case.nl.describing(np.array([a]))[0])
            w = residual(N)[1]
            out.append(Prediction(a, w, _loeb_stable(case, a, w), N))
    return out


def _loeb_stable(case: LureCase, a: float, w: float, rel: float = 1e-4) -> bool:
    def growth(aa: float) -> float:
        roots = case.plant.closed_loop_roots(complex(case.nl.describing(np.array([aa]))[0]))
        return float(roots[np.argmin(np.abs(roots - 1j * w))].real)

    return growth(a * (1 + rel)) < 0.0 < growth(a * (1 - rel))


def distortion_index(case: LureCase, pred: Prediction, kmax: int = 31) -> float:
    r"""How far the loop is from the filter hypothesis at the predicted cycle:
    :math:`\sqrt{\sum_{k\ge2}|c_k G(ik\omega)|^2}/|c_1 G(i\omega)|`, the higher harmonics of the
    nonlinearity's output (under e = a sin) after the plant, relative to the fundamental."""
    c = harmonics_of(case.nl, pred.a)
    k = np.arange(2, kmax + 1)
    higher = np.abs(c[k] * case.plant.G(k * pred.omega))
    return float(np.sqrt(np.sum(higher**2)) / abs(c[1] * case.plant.G(np.array([pred.omega]))[0]))


@dataclass
class Steady:
    """The measured steady oscillation of a simulated Lur'e loop."""

    period: float
    omega: float
    first_harmonic: float  # of e
    peak: float  # max |e|
    mean: float
    period_change: float  # |P_k - P_{k-1}| / P over the last two periods
    peak_change: float
    t_end: float
    n_switches: int
    state: np.ndarray  # (x, z) at the last upward zero crossing of e
    t: np.ndarray = field(repr=False)  # the last two periods, from that crossing
    e: np.ndarray = field(repr=False)
    u: np.ndarray = field(repr=False)
    seconds: float = 0.0


def _affine(case: LureCase, mode: Mode) -> tuple[np.ndarray, np.ndarray]:
    """X' = A_m X + b_m for X = (x, z) in one mode (e = -C x)."""
    A, B, C = case.plant.A, case.plant.B, case.plant.C
    n = A.shape[0]
    Am = np.zeros((n + 1, n + 1))
    bm = np.zeros(n + 1)
    Am[:n, :n] = A - mode.ke * np.outer(B, C)
    Am[:n, n] = mode.kz * B
    bm[:n] = mode.u0 * B
    if mode.follows:  # z' = e' = -C x'
        Am[n] = -C @ Am[:n]
        bm[n] = -C @ bm[:n]
    return Am, bm


def initial_state(case: LureCase, a: float, w: float) -> np.ndarray:
    """x with e = 0, e' = a w, e'' = 0 (the cycle e = a sin(w t) at t = 0; u ignored)."""
    A, C = case.plant.A, case.plant.C
    O = np.vstack([C @ np.linalg.matrix_power(A, k) for k in range(A.shape[0])])
    return np.linalg.solve(O, np.array([0.0, -a * w, 0.0]))


def simulate_lure(
    case: LureCase,
    x0: np.ndarray,
    z0: float = 0.0,
    *,
    period_hint: float,
    max_periods: int = 400,
    tol: float = 1e-9,
    rtol: float = 1e-11,
    atol: float = 1e-13,
    n_samples: int = 4096,
) -> Steady:
    """Event-driven simulation of u = n(e), e = -y, y = G u, until the oscillation repeats.

    Each mode is affine (``_affine``); the switching surfaces are terminal events, after which
    the mode changes and the integration restarts.  Upward zero crossings of e (non-terminal)
    give the period; integration goes on in chunks of 10 periods until the period and the peak
    of |e| change by less than ``tol`` (relative) from one period to the next.
    """
    start = time.perf_counter()
    nl, plant = case.nl, case.plant
    n = plant.A.shape[0]
    C = plant.C
    systems = {m: _affine(case, mode) for m, mode in nl.modes.items()}
    X = np.append(np.asarray(x0, float), z0)
    e0 = -float(C @ X[:n])
    mode = nl.initial_mode(e0, z0)
    X[n] = nl.enter(mode, e0, X[n])
    t = 0.0
    segments: list[tuple[float, float, object, int]] = []
    ups: list[float] = []
    n_switches = 0
    chunk = 10.0 * period_hint
    t_stop = chunk
    steady = None
    while True:
        Am, bm = systems[mode]

        def rhs(tt, XX, Am=Am, bm=bm):
            return Am @ XX + bm

        sw = nl.switches[mode]
        events = []
        for s_ in sw:
            # g = ce e + ced e' + cz z + c0, linear in X along this mode
            w_e = np.append(-C, 0.0)
            w_ed = -np.append(C, 0.0) @ np.vstack([Am[:n], np.zeros(n + 1)])
            c_ed = -float(C @ bm[:n])
            wv = s_.ce * w_e + s_.ced * w_ed
            wv[n] += s_.cz
            c = s_.c0 + s_.ced * c_ed

            def ev(tt, XX, wv=wv, c=c):
                return float(wv @ XX) + c

            ev.terminal = True
            ev.direction = s_.direction
            events.append(ev)

        def up(tt, XX):
            return -float(C @ XX[:n])

        up.direction = 1.0
        events.append(up)
        sol = solve_ivp(
            rhs, (t, t_stop), X, method="DOP853", rtol=rtol, atol=atol, events=events,
            dense_output=True,
        )  # fmt: skip
        segments.append((t, float(sol.t[-1]), sol.sol, mode))
        ups.extend(float(tu) for tu in sol.t_events[-1])
        if sol.status == 1:
            k = next(i for i in range(len(sw)) if sol.t_events[i].size)
            t = float(sol.t_events[k][0])
            X = sol.y_events[k][0].copy()
            mode = sw[k].to
            X[n] = nl.enter(mode, -float(C @ X[:n]), X[n])
            n_switches += 1
            continue
        t, X = float(sol.t[-1]), sol.y[:, -1].copy()
        steady = _measure(case, segments, ups, n_samples)
        if steady is not None and (
            (steady.period_change < tol and steady.peak_change < tol)
            or t >= max_periods * period_hint
        ):
            break
        t_stop = t + chunk
        # keep what the measurement needs: the last few periods
        segments = [sg for sg in segments if sg[1] >= t - 4.0 * period_hint]
    steady.t_end = t
    steady.n_switches = n_switches
    steady.seconds = time.perf_counter() - start
    return steady


def _dedup(times: list[float], scale: float) -> np.ndarray:
    """Crossing times without the repeats that a restart exactly on e = 0 produces."""
    out: list[float] = []
    for tt in sorted(times):
        if not out or tt - out[-1] > 1e-7 * scale:
            out.append(tt)
    return np.array(out)


def _evaluate(case: LureCase, segments, ts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """e and u at times ``ts`` from the stored dense segments."""
    n = case.plant.A.shape[0]
    starts = np.array([sg[0] for sg in segments])
    idx = np.clip(np.searchsorted(starts, ts, side="right") - 1, 0, len(segments) - 1)
    e = np.empty(ts.size)
    u = np.empty(ts.size)
    for i in np.unique(idx):
        sel = idx == i
        _, _, dense, mode = segments[i]
        X = dense(ts[sel])
        md = case.nl.modes[mode]
        e[sel] = -(case.plant.C @ X[:n])
        u[sel] = md.ke * e[sel] + md.kz * X[n] + md.u0
    return e, u


def _measure(case: LureCase, segments, ups: list[float], n_samples: int) -> Steady | None:
    if not ups:
        return None
    scale = max(abs(ups[-1]), 1.0)
    cr = _dedup(ups, scale)
    if cr.size < 4:
        return None
    P, P_prev = cr[-1] - cr[-2], cr[-2] - cr[-3]
    if cr[-3] < segments[0][0]:
        return None
    ts = cr[-2] + P * np.arange(n_samples) / n_samples
    e, _ = _evaluate(case, segments, ts)
    ts_prev = cr[-3] + P_prev * np.arange(n_samples) / n_samples
    e_prev, _ = _evaluate(case, segments, ts_prev)
    c = np.fft.rfft(e) / n_samples
    peak = float(np.max(np.abs(e)))
    t2 = cr[-3] + (P + P_prev) * np.arange(2 * n_samples) / (2 * n_samples)
    e2, u2 = _evaluate(case, segments, t2)
    # the state at the last crossing, for an independent re-integration
    dense = next(sg for sg in reversed(segments) if sg[0] <= cr[-1] <= sg[1] + 1e-12)
    state = dense[2](min(cr[-1], dense[1]))
    return Steady(
        period=float(P),
        omega=TWO_PI / float(P),
        first_harmonic=float(2.0 * abs(c[1])),
        peak=peak,
        mean=float(c[0].real),
        period_change=abs(P - P_prev) / P,
        peak_change=abs(peak - float(np.max(np.abs(e_prev)))) / peak,
        t_end=float("nan"),
        n_switches=0,
        state=np.array(state, float),
        t=t2 - cr[-3],
        e=e2,
        u=u2,
    )


# ============================================================================================
# 4. dry friction and stick-slip, the event map of van der Pol, continuation through a fold
# ============================================================================================
#: a mass on a moving belt, m x'' + c x' + k x = N mu(v_b - x'), m = k = N = 1 (representative
#: values; the seed gives none): Coulomb friction with a static coefficient above the kinetic
#: one (c = 0, for the closed form) and Stribeck friction
#: mu(v) = sign(v) (mu_k + (mu_s - mu_k) exp(-|v|/v_s)) with c > 0
BELT = {"v_b": 0.2, "mu_s": 0.4, "mu_k": 0.3}
STRIBECK = {"c": 0.05, "v_s": 0.2}
#: forced Duffing x'' + mu x' + x + alpha x^3 = F cos(Omega t), one-harmonic balance
FOLD_DUFFING = {"mu": 0.1, "alpha": 1.0, "F": 0.5}
FOLD_WINDOW = (0.5, 2.5)
VDP_EPS = (0.1, 1.0, 5.0)


def stribeck_oscillator() -> Oscillator:
    """The Stribeck belt system as perturb reads it: x'' + c x' + x - mu(v_b - x') = 0."""
    b, s_ = BELT, STRIBECK
    rel = f"({b['v_b']!r} - x')"
    law = f"sign{rel}*({b['mu_k']!r} + {b['mu_s'] - b['mu_k']!r}*exp(-Abs{rel}/{s_['v_s']!r}))"
    return Oscillator.parse(f"x'' + {s_['c']!r}*x' + x - {law} = 0")


def stribeck_mu(v_rel: float) -> float:
    b, s_ = BELT, STRIBECK
    mu = b["mu_k"] + (b["mu_s"] - b["mu_k"]) * math.exp(-abs(v_rel) / s_["v_s"])
    return math.copysign(mu, v_rel)


def coulomb_cycle_closed_form() -> dict[str, float]:
    """The Coulomb stick-slip cycle of the undamped belt system (m = k = N = 1), in closed form.

    Stick: x' = v_b until the spring force reaches static friction, x_s = mu_s.  Slip:
    harmonic motion about x_k = mu_k, from (x_s, v_b): x - x_k = A sin(t + psi) with
    A sin psi = d = x_s - x_k, A cos psi = v_b; it returns to x' = v_b at x = x_k - d after
    2 pi - 2 psi, then sticks for 2 d / v_b.
    """
    b = BELT
    d = b["mu_s"] - b["mu_k"]
    A = math.hypot(d, b["v_b"])
    psi = math.atan2(d, b["v_b"])
    t_slip, t_stick = TWO_PI - 2.0 * psi, 2.0 * d / b["v_b"]
    return {
        "period": t_slip + t_stick,
        "t_slip": t_slip,
        "t_stick": t_stick,
        "x_max": b["mu_k"] + A,
        "x_min": b["mu_k"] - A,
        "amplitude": A,
    }


@dataclass
class StickSlip:
    """A stick-slip limit cycle: period, extremes of x, stick time, one cycle for the figure."""

    law: str
    period: float
    x_max: float
    x_min: float
    t_stick: float
    stick_onsets: np.ndarray
    periods: np.ndarray  # every completed cycle's period (the cycle is reached at once)
    cycle: tuple[np.ndarray, np.ndarray, np.ndarray]  # t (from a stick onset), x, x'

    @property
    def amplitude(self) -> float:
        return 0.5 * (self.x_max - self.x_min)


def coulomb_stick_slip(n_cycles: int, rtol: float) -> StickSlip:
    """The Coulomb belt system (mu_s > mu_k, c = 0) by ``solve_ivp`` with located switches.

    perturb's event-driven integrator reads ``sign(v_b - x')`` with Filippov sliding, whose
    sticking limit is the kinetic coefficient, so it cannot hold a static coefficient above the
    kinetic one: this system is integrated here.  Stick: x' = v_b exactly, x grows linearly
    until x = mu_s (closed form).  Slip (x' < v_b): DOP853 on the smooth field with the friction
    frozen at +mu_k, a terminal event at x' = v_b (from below) and the extremes of x at the
    located zeros of x'; the mass sticks there if |x| <= mu_s (it does for these values) and
    an error is raised otherwise.  From rest the mass sticks at once.
    """
    b = BELT
    v_b, mu_s, mu_k = b["v_b"], b["mu_s"], b["mu_k"]

    def slip(_t, y):  # the friction force frozen at +mu_k: x' < v_b throughout a slip
        return [y[1], -y[0] + mu_k]

    def back_to_belt(_t, y):
        return y[1] - v_b

    back_to_belt.terminal, back_to_belt.direction = True, 1.0

    def turn(_t, y):
        return y[1]

    t, x = 0.0, 0.0
    onsets, stuck, extremes, pieces = [], [], [], []
    for _ in range(n_cycles + 1):  # capped: one stick and one slip per cycle
        if abs(x) > mu_s:
            raise RuntimeError("Coulomb belt: the mass does not stick on the belt")
        onsets.append(t)
        stuck.append((mu_s - x) / v_b)
        ts = np.linspace(t, t + stuck[-1], 40)
        pieces.append((ts, x + v_b * (ts - t), np.full_like(ts, v_b)))
        t, x = t + stuck[-1], mu_s
        sol = solve_ivp(
            slip, (t, t + 100.0), [x, v_b], method="DOP853", rtol=rtol, atol=1e-2 * rtol,
            events=[back_to_belt, turn], dense_output=True,
        )  # fmt: skip
        if sol.status != 1:
            raise RuntimeError("Coulomb belt: no return to the belt speed")
        extremes.append([float(sol.sol(te)[0]) for te in sol.t_events[1]])
        ts = np.linspace(t, sol.t[-1], 400)
        pieces.append((ts, *sol.sol(ts)))
        t, x = float(sol.t[-1]), float(sol.y[0, -1])
    onsets = np.array(onsets)
    last = [p for p in pieces[-4:-2]]  # the last complete cycle: stick, slip
    t0 = last[0][0][0]
    cycle = tuple(np.concatenate([p[k] for p in last]) for k in range(3))
    return StickSlip(
        "Coulomb", float(onsets[-1] - onsets[-2]), max(extremes[-2]), min(extremes[-2]),
        stuck[-2], onsets, np.diff(onsets), (cycle[0] - t0, cycle[1], cycle[2]),
    )  # fmt: skip


def _refined_extremes(t, x, v, accel) -> list[float]:
    """x at the zeros of x' between samples: one Taylor step from the nearer sample,
    x + v d + a d^2/2 with d = -v/a (error O(d^3), d at most half a sample spacing)."""
    out = []
    for j in np.nonzero(np.sign(v[:-1]) * np.sign(v[1:]) < 0)[0]:
        k = j if abs(v[j]) < abs(v[j + 1]) else j + 1
        a = accel(x[k], v[k])
        d = -v[k] / a
        out.append(float(x[k] + v[k] * d + 0.5 * a * d * d))
    return out


def stribeck_stick_slip(n_cycles: int, rtol: float, n_samples: int) -> StickSlip:
    """The Stribeck belt system by perturb's event-driven integrator (Filippov sticking).

    The period is the spacing of the 'stick' events; the extremes of x come from a second run
    over the last cycle, started at its stick onset, sampled ``n_samples`` times and refined
    at the zeros of x' by :func:`_refined_extremes`.
    """
    osc = stribeck_oscillator()
    c, v_b = STRIBECK["c"], BELT["v_b"]
    T_guess = TWO_PI + 2.0 * (BELT["mu_s"] - BELT["mu_k"]) / v_b
    tr = event_driven_simulate(osc, [0.0, 0.0], (0.0, (n_cycles + 1) * T_guess), rtol=rtol,
                               atol=rtol * 1e-2)  # fmt: skip
    sticks = [e for e in tr.events if e.kind == "stick"]
    slips = [e for e in tr.events if e.kind == "slip"]
    onsets = np.array([e.time for e in sticks])
    period = float(onsets[-1] - onsets[-2])
    start = sticks[-2]
    t_stick = next(e.time for e in slips if e.time > start.time) - start.time
    times = np.linspace(0.0, period, n_samples)
    one = event_driven_simulate(osc, [start.x, start.v], (0.0, period), t_eval=times, rtol=rtol,
                                atol=rtol * 1e-2)  # fmt: skip

    def accel(x, v):
        return -c * v - x + stribeck_mu(v_b - v)

    ext = _refined_extremes(one.t, one.x, one.v, accel)
    return StickSlip(
        "Stribeck", period, max(ext), min(ext), float(t_stick), onsets, np.diff(onsets),
        (one.t, one.x, one.v),
    )  # fmt: skip


# --------------------------------------------------------------------------------------------
# the event map of van der Pol: x at successive maxima (section x' = 0, x > 0)
# --------------------------------------------------------------------------------------------
@cache
def _vdp_rhs(eps: float) -> NumericRHS:
    return first_order_rhs(builtin_model("vanderpol", eps=eps))


def vdp_return(eps: float, a: float, rtol: float = 1e-12) -> tuple[float, float]:
    """The return map P(a) and return time of van der Pol on the section x' = 0 (x' turning
    negative, a maximum of x), from (a, 0); DOP853 on perturb's right-hand side with the
    crossing located as an event (the event is off for t < 1, before the orbit leaves the
    section)."""
    fun = _vdp_rhs(eps).fun

    def section(t, y):
        return y[1] if t > 1.0 else -1.0

    section.terminal, section.direction = True, -1.0
    T_max = 4.0 * (TWO_PI + 2.0 * eps)
    sol = solve_ivp(
        fun, (0.0, T_max), [a, 0.0], method="DOP853", rtol=rtol, atol=1e-3 * rtol,
        events=section,
    )  # fmt: skip
    if sol.status != 1:
        raise RuntimeError(f"van der Pol eps={eps}: no return to x' = 0 from a = {a}")
    return float(sol.y_events[0][0][0]), float(sol.t_events[0][0])


@dataclass
class ReturnMap:
    eps: float
    grid: np.ndarray
    P: np.ndarray
    fixed: float
    period: float
    slope: float  # P'(a*), central difference of the map
    multiplier: float  # det of the monodromy matrix (perturb's ODEFlow, sensitivities)
    iterates: np.ndarray  # a_0, P(a_0), P(P(a_0)), ...


def vdp_return_map(eps: float, n_grid: int, n_iter: int = 6) -> ReturnMap:
    """P on a grid of a in [0.25, 4], its fixed point a* (brentq on P(a) - a), the slope
    P'(a*) by a central difference and, for comparison, the non-trivial Floquet multiplier:
    the monodromy matrix of a planar autonomous flow has the eigenvalue 1 (along the orbit),
    so the other one is its determinant, and it equals P'(a*)."""
    grid = np.linspace(0.25, 4.0, n_grid)
    P = np.array([vdp_return(eps, a)[0] for a in grid])
    fixed = brentq(lambda a: vdp_return(eps, a)[0] - a, 1.0, 3.5, xtol=1e-14, rtol=1e-15)
    h = 1e-4
    slope = (vdp_return(eps, fixed + h)[0] - vdp_return(eps, fixed - h)[0]) / (2 * h)
    period = vdp_return(eps, fixed)[1]
    flow = ODEFlow(builtin_model("vanderpol", eps=eps), rtol=1e-12, atol=1e-14)
    M = flow([fixed, 0.0], 0.0, period, sensitivity=True).sensitivity
    its = [0.5]
    for _ in range(n_iter):  # capped cobweb
        its.append(vdp_return(eps, its[-1])[0])
    return ReturnMap(eps, grid, P, fixed, period, slope, float(np.linalg.det(M)), np.array(its))


# --------------------------------------------------------------------------------------------
# sequential (natural-parameter) continuation against pseudo-arclength at a fold
# --------------------------------------------------------------------------------------------
def duffing_hb1(u, Om):
    """One-harmonic balance of x'' + mu x' + x + alpha x^3 = F cos(Om t), x = a cos + b sin."""
    d = FOLD_DUFFING
    a, b = u
    k = 1.0 + 0.75 * d["alpha"] * (a * a + b * b) - Om * Om
    return np.array([k * a + d["mu"] * Om * b - d["F"], k * b - d["mu"] * Om * a])


def duffing_hb1_jac(u, Om):
    d = FOLD_DUFFING
    a, b = u
    k = 1.0 + 0.75 * d["alpha"] * (a * a + b * b) - Om * Om
    g = 1.5 * d["alpha"]
    mO = d["mu"] * Om
    Fu = np.array([[k + g * a * a, g * a * b + mO], [g * a * b - mO, k + g * b * b]])
    Fl = np.array([-2.0 * Om * a + d["mu"] * b, -2.0 * Om * b - d["mu"] * a])
    return Fu, Fl


@dataclass
class Sweep:
    """Natural-parameter continuation: Newton at each Omega from the previous solution."""

    direction: int
    Omega: np.ndarray
    amplitude: np.ndarray  # nan where Newton failed
    iterations: np.ndarray
    fail: int  # index of the first point off the branch it started on (-1: none)
    recovered: int  # index of the first converged point after ``fail`` (-1: none)


def sequential_sweep(direction: int, step: float) -> Sweep:
    lo, hi = FOLD_WINDOW
    n = int(round((hi - lo) / step)) + 1
    Om = np.linspace(lo, hi, n)[:: 1 if direction > 0 else -1]
    u = newton_fixed(duffing_hb1, duffing_hb1_jac, [FOLD_DUFFING["F"], 0.0], Om[0], tol=1e-13)[0]
    amp, its = [], []
    for w in Om:  # capped by the grid
        try:
            u, it = newton_fixed(duffing_hb1, duffing_hb1_jac, u, w, tol=1e-13, max_iterations=50)
        except ContinuationError:
            amp.append(math.nan)
            its.append(50)
            continue
        amp.append(float(np.hypot(*u)))
        its.append(it)
    amp = np.array(amp)
    rel = np.abs(np.diff(amp)) / amp[:-1]
    off = np.nonzero((rel > 0.25) | ~np.isfinite(rel))[0]
    fail = int(off[0] + 1) if len(off) else -1
    back = np.nonzero(np.isfinite(amp[fail:]))[0] if fail >= 0 else []
    rec = int(fail + back[0]) if len(back) else -1
    return Sweep(direction, Om, amp, np.array(its), fail, rec)


def arclength_curve(ds_max: float):
    lo, hi = FOLD_WINDOW
    u0 = newton_fixed(duffing_hb1, duffing_hb1_jac, [FOLD_DUFFING["F"], 0.0], lo, tol=1e-13)[0]
    return continue_curve(
        duffing_hb1, duffing_hb1_jac, u0, lo, FOLD_WINDOW, ds_max=ds_max, tol=1e-12,
        max_points=20000,
    )  # fmt: skip


def coulomb_equal_coefficients(n_turns: int = 6) -> dict:
    """mu_s = mu_k (plain Coulomb, c = 0) on perturb's event-driven integrator, from rest:
    after the first stick the slip ellipse about x = mu_k only touches the belt speed.
    Returns the event kinds after the first slip and the spacing of those events."""
    b = BELT
    osc = Oscillator.parse(f"x'' + x - {b['mu_k']!r}*sign({b['v_b']!r} - x') = 0")
    tr = event_driven_simulate(osc, [0.0, 0.0], (0.0, (n_turns + 1.5) * TWO_PI), rtol=1e-11,
                               atol=1e-13)  # fmt: skip
    first_slip = next(j for j, e in enumerate(tr.events) if e.kind == "slip")
    later = tr.events[first_slip + 1 :]
    times = np.array([e.time for e in later])
    return {
        "kinds": sorted({e.kind for e in later}),
        "n_later": len(later),
        "spacing_error": float(np.max(np.abs(np.diff(times) - TWO_PI))) if len(later) > 1
        else math.inf,
        "v_max": float(np.max(tr.v)),
    }  # fmt: skip


@dataclass
class LimitCycleTools:
    coulomb: StickSlip
    coulomb_exact: dict[str, float]
    stribeck: StickSlip
    maps: list[ReturnMap]
    up: Sweep
    down: Sweep
    curve: object
    step: float
    equal: dict = field(default_factory=dict)
    seconds: float = 0.0


def study_limit_cycle_tools(fast: bool) -> LimitCycleTools:
    t0 = time.perf_counter()
    coulomb = coulomb_stick_slip(4 if fast else 10, rtol=1e-12)
    stribeck = stribeck_stick_slip(4 if fast else 10, rtol=1e-11, n_samples=4001 if fast else 20001)
    maps = [vdp_return_map(eps, 12 if fast else 40) for eps in VDP_EPS]
    step = 0.02 if fast else 0.005
    up, down = sequential_sweep(+1, step), sequential_sweep(-1, step)
    curve = arclength_curve(0.05 if fast else 0.02)
    return LimitCycleTools(
        coulomb, coulomb_cycle_closed_form(), stribeck, maps, up, down, curve, step,
        coulomb_equal_coefficients(), time.perf_counter() - t0,
    )  # fmt: skip


# ============================================================================================
# the study
# ============================================================================================
@dataclass(frozen=True)
class Check:
    """A claim and its measurement: ``ok`` when ``value <= limit`` (or ``>=`` when
    ``above``)."""

    name: str
    tex: str
    value: float
    limit: float
    above: bool = False

    @property
    def ok(self) -> bool:
        if not math.isfinite(self.value):
            return False
        return self.value >= self.limit if self.above else self.value <= self.limit


@dataclass
class LureResult:
    case: LureCase
    predictions: list[Prediction]
    stable: Prediction
    distortion: float
    steady: Steady

    @property
    def error_a(self) -> float:
        return self.stable.a / self.steady.first_harmonic - 1.0

    @property
    def error_w(self) -> float:
        return self.stable.omega / self.steady.omega - 1.0


@dataclass
class Results:
    fast: bool
    cases: list[OrbitCase]
    refs: dict[str, Reference]
    runs: list[MethodRun]
    wp: list[MethodRun]
    wp_cases: list[str]
    nls: list[Nonlinearity]
    a_grid: np.ndarray
    df_values: dict[str, np.ndarray]
    df_checks: dict[str, dict[str, float]]
    symbolic: dict[str, sp.Expr]
    memory: dict[str, tuple[sp.Expr, sp.Expr]]
    rejection: str
    lure: list[LureResult]
    nsd_fd: list[MethodRun] = field(default_factory=list)
    tools: LimitCycleTools | None = None
    checks: list[Check] = field(default_factory=list)
    seconds: dict[str, float] = field(default_factory=dict)

    def run_of(self, case: str, label: str) -> MethodRun:
        return next(r for r in self.runs if r.case == case and r.spec.label == label)


def study_orbits(fast: bool) -> tuple[list[OrbitCase], dict[str, Reference], list[MethodRun]]:
    cases = orbit_cases()
    refs = {c.key: reference_orbit(c) for c in cases}
    runs = [run_method(c, refs[c.key], spec) for c in cases for spec in method_specs(c, fast)]
    return cases, refs, runs


def study_work_precision(
    cases: list[OrbitCase], refs: dict[str, Reference], fast: bool
) -> tuple[list[str], list[MethodRun]]:
    keys = ["duffing"] if fast else ["duffing", "vdp1", "vdp5"]
    by_key = {c.key: c for c in cases}
    runs = []
    for key in keys:
        for spec in work_precision_specs(fast):
            if key == "vdp5" and spec.method == "single":
                spec = MethodSpec("single", rtol=spec.rtol, guess="crude")
            runs.append(run_method(by_key[key], refs[key], spec))
    return keys, runs


def study_nsd_fd(cases: list[OrbitCase], refs: dict[str, Reference], fast: bool) -> list[MethodRun]:
    """Finite differences of orders 2 and 8 under grid halving on the nonsmooth nsd orbit."""
    case = next(c for c in cases if c.key == "nsd")
    grids = (128, 256, 512) if fast else (128, 256, 512, 1024, 2048)
    return [
        run_method(case, refs["nsd"], MethodSpec("collocation", n_points=n, order=p))
        for p in (2, 8)
        for n in grids
    ]


def observed_orders(runs: list[MethodRun], order: int) -> list[tuple[int, int, float]]:
    """(N, 2N, log2(e_N / e_2N)) of the finite-difference runs of one order."""
    errs = sorted((r.spec.n_points, r.error) for r in runs if r.ok and r.spec.order == order)
    return [
        (n1, n2, math.log(e1 / e2) / math.log(n2 / n1))
        for (n1, e1), (n2, e2) in zip(errs[:-1], errs[1:], strict=True)
    ]


def study_describing(fast: bool):
    nls = nonlinearities()
    a_grid = np.geomspace(0.05, 20.0, 120 if fast else 400)
    values, checks = {}, {}
    symbolic = perturb_symbolic_describing()
    a_sym = sp.Symbol("a", positive=True)
    subs = {"dead_zone": {"delta": 1.0}, "saturation": {"L": 1.0}, "relay": {"M": 1.0}}
    for nl in nls:
        a = a_grid[a_grid > nl.threshold * (1 + 1e-9)]
        N = nl.describing(a)
        full = np.full(a_grid.size, np.nan, complex)
        full[a_grid > nl.threshold * (1 + 1e-9)] = N
        if nl.key == "dead_zone":
            full[a_grid <= nl.threshold] = 0.0
        values[nl.key] = full
        a_q = a[:: max(1, a.size // (12 if fast else 40))]
        quad_err = max(
            abs(complex(nl.describing(np.array([x]))[0]) - describing_by_quadrature(nl, x))
            for x in a_q
        )
        res = {"quadrature": quad_err}
        if nl.key in symbolic:
            expr = symbolic[nl.key]
            expr = expr.subs({sp.Symbol(k, positive=True): v for k, v in subs[nl.key].items()})
            f = sp.lambdify(a_sym, expr, "numpy")
            # the theta-form holds where the motion crosses the breakpoints (|a| > 1 here)
            crossing = a > 1.0 if nl.key == "saturation" else np.ones(a.size, bool)
            sym_vals = np.array([complex(f(x)) for x in a[crossing]])
            res["perturb symbolic"] = float(np.max(np.abs(sym_vals - N[crossing])))
        res["textbook"] = float(np.max(np.abs(textbook_describing(nl, a) - N)))
        checks[nl.key] = res
    return nls, a_grid, values, checks, symbolic


def textbook_describing(nl: Nonlinearity, a: np.ndarray) -> np.ndarray:
    """The classical closed forms (Gelb & Vander Velde 1968; Khalil 1996), typed in from the
    literature, to compare with perturb's and SymPy's."""
    a = np.asarray(a, float)
    if isinstance(nl, DeadZone | Saturation):
        d = nl.delta if isinstance(nl, DeadZone) else nl.level
        r = np.minimum(d / a, 1.0)
        sat = (2.0 / np.pi) * (np.arcsin(r) + r * np.sqrt(1.0 - r * r))
        return (1.0 - sat if isinstance(nl, DeadZone) else sat) + 0j
    if isinstance(nl, Relay):
        r = nl.h / a
        return 4.0 * nl.M / (np.pi * a) * (np.sqrt(1.0 - r * r) - 1j * r)
    r = nl.b / a
    re = 0.5 + (np.arcsin(1 - 2 * r) + 2 * (1 - 2 * r) * np.sqrt(r * (1 - r))) / np.pi
    return re - 1j * 4.0 * r * (1 - r) / np.pi


def study_lure(fast: bool) -> list[LureResult]:
    out = []
    for case in lure_cases():
        preds = predict_cycles(case)
        stable = [p for p in preds if p.stable]
        if not stable:
            raise RuntimeError(f"{case.key}: the describing function predicts no stable cycle")
        p = stable[-1]
        # start 20 % outside the predicted cycle: the simulation has to find it by itself
        x0 = initial_state(case, 1.2 * p.a, p.omega)
        st = simulate_lure(
            case,
            x0,
            period_hint=TWO_PI / p.omega,
            max_periods=150 if fast else 400,
            tol=1e-8 if fast else 1e-10,
            rtol=1e-10 if fast else 1e-12,
            atol=1e-12 if fast else 1e-14,
        )
        out.append(LureResult(case, preds, p, distortion_index(case, p), st))
    return out


def _claims(res: Results) -> list[Check]:
    checks = []

    def run(case, label):
        return res.run_of(case, label)

    # 1. three methods on the same smooth orbit
    for key in ("duffing", "vdp1"):
        labels = [sp_.label for sp_ in method_specs(_case(res, key), res.fast)]
        for label in (labels[0], labels[1], labels[3]):
            r = run(key, label)
            checks.append(
                Check(
                    f"{key}: {label} vs reference",
                    rf"{_case(res, key).title}: {r.spec.tex}, $\max|\Delta y|, |\Delta T|$",
                    r.error if r.ok else math.inf,
                    1e-8,
                )
            )
    vdp5 = [sp_.label for sp_ in method_specs(_case(res, "vdp5"), res.fast)]
    for label in (vdp5[1], vdp5[2]):
        r = run("vdp5", label)
        checks.append(
            Check(
                f"vdp5: {label} vs reference",
                rf"van der Pol $\varepsilon=5$: {r.spec.tex}, $\max|\Delta y|, |\Delta T|$",
                r.error if r.ok else math.inf,
                1e-6 if res.fast else 1e-8,
            )
        )
    # 2. nsd: exact flows to rounding, event-driven to its tolerance, FD only to low order
    nsd = {r.spec.label: r for r in res.runs if r.case == "nsd"}
    for label, lim in (
        ("single shooting, ExactPWLFlow", 1e-10),
        ("multiple shooting (8 nodes), ExactPWLFlow", 1e-10),
        ("single shooting, EventFlow", 1e-8),
        ("single shooting, ODEFlow", 1e-7),
    ):
        checks.append(
            Check(
                f"nsd: {label} vs reference",
                rf"nsd large orbit: {nsd[label].spec.tex}, $\max|\Delta y|$",
                nsd[label].error if nsd[label].ok else math.inf,
                lim,
            )
        )
    fd = next(r for r in res.runs if r.case == "nsd" and r.spec.method == "collocation")
    smooth = run("duffing", labels_for(res, "duffing")[3])
    checks.append(
        Check(
            "nsd: finite differences lose their order on the nonsmooth orbit",
            r"nsd large orbit, finite differences (order 8): $\max|\Delta y|$ (at least $10^{-6}$"
            r" although $10^{-9}$ on Duffing)",
            fd.error if fd.ok else 0.0,
            1e-6,
            above=True,
        )
    )
    for order in (2, 8):
        worst_order = max(p for _, _, p in observed_orders(res.nsd_fd, order))
        checks.append(
            Check(
                f"nsd: observed order of FD order {order} below 3",
                rf"nsd large orbit, finite differences order {order}: largest observed order "
                r"under grid halving",
                worst_order,
                3.0,
            )
        )
    checks.append(
        Check(
            "duffing: finite differences order 8 reach 1e-9",
            r"Duffing, finite differences (order 8): $\max|\Delta y|$",
            smooth.error if smooth.ok else math.inf,
            1e-9,
        )
    )
    saddle = {r.spec.label: r for r in res.runs if r.case == "nsd_saddle"}
    checks.append(
        Check(
            "nsd saddle: single shooting fails from a 0.05 guess",
            r"nsd saddle orbit: single shooting from $y_{\mathrm{ref}} + (0.05, -0.05)$ fails"
            r" (1 = failed)",
            0.0 if saddle["single shooting, ExactPWLFlow"].ok else 1.0,
            1.0,
            above=True,
        )
    )
    for label in (
        "multiple shooting (16 nodes), ExactPWLFlow",
        "finite differences N=128, order 8",
    ):
        checks.append(
            Check(
                f"nsd saddle: {label} vs closed form",
                rf"nsd saddle orbit: {saddle[label].spec.tex}, $\max|\Delta y|$",
                saddle[label].error if saddle[label].ok else math.inf,
                1e-10,
            )
        )
    # finite-difference convergence order on Duffing (grid halving in the sweep)
    for order, lo, hi in ((4, 3.5, 4.5),):
        errs = sorted(
            (r.spec.n_points, r.error)
            for r in res.wp
            if r.case == "duffing" and r.spec.method == "collocation" and r.spec.order == order
        )
        (n1, e1), (n2, e2) = errs[-2], errs[-1]
        p_obs = math.log(e1 / e2) / math.log(n2 / n1)
        checks.append(Check(f"duffing: observed order of FD order {order} >= {lo}",
                            rf"Duffing, finite differences order {order}: observed order"
                            rf" ($N={n1}\to{n2}$)", p_obs, lo, above=True))  # fmt: skip
        checks.append(Check(f"duffing: observed order of FD order {order} <= {hi}",
                            rf"Duffing, finite differences order {order}: observed order"
                            rf" ($N={n1}\to{n2}$)", p_obs, hi))  # fmt: skip
    # 3. describing functions against quadrature, perturb's symbolic form and the textbook
    for nl in res.nls:
        for what, err in res.df_checks[nl.key].items():
            checks.append(
                Check(
                    f"N(a) of {nl.key}: closed form vs {what}",
                    rf"{nl.title}: $N(a)$ vs {what}, $\max|\Delta N|$",
                    err,
                    1e-10,
                )
            )
    # 4. Lur'e loops
    for lr in res.lure:
        nm = lr.case.nl.title
        checks.append(
            Check(
                f"{lr.case.key}: simulation settled",
                rf"{nm}: period change over the last period (relative)",
                lr.steady.period_change,
                1e-7,
            )
        )
        for what, err in (("amplitude", lr.error_a), ("frequency", lr.error_w)):
            checks.append(
                Check(
                    f"{lr.case.key}: describing-function {what} within 10%",
                    rf"{nm}: predicted vs simulated {what}, relative error",
                    abs(err),
                    0.10,
                )
            )
    return checks


def _case(res: Results, key: str) -> OrbitCase:
    return next(c for c in res.cases if c.key == key)


def labels_for(res: Results, key: str) -> list[str]:
    return [sp_.label for sp_ in method_specs(_case(res, key), res.fast)]


def run(fast: bool) -> Results:
    seconds = {}
    t0 = time.perf_counter()
    cases, refs, runs = study_orbits(fast)
    seconds["orbits"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    wp_cases, wp = study_work_precision(cases, refs, fast)
    nsd_fd = study_nsd_fd(cases, refs, fast)
    seconds["work-precision"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    nls, a_grid, values, df_checks, symbolic = study_describing(fast)
    memory = memory_describing_functions()
    seconds["describing functions"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    lure = study_lure(fast)
    seconds["Lur'e loops"] = time.perf_counter() - t0
    res = Results(
        fast, cases, refs, runs, wp, wp_cases, nls, a_grid, values, df_checks, symbolic, memory,
        perturb_rejects_hysteresis(), lure, nsd_fd, seconds=seconds,
    )  # fmt: skip
    t0 = time.perf_counter()
    res.tools = study_limit_cycle_tools(fast)
    res.seconds["friction, event map, fold"] = time.perf_counter() - t0
    res.checks = _claims(res) + _tool_claims(res.tools)
    return res


# ============================================================================================
# outputs
# ============================================================================================
RUN_HEADER = [
    "case", "method", "flow", "nodes", "n_points", "order", "rtol", "guess", "ok", "seconds",
    "newton_iterations", "rhs_evals_or_pwl_pieces", "jac_evals_or_flow_calls", "period",
    "period_error", "state_error", "amplitude_error", "stability", "max_multiplier", "message",
]  # fmt: skip


def _run_row(r: MethodRun) -> list[object]:
    sp_ = r.spec
    return [
        r.case, sp_.method, sp_.flow, sp_.nodes, sp_.n_points, sp_.order, sp_.rtol, sp_.guess,
        r.ok, r.seconds, r.iterations, r.nfev, r.njev, r.period, r.period_error, r.state_error,
        r.amplitude_error, r.stability, r.max_multiplier, r.message,
    ]  # fmt: skip


def fold_polynomial_residual(Omega: np.ndarray, A: np.ndarray) -> np.ndarray:
    """The one-harmonic Duffing response in closed form, A^2[(1 - W^2 + 3 alpha A^2/4)^2 +
    (mu W)^2] - F^2, relative to F^2: zero on the curve."""
    d = FOLD_DUFFING
    k = 1.0 - Omega**2 + 0.75 * d["alpha"] * A**2
    return (A**2 * (k**2 + (d["mu"] * Omega) ** 2) - d["F"] ** 2) / d["F"] ** 2


def _in_unit(x: float) -> float:
    """x when it lies in (0, 1], else inf (a failed check)."""
    return x if 0.0 < x <= 1.0 else math.inf


def _tool_claims(lt: LimitCycleTools) -> list[Check]:
    cf, co, sb = lt.coulomb_exact, lt.coulomb, lt.stribeck
    curve = lt.curve
    amps = np.hypot(curve.u[:, 0], curve.u[:, 1])
    hi_fold = max(f.lam for f in curve.folds) if curve.folds else math.nan
    lo_fold = min(f.lam for f in curve.folds) if curve.folds else math.nan
    up, down = lt.up, lt.down
    checks = [
        Check(
            "Coulomb stick-slip: period vs closed form",
            r"Coulomb belt: $|T - T_{\mathrm{closed}}|/T_{\mathrm{closed}}$",
            abs(co.period / cf["period"] - 1.0),
            1e-9,
        ),
        Check(
            "Coulomb stick-slip: extremes vs closed form",
            r"Coulomb belt: $\max(|\Delta x_{\max}|, |\Delta x_{\min}|)$ vs closed form",
            max(abs(co.x_max - cf["x_max"]), abs(co.x_min - cf["x_min"])),
            1e-9,
        ),
        Check(
            "Stribeck stick-slip: the cycle repeats",
            r"Stribeck belt (perturb, event-driven): spread of the last periods",
            float(np.ptp(sb.periods[1:])),
            1e-8,
        ),
        Check(
            "Stribeck: stick time = (x_break - x_onset)/v_b",
            r"Stribeck belt: stick time vs $(\mu_s - c v_b - x_{\mathrm{onset}})/v_b$",
            abs(
                sb.t_stick
                - (BELT["mu_s"] - STRIBECK["c"] * BELT["v_b"] - sb.cycle[1][0]) / BELT["v_b"]
            ),
            1e-8,
        ),
    ]
    checks.append(
        Check(
            "mu_s = mu_k: no stick after the first, grazes every 2 pi",
            r"Coulomb belt, $\mu_s=\mu_k$ (perturb): spacing of the later events $-2\pi$ "
            r"(all grazes)",
            lt.equal["spacing_error"] if lt.equal["kinds"] == ["graze"] else math.inf,
            1e-8,
        )
    )
    for rm in lt.maps:
        checks.append(
            Check(
                f"van der Pol eps={rm.eps:g}: P'(a*) = Floquet multiplier",
                rf"van der Pol, $\varepsilon={rm.eps:g}$: $|P'(a^*) - \det M|$",
                abs(rm.slope - rm.multiplier),
                1e-6,
            )
        )
    checks += [
        Check(
            "pseudo-arclength passes both folds",
            r"forced Duffing (HB1): folds found by pseudo-arclength",
            float(len(curve.folds)),
            2.0,
            above=True,
        ),
        Check(
            "pseudo-arclength curve on the closed-form response",
            r"forced Duffing: $\max|A^2[(1-\Omega^2+\frac34\alpha A^2)^2+\mu^2\Omega^2]-F^2|/F^2$",
            float(np.max(np.abs(fold_polynomial_residual(curve.lam, amps)))),
            1e-9,
        ),
        Check(
            "sequential sweep up leaves the branch at the first step past the fold",
            r"sweep up: $(\Omega_{\mathrm{fail}}-\Omega_{\mathrm{fold}})/\Delta\Omega\in(0,1]$",
            _in_unit((up.Omega[up.fail] - hi_fold) / lt.step) if up.fail > 0 else math.inf,
            1.0,
        ),
        Check(
            "sequential sweep down leaves the branch at the first step past the fold",
            r"sweep down: $(\Omega_{\mathrm{fold}}-\Omega_{\mathrm{fail}})/\Delta\Omega\in(0,1]$",
            _in_unit((lo_fold - down.Omega[down.fail]) / lt.step) if down.fail > 0 else math.inf,
            1.0,
        ),
    ]
    return checks


def figure_tools(res: Results, path: Path) -> None:
    """Stick-slip cycles, the van der Pol return maps, continuation through the folds."""
    plt = _plt()
    lt = res.tools
    fig, axes = plt.subplots(2, 2, figsize=(10, 7.6))
    ax = axes[0, 0]
    for sl, col in ((lt.coulomb, "C0"), (lt.stribeck, "C3")):
        ax.plot(sl.cycle[1], sl.cycle[2], "-", color=col, lw=1.2,
                label=f"{sl.law}: T = {sl.period:.6f}")  # fmt: skip
    ax.axhline(BELT["v_b"], color="k", lw=0.6, ls="--", label="belt speed (stick)")
    ax.set_xlabel("x")
    ax.set_ylabel("x'")
    ax.set_title("stick-slip limit cycles on the belt", fontsize=9)
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    ax = axes[0, 1]
    for sl, col in ((lt.coulomb, "C0"), (lt.stribeck, "C3")):
        ax.plot(sl.cycle[0], sl.cycle[1], "-", color=col, lw=1.2, label=sl.law)
    ax.set_xlabel("t (from a stick onset)")
    ax.set_ylabel("x")
    ax.set_title("one cycle: stick (linear rise), then slip", fontsize=9)
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    ax = axes[1, 0]
    ax.plot([0, 4], [0, 4], "k-", lw=0.6)
    for rm, col in zip(lt.maps, ("C0", "C1", "C2"), strict=False):
        ax.plot(rm.grid, rm.P, "o-", color=col, ms=3, lw=1.0,
                label=rf"$\varepsilon={rm.eps:g}$: $a^*={rm.fixed:.6f}$")  # fmt: skip
        xs, ys = [rm.iterates[0]], [rm.iterates[0]]
        for a, b in zip(rm.iterates[:-1], rm.iterates[1:], strict=True):
            xs += [a, b]
            ys += [b, b]
        ax.plot(xs, ys, ":", color=col, lw=0.8)
    ax.set_xlabel("a (x at a maximum)")
    ax.set_ylabel("P(a) (x at the next maximum)")
    ax.set_title("van der Pol return map on x' = 0, x > 0 (dotted: cobweb from 0.5)", fontsize=9)
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    ax = axes[1, 1]
    cv = lt.curve
    ax.plot(cv.lam, np.hypot(cv.u[:, 0], cv.u[:, 1]), "k-", lw=1.2, label="pseudo-arclength")
    for sw, mk, col in ((lt.up, "^", "C0"), (lt.down, "v", "C3")):
        good = np.isfinite(sw.amplitude)
        ax.plot(sw.Omega[good][::2], sw.amplitude[good][::2], mk, color=col, ms=3, mfc="none",
                label="sequential, " + ("up" if sw.direction > 0 else "down"))  # fmt: skip
        if sw.fail > 0:
            ax.axvline(sw.Omega[sw.fail], color=col, lw=0.7, ls="--")
    for f in cv.folds:
        ax.plot([f.lam], [np.hypot(*f.u)], "ks", ms=5)
    ax.set_xlabel(r"$\Omega$")
    ax.set_ylabel("A")
    ax.set_title("forced Duffing (HB1): folds (squares), first failures (dashed)", fontsize=9)
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def write_tools_csv(st: Study, lt: LimitCycleTools) -> None:
    cf = lt.coulomb_exact
    rows = []
    for sl in (lt.coulomb, lt.stribeck):
        rows.append((sl.law, sl.period, sl.x_max, sl.x_min, sl.amplitude, sl.t_stick))
    rows.append(("Coulomb closed form", cf["period"], cf["x_max"], cf["x_min"], cf["amplitude"],
                 cf["t_stick"]))  # fmt: skip
    st.write_csv(
        "stick_slip.csv", ["law", "period", "x_max", "x_min", "half_range", "stick_time"], rows
    )
    st.write_csv(
        "vdp_return_map.csv",
        ["eps", "a", "P(a)"],
        [
            (rm.eps, float(a), float(p))
            for rm in lt.maps
            for a, p in zip(rm.grid, rm.P, strict=True)
        ],
    )
    st.write_csv(
        "vdp_fixed_points.csv",
        ["eps", "a_star", "period", "slope_P", "floquet_multiplier_detM"],
        [(rm.eps, rm.fixed, rm.period, rm.slope, rm.multiplier) for rm in lt.maps],
    )
    st.write_csv(
        "fold_sequential.csv",
        ["direction", "Omega", "amplitude", "newton_iterations"],
        [
            (sw.direction, float(w), float(a), int(i))
            for sw in (lt.up, lt.down)
            for w, a, i in zip(sw.Omega, sw.amplitude, sw.iterations, strict=True)
        ],
    )
    st.write_csv(
        "fold_arclength.csv",
        ["Omega", "a", "b", "amplitude"],
        [(float(w), float(u[0]), float(u[1]), float(np.hypot(*u)))
         for w, u in zip(lt.curve.lam, lt.curve.u, strict=True)],
    )  # fmt: skip
    st.write_csv(
        "fold_points.csv",
        ["Omega", "amplitude", "refined"],
        [(float(f.lam), float(np.hypot(*f.u)), f.refined) for f in lt.curve.folds],
    )


def _tools_tex(st: Study, res: Results) -> str:
    lt = res.tools
    cf, co, sb = lt.coulomb_exact, lt.coulomb, lt.stribeck
    b, s_ = BELT, STRIBECK
    up, down, cv = lt.up, lt.down, lt.curve
    folds = sorted(cv.folds, key=lambda f: f.lam)
    lo, hi = folds[0], folds[-1]
    period_err = abs(co.period / cf["period"] - 1.0)
    ext_err = max(abs(co.x_max - cf["x_max"]), abs(co.x_min - cf["x_min"]))
    neg_damp = (b["mu_s"] - b["mu_k"]) / s_["v_s"] * math.exp(-b["v_b"] / s_["v_s"])

    def slope_tex(rm):
        if abs(rm.slope) < 1e-8:  # a central difference of rounding errors
            return r"$|P'(a^*)|<10^{-8}$"
        return rf"$P'(a^*)={_num(rm.slope)}$"

    maps = ", ".join(
        rf"$a^*={rm.fixed:.6f}$ ($\varepsilon={rm.eps:g}$, $T={rm.period:.4f}$, {slope_tex(rm)})"
        for rm in lt.maps
    )
    big = lt.maps[-1]
    mult_diff = max(abs(rm.slope - rm.multiplier) for rm in lt.maps)
    if max(abs(big.slope), abs(big.multiplier)) < 1e-8:
        big_tex = (
            rf"at $\varepsilon={big.eps:g}$ both are below $10^{{-8}}$ ($\det M = "
            rf"{_num(big.multiplier, 2)}$, rounding level): the relaxation cycle forgets its "
            "start in one turn"
        )
    else:
        big_tex = rf"at $\varepsilon={big.eps:g}$, $P'(a^*)={_num(big.slope)}$"
    one = next((rm for rm in lt.maps if rm.eps == 1.0), lt.maps[0])
    iters = ", ".join(f"{a:.6f}" for a in one.iterates[:5])

    def after(sw):
        if sw.recovered < 0:
            return (
                "never converges again in the window (Newton keeps starting from the last "
                "point of the lost branch)"
            )
        return (
            rf"converges again only at $\Omega={sw.Omega[sw.recovered]:.3f}$, on the other "
            rf"branch ($A={sw.amplitude[sw.recovered]:.4f}$)"
        )

    up_last, dn_last = up.fail - 1, down.fail - 1
    eq = lt.equal
    eq_kinds = " and ".join(k + "s" for k in eq["kinds"])
    fig = st.tex_path("limit_cycle_tools.png")
    return rf"""\subsection{{Dry friction, an event map and continuation through a fold}}
\label{{sec:ps-tools}}
Dry friction is the study's first cause of limit cycling; event maps and sequential against
pseudo-arclength continuation are among its tools. Three small cases put numbers on them
(representative values: the seed gives none).

\emph{{Stick--slip on a moving belt.}} $\ddot x + c\dot x + x = \mu(v_b-\dot x)$ ($m=k=N=1$),
$v_b={b["v_b"]:g}$, static and kinetic coefficients $\mu_s={b["mu_s"]:g}$, $\mu_k={b["mu_k"]:g}$.
\emph{{Coulomb}} ($\mu=\mu_k\operatorname{{sign}}v$ while slipping, up to $\mu_s$ while stuck,
$c=0$): the mass rides the belt until $x=\mu_s$, then slips harmonically about $x=\mu_k$ from
$(\mu_s, v_b)$ with amplitude $A=\sqrt{{(\mu_s-\mu_k)^2+v_b^2}}$ and returns to the belt speed at
$x=2\mu_k-\mu_s$, so in closed form $T = 2\pi - 2\operatorname{{atan2}}(\mu_s-\mu_k, v_b) +
2(\mu_s-\mu_k)/v_b = {cf["period"]:.10f}$ (slip ${cf["t_slip"]:.6f}$, stick ${cf["t_stick"]:.6f}$),
$x\in[{cf["x_min"]:.8f}, {cf["x_max"]:.8f}]$. perturb's event-driven integrator sticks by
Filippov's rule on $\operatorname{{sign}}(v_b-\dot x)$, whose sticking limit is the kinetic
coefficient itself, so it cannot hold $\mu_s>\mu_k$; this case runs on \texttt{{solve\_ivp}}
written here (stick in closed form, slip by DOP853 with the return to $v_b$ and the zeros of
$\dot x$ located as events) and matches the closed form to ${_num(period_err, 2)}$ (period,
relative) and ${_num(ext_err, 2)}$ (extremes). With $\mu_s=\mu_k$ (which perturb does take)
the mass from rest sticks once, then slips on the ellipse about $x=\mu_k$ of radius $v_b$ that
only touches the belt speed: the event-driven integrator logs {eq["n_later"]} later events,
all {eq_kinds}, spaced by $2\pi$ to ${_num(eq["spacing_error"], 2)}$; no stick--slip cycle. The
cause of the cycle is the drop from static to kinetic friction.
\emph{{Stribeck}} ($\mu(v)=\operatorname{{sign}}v\,(\mu_k+(\mu_s-\mu_k)
e^{{-|v|/v_s}})$, $v_s={s_["v_s"]:g}$, $c={s_["c"]:g}$) is a switch perturb reads, and runs on
\texttt{{perturb.simulate.event\_driven}}: the falling friction law acts as a negative damping
${_num(neg_damp)}>c$ at $v_b$, steady sliding is unstable, and the orbit settles on a stick--slip
cycle of period $T={sb.period:.10f}$ (stuck for ${sb.t_stick:.6f}$ of it),
$x\in[{sb.x_min:.8f}, {sb.x_max:.8f}]$ (half range ${sb.amplitude:.8f}$; the Coulomb
cycle's is ${co.amplitude:.8f}$). Every stick ends at the same state $(\mu_s-cv_b, v_b)$, so
the cycle is reached at the first stick (a stick erases any perturbation of the slip): the
periods after the first differ by ${_num(float(np.ptp(sb.periods[1:])), 2)}$.

\emph{{The event map of van der Pol.}} On the section $\dot x=0$, $x>0$ (the maxima of $x$),
$P(a)$ is the next maximum from $(a,0)$, computed by DOP853 on perturb's right-hand side with
the section crossing located as an event. Its fixed points (\texttt{{brentq}} on $P(a)-a$) are
the limit cycles: {maps}. From $a_0=0.5$ at $\varepsilon=1$ the iterates are {iters}, \ldots:
the map contracts by $P'(a^*)$ per turn. $P'(a^*)$ (central difference) equals the determinant
of the monodromy matrix (perturb's \texttt{{ODEFlow}} with sensitivities; the other multiplier
of a planar autonomous orbit is 1) to ${_num(mult_diff, 2)}$; {big_tex}.

\emph{{Sequential continuation at a fold.}} The one-harmonic balance of
$\ddot x+\mu\dot x+x+\alpha x^3=F\cos\Omega t$ ($\mu={FOLD_DUFFING["mu"]:g}$,
$\alpha={FOLD_DUFFING["alpha"]:g}$, $F={FOLD_DUFFING["F"]:g}$, the Duffing case above) in
$x=a\cos\Omega t+b\sin\Omega t$ is traced over $\Omega\in[{FOLD_WINDOW[0]:g},
{FOLD_WINDOW[1]:g}]$ twice. Pseudo-arclength continuation (\texttt{{perturb.numeric.continuation.
continue\_curve}}, {len(cv.lam)} points) passes both folds, at $\Omega={hi.lam:.6f}$
($A={np.hypot(*hi.u):.6f}$) and $\Omega={lo.lam:.6f}$ ($A={np.hypot(*lo.u):.6f}$), and stays on
the closed-form response $A^2[(1-\Omega^2+\tfrac34\alpha A^2)^2+\mu^2\Omega^2]=F^2$.
Sequential continuation, Newton (perturb's damped \texttt{{newton\_fixed}}) at
$\Omega_{{j+1}}=\Omega_j\pm{lt.step:g}$ from the solution at $\Omega_j$, follows the upper branch
upwards to $\Omega={up.Omega[up_last]:.3f}$ ($A={up.amplitude[up_last]:.4f}$) and fails at the
next step, $\Omega={up.Omega[up.fail]:.3f}$, just past the fold; it {after(up)}. Downwards it
follows the lower branch to $\Omega={down.Omega[dn_last]:.3f}$, fails at
$\Omega={down.Omega[down.fail]:.3f}$ and {after(down)}. A natural-parameter method cannot turn
at a fold: it loses the branch there and, at best, lands on another (the jump of a slow sweep);
the middle branch between the folds is reached only by arclength (Fig.~\ref{{fig:ps-tools}}).

\begin{{figure}}[ht]
\centering
\includegraphics[width=\textwidth]{{{fig}}}
\caption{{Top: the stick--slip cycles of the belt system (Coulomb with $\mu_s>\mu_k$, closed
form and event-located \texttt{{solve\_ivp}}; Stribeck, perturb's event-driven integrator);
representative values. Bottom left: van der Pol's return map on $\dot x=0$, $x>0$ with cobwebs
from $a_0=0.5$; its fixed points are the limit-cycle amplitudes. Bottom right: one-harmonic
forced Duffing, pseudo-arclength (line, folds as squares) against sequential sweeps up and down
(every second point), which lose their branch at the dashed lines.}}
\label{{fig:ps-tools}}
\end{{figure}}
"""


def write_csv(st: Study, res: Results) -> None:
    st.write_csv("orbit_methods.csv", RUN_HEADER, [_run_row(r) for r in res.runs])
    st.write_csv("work_precision.csv", RUN_HEADER, [_run_row(r) for r in res.wp])
    st.write_csv("nsd_finite_differences.csv", RUN_HEADER, [_run_row(r) for r in res.nsd_fd])
    st.write_csv(
        "references.csv",
        ["case", "x0", "v0", "period", "amplitude", "how", "seconds"],
        [
            (k, float(r.y0[0]), float(r.y0[1]), r.period, r.amplitude, r.how, r.seconds)
            for k, r in res.refs.items()
        ],
    )
    header = ["a"]
    for nl in res.nls:
        header += [f"{nl.key}_re", f"{nl.key}_im"]
    rows = []
    for i, a in enumerate(res.a_grid):
        row: list[object] = [float(a)]
        for nl in res.nls:
            N = res.df_values[nl.key][i]
            row += [float(N.real), float(N.imag)]
        rows.append(row)
    st.write_csv("describing_functions.csv", header, rows)
    st.write_csv(
        "lure_cycles.csv",
        [
            "nonlinearity", "plant", "a_predicted", "omega_predicted", "stable_df",
            "distortion_index", "a_first_harmonic_sim", "peak_sim", "omega_sim", "period_sim",
            "rel_error_a", "rel_error_omega", "period_change", "t_end", "switches", "seconds",
        ],
        [
            (
                lr.case.key, lr.case.plant.key, p.a, p.omega, p.stable, lr.distortion,
                lr.steady.first_harmonic, lr.steady.peak, lr.steady.omega, lr.steady.period,
                p.a / lr.steady.first_harmonic - 1.0 if p is lr.stable else math.nan,
                p.omega / lr.steady.omega - 1.0 if p is lr.stable else math.nan,
                lr.steady.period_change, lr.steady.t_end, lr.steady.n_switches,
                lr.steady.seconds,
            )
            for lr in res.lure
            for p in lr.predictions
        ],
    )  # fmt: skip
    rows = []
    for lr in res.lure:
        step = max(1, lr.steady.t.size // 512)
        for tt, e, u in zip(lr.steady.t[::step], lr.steady.e[::step], lr.steady.u[::step],
                            strict=True):  # fmt: skip
            rows.append((lr.case.key, float(tt), float(e), float(u)))
    st.write_csv("lure_waveforms.csv", ["nonlinearity", "t", "e", "u"], rows)
    st.write_csv(
        "checks.csv",
        ["claim", "measured", "limit", "kind", "ok"],
        [(c.name, c.value, c.limit, ">=" if c.above else "<=", c.ok) for c in res.checks],
    )


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


PLAIN_TITLES = {
    "duffing": "Duffing (mu=0.1, alpha=1, F=0.5, Omega=1.2)",
    "vdp1": "van der Pol, eps=1",
    "vdp5": "van der Pol, eps=5",
    "nsd": "nsd large orbit",
    "nsd_saddle": "nsd saddle orbit",
}


def figure_work_precision(res: Results, path: Path) -> None:
    plt = _plt()
    from matplotlib.ticker import NullFormatter

    n = len(res.wp_cases)
    fig, axes = plt.subplots(n, 2, figsize=(10.5, 3.6 * n), squeeze=False)
    styles = {
        ("single", 0): ("o-", "single shooting"),
        ("multiple", 0): ("s-", "multiple shooting (8)"),
        ("collocation", 4): ("^-", "finite differences, order 4"),
        ("collocation", 8): ("v-", "finite differences, order 8"),
    }
    for row, key in enumerate(res.wp_cases):
        runs = [r for r in res.wp if r.case == key and r.ok]
        for (method, order), (style, label) in styles.items():
            sel = [r for r in runs if r.spec.method == method and r.spec.order == order]
            if not sel:
                continue
            err = [max(r.error, 1e-16) for r in sel]
            axes[row, 0].loglog([r.seconds for r in sel], err, style, label=label, ms=4)
            axes[row, 1].loglog([max(r.nfev, 1) for r in sel], err, style, label=label, ms=4)
        title = PLAIN_TITLES[key]
        for ax, xl in zip(axes[row], ("wall time (s)", "right-hand-side evaluations"),
                          strict=True):  # fmt: skip
            ax.xaxis.set_minor_formatter(NullFormatter())  # the labelled minor ticks collide
            ax.set_xlabel(xl)
            ax.set_ylabel(r"max(|$\Delta y$|, |$\Delta T$|)")
            ax.set_title(title, fontsize=9)
            ax.grid(True, which="both", alpha=0.3)
        axes[row, 0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def figure_orbits(res: Results, path: Path) -> None:
    plt = _plt()
    keys = ["duffing", "vdp1", "vdp5", "nsd"]
    fig, axes = plt.subplots(1, 4, figsize=(14, 3.6))
    for ax, key in zip(axes, keys, strict=True):
        ref = res.refs[key]
        y = ref.states(np.arange(600) / 600)
        ax.plot(y[:, 0], y[:, 1], "k-", lw=1.0, label="reference")
        for r in res.runs:
            if r.case != key or not r.ok or r.orbit is None or r.orbit.nodes is None:
                continue
            nodes = r.orbit.nodes
            if r.spec.method == "multiple":
                ax.plot(nodes[:, 0], nodes[:, 1], "rs", ms=5, label="shooting nodes")
            elif r.spec.order == 8:
                step = max(1, nodes.shape[0] // 64)
                ax.plot(nodes[::step, 0], nodes[::step, 1], "b.", ms=3,
                        label=f"FD grid (every {step})")  # fmt: skip
        if key == "nsd":
            sad = res.refs["nsd_saddle"].states(np.arange(200) / 200)
            ax.plot(sad[:, 0], sad[:, 1], "g-", lw=1.0, label="saddle orbit")
            for d in (-1, 1):
                ax.axvline(d, color="0.6", lw=0.6, ls=":")
        ax.set_title(_case(res, key).title.split(",")[0] + (
            f" eps={key[3:]}" if key.startswith("vdp") else ""), fontsize=9)  # fmt: skip
        ax.set_xlabel("x")
        ax.set_ylabel("x'")
        ax.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def figure_describing(res: Results, path: Path) -> None:
    plt = _plt()
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10.5, 3.8))
    for nl in res.nls:
        N = res.df_values[nl.key]
        label = nl.title.replace("$", "")
        ax1.semilogx(res.a_grid, np.abs(N), label=label)
        ax2.semilogx(res.a_grid, np.degrees(np.angle(N)), label=label)
    ax1.set_ylim(0, 2.5)
    ax1.set_xlabel("input amplitude a")
    ax1.set_ylabel("|N(a)|")
    ax2.set_xlabel("input amplitude a")
    ax2.set_ylabel("arg N(a) (deg)")
    for ax in (ax1, ax2):
        ax.grid(True, which="both", alpha=0.3)
    ax1.legend(fontsize=7)
    ax1.set_title(r"dead zone $\delta=1$, saturation $L=1$, relays $M=1$, backlash $b=0.5$",
                  fontsize=8)  # fmt: skip
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def figure_lure(res: Results, path: Path) -> None:
    plt = _plt()
    n = len(res.lure)
    fig, axes = plt.subplots(2, n, figsize=(3.3 * n, 6.4))
    for j, lr in enumerate(res.lure):
        ax = axes[0, j]
        w = np.geomspace(0.05, 20, 2000)
        G = lr.case.plant.G(w)
        ax.plot(G.real, G.imag, "k-", lw=1, label="G(i omega)")
        lo = lr.case.nl.threshold * 1.0005 if lr.case.nl.threshold else 0.05
        a = np.geomspace(lo, 30, 400)
        inv = -1.0 / lr.case.nl.describing(a)
        ax.plot(inv.real, inv.imag, "r-", lw=1, label="-1/N(a)")
        for p in lr.predictions:
            Gp = lr.case.plant.G(np.array([p.omega]))[0]
            ax.plot(Gp.real, Gp.imag, "o" if p.stable else "x", color="b", ms=6,
                    mfc="b" if p.stable else "none")  # fmt: skip
        ax.set_xlim(-3.5, 1.0)
        ax.set_ylim(-3.0, 1.0)
        ax.axhline(0, color="0.7", lw=0.5)
        ax.axvline(0, color="0.7", lw=0.5)
        ax.set_title(lr.case.nl.title.replace("$", ""), fontsize=9)
        ax.set_xlabel("Re")
        if j == 0:
            ax.set_ylabel("Im")
            ax.legend(fontsize=7, loc="lower left")
        ax = axes[1, j]
        st, p = lr.steady, lr.stable
        ax.plot(st.t, st.e, "k-", lw=1, label="e(t), simulated")
        ax.plot(st.t, p.a * np.sin(p.omega * st.t), "r--", lw=1, label="a sin(omega t), DF")
        ax.plot(st.t, st.u, "-", color="0.6", lw=0.8, label="u(t)")
        ax.set_xlabel("t (from an upward zero crossing of e)")
        if j == 0:
            ax.legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def _err(x: float) -> str:
    return "--" if not math.isfinite(x) else f"${_num(x, 2)}$"


def liouville_multiplier(case: OrbitCase, ref: Reference, n: int = 4096) -> float:
    """The non-trivial multiplier of a van der Pol cycle from Liouville's formula: the trivial
    one is 1, so mu = det M = exp(oint div f dt) = exp(eps oint (1 - x^2) dt) (the periodic
    trapezoid rule is spectrally accurate)."""
    eps = float(case.model.params["eps"])
    x = ref.states(np.arange(n) / n)[:, 0]
    return math.exp(eps * float(np.mean(1.0 - x * x)) * ref.period)


def _orbit_table(res: Results) -> str:
    lines = []
    for case in res.cases:
        ref = res.refs[case.key]
        liou = ""
        if case.autonomous:
            liou = rf", Liouville $\mu = {_num(liouville_multiplier(case, ref), 3)}$"
        lines.append(
            rf"\multicolumn{{8}}{{l}}{{\emph{{{case.title}}}: $T={ref.period:.10f}$, "
            rf"amplitude ${ref.amplitude:.8f}${liou}; reference: {ref.how}}} \\"
        )
        for r in res.runs:
            if r.case != case.key:
                continue
            pwl = r.spec.flow != "ode" and r.spec.method != "collocation"
            evals = f"{r.nfev}/{r.njev}" + ("$^p$" if pwl else "")
            if r.ok:
                mult = f"${_num(r.max_multiplier, 3)}$"
                lines.append(
                    rf"\quad {r.spec.tex} & {r.seconds:.2f} & {r.iterations} & {evals} & "
                    rf"{_err(r.state_error)} & {_err(r.period_error)} & "
                    rf"{_err(r.amplitude_error)} & {mult} \\"
                )
            else:
                why = "equilibrium" if "equilibrium" in r.message else (
                    "runaway" if "|x|" in r.message else "no convergence")  # fmt: skip
                lines.append(
                    rf"\quad {r.spec.tex} & {r.seconds:.2f} & {r.iterations} & {evals} & "
                    rf"\multicolumn{{4}}{{l}}{{failed: {why}}} \\"
                )
    return "\n".join(lines)


def _df_rows(res: Results) -> str:
    rows = []
    for nl in res.nls:
        q = res.df_checks[nl.key]
        rows.append(
            rf"{nl.title} & $\displaystyle {nl.formula()}$ & {nl.source} & "
            rf"${_num(q['quadrature'], 1)}$ \\[1ex]"
        )
    return "\n".join(rows)


def _lure_rows(res: Results) -> str:
    rows = []
    for lr in res.lure:
        st = lr.steady
        for p in sorted(lr.predictions, key=lambda q: q is not lr.stable):
            if p is lr.stable:
                rows.append(
                    rf"{lr.case.nl.title} & ${lr.case.plant.tex}$ & ${p.a:.4f}$ & "
                    rf"${p.omega:.4f}$ & ${st.first_harmonic:.4f}$ & ${st.peak:.4f}$ & "
                    rf"${st.omega:.4f}$ & ${100 * lr.error_a:+.2f}$ & ${100 * lr.error_w:+.2f}$ & "
                    rf"${100 * lr.distortion:.2f}$ \\"
                )
            else:
                rows.append(
                    rf"\quad (second root) & & ${p.a:.4f}$ & ${p.omega:.4f}$ & "
                    rf"\multicolumn{{6}}{{l}}{{unstable by the Loeb criterion: not simulated}} \\"
                )
    return "\n".join(rows)


def _checks_rows(res: Results) -> str:
    rows = []
    for c in res.checks:
        rel = r"\ge" if c.above else r"\le"
        rows.append(
            rf"{c.tex} & ${_num(c.value, 2)}$ & ${rel}\,{_num(c.limit, 2)}$ & "
            rf"{'yes' if c.ok else 'NO'} \\"
        )
    return "\n".join(rows)


def section_tex(st: Study, res: Results, seconds: float) -> str:
    R = {(r.case, r.spec.label): r for r in res.runs}
    duf, vdp1, vdp5 = labels_for(res, "duffing"), labels_for(res, "vdp1"), labels_for(res, "vdp5")
    d_ss, d_fd8 = R[("duffing", duf[0])], R[("duffing", duf[3])]
    v1_ss, v1_fd8 = R[("vdp1", vdp1[0])], R[("vdp1", vdp1[3])]
    v5_ss, v5_crude, v5_ms = R[("vdp5", vdp5[0])], R[("vdp5", vdp5[1])], R[("vdp5", vdp5[2])]
    v5_fd8 = R[("vdp5", vdp5[4])]
    nsd_fd = next(r for r in res.runs if r.case == "nsd" and r.spec.method == "collocation")
    nsd_ex = R[("nsd", "single shooting, ExactPWLFlow")]
    nsd_ode = R[("nsd", "single shooting, ODEFlow")]
    sad = {r.spec.label: r for r in res.runs if r.case == "nsd_saddle"}
    sad_ss = sad["single shooting, ExactPWLFlow"]
    sad_ms = sad["multiple shooting (16 nodes), ExactPWLFlow"]
    mu_sad = sad_ms.max_multiplier
    lure = {lr.case.key: lr for lr in res.lure}
    errs_a = [abs(lr.error_a) for lr in res.lure]
    errs_w = [abs(lr.error_w) for lr in res.lure]
    worst = max(res.lure, key=lambda lr: abs(lr.error_a))
    ratios = [abs(lr.error_a) / lr.distortion for lr in res.lure]
    ratio_lo, ratio_hi = min(ratios), max(ratios)
    bl = lure["backlash"]
    n_ok = sum(c.ok for c in res.checks)
    figs = {k: st.tex_path(f"{k}.png") for k in ("work_precision", "orbits", "describing", "lure")}
    dz_sym = latex(res.symbolic["dead_zone"].subs(sp.Symbol("delta", positive=True),
                                                  sp.Symbol("delta", positive=True)))  # fmt: skip
    bl_re, bl_im = res.memory["backlash"]
    hy_re, hy_im = res.memory["relay_hysteresis"]
    timing = ", ".join(f"{escape(k)} {v:.0f}\\,s" for k, v in res.seconds.items())
    if v5_ss.ok:
        v5_outcome = f"converges in {v5_ss.iterations} iterations"
    elif "equilibrium" in v5_ss.message:
        v5_outcome = "converges to the equilibrium at the origin (perturb detects and rejects it)"
    else:
        v5_outcome = "fails"
    sad_outcome = "fails" if not sad_ss.ok else "converges"
    # the refusal in words, not perturb's message quoted (SymPy text in the body of a paper)
    rejection = (
        r"refuses it with a \texttt{ModelError}: the switch depends on $\dot x$, so the "
        r"term has no closed-form Fourier coefficients in $x$ alone"
        if res.rejection
        else r"does not refuse it"
    )
    fd_orders = {
        p: ", ".join(f"{q:.2f}" for _, _, q in observed_orders(res.nsd_fd, p)) for p in (2, 8)
    }
    fd_ratio = (v1_ss.nfev + v1_ss.njev) / max(v1_fd8.nfev + v1_fd8.njev, 1)
    mode = "fast mode: coarser grids, fewer tolerances" if res.fast else "full grids"
    wp_cases = ", ".join(_case(res, k).title for k in res.wp_cases)
    return rf"""
\section{{Periodic solutions: shooting, finite differences and describing functions}}
\label{{sec:periodic-solutions}}

The literature study on limit cycling (docs/references.md \S3) reviews the nonsmooth causes of
self-excited oscillation --- dead zone, saturation, backlash, relays, hysteresis --- and the
tools that predict periodic solutions: the describing function of a Lur'e loop,
$1 + N(a)W(i\omega) = 0$; single shooting with the phase condition; periodic finite
differences; multiple shooting.  Its comparisons are qualitative (finite differences are
``computationally more efficient'' than shooting, shooting is ``very vulnerable to bad initial
guesses'', finite differences ``can only be applied to smooth systems'', the describing
function gives a limit cycle that ``probably'' exists ``close to'' the prediction).  This
section puts numbers on each of them.  All parameter values are representative choices (the
study gives none), except the nsd values $k=-2$, $\mu=0.05$, $F=2$, $\Omega=0.6$, the
Zou--Nagarajaiah Fig.~5 parameters \emph{{reconstructed}} from the damaged seed text
(docs/references.md \S1).  Script: \texttt{{derivations/periodic\_solutions.py}} ({mode};
{seconds:.0f}\,s: {timing}).

\subsection{{Three routes to the same periodic orbit}}

\emph{{Single shooting}} solves $\varphi_T(y_0) = y_0$ by Newton's method with the monodromy
matrix from the variational equations; for an autonomous system the period is a further
unknown and the phase condition $\dot x(0) = 0$ closes the bordered system.  \emph{{Multiple
shooting}} places $N$ nodes on the orbit and asks each flow segment to end on the next node
(a sparse block-cyclic Newton system).  \emph{{Periodic finite differences}} impose the equation
of motion with centred differences of order $p$ on $N$ grid points and use no integrator at all
(perturb's \texttt{{collocation\_orbit}}).  Every method starts from the same guess: the
reference orbit with its states scaled by 1.02 and shifted by 0.02 and, for autonomous systems,
its period scaled by 0.98 (single shooting takes the first point, multiple shooting $N$ nodes,
finite differences the $N$ grid values); the nsd saddle orbit is perturbed by $(0.05, -0.05)$.
The references are computed in the script with \texttt{{solve\_ivp}} (DOP853, rtol
$10^{{-13}}$) on the equations of motion typed in by hand (Table~\ref{{tab:ps-orbits}}).  Cost
is the wall time of the perturb call (it includes perturb's orbit statistics: 1024 samples,
refined extrema, and for finite differences one variational pass for the multipliers), Newton
iterations, and right-hand-side/Jacobian evaluations, counted by wrapping the
\texttt{{NumericRHS}} that \texttt{{ODEFlow}} integrates; for the piecewise-linear flows
(marked $^p$) the counts are linear pieces propagated and flow calls.  $\max|\Delta y|$ is the
largest state difference to the reference on {N_COMPARE} phase-aligned samples over the period.

\begin{{table}}[ht]
\centering\scriptsize
\caption{{Cost and accuracy of the periodic-orbit solvers on the same orbits (wall times on a
shared, loaded machine: compare within a row group).  $\mu_{{\max}}$: largest non-trivial
Floquet multiplier (for van der Pol compare Liouville's $\mu = \exp\oint\varepsilon(1-x^2)\,dt$;
at $\varepsilon = 5$ it is far below rounding, and the solvers return noise of order
$10^{{-14}}$ or 0).  $^c$ crude guess $(x, \dot x) = (2, 0)$ and
$T = (3 - 2\ln 2)\varepsilon + 7.014\varepsilon^{{-1/3}}$ (the relaxation-oscillation
asymptote).}}
\label{{tab:ps-orbits}}
\resizebox{{\textwidth}}{{!}}{{%
\begin{{tabular}}{{lrrrllll}}
\toprule
method & s & Newton & $f$/$J$ evals & $\max|\Delta y|$ & $|\Delta T|$ & $|\Delta A|$ &
$\mu_{{\max}}$ \\
\midrule
{_orbit_table(res)}
\bottomrule
\end{{tabular}}}}
\end{{table}}

\begin{{figure}}[ht]
\centering
\includegraphics[width=\textwidth]{{{figs["orbits"]}}}
\caption{{The orbits of Table~\ref{{tab:ps-orbits}}: reference (black), multiple-shooting nodes
(red squares), finite-difference grid values of order 8 (blue dots); right: the large nsd orbit
and the small saddle orbit, breakpoints $x = \pm 1$ dotted.}}
\label{{fig:ps-orbits}}
\end{{figure}}

\begin{{figure}}[ht]
\centering
\includegraphics[width=0.9\textwidth]{{{figs["work_precision"]}}}
\caption{{Work--precision: error against wall time and against right-hand-side evaluations as
the ODE tolerance of the shooting methods ($10^{{-5}}$ to $10^{{-13}}$) and the grid of the
finite differences ($N = 32$ to 512) vary; {wp_cases} (at $\varepsilon = 5$ single shooting
starts from the crude guess$^c$ of Table~\ref{{tab:ps-orbits}}, where the common guess fails).
Coarse grids on the relaxation oscillation converge to spurious discrete solutions (errors of
order 1).}}
\label{{fig:ps-work-precision}}
\end{{figure}}

What the numbers say:
\begin{{itemize}}
\item \emph{{Efficiency.}}  On smooth orbits the order-8 finite differences get within
$10^{{-9}}$ of the reference (shooting, at ODE tolerance $10^{{-11}}$, within $10^{{-11}}$) with
far fewer evaluations: on van der Pol at $\varepsilon = 1$,
$\max|\Delta y| = {_num(v1_fd8.error, 2)}$ with {v1_fd8.nfev} evaluations of $f$ against
${_num(v1_ss.error, 2)}$ with {v1_ss.nfev} for single shooting (about {fd_ratio:.0f} times fewer
$f$ and $J$ calls), and on Duffing ${_num(d_fd8.error, 2)}$ in {d_fd8.seconds:.2f}\,s against
${_num(d_ss.error, 2)}$ in {d_ss.seconds:.2f}\,s.  The seed's claim holds, with the caveat
that a uniform grid pays for fast phases: on the relaxation oscillation at $\varepsilon = 5$
the same order-8 scheme with $N = 512$ is only accurate to ${_num(v5_fd8.error, 2)}$.
Multiple shooting costs about as much as single shooting on stable orbits.
\item \emph{{Robustness.}}  From the common guess (2\,\% off), single shooting on van der Pol at
$\varepsilon = 5$ {v5_outcome},
while multiple shooting converges in {v5_ms.iterations} iterations; from the crude guess$^c$
single shooting needs {v5_crude.iterations} iterations.  On the nsd saddle orbit (multiplier
${_num(mu_sad, 3)}$) single shooting from a guess $0.05$ off {sad_outcome}
({sad_ss.iterations} iterations), while multiple shooting with 16 nodes converges in
{sad_ms.iterations} iteration to ${_num(sad_ms.error, 2)}$ of the closed form: sub-intervals keep
the growth $e^{{\lambda T/N}}$ of each segment small.  This is the seed's ``vulnerable to bad
initial guesses'', made quantitative.
\item \emph{{Smoothness.}}  On the large nsd orbit the force has kinks at $x = \pm 1$, so
$\dddot x$ jumps: finite differences of order 8 reach only ${_num(nsd_fd.error, 2)}$
($N = {nsd_fd.spec.n_points}$).  Under grid halving the observed order is {fd_orders[2]} for
the second-order scheme and {fd_orders[8]} for the eighth-order one
(\texttt{{nsd\_finite\_differences.csv}}): the nominal order is lost.  Shooting on the exact PWL
flow is exact to rounding
(${_num(nsd_ex.error, 2)}$) and a plain ODE flow that steps over the kinks still gets
${_num(nsd_ode.error, 2)}$ at {nsd_ode.seconds:.1f}\,s.  The seed's ``only for smooth systems''
is, more precisely, ``at reduced order for nonsmooth ones''.
\end{{itemize}}

\subsection{{Describing functions}}

For an input $e = a\sin\theta$ the describing function is the complex gain of the first
harmonic of the output, $N(a) = (b_1 + i a_1)/a$ (Table~\ref{{tab:ps-df}},
Fig.~\ref{{fig:ps-df}}).  The single-valued nonlinearities come from perturb's Fourier engine:
numerically from \texttt{{deadzone\_coefficients}}, \texttt{{saturation\_coefficients}},
\texttt{{sign\_coefficients}}, and symbolically from \texttt{{equivalent\_linearisation}}, which
returns the crossing-angle form, e.g.\ for the dead zone
\[
N(a) = {dz_sym}.
\]
perturb has no describing function for nonlinearities with memory: its Fourier engine takes
static $g(x)$, and \texttt{{equivalent\_linearisation}} of the hysteretic relay
$M\operatorname{{sign}}(x - h\operatorname{{sign}}\dot x)$ {rejection}.
The hysteretic relay and the backlash (half-gap $b$) are therefore derived in the script with
SymPy by integrating the steady output waveform piece by piece:
\begin{{align*}}
N_{{\mathrm{{hyst}}}} &= {latex(hy_re)} {latex(hy_im)}\,i,\\
N_{{\mathrm{{backlash}}}} &= {latex(bl_re)} {latex(bl_im)}\,i.
\end{{align*}}
Every closed form agrees with adaptive quadrature of the waveform (split at its switching
angles) to the last column of Table~\ref{{tab:ps-df}}, with the classical forms of Gelb \& Vander
Velde, and (dead zone, saturation, relay) with perturb's symbolic form.

\begin{{table}}[ht]
\centering\small
\caption{{Describing functions, their source, and the largest difference to quadrature of the
steady output on the amplitude grid.}}
\label{{tab:ps-df}}
\resizebox{{\textwidth}}{{!}}{{%
\begin{{tabular}}{{llp{{0.3\textwidth}}l}}
\toprule
nonlinearity & $N(a)$ & source & vs quadrature \\
\midrule
{_df_rows(res)}
\bottomrule
\end{{tabular}}}}
\end{{table}}

\begin{{figure}}[ht]
\centering
\includegraphics[width=0.9\textwidth]{{{figs["describing"]}}}
\caption{{Gain and phase of the describing functions (representative parameters: dead zone
$\delta = 1$, saturation $L = 1$, relays $M = 1$ with hysteresis $h = 0$ and $0.2$, backlash
$b = 0.5$, all of unit slope).}}
\label{{fig:ps-df}}
\end{{figure}}

\subsection{{Limit cycles of Lur'e loops}}

Each nonlinearity $u = n(e)$ closes a loop $e = -y$, $Y = G(s)U$ with a third-order plant.  The
harmonic-balance condition $1 + N(a)G(i\omega) = 0$ is solved for $(a, \omega)$ (all roots on
a logarithmic amplitude grid, refined by Brent's method), and each root is classified by the
Loeb criterion: the quasi-linear loop $\mathrm{{den}}(s) + N(a)K\,\mathrm{{num}}(s)$ must have
its root near $i\omega$ in the left half-plane just above $a$ and in the right half-plane just
below.  The servo plant $G_1 = K/(s(s+1)(s+2))$ serves the saturation ($K = 10$: the linear loop
is unstable, $K > 6$) and the relays and backlash ($K = 4$).  A dead zone needs a loop that is
unstable at low gain and stable at high gain for a \emph{{stable}} cycle (with $G_1$ its cycle
is the unstable threshold between decay and divergence), hence the open-loop unstable
$G_2 = 4(s+0.5)/(s^3+s^2+s+2)$, stable for $NK > 2$.  The simulations (written in the script:
\texttt{{solve\_ivp}} on each affine mode, switches as terminal events) start 20\,\% outside the
predicted cycle and run until the period and the peak of $|e|$ repeat to
${_num(1e-8 if res.fast else 1e-10, 1)}$; the amplitude compared is the first harmonic of $e$
over the last period (FFT of 4096 samples), its peak is listed too.  $\delta_h$ measures the
filter hypothesis at the prediction: the harmonics $k \ge 2$ of the nonlinearity's output after
the plant, relative to the fundamental,
$\delta_h = \big(\sum_{{k\ge2}} |c_k G(ik\omega)|^2\big)^{{1/2}}/|c_1 G(i\omega)|$.

\begin{{table}}[ht]
\centering\scriptsize
\caption{{Describing-function prediction against simulation (relative errors of the prediction
in \%; $\delta_h$ in \%).}}
\label{{tab:ps-lure}}
\begin{{tabular}}{{llrrrrrrrr}}
\toprule
nonlinearity & $G(s)$ & $a_{{\mathrm{{DF}}}}$ & $\omega_{{\mathrm{{DF}}}}$ & $a_1$ sim & peak sim &
$\omega$ sim & err $a$ & err $\omega$ & $\delta_h$ \\
\midrule
{_lure_rows(res)}
\bottomrule
\end{{tabular}}
\end{{table}}

\begin{{figure}}[ht]
\centering
\includegraphics[width=\textwidth]{{{figs["lure"]}}}
\caption{{Top: Nyquist plot of $G$ and the critical locus $-1/N(a)$; dots: predicted cycles
(filled: stable by the Loeb criterion).  Bottom: the simulated steady $e(t)$ against the
describing-function prediction $a\sin\omega t$, and the nonlinearity's output $u(t)$.}}
\label{{fig:ps-lure}}
\end{{figure}}

Every predicted stable cycle exists, attracts the simulation, and lies within
{100 * max(errs_a):.1f}\,\% (amplitude) and {100 * max(errs_w):.1f}\,\% (frequency) of the
prediction.  The amplitude error is of the size of $\delta_h$ ({ratio_lo:.1f} to
{ratio_hi:.1f} times it): largest for the {worst.case.nl.title}
({100 * abs(worst.error_a):.1f}\,\%; its square-wave output carries the strongest harmonics)
and small for the backlash, whose output is nearly sinusoidal at the large cycle.
The backlash loop has a second, smaller root ($a = {bl.predictions[0].a:.3f}$) that the Loeb
criterion marks unstable: the threshold below which the loop comes to rest inside the gap.
The seed's ``probably'' and ``close to'' are, for these loops, a few per cent.

{_tools_tex(st, res)}

\subsection{{Checks}}

{n_ok} of {len(res.checks)} checks hold (Table~\ref{{tab:ps-checks}}; \texttt{{checks.csv}}).

\begin{{table}}[ht]
\centering\scriptsize
\caption{{The claims of this section as measured.}}
\label{{tab:ps-checks}}
\begin{{tabular}}{{p{{0.62\textwidth}}lll}}
\toprule
claim & measured & limit & holds \\
\midrule
{_checks_rows(res)}
\bottomrule
\end{{tabular}}
\end{{table}}

\paragraph{{What perturb lacks.}}  No describing function (or averaging term) for
nonlinearities with memory --- backlash, hysteretic relay --- so they are derived here; no
solver for $1 + N(a)G(i\omega) = 0$; its flows, shooting and event-driven integrators take a
single oscillator $y = (x, \dot x)$ only, so the third-order Lur'e loops are integrated with
\texttt{{solve\_ivp}} written here; a \texttt{{PeriodicOrbit}} carries no solver statistics
(evaluations, time), so they are counted by wrapping the right-hand side.
"""


def main(argv: Sequence[str] | None = None) -> int:
    st = study(NAME, "Limit cycles and periodic solutions: solvers and describing functions", argv)
    start = time.perf_counter()
    res = run(st.fast)
    t0 = time.perf_counter()
    figure_work_precision(res, st.path("work_precision.png"))
    figure_orbits(res, st.path("orbits.png"))
    figure_describing(res, st.path("describing.png"))
    figure_lure(res, st.path("lure.png"))
    figure_tools(res, st.path("limit_cycle_tools.png"))
    write_csv(st, res)
    write_tools_csv(st, res.tools)
    res.seconds["figures"] = time.perf_counter() - t0
    seconds = time.perf_counter() - start
    st.write_section(section_tex(st, res, seconds))
    bad = [c.name for c in res.checks if not c.ok]
    for c in res.checks:
        print(f"{'ok ' if c.ok else 'BAD'} {c.name}: {c.value:.4g} ({'>=' if c.above else '<='} "
              f"{c.limit:g})")  # fmt: skip
    print(f"wrote {st.dir} in {seconds:.1f} s")
    if bad:
        print("FAILED: " + "; ".join(bad), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
