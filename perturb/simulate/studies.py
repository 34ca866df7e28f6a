r"""Brute-force studies of forced oscillators: sweeps, sections, diagrams, basins, Lyapunov.

Everything here is *simulation*: the attractors are whatever the equations of motion settle
on, found by integrating long enough, never by solving for a periodic orbit.  That makes the
results an independent check of the approximate and continuation methods (which also find
unstable orbits) and covers what those cannot: hysteresis jumps, period doubling, chaos.

All functions take an :class:`~perturb.model.oscillator.Oscillator` ``x'' + g(x, x') = F
cos(Omega t)`` (any forcing the flows accept) or, where it makes sense, a
:class:`~perturb.simulate.flows.base.Flow`, whose declared capabilities (its forcing
``period``) are read, never probed. The flow of an oscillator comes from the one factory,
:func:`perturb.simulate.flows.factory.make_flow`: the exact piecewise-linear flow
(:class:`~perturb.simulate.flows.exact.ExactPWLFlow`) when the model is PWL, else
:class:`~perturb.simulate.flows.base.ODEFlow` (DOP853 on the state and its variational
equations).

With the forcing period :math:`T = 2\pi/\Omega`:

* :func:`frequency_sweep` — stepped-sine sweep up and/or down in :math:`\Omega`, each step
  starting from the state the previous one ended in (as on a shaker table), so the curves
  show the jumps and the hysteresis window of a multistable response;
* :func:`poincare_section` — the stroboscopic map :math:`y_j = y(\varphi T + jT)`;
* :func:`bifurcation_diagram` — stroboscopic :math:`x` against any parameter (Zou and
  Nagarajaiah Figs. 6–8);
* :func:`basins` — which attractor a grid of initial conditions settles on, integrated for all
  initial conditions at once (vectorised);
* :func:`lyapunov_exponent` — the largest Lyapunov exponent from the tangent dynamics over
  each forcing period (the flow's sensitivity, saltation included when the flow does it),
  renormalised every period (Benettin's method).

Periodicity test
----------------
A settled response of period :math:`mT` has stroboscopic points with
:math:`y_{j+m} = y_j`.  The *residual* of period :math:`m` over the last :math:`W`
points is

.. math::

    r_m = \frac{\max_{j} \lVert y_j - y_{j-m} \rVert_\infty}{1 + \max_j \lVert y_j
    \rVert_\infty},

and the detected period is the smallest :math:`m \le m_{\max}` with :math:`r_m \le`
``tol``.  With a dominant multiplier :math:`\mu` per period the distance of the last point to
the orbit is about :math:`r_1 / (1 - |\mu|)` (times the scale), so a lightly damped or
near-fold response needs a smaller ``tol`` for the same accuracy; the residual reached is
reported with every result.  Transients decay like :math:`e^{-\mu t/2}` for the linear
oscillator :math:`x'' + \mu x' + x = F\cos\Omega t`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike

from perturb import checks
from perturb.errors import ModelError, ParameterError, PerturbError
from perturb.model.oscillator import Oscillator
from perturb.progress import Progress
from perturb.response import Branch, Response
from perturb.simulate.flows.base import Flow, FlowResult, as_flow
from perturb.simulate.flows.factory import FlowMethod, make_flow
from perturb.simulate.flows.system import first_order_rhs, frequency_symbol

__all__ = [
    "BasinOptions",
    "BifurcationOptions",
    "SweepOptions",
    "SteadyState",
    "SweepBranch",
    "SweepResult",
    "frequency_sweep",
    "system_frequency_sweep",
    "PoincareSection",
    "poincare_section",
    "BifurcationDiagram",
    "bifurcation_diagram",
    "Attractor",
    "BasinResult",
    "basins",
    "LyapunovResult",
    "lyapunov_exponent",
]

Direction = Literal["up", "down", "both"]


# ------------------------------------------------------------------------------ options --
@dataclass(frozen=True)
class SweepOptions:
    """Tuning knobs of :func:`frequency_sweep` (also accepted as its keyword arguments).

    Attributes
    ----------
    transient_periods
        Largest number of forcing periods discarded per frequency.
    record_periods
        Periods recorded after the transient (amplitude, FFT, Poincaré points).
    tol
        Periodicity tolerance ending the transient (``None``: always integrate
        ``transient_periods``); the period is then detected with ``4 tol``, or ``1e-6`` when
        ``tol`` is None.
    max_period
        Largest period (in forcing periods) looked for.
    samples_per_period
        Samples per forcing period in the record (``>= 16``).
    multipliers
        Compute ``max_multiplier`` from the flow's sensitivity over the orbit period (costs
        ``m`` periods with sensitivity per frequency); otherwise estimate it from the decay
        of the transient.
    method, rtol, atol
        Flow selection and ODE tolerances (:func:`make_flow`).
    progress
        Show a :class:`~perturb.progress.Progress` line (default: on unless
        ``PERTURB_PROGRESS=0``).
    """

    transient_periods: int = 400
    record_periods: int = 8
    tol: float | None = 1e-8
    max_period: int = 8
    samples_per_period: int = 128
    multipliers: bool = True
    method: FlowMethod = "auto"
    rtol: float = 1e-10
    atol: float = 1e-12
    progress: bool | None = None


@dataclass(frozen=True)
class BifurcationOptions:
    r"""Tuning knobs of :func:`bifurcation_diagram` (also accepted as its keyword arguments).

    Attributes
    ----------
    transient_periods, record_periods, tol, max_period
        As in :class:`SweepOptions` (``tol`` ends transients early).
    phase
        Section phase :math:`\varphi \in [0, 1)`; runs keep the forcing phase continuous
        from one value to the next by starting each value at :math:`t = \varphi T`.
    continuation
        ``False``: restart every value from the initial conditions.
    method, rtol, atol, progress
        Flow selection and ODE tolerances; progress line.
    """

    transient_periods: int = 400
    record_periods: int = 32
    phase: float = 0.0
    tol: float | None = 1e-9
    max_period: int = 8
    continuation: bool = True
    method: FlowMethod = "auto"
    rtol: float = 1e-10
    atol: float = 1e-12
    progress: bool | None = None


@dataclass(frozen=True)
class BasinOptions:
    """Tuning knobs of :func:`basins` (also accepted as its keyword arguments).

    Attributes
    ----------
    max_periods
        Periods after which unsettled orbits are labelled ``-1``.
    check_every
        Periods per round.
    tol, match_tol
        Periodicity tolerance; attractor matching tolerance (both relative to
        ``1 + max|y|``).
    max_period
        Largest attractor period looked for.
    steps_per_period
        RK4 steps per period (vectorised mode).
    escape_radius
        Orbits with ``max(|x|, |x'|)`` above it are labelled ``-2``.
    vectorised
        ``False``: integrate each initial condition with the accurate flow (exact for PWL
        models with the exact flow; slow).
    refine, method, progress
        Refinement of the attractors with the accurate flow; flow selection; progress line.
    """

    max_periods: int = 600
    check_every: int = 10
    tol: float = 1e-7
    match_tol: float = 1e-3
    max_period: int = 4
    steps_per_period: int = 128
    escape_radius: float = 1e6
    vectorised: bool = True
    refine: bool = True
    method: FlowMethod = "auto"
    progress: bool | None = None


def _options(cls: type, options: Any, knobs: dict[str, Any], where: str) -> Any:
    return checks.options_with(cls, options, knobs, where)


_TWO_PI = 2.0 * math.pi
#: label of an initial condition whose orbit did not settle within the allowed time
UNRESOLVED = -1
#: label of an initial condition whose orbit left the escape radius (or overflowed)
ESCAPED = -2


# --------------------------------------------------------------------------------------------
# validation helpers
# --------------------------------------------------------------------------------------------
def _int(name: str, value: object, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        raise ParameterError(f"{name} = {value!r}: expected an integer >= {minimum}")
    if value < minimum:
        raise ParameterError(f"{name} = {value!r}: expected an integer >= {minimum}")
    return int(value)


def _real(name: str, value: object, *, positive: bool = False, nonneg: bool = False) -> float:
    try:
        out = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise ParameterError(f"{name} = {value!r}: expected a finite real number") from None
    if not math.isfinite(out):
        raise ParameterError(f"{name} = {value!r}: expected a finite real number")
    if positive and out <= 0.0:
        raise ParameterError(f"{name} = {value!r}: expected a positive number")
    if nonneg and out < 0.0:
        raise ParameterError(f"{name} = {value!r}: expected a number >= 0")
    return out


def _state(name: str, value: ArrayLike | None) -> np.ndarray:
    if value is None:
        return np.zeros(2)
    try:
        y = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ParameterError(f"{name} = {value!r}: expected two finite numbers (x, x')") from None
    if y.shape != (2,) or not np.all(np.isfinite(y)):
        raise ParameterError(f"{name} = {value!r}: expected two finite numbers (x, x')")
    return y


def _values(name: str, values: ArrayLike, *, positive: bool = False) -> np.ndarray:
    try:
        arr = np.array(values, dtype=float)
    except (TypeError, ValueError):
        raise ParameterError(f"{name} = {values!r}: expected a 1-D sequence of reals") from None
    if arr.ndim != 1 or arr.size == 0:
        raise ParameterError(
            f"{name} has shape {arr.shape}: expected a non-empty 1-D sequence of reals"
        )
    if not np.all(np.isfinite(arr)):
        raise ParameterError(f"{name} = {arr.tolist()!r}: expected finite values")
    if positive and np.any(arr <= 0.0):
        raise ParameterError(f"{name} = {arr.tolist()!r}: expected positive values")
    return arr


def _tol(name: str, value: object) -> float:
    out = _real(name, value, positive=True)
    if out >= 1.0:
        raise ParameterError(f"{name} = {value!r}: expected a relative tolerance in (0, 1)")
    return out


def _frozen(a: ArrayLike, dtype: type = float) -> np.ndarray:
    arr = np.array(a, dtype=dtype)
    arr.setflags(write=False)
    return arr


# --------------------------------------------------------------------------------------------
# flows
# --------------------------------------------------------------------------------------------
def _flow_argument(obj: object, what: str, method: FlowMethod = "auto") -> Flow:
    """The flow of a ``flow_or_osc`` argument: :func:`make_flow` for an oscillator, the flow
    itself with its declared capabilities (:func:`~perturb.simulate.flows.base.as_flow`)
    otherwise."""
    if isinstance(obj, Oscillator):
        return make_flow(obj, method=method)
    if isinstance(obj, Flow):
        return as_flow(obj)
    raise ParameterError(f"{what} = {obj!r}: expected an Oscillator or a Flow")


def _period_of(flow: Flow, period: float | None, what: str = "flow") -> float:
    if period is not None:
        return _real("period", period, positive=True)
    T = flow.period
    if T is None:
        raise ParameterError(
            f"the {what} is autonomous (no forcing period): pass period=... to set the "
            "sampling period of the stroboscopic map"
        )
    return _real("flow.period", T, positive=True)


def _section_period(flow: Flow, osc: Oscillator, period: float | None = None) -> float:
    """Sampling period: ``period``, else the flow's forcing period, else ``2 pi/Omega`` of the
    model's forcing term even when its amplitude is 0 (e.g. nsd with ``F = 0``, whose exact
    flow is autonomous)."""
    if period is not None:
        return _real("period", period, positive=True)
    T = flow.period
    if T is None:
        T = first_order_rhs(osc).period
    if T is None:
        raise ParameterError(
            f"model {osc.name!r} is autonomous (no forcing period): pass period=... to set "
            "the sampling period of the stroboscopic map"
        )
    return _real("period", T, positive=True)


def _step(flow: Flow, y: np.ndarray, t0: float, t1: float, **kw: Any) -> FlowResult:
    res = flow(y, t0, t1, **kw)
    if not np.all(np.isfinite(res.y)):
        raise PerturbError(
            f"the orbit left the representable range between t = {t0:.6g} and t = {t1:.6g} "
            f"(state {res.y.tolist()!r}); the response is unbounded"
        )
    return res


# --------------------------------------------------------------------------------------------
# periodicity of stroboscopic sequences
# --------------------------------------------------------------------------------------------
def _residuals(points: np.ndarray, max_period: int) -> np.ndarray:
    """Relative residuals ``r_m`` (m = 1..max_period) of the end of stroboscopic sequences.

    ``points`` has shape (n, 2, ...) (trailing axes: independent sequences); returns shape
    (max_period, ...).  ``r_m`` compares each of the last ``m + 1`` points with the point
    ``m`` before it (every point of an ``m``-cycle at least once, one comparison to spare
    against a chance near-return); only the most recent differences are used because the
    older ones are larger by the contraction factor and would prolong the transient for
    nothing.  ``r_m = inf`` when fewer than ``2m + 1`` points exist.
    """
    n = points.shape[0]
    w = min(2 * max_period + 1, n)
    scale = 1.0 + np.max(np.abs(points[n - w :]), axis=(0, 1))
    out = np.full((max_period,) + points.shape[2:], np.inf)
    for m in range(1, max_period + 1):
        if n < 2 * m + 1:
            break
        tail = points[n - 2 * m - 1 :]
        d = np.max(np.abs(tail[m:] - tail[:-m]), axis=(0, 1))
        out[m - 1] = d / scale
    return out


#: a cycle closer than this many tol to a shorter one is that shorter cycle still converging
_AMBIGUITY = 1000.0


def _period_from_residuals(r: np.ndarray, tol: float) -> np.ndarray:
    """Smallest ``m`` with ``r_m <= tol`` per column of ``r`` (shape (max_period, ...)); 0 when
    none fits or when a divisor ``d`` of ``m`` has ``r_d <= 1000 tol``.

    The second rule avoids calling a period-1 orbit with a multiplier near -1 "period 2"
    while it converges: there ``y_j - y_{j-2}`` shrinks much faster than ``y_j - y_{j-1}``.
    """
    ok = r <= tol
    m = np.where(ok.any(axis=0), np.argmax(ok, axis=0) + 1, 0)
    for mm in range(2, r.shape[0] + 1):
        sel = m == mm
        if not np.any(sel):
            continue
        for d in range(1, mm):
            if mm % d == 0:
                sel &= ~(r[d - 1] <= _AMBIGUITY * tol)
        m = np.where((m == mm) & ~sel, 0, m)
    return m


def _detect(points: np.ndarray, tol: float, max_period: int) -> tuple[int, float]:
    """(period m, residual) of a single sequence (n, 2); ``m = 0`` when none fits."""
    r = _residuals(points, max_period)
    m = int(_period_from_residuals(r, tol))
    if m:
        return m, float(r[m - 1])
    best = float(np.min(r))
    return 0, best if math.isfinite(best) else math.inf


@dataclass
class _Settled:
    y: np.ndarray
    t: float
    strobe: list[np.ndarray]
    periods: int
    period: int
    residual: float
    history: list[float]


def _settle(
    flow: Flow,
    y0: np.ndarray,
    t0: float,
    T: float,
    *,
    max_periods: int,
    tol: float | None,
    max_period: int,
) -> _Settled:
    """Integrate whole forcing periods from ``(t0, y0)`` until periodic or ``max_periods``.

    Stops early once some ``m <= max_period`` has residual ``<= tol`` (see
    :func:`_residuals`; ``tol=None``: always run ``max_periods``).
    """
    window = 2 * max_period + 1
    y = y0
    strobe = [y0]
    history: list[float] = []
    m, res = 0, math.inf
    k = 0
    while k < max_periods:
        # absolute times from the period count, not by accumulation (no drift in the phase)
        y = _step(flow, y, t0 + k * T, t0 + (k + 1) * T).y
        k += 1
        strobe.append(y)
        if len(strobe) > 4 * window:
            del strobe[: len(strobe) - 4 * window]
        if tol is not None and len(strobe) >= 3:
            m, res = _detect(np.asarray(strobe), tol, max_period)
            history.append(res)
            if m:
                break
    return _Settled(y, t0 + k * T, strobe, k, m, res, history)


def _decay_multiplier(history: Sequence[float]) -> float:
    r"""Per-period contraction estimated from the geometric decay of the residuals.

    A residual that decays like :math:`|\mu|^j` (per forcing period) gives
    :math:`|\mu| \approx (r_{\text{last}}/r_{\text{first}})^{1/k}` over the last
    :math:`k \le 12` checks above the rounding floor (the asymptotic part of the transient);
    ``0.0`` when fewer than three are usable (the transient was already below the tolerance
    when checking began).
    """
    h = np.asarray(history, float)
    h = h[np.isfinite(h) & (h > 1e-13)][-13:]
    if h.size < 3:
        return 0.0
    rate = (h[-1] / h[0]) ** (1.0 / (h.size - 1))
    return float(min(rate, 1.0))


def _hermite_extrema(
    t: np.ndarray, x: np.ndarray, v: np.ndarray, accel: Callable[[int], float] | None = None
) -> np.ndarray:
    r"""Values of x at its interior extrema, located on a Hermite interpolant of the samples.

    In each sample interval where ``v`` changes sign the interpolant through ``(x, v)`` — and
    the acceleration ``accel(i)`` at the ends when given (quintic, error :math:`O(h^6)`),
    else cubic (:math:`O(h^4)`) — has a stationary point, found by 50 vectorised bisections
    of its derivative.  The sampled maximum alone would be low by up to
    :math:`A (\pi/N)^2/2`.
    """
    i = np.flatnonzero(v[:-1] * v[1:] < 0.0)
    if i.size == 0:
        return np.empty(0)
    h = t[i + 1] - t[i]
    x0, x1, m0, m1 = x[i], x[i + 1], v[i] * h, v[i + 1] * h
    if accel is not None:
        c0 = np.array([accel(int(k)) for k in i]) * h * h
        c1 = np.array([accel(int(k) + 1) for k in i]) * h * h
    else:
        c0 = c1 = None

    def dp(s: np.ndarray) -> np.ndarray:
        s2, s3, s4 = s * s, s**3, s**4
        if c0 is None:
            return (6 * s2 - 6 * s) * (x0 - x1) + (3 * s2 - 4 * s + 1) * m0 + (3 * s2 - 2 * s) * m1
        return (
            (-30 * s2 + 60 * s3 - 30 * s4) * (x0 - x1)
            + (1 - 18 * s2 + 32 * s3 - 15 * s4) * m0
            + (s - 4.5 * s2 + 6 * s3 - 2.5 * s4) * c0
            + (1.5 * s2 - 4 * s3 + 2.5 * s4) * c1
            + (-12 * s2 + 28 * s3 - 15 * s4) * m1
        )

    lo, hi = np.zeros_like(h), np.ones_like(h)
    sgn0 = np.sign(m0)
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        same = np.sign(dp(mid)) == sgn0
        lo = np.where(same, mid, lo)
        hi = np.where(same, hi, mid)
    s = 0.5 * (lo + hi)
    s2, s3, s4, s5 = s * s, s**3, s**4, s**5
    if c0 is None:
        return (
            (2 * s3 - 3 * s2 + 1) * x0
            + (s3 - 2 * s2 + s) * m0
            + (-2 * s3 + 3 * s2) * x1
            + (s3 - s2) * m1
        )
    return (
        (1 - 10 * s3 + 15 * s4 - 6 * s5) * x0
        + (s - 6 * s3 + 8 * s4 - 3 * s5) * m0
        + (0.5 * s2 - 1.5 * s3 + 1.5 * s4 - 0.5 * s5) * c0
        + (0.5 * s3 - s4 + 0.5 * s5) * c1
        + (-4 * s3 + 7 * s4 - 3 * s5) * m1
        + (10 * s3 - 15 * s4 + 6 * s5) * x1
    )


# --------------------------------------------------------------------------------------------
# steady states and frequency sweeps
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class SteadyState:
    r"""The settled response at one forcing frequency.

    Attributes
    ----------
    omega
        Forcing frequency :math:`\Omega`.
    amplitude
        :math:`\max |x(t)|` over the recorded periods (sampled, with the peaks located on the
        quintic Hermite interpolant of x, x', x'' at the samples).
    first_harmonic_amplitude, mean
        :math:`2|c_P|` and :math:`c_0` of the FFT of :math:`x` over :math:`P` whole forcing
        periods (:math:`P` a multiple of the detected period when the record holds a whole
        cycle, so subharmonics do not leak into the forcing bin).
    period
        Detected period in forcing periods, ``0`` when no :math:`m \le m_{\max}` fits
        ("not periodic").
    residual
        The relative periodicity residual reached (see the module docstring).
    poincare
        Stroboscopic points :math:`y(t_r + jT)` over the record, shape (R, 2).
    transient_periods
        Forcing periods integrated before recording.
    max_multiplier
        Growth per forcing period of small perturbations: :math:`|\mu_{\max}|^{1/m}` from
        the monodromy over :math:`mT` for a period-:math:`m` response, the largest singular
        value of the sensitivity over :math:`m_{\max}` periods to the power :math:`1/m_{\max}`
        for a response that is not periodic, or (``multipliers=False``) the decay rate of
        the transient residuals (``0.0`` when it could not be estimated).
    y_end
        State at the end (a point of the orbit at forcing phase 0).
    """

    omega: float
    amplitude: float
    first_harmonic_amplitude: float
    mean: float
    period: int
    residual: float
    poincare: np.ndarray
    transient_periods: int
    max_multiplier: float
    y_end: np.ndarray
    #: A system's sweep (:func:`system_frequency_sweep`): ``max |.|`` of every coordinate.
    coordinates: Mapping[str, float] = field(default_factory=lambda: MappingProxyType({}))

    @property
    def periodic(self) -> bool:
        return self.period > 0

    def describe_period(self) -> str:
        return f"period-{self.period}" if self.period else "not periodic"

    def __repr__(self) -> str:
        return (
            f"SteadyState(omega={self.omega:.6g}, amplitude={self.amplitude:.6g}, "
            f"H1={self.first_harmonic_amplitude:.6g}, mean={self.mean:.6g}, "
            f"{self.describe_period()}, residual={self.residual:.2g}, "
            f"max_multiplier={self.max_multiplier:.4g}, "
            f"after {self.transient_periods} periods)"
        )


def _steady_state(
    flow: Flow,
    omega: float,
    y0: np.ndarray,
    *,
    transient_periods: int,
    record_periods: int,
    tol: float | None,
    max_period: int,
    samples_per_period: int,
    multipliers: bool,
) -> SteadyState:
    T = _TWO_PI / omega
    flow_T = flow.period
    if flow_T is not None and not math.isclose(flow_T, T, rel_tol=1e-12):
        raise ModelError(
            f"the flow has period {flow_T!r} but Omega = {omega!r} gives {T!r}: the sweep needs "
            "a model forced at the single frequency Omega"
        )
    settled = _settle(
        flow, y0, 0.0, T, max_periods=transient_periods, tol=tol, max_period=max_period
    )
    y, t = settled.y, settled.t
    N = samples_per_period
    # at least one whole cycle of a subharmonic found while settling, so the FFT window
    # below can be a multiple of it
    R = max(record_periods, settled.period)
    te = t + T * np.arange(R * N + 1) / N
    te[-1] = t + R * T
    rec = _step(flow, y, t, t + R * T, t_eval=te)
    if rec.ys is None or rec.t is None or rec.ys.shape[0] != te.size:
        raise PerturbError("the flow did not return the requested samples (t_eval)")
    xs, vs = rec.ys[:, 0], rec.ys[:, 1]
    poincare = rec.ys[::N]  # R + 1 points, the last one at the end of the record
    strobe = np.concatenate([np.asarray(settled.strobe[:-1]), poincare])
    det_tol = 4.0 * tol if tol is not None else 1e-6
    m, residual = _detect(strobe, det_tol, max_period)

    # amplitude: samples plus the Hermite-located peaks between them
    def accel(k: int) -> float:
        return float(flow.vector_field(float(te[k]), rec.ys[k])[1])

    peaks = _hermite_extrema(te, xs, vs, accel)
    amplitude = float(max(np.max(np.abs(xs)), np.max(np.abs(peaks), initial=0.0)))
    # first harmonic and mean over whole periods; a multiple of the response period avoids
    # leakage of the subharmonics into the forcing bin
    P = R if m == 0 or m > R else m * (R // m)
    xw = xs[xs.size - 1 - P * N : xs.size - 1]
    c = np.fft.rfft(xw) / xw.size
    mean = float(c[0].real)
    h1 = float(2.0 * abs(c[P]))

    y_end = rec.y
    if multipliers:
        n = m if m else max_period
        sens = _step(flow, y_end, t + R * T, t + (R + n) * T, sensitivity=True)
        if sens.sensitivity is None:
            raise PerturbError("the flow did not return the sensitivity matrix")
        if m:
            mult = float(np.max(np.abs(np.linalg.eigvals(sens.sensitivity)))) ** (1.0 / m)
        else:
            mult = float(np.linalg.norm(sens.sensitivity, 2)) ** (1.0 / n)
        y_end = sens.y  # still on the attractor, and still at forcing phase 0
    else:
        mult = _decay_multiplier(settled.history)
    return SteadyState(
        omega=float(omega),
        amplitude=amplitude,
        first_harmonic_amplitude=h1,
        mean=mean,
        period=m,
        residual=float(residual),
        poincare=_frozen(poincare[:-1]),
        transient_periods=settled.periods,
        max_multiplier=mult,
        y_end=_frozen(y_end),
    )


@dataclass(frozen=True, eq=False)
class SweepBranch:
    """One sweep direction: the steady states in the order they were visited."""

    direction: str
    states: tuple[SteadyState, ...]

    def _col(self, name: str, dtype: type = float) -> np.ndarray:
        return _frozen([getattr(s, name) for s in self.states], dtype)

    @property
    def omega(self) -> np.ndarray:
        return self._col("omega")

    @property
    def amplitude(self) -> np.ndarray:
        return self._col("amplitude")

    @property
    def first_harmonic_amplitude(self) -> np.ndarray:
        return self._col("first_harmonic_amplitude")

    @property
    def mean(self) -> np.ndarray:
        return self._col("mean")

    @property
    def period(self) -> np.ndarray:
        """Detected periods (0 = not periodic)."""
        return self._col("period", int)

    @property
    def max_multiplier(self) -> np.ndarray:
        return self._col("max_multiplier")

    @property
    def residual(self) -> np.ndarray:
        return self._col("residual")

    def jumps(self, threshold: float = 0.25) -> list[tuple[float, float, float, float]]:
        r"""Steps where the amplitude changes by more than ``threshold`` (relative).

        Returns ``(omega_before, omega_after, amplitude_before, amplitude_after)`` for each
        pair of neighbours with :math:`|A_{i+1} - A_i| > \text{threshold}\,\max(A_i,
        A_{i+1})`; a fold lies between the two frequencies.
        """
        th = _real("threshold", threshold, positive=True)
        w, a = self.omega, self.amplitude
        out = []
        for i in range(len(w) - 1):
            if abs(a[i + 1] - a[i]) > th * max(a[i], a[i + 1]):
                out.append((float(w[i]), float(w[i + 1]), float(a[i]), float(a[i + 1])))
        return out

    def to_branch(self) -> Branch:
        """The periodic steady states as a :class:`~perturb.response.Branch` (a response that
        is not periodic, chaotic or quasi-periodic, is no periodic solution: it is left out)."""
        keep = self.period > 0
        return Branch(
            omega=self.omega[keep],
            amplitude=self.amplitude[keep],
            first_harmonic_amplitude=self.first_harmonic_amplitude[keep],
            mean=self.mean[keep],
            stable=np.ones(int(keep.sum()), bool),
            max_multiplier=self.max_multiplier[keep],
        )

    def __len__(self) -> int:
        return len(self.states)

    def __repr__(self) -> str:
        if not self.states:
            return f"SweepBranch({self.direction}, empty)"
        per = self.period
        return (
            f"SweepBranch({self.direction}, {len(self)} points, omega "
            f"{self.omega[0]:.4g}->{self.omega[-1]:.4g}, amplitude {self.amplitude.min():.4g}.."
            f"{self.amplitude.max():.4g}, {int(np.sum(per == 1))} period-1, "
            f"{int(np.sum(per > 1))} subharmonic, {int(np.sum(per == 0))} not periodic)"
        )


@dataclass(frozen=True, eq=False)
class SweepResult:
    """Result of :func:`frequency_sweep`: one :class:`SweepBranch` per direction."""

    branches: tuple[SweepBranch, ...]
    model: str = ""
    params: Mapping[str, float] = field(default_factory=lambda: MappingProxyType({}))
    settings: Mapping[str, Any] = field(default_factory=lambda: MappingProxyType({}))

    def branch(self, direction: str) -> SweepBranch:
        for b in self.branches:
            if b.direction == direction:
                return b
        have = ", ".join(b.direction for b in self.branches)
        raise ParameterError(f"direction = {direction!r}: this sweep has {have}")

    @property
    def up(self) -> SweepBranch:
        return self.branch("up")

    @property
    def down(self) -> SweepBranch:
        return self.branch("down")

    def to_response(self, direction: str | None = None) -> Response:
        """The sweep as a :class:`~perturb.response.Response`.

        ``direction="up"`` / ``"down"`` gives method ``"sweep-up"`` / ``"sweep-down"`` with one
        branch; ``None`` gives the only direction, or for a two-way sweep method
        ``"sweep-both"`` with branch 0 the up sweep and branch 1 the down sweep.  Every point
        is ``stable`` (simulation only finds attractors); ``max_multiplier`` is the growth per
        forcing period described in :class:`SteadyState`.  Frequencies where the response is
        not periodic are left out of the branches and listed in ``notes``, as are subharmonic
        responses.
        """
        if direction is None and len(self.branches) == 1:
            direction = self.branches[0].direction
        if direction is None:
            chosen = self.branches
            method = "sweep-both"
        else:
            chosen = (self.branch(direction),)
            method = f"sweep-{direction}"
        notes = tuple(f"branch {i}: sweep-{b.direction}" for i, b in enumerate(chosen))
        notes += ("stable = found by simulation (attracting); max_multiplier per forcing period",)
        for i, b in enumerate(chosen):
            per = b.period
            if np.any(per == 0):
                ws = ", ".join(f"{w:.6g}" for w in b.omega[per == 0])
                notes += (
                    f"branch {i}: no periodic response (period <= max_period) at Omega = {ws}; "
                    "those points are left out (chaotic or quasi-periodic motion: see the "
                    "sweep's period column, or lyapunov_exponent)",
                )
            if np.any(per > 1):
                sub = [(w, m) for w, m in zip(b.omega, per, strict=True) if m > 1]
                ws = ", ".join(f"{w:.6g} ({m}T)" for w, m in sub)
                notes += (f"branch {i}: subharmonic response at Omega = {ws}",)
        return Response(
            branches=tuple(b.to_branch() for b in chosen),
            method=method,
            model=self.model,
            params=self.params,
            notes=notes,
        )

    def __repr__(self) -> str:
        lines = [f"SweepResult({self.model or 'model'}, {len(self.branches)} directions)"]
        lines += [f"  {b!r}" for b in self.branches]
        return "\n".join(lines)


def _check_common(
    transient_periods: object,
    record_periods: object,
    max_period: object,
    tol: object,
) -> tuple[int, int, int, float | None]:
    tp = _int("transient_periods", transient_periods, 0)
    rp = _int("record_periods", record_periods, 1)
    mp = _int("max_period", max_period, 1)
    tl = None if tol is None else _tol("tol", tol)
    return tp, rp, mp, tl


def frequency_sweep(
    osc: Oscillator,
    omegas: ArrayLike,
    options: SweepOptions | None = None,
    *,
    direction: Direction = "up",
    y0: ArrayLike | None = None,
    **knobs: Any,
) -> SweepResult:
    r"""Stepped-sine sweep: the steady response at each :math:`\Omega`, continued in order.

    At each frequency the state the previous frequency ended in (at forcing phase 0, so the
    excitation stays continuous) is integrated over whole forcing periods until the
    stroboscopic points repeat with some period :math:`m \le` ``max_period`` to ``tol`` (or
    for ``transient_periods`` periods), then ``record_periods`` more periods are recorded at
    ``samples_per_period`` points each.  ``direction="both"`` runs up, then down from where the
    up sweep ended: in a multistable window the up sweep stays on the branch it came from
    until that branch ends at a fold, the down sweep on the other one (hysteresis).

    Parameters
    ----------
    osc
        Oscillator forced at one frequency parameter (e.g. ``Omega``), all other parameters set.
    omegas
        Frequencies (positive); sorted ascending for ``"up"``, descending for ``"down"``.
    options
        The tuning knobs (:class:`SweepOptions`: transient and record lengths, periodicity
        tolerance, multipliers, flow method and tolerances, progress line).
    direction
        ``"up"``, ``"down"`` or ``"both"``.
    y0
        Initial state ``(x, x')`` at ``t = 0`` of the first frequency (default rest).
    **knobs
        Fields of :class:`SweepOptions` as keywords, replacing those of ``options``.

    Returns
    -------
    SweepResult

    Raises
    ------
    ParameterError
        Bad arguments.
    ModelError
        The model has no forcing-frequency parameter.
    PerturbError
        The response is unbounded at some frequency, or the integration failed.

    Notes
    -----
    Accuracy: the recorded amplitude differs from the attractor's by about the distance of
    the state to the orbit, :math:`\lesssim r/(1-|\mu|)` relative (see the module docstring),
    plus the flow's error; for the linear oscillator the transient left after :math:`t` is
    :math:`\propto e^{-\mu t/2}`.
    """
    o = _options(SweepOptions, options, knobs, "frequency_sweep")
    transient_periods, record_periods, tol, max_period = (
        o.transient_periods,
        o.record_periods,
        o.tol,
        o.max_period,
    )
    samples_per_period, multipliers, progress = o.samples_per_period, o.multipliers, o.progress
    method, rtol, atol = o.method, o.rtol, o.atol
    if not isinstance(osc, Oscillator):
        raise ParameterError(f"osc = {osc!r}: expected an Oscillator")
    if direction not in ("up", "down", "both"):
        raise ParameterError(f"direction = {direction!r}: expected 'up', 'down' or 'both'")
    w = np.unique(_values("omegas", omegas, positive=True))
    tp, rp, mp, tl = _check_common(transient_periods, record_periods, max_period, tol)
    N = _int("samples_per_period", samples_per_period, 16)
    if frequency_symbol(osc) is None:
        raise ModelError(
            f"model {osc.name!r} has no forcing-frequency parameter to sweep (expected a "
            "forcing F cos(Omega t) with Omega a parameter)"
        )
    y = _state("y0", y0)
    dirs = ["up", "down"] if direction == "both" else [direction]
    # build the flows once per frequency (compiling the model is the expensive part)
    flows: dict[float, Flow] = {}
    branches = []
    with Progress(len(w) * len(dirs), f"sweep {direction}", enabled=progress) as bar:
        for d in dirs:
            order = w if d == "up" else w[::-1]
            states = []
            for om in order:
                flow = flows.get(float(om))
                if flow is None:
                    flow = make_flow(osc, float(om), method=method, rtol=rtol, atol=atol)
                    flows[float(om)] = flow
                try:
                    st = _steady_state(
                        flow,
                        float(om),
                        y,
                        transient_periods=tp,
                        record_periods=rp,
                        tol=tl,
                        max_period=mp,
                        samples_per_period=N,
                        multipliers=bool(multipliers),
                    )
                except PerturbError as err:
                    raise type(err)(f"sweep {d} at Omega = {om:.6g}: {err}") from None
                states.append(st)
                y = np.array(st.y_end)
                bar.update()
            branches.append(SweepBranch(d, tuple(states)))
    params = {k: float(v) for k, v in osc.params.items() if v is not None}
    settings = {
        "transient_periods": tp,
        "record_periods": rp,
        "tol": tl,
        "max_period": mp,
        "samples_per_period": N,
        "flow": type(next(iter(flows.values()))).__name__,
    }
    return SweepResult(
        branches=tuple(branches),
        model=osc.name,
        params=MappingProxyType(params),
        settings=MappingProxyType(settings),
    )


def _peak(values: np.ndarray) -> float:
    """``max |v|`` of periodic samples, the largest refined by the parabola through it and its
    neighbours (a kink or flat top keeps the sample)."""
    a = np.abs(values)
    i = int(np.argmax(a))
    y0, y1, y2 = a[i - 1], a[i], a[(i + 1) % a.size]
    den = y0 - 2 * y1 + y2
    if den >= 0:
        return float(y1)
    return float(y1 - 0.125 * (y2 - y0) ** 2 / den)


def system_frequency_sweep(
    system: Any,
    omegas: ArrayLike,
    *,
    output: str | None = None,
    direction: Direction = "up",
    y0: ArrayLike | None = None,
    transient_periods: int = 400,
    record_periods: int = 4,
    tol: float = 1e-8,
    max_period: int = 8,
    samples_per_period: int = 1024,
    method: FlowMethod = "auto",
    progress: bool = False,
) -> SweepResult:
    r"""Stepped-sine sweep of a system of several coordinates
    (:class:`~perturb.model.system.System` with a forcing-frequency parameter ``Omega``).

    As :func:`frequency_sweep`: at each frequency the state the previous one ended in (at
    forcing phase 0) is integrated period by period (:func:`make_flow`: exact when piecewise
    affine, event-driven with stops or friction, else DOP853) until the stroboscopic points
    repeat with a period :math:`m \le` ``max_period`` to ``tol`` (at most
    ``transient_periods``), then ``record_periods`` periods (a whole number of the detected
    period) are sampled at ``samples_per_period`` points each. ``amplitude`` is ``max |.|``
    of ``output`` (a coordinate or a combination, default the first coordinate; the sampled
    peak refined by a parabola), ``first_harmonic_amplitude`` and ``mean`` its Fourier
    coefficients over whole periods, ``coordinates`` every coordinate's ``max |.|``;
    ``max_multiplier`` the decay of the transient residuals.

    Raises
    ------
    ParameterError
        Bad arguments, an ``output`` that is not a coordinate or combination (naming the
        states).
    ModelError
        A system without the parameter ``Omega``.
    """
    from perturb.model.system import System

    if not isinstance(system, System):
        raise ParameterError(f"system = {system!r:.80}: expected a perturb System")
    if "Omega" not in system.params:
        raise ModelError(
            f"system {system.name!r} has no forcing-frequency parameter 'Omega' to sweep "
            f"(its parameters: {', '.join(system.params) or 'none'})"
        )
    if direction not in ("up", "down", "both"):
        raise ParameterError(f"direction = {direction!r}: expected 'up', 'down' or 'both'")
    w = np.unique(_values("omegas", omegas, positive=True))
    tp, rp, mp, tl = _check_common(transient_periods, record_periods, max_period, tol)
    N = _int("samples_per_period", samples_per_period, 16)
    names = system.state_names
    coords = (*system.coordinates, *system.first_order)
    c = np.asarray(system.output(output if output is not None else coords[0]), dtype=float)
    y = np.zeros(len(names)) if y0 is None else np.asarray(y0, dtype=float)
    if y.shape != (len(names),) or not np.all(np.isfinite(y)):
        raise ParameterError(
            f"y0 = {y0!r}: expected {len(names)} finite numbers ({', '.join(names)})"
        )
    eye = np.eye(len(names))
    dirs = ["up", "down"] if direction == "both" else [direction]
    branches = []
    flow_name = ""
    with Progress(len(w) * len(dirs), f"sweep {direction}", enabled=progress) as bar:
        for d in dirs:
            states = []
            for om in w if d == "up" else w[::-1]:
                flow = make_flow(system.with_params(Omega=float(om)), method=method)
                flow_name = type(flow).__name__
                T = _TWO_PI / float(om)
                try:
                    settled = _settle(flow, y, 0.0, T, max_periods=tp, tol=tl, max_period=mp)
                    R = max(rp, settled.period)
                    R = settled.period * (R // settled.period) if settled.period else R
                    te = settled.t + T * np.arange(R * N + 1) / N
                    te[-1] = settled.t + R * T
                    rec = _step(flow, settled.y, settled.t, settled.t + R * T, t_eval=te)
                except PerturbError as err:
                    raise type(err)(f"sweep {d} at Omega = {om:.6g}: {err}") from None
                if rec.ys is None or rec.ys.shape[0] != te.size:
                    raise PerturbError("the flow did not return the requested samples (t_eval)")
                Y = rec.ys[:-1]  # R whole periods
                out = Y @ c
                z = np.fft.rfft(out) / out.size
                states.append(
                    SteadyState(
                        omega=float(om),
                        amplitude=_peak(out),
                        first_harmonic_amplitude=float(2.0 * abs(z[R])) if R < z.size else 0.0,
                        mean=float(z[0].real),
                        period=settled.period,
                        residual=float(settled.residual),
                        poincare=_frozen(rec.ys[::N][:-1]),
                        transient_periods=settled.periods,
                        max_multiplier=_decay_multiplier(settled.history),
                        y_end=_frozen(rec.y),
                        coordinates=MappingProxyType(
                            {n: _peak(Y @ eye[names.index(n)]) for n in coords}
                        ),
                    )
                )
                y = np.array(rec.y)
                bar.update()
            branches.append(SweepBranch(d, tuple(states)))
    params = {k: float(v) for k, v in system.params.items() if v is not None and k != "Omega"}
    settings = {
        "transient_periods": tp,
        "record_periods": rp,
        "tol": tl,
        "max_period": mp,
        "samples_per_period": N,
        "flow": flow_name,
        "output": output if output is not None else coords[0],
    }
    return SweepResult(
        branches=tuple(branches),
        model=system.name,
        params=MappingProxyType(params),
        settings=MappingProxyType(settings),
    )


# --------------------------------------------------------------------------------------------
# Poincaré sections
# --------------------------------------------------------------------------------------------
def _clusters(points: np.ndarray, tol: float) -> list[np.ndarray]:
    """Greedy clusters of points (n, d) within ``tol`` (max-norm) of a cluster's first point."""
    left = np.arange(points.shape[0])
    out = []
    while left.size:
        ref = points[left[0]]
        near = np.max(np.abs(points[left] - ref), axis=-1) <= tol
        out.append(left[near])
        left = left[~near]
    return out


@dataclass(frozen=True, eq=False)
class PoincareSection:
    r"""Stroboscopic points :math:`y_j = y(\varphi T + jT)`, :math:`j = j_0, j_0 + 1, \dots`

    Attributes
    ----------
    points
        Shape (n, 2): ``(x, x')`` at the section.
    times
        Section times, shape (n,).
    period, phase
        :math:`T` and :math:`\varphi`.
    """

    points: np.ndarray
    times: np.ndarray
    period: float
    phase: float

    @property
    def spread(self) -> float:
        """Largest distance (max-norm) of a point from the first one."""
        return float(np.max(np.abs(self.points - self.points[0])))

    def distinct(self, tol: float = 1e-6) -> np.ndarray:
        """Representatives of the distinct points (clusters within ``tol`` relative)."""
        tol = _tol("tol", tol)
        scale = 1.0 + float(np.max(np.abs(self.points)))
        return _frozen([self.points[c[0]] for c in _clusters(self.points, tol * scale)])

    def detected_period(self, tol: float = 1e-6, max_period: int = 16) -> int:
        """Smallest ``m`` with ``y_{j+m} = y_j`` to ``tol`` over all points (0 if none)."""
        tol = _tol("tol", tol)
        mp = _int("max_period", max_period, 1)
        P = self.points
        scale = 1.0 + float(np.max(np.abs(P)))
        for m in range(1, min(mp, P.shape[0] - 1) + 1):
            if np.max(np.abs(P[m:] - P[:-m])) <= tol * scale:
                return m
        return 0

    def __len__(self) -> int:
        return int(self.points.shape[0])

    def __repr__(self) -> str:
        return (
            f"PoincareSection({len(self)} points, T={self.period:.6g}, phase={self.phase:.3g}, "
            f"spread={self.spread:.3g}, {len(self.distinct())} distinct)"
        )


def poincare_section(
    flow_or_osc: Flow | Oscillator,
    y0: ArrayLike,
    n_points: int,
    *,
    phase: float = 0.0,
    transient: int = 200,
    period: float | None = None,
    method: FlowMethod = "auto",
    progress: bool | None = None,
) -> PoincareSection:
    r"""The stroboscopic (Poincaré) map of a forced oscillator.

    From ``y0`` at ``t = 0`` the orbit is integrated to :math:`\varphi T` and through
    ``transient`` forcing periods, then ``n_points`` section points
    :math:`y(\varphi T + jT)` are recorded.  A period-:math:`m` attractor gives :math:`m`
    distinct points, a chaotic one a fractal cloud.

    Parameters
    ----------
    flow_or_osc
        A :class:`~perturb.simulate.flows.base.Flow` or an oscillator (flow from :func:`make_flow`).
    y0
        State at ``t = 0``.
    n_points
        Number of section points (``>= 1``).
    phase
        :math:`\varphi \in [0, 1)`, the section's forcing phase as a fraction of a period.
    transient
        Forcing periods discarded.
    period
        Sampling period; default the flow's forcing period (required for autonomous flows).
    """
    flow = _flow_argument(flow_or_osc, "flow_or_osc", method)
    y = _state("y0", y0)
    n = _int("n_points", n_points, 1)
    tr = _int("transient", transient, 0)
    ph = _real("phase", phase, nonneg=True)
    if ph >= 1.0:
        raise ParameterError(f"phase = {phase!r}: expected a fraction of a period in [0, 1)")
    T = _period_of(flow, period)
    t0 = ph * T
    if t0 > 0.0:
        y = _step(flow, y, 0.0, t0).y
    pts = np.empty((n, 2))
    times = t0 + T * np.arange(tr, tr + n)
    with Progress(tr + n, "Poincaré section", enabled=progress) as bar:
        for k in range(tr + n):
            if k >= tr:
                pts[k - tr] = y
            if k < tr + n - 1:
                y = _step(flow, y, t0 + k * T, t0 + (k + 1) * T).y
            bar.update()
    return PoincareSection(points=_frozen(pts), times=_frozen(times), period=T, phase=ph)


# --------------------------------------------------------------------------------------------
# bifurcation diagrams
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class BifurcationDiagram:
    r"""Stroboscopic points against a parameter, one continuation run per initial condition.

    Attributes
    ----------
    parameter
        Name of the varied parameter.
    values
        Parameter values in the order visited, shape (n,).
    x, v
        Section points, shape (runs, n, R): run ``i`` at value ``j`` recorded ``R`` points.
    period
        Detected period per (run, value); 0 = not periodic.
    residual
        Relative periodicity residual per (run, value).
    phase
        Section phase (fraction of the forcing period).
    """

    parameter: str
    values: np.ndarray
    x: np.ndarray
    v: np.ndarray
    period: np.ndarray
    residual: np.ndarray
    phase: float = 0.0
    model: str = ""
    params: Mapping[str, float] = field(default_factory=lambda: MappingProxyType({}))

    @property
    def n_runs(self) -> int:
        return int(self.x.shape[0])

    def points(self, run: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Flat ``(parameter, x)`` arrays for a scatter plot (all runs by default)."""
        xs = self.x if run is None else self.x[run : run + 1]
        p = np.broadcast_to(self.values[None, :, None], xs.shape)
        return p.ravel().copy(), xs.ravel().copy()

    def n_distinct(self, tol: float = 1e-6) -> np.ndarray:
        """Number of distinct section points (x, x') per (run, value), clustered within
        ``tol`` relative to ``1 + max|y|``."""
        tol = _tol("tol", tol)
        out = np.zeros(self.period.shape, int)
        for i in range(self.x.shape[0]):
            for j in range(self.x.shape[1]):
                pts = np.stack([self.x[i, j], self.v[i, j]], axis=-1)
                scale = 1.0 + float(np.max(np.abs(pts)))
                out[i, j] = len(_clusters(pts, tol * scale))
        return out

    def __repr__(self) -> str:
        per = self.period
        return (
            f"BifurcationDiagram({self.model or 'model'}: x at phase {self.phase:g} vs "
            f"{self.parameter} in [{self.values.min():.4g}, {self.values.max():.4g}], "
            f"{self.values.size} values x {self.n_runs} runs x {self.x.shape[2]} points; "
            f"{int(np.sum(per == 1))} period-1, {int(np.sum(per > 1))} subharmonic, "
            f"{int(np.sum(per == 0))} not periodic)"
        )


def bifurcation_diagram(
    osc: Oscillator,
    parameter: str,
    values: ArrayLike,
    options: BifurcationOptions | None = None,
    *,
    y0: ArrayLike | None = None,
    initial_conditions: ArrayLike | None = None,
    **knobs: Any,
) -> BifurcationDiagram:
    r"""Stroboscopic :math:`x` of the attractors against any parameter.

    For each run (one per initial condition) and each value of ``parameter`` in the order
    given, the orbit is integrated from the state the run ended in at the previous value
    (``continuation=True``; at the first value from the initial condition) until its section
    points repeat to ``tol`` with some period :math:`m \le` ``max_period`` (or for
    ``transient_periods``), then ``record_periods`` section points
    :math:`y(\varphi T + jT)` are recorded.  A period-:math:`m` attractor shows :math:`m`
    points per value, a chaotic one a vertical smear — Zou and Nagarajaiah's Figs. 6–8.

    Parameters
    ----------
    osc
        Oscillator; ``parameter`` must be one of its parameters (``Omega`` included).
    parameter, values
        The parameter varied and its values (visited in the given order).
    options
        The tuning knobs (:class:`BifurcationOptions`: transient and record lengths,
        section phase, continuation, flow method and tolerances, progress line).
    y0, initial_conditions
        One initial state, or an array (n_runs, 2) of them, at ``t = 0`` (default rest).
    **knobs
        Fields of :class:`BifurcationOptions` as keywords, replacing those of ``options``.
    """
    o = _options(BifurcationOptions, options, knobs, "bifurcation_diagram")
    transient_periods, record_periods, tol, max_period = (
        o.transient_periods,
        o.record_periods,
        o.tol,
        o.max_period,
    )
    phase, continuation, progress = o.phase, o.continuation, o.progress
    method, rtol, atol = o.method, o.rtol, o.atol
    if not isinstance(osc, Oscillator):
        raise ParameterError(f"osc = {osc!r}: expected an Oscillator")
    if not isinstance(parameter, str) or parameter not in osc.params:
        known = ", ".join(osc.params) or "none"
        raise ParameterError(
            f"parameter = {parameter!r}: expected one of the parameters of model "
            f"{osc.name!r} ({known})"
        )
    vals = _values("values", values)
    tp, rp, mp, tl = _check_common(transient_periods, record_periods, max_period, tol)
    ph = _real("phase", phase, nonneg=True)
    if ph >= 1.0:
        raise ParameterError(f"phase = {phase!r}: expected a fraction of a period in [0, 1)")
    if initial_conditions is not None and y0 is not None:
        raise ParameterError("pass either y0 or initial_conditions, not both")
    if initial_conditions is not None:
        try:
            ics = np.array(initial_conditions, dtype=float)
        except (TypeError, ValueError):
            raise ParameterError(
                f"initial_conditions = {initial_conditions!r}: expected an array (n, 2)"
            ) from None
        if ics.ndim != 2 or ics.shape[1] != 2 or ics.shape[0] == 0 or not np.all(np.isfinite(ics)):
            raise ParameterError(
                f"initial_conditions has shape {ics.shape}: expected finite values of shape "
                "(n_runs, 2)"
            )
    else:
        ics = _state("y0", y0)[None, :]
    n_runs, n = ics.shape[0], vals.size
    X = np.empty((n_runs, n, rp))
    V = np.empty((n_runs, n, rp))
    per = np.zeros((n_runs, n), int)
    res = np.zeros((n_runs, n))
    osc_j = [osc.with_params({parameter: float(p)}) for p in vals]
    flows: list[Flow | None] = [None] * n
    det_tol = 4.0 * tl if tl is not None else 1e-6
    with Progress(n_runs * n, f"bifurcation diagram over {parameter}", enabled=progress) as bar:
        for i in range(n_runs):
            y, t_prev_end = ics[i].copy(), None
            for j in range(n):
                if flows[j] is None:
                    flows[j] = make_flow(osc_j[j], method=method, rtol=rtol, atol=atol)
                flow = flows[j]
                assert flow is not None
                T = _section_period(flow, osc_j[j])
                t0 = ph * T
                if not continuation or t_prev_end is None:
                    y = ics[i].copy()
                    if t0 > 0.0:
                        y = _step(flow, y, 0.0, t0).y
                try:
                    settled = _settle(flow, y, t0, T, max_periods=tp, tol=tl, max_period=mp)
                    y, t = settled.y, settled.t
                    pts = np.empty((rp, 2))
                    for k in range(rp):
                        pts[k] = y
                        y = _step(flow, y, t + k * T, t + (k + 1) * T).y
                except PerturbError as err:
                    raise type(err)(
                        f"bifurcation diagram, run {i} at {parameter} = {vals[j]:.6g}: {err}"
                    ) from None
                strobe = np.concatenate([np.asarray(settled.strobe[:-1]), pts, y[None, :]])
                m, r = _detect(strobe, det_tol, mp)
                X[i, j], V[i, j], per[i, j], res[i, j] = pts[:, 0], pts[:, 1], m, r
                t_prev_end = t + rp * T
                bar.update()
    params = {k: float(v) for k, v in osc.params.items() if v is not None and k != parameter}
    return BifurcationDiagram(
        parameter=parameter,
        values=_frozen(vals),
        x=_frozen(X),
        v=_frozen(V),
        period=_frozen(per, int),
        residual=_frozen(res),
        phase=ph,
        model=osc.name,
        params=MappingProxyType(params),
    )


# --------------------------------------------------------------------------------------------
# basins of attraction
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Attractor:
    """A periodic attractor found by :func:`basins`: its ``period`` section points."""

    points: np.ndarray
    period: int
    fraction: float = 0.0

    @property
    def mean_x(self) -> float:
        return float(np.mean(self.points[:, 0]))

    def __repr__(self) -> str:
        pts = ", ".join(f"({p[0]:.6g}, {p[1]:.6g})" for p in self.points[:4])
        more = ", ..." if self.period > 4 else ""
        return (
            f"Attractor(period-{self.period}, section points {pts}{more}, "
            f"basin fraction {self.fraction:.3g})"
        )


@dataclass(frozen=True, eq=False)
class BasinResult:
    """Labels of a grid of initial conditions (at ``t = 0``).

    Attributes
    ----------
    x, v
        Grid axes, shapes (nx,) and (nv,).
    labels
        Shape (nv, nx): index into ``attractors``, ``-1`` (not settled in the allowed time;
        chaotic or a period above ``max_period``) or ``-2`` (escaped beyond
        ``escape_radius``, overflowed, or — per-initial-condition mode — the flow failed).
    attractors
        The distinct attractors, in order of discovery along the grid (row by row).
    periods_used
        Forcing periods each initial condition was integrated for, shape (nv, nx).
    """

    x: np.ndarray
    v: np.ndarray
    labels: np.ndarray
    attractors: tuple[Attractor, ...]
    periods_used: np.ndarray
    period: float
    model: str = ""

    def fractions(self) -> dict[int, float]:
        """Share of the grid per label (attractor index, -1 and -2 when present)."""
        lab, cnt = np.unique(self.labels, return_counts=True)
        return {int(a): float(c) / self.labels.size for a, c in zip(lab, cnt, strict=True)}

    def label_at(self, x: float, v: float) -> int:
        """Label of the grid point nearest to ``(x, v)``."""
        i = int(np.argmin(np.abs(self.v - v)))
        j = int(np.argmin(np.abs(self.x - x)))
        return int(self.labels[i, j])

    def __repr__(self) -> str:
        fr = self.fractions()
        parts = [f"{a!r}" for a in self.attractors]
        extra = []
        if UNRESOLVED in fr:
            extra.append(f"unresolved {fr[UNRESOLVED]:.3g}")
        if ESCAPED in fr:
            extra.append(f"escaped {fr[ESCAPED]:.3g}")
        head = (
            f"BasinResult({self.model or 'model'}: {self.v.size}x{self.x.size} grid, x in "
            f"[{self.x[0]:.4g}, {self.x[-1]:.4g}], x' in [{self.v[0]:.4g}, {self.v[-1]:.4g}], "
            f"{len(self.attractors)} attractors{'; ' + ', '.join(extra) if extra else ''})"
        )
        return "\n".join([head] + ["  " + p for p in parts])


def _grid_axis(name: str, rng: object, n: int) -> np.ndarray:
    lo, hi = checks.window(rng, name, positive=False)
    if n == 1:
        return np.array([0.5 * (lo + hi)])
    # u = (2i - (n-1))/(n-1) is exactly antisymmetric (integer numerators, one rounding), so
    # a range symmetric about 0 gives a grid with x_{n-1-i} = -x_i bit for bit: symmetric
    # systems then give exactly mirrored basins
    u = (2.0 * np.arange(n) - (n - 1)) / (n - 1)
    c, h = 0.5 * (lo + hi), 0.5 * (hi - lo)
    return c + h * u


def _batch_rhs(osc: Oscillator) -> Callable[[float, np.ndarray], np.ndarray]:
    """Vectorised ``y' = F(t, y)`` for ``y`` of shape (2, N)."""
    rhs = first_order_rhs(osc)

    def fun(t: float, y: np.ndarray) -> np.ndarray:
        out = rhs.fun(t, y)
        return np.broadcast_to(out, y.shape) if np.shape(out) != y.shape else out

    try:
        probe = fun(0.0, np.zeros((2, 3)))
    except (ValueError, TypeError):
        probe = None
    if probe is None or probe.shape != (2, 3):
        raise ModelError(f"the equations of model {osc.name!r} do not vectorise over states")
    return fun


def _rk4_periods(
    fun: Callable[[float, np.ndarray], np.ndarray],
    Y: np.ndarray,
    t0: float,
    T: float,
    steps: int,
) -> np.ndarray:
    """Classical RK4 over one period ``[t0, t0 + T]`` for all columns of ``Y`` at once.

    Fixed steps on purpose: every column sees the same arithmetic, so a system symmetric
    under ``y -> -y`` maps mirrored initial conditions to exactly mirrored orbits.
    """
    h = T / steps
    for s in range(steps):
        t = t0 + s * h
        k1 = fun(t, Y)
        k2 = fun(t + 0.5 * h, Y + (0.5 * h) * k1)
        k3 = fun(t + 0.5 * h, Y + (0.5 * h) * k2)
        k4 = fun(t + h, Y + h * k3)
        Y = Y + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    return Y


def basins(
    osc: Oscillator,
    x_range: tuple[float, float],
    v_range: tuple[float, float],
    n: int | tuple[int, int],
    options: BasinOptions | None = None,
    *,
    period: float | None = None,
    **knobs: Any,
) -> BasinResult:
    r"""Basins of attraction on a grid of initial conditions ``(x, x')`` at ``t = 0``.

    All initial conditions are integrated together (``vectorised=True``: classical RK4 with
    ``steps_per_period`` fixed steps per forcing period, numpy across the grid) in rounds of
    ``check_every`` periods.  After each round, every orbit whose last ``2 max_period + 1``
    section points repeat with some period :math:`m` to ``tol`` is *settled*; it is given
    the label of a known attractor if its last section point lies within ``match_tol``
    (relative) of a point of that attractor's cycle of the same period, else it founds a new
    attractor.  Settled orbits leave the batch.  With ``refine=True`` each attractor is then
    settled again with the accurate flow (:func:`make_flow`) from its cycle, and attractors
    that coincide after refinement are merged.

    Parameters
    ----------
    osc
        Oscillator with all parameters set.
    x_range, v_range
        ``(low, high)`` of the grid axes (a range symmetric about 0 gives an exactly
        symmetric grid).
    n
        Points per axis, or ``(nx, nv)``.
    options
        The tuning knobs (:class:`BasinOptions`: settling time and tolerances, attractor
        matching, RK4 steps, escape radius, vectorised or accurate integration, refinement,
        flow method, progress line).
    period
        Section period; default the forcing period (required for autonomous models).
    **knobs
        Fields of :class:`BasinOptions` as keywords, replacing those of ``options``.

    Notes
    -----
    The RK4 grid integration has a local error :math:`O(h^5)` per step for smooth fields and
    :math:`O(h^2)` per crossing of a kink; it only decides which attractor an orbit
    approaches, so initial conditions within that error of a basin boundary may be
    misassigned (``vectorised=False`` avoids this for PWL models).
    """
    o = _options(BasinOptions, options, knobs, "basins")
    xs, vs, run = _basin_setup(osc, x_range, v_range, n, o, period)
    nx, nv = xs.size, vs.size
    X, Vg = np.meshgrid(xs, vs)  # shape (nv, nx), row = one x' value
    Y0 = np.stack([X.ravel(), Vg.ravel()])  # (2, N)
    if o.vectorised:
        _basins_vectorised(osc, Y0, run, o.progress)
    else:
        _basins_per_point(Y0, run, o.progress)
    final, remap = _refine_attractors(run, o.refine)
    lab = run.labels.copy()
    if run.cycles:
        lab = np.where(run.labels >= 0, remap[np.maximum(run.labels, 0)], run.labels)
    attractors = tuple(
        Attractor(points=_frozen(c), period=c.shape[0], fraction=float(np.mean(lab == a)))
        for a, c in enumerate(final)
    )
    return BasinResult(
        x=_frozen(xs),
        v=_frozen(vs),
        labels=_frozen(lab.reshape(nv, nx), int),
        attractors=attractors,
        periods_used=_frozen(run.used.reshape(nv, nx), int),
        period=run.T,
        model=osc.name,
    )


@dataclass
class _BasinRun:
    """The checked settings of :func:`basins` and its state: per initial condition the
    label (attractor index, :data:`UNRESOLVED` or :data:`ESCAPED`) and the periods used,
    and the attractor cycles ``(m, 2)`` in discovery order."""

    maxp: int
    every: int
    tol: float
    mtol: float
    mp: int
    steps: int
    rad: float
    T: float
    flow: Flow | None
    labels: np.ndarray
    used: np.ndarray
    cycles: list[np.ndarray] = field(default_factory=list)

    @property
    def window(self) -> int:
        """Section points needed to detect a period up to ``mp``."""
        return 2 * self.mp + 1

    def classify(self, idx: np.ndarray, tails: np.ndarray, k: int) -> np.ndarray:
        """Label the settled sequences among ``idx``; returns a mask of those settled."""
        labels, cycles, mtol = self.labels, self.cycles, self.mtol
        mper = _period_from_residuals(_residuals(tails, self.mp), self.tol)  # (len(idx),)
        settled = mper > 0
        last = tails[-1]  # (2, len)
        scale = 1.0 + np.max(np.abs(tails), axis=(0, 1))
        pending = np.flatnonzero(settled)
        while pending.size:
            matched = np.zeros(pending.size, bool)
            for a, cyc in enumerate(cycles):
                same_m = mper[pending] == cyc.shape[0]
                d = np.min(
                    np.max(np.abs(last[:, pending][None, :, :] - cyc[:, :, None]), axis=1), axis=0
                )
                hit = same_m & (d <= mtol * scale[pending]) & ~matched
                labels[idx[pending[hit]]] = a
                matched |= hit
            pending = pending[~matched]
            if pending.size:
                # the first unmatched settled orbit founds a new attractor: its last m points
                p = pending[0]
                m = int(mper[p])
                cycles.append(tails[-m:, :, p].copy())
        self.used[idx[settled]] = k
        return settled


def _basin_setup(
    osc: Oscillator,
    x_range: tuple[float, float],
    v_range: tuple[float, float],
    n: int | tuple[int, int],
    o: BasinOptions,
    period: float | None,
) -> tuple[np.ndarray, np.ndarray, _BasinRun]:
    """Step 1 of :func:`basins`: the grid axes and the checked settings (the accurate flow
    when refining or not vectorised; the section period)."""
    if not isinstance(osc, Oscillator):
        raise ParameterError(f"osc = {osc!r}: expected an Oscillator")
    if isinstance(n, tuple | list):
        if len(n) != 2:
            raise ParameterError(f"n = {n!r}: expected an integer or (nx, nv)")
        nx, nv = _int("n[0]", n[0], 1), _int("n[1]", n[1], 1)
    else:
        nx = nv = _int("n", n, 1)
    xs, vs = _grid_axis("x_range", x_range, nx), _grid_axis("v_range", v_range, nv)
    maxp = _int("max_periods", o.max_periods, 1)
    every = _int("check_every", o.check_every, 1)
    tol = _tol("tol", o.tol)
    mtol = _tol("match_tol", o.match_tol)
    mp = _int("max_period", o.max_period, 1)
    steps = _int("steps_per_period", o.steps_per_period, 4)
    rad = _real("escape_radius", o.escape_radius, positive=True)
    flow = make_flow(osc, method=o.method) if (o.refine or not o.vectorised) else None
    if flow is not None:
        T = _section_period(flow, osc, period)
    elif period is not None:
        T = _real("period", period, positive=True)
    else:
        rhs_period = first_order_rhs(osc).period
        if rhs_period is None:
            raise ParameterError(
                f"model {osc.name!r} is autonomous: pass period=... for the section"
            )
        T = float(rhs_period)
    N = nx * nv
    labels = np.full(N, UNRESOLVED, int)
    used = np.zeros(N, int)
    return xs, vs, _BasinRun(maxp, every, tol, mtol, mp, steps, rad, T, flow, labels, used)


def _basins_vectorised(osc: Oscillator, Y0: np.ndarray, run: _BasinRun, progress: bool) -> None:
    """Step 2 of :func:`basins` (``vectorised=True``): RK4 on the whole grid in rounds of
    ``check_every`` periods; after each, escaped orbits and settled ones (labelled) leave
    the batch."""
    maxp, every, T, steps, rad, window = (
        run.maxp,
        run.every,
        run.T,
        run.steps,
        run.rad,
        run.window,
    )
    labels, used = run.labels, run.used
    rounds = -(-maxp // every)
    fun = _batch_rhs(osc)
    active = np.arange(Y0.shape[1])
    Y = Y0.copy()
    tails = Y[None].copy()  # (n_points, 2, N_active)
    k = 0
    with Progress(rounds, "basins", enabled=progress) as bar:
        while k < maxp and active.size:
            nk = min(every, maxp - k)
            for _ in range(nk):
                with np.errstate(over="ignore", invalid="ignore"):
                    Y = _rk4_periods(fun, Y, k * T, T, steps)
                k += 1
                tails = np.concatenate([tails, Y[None]])[-window:]
            big = ~np.all(np.isfinite(Y), axis=0) | (np.max(np.abs(Y), axis=0) > rad)
            if big.any():
                labels[active[big]] = ESCAPED
                used[active[big]] = k
                keep = ~big
                active, Y, tails = active[keep], Y[:, keep], tails[:, :, keep]
            if tails.shape[0] >= 3 and active.size:
                done = run.classify(active, tails, k)
                keep = ~done
                active, Y, tails = active[keep], Y[:, keep], tails[:, :, keep]
            bar.update()
    used[active] = k


def _basins_per_point(Y0: np.ndarray, run: _BasinRun, progress: bool) -> None:
    """Step 2 of :func:`basins` (``vectorised=False``): each initial condition settled
    with the accurate flow, then labelled."""
    flow = run.flow
    assert flow is not None
    N = Y0.shape[1]
    with Progress(N, "basins (flow)", enabled=progress) as bar:
        for i in range(N):
            try:
                s = _settle(
                    flow,
                    Y0[:, i],
                    0.0,
                    run.T,
                    max_periods=run.maxp,
                    tol=run.tol,
                    max_period=run.mp,
                )
            except PerturbError:
                run.labels[i] = ESCAPED
                bar.update()
                continue
            tails = np.asarray(s.strobe)[-run.window :, :, None]
            if np.max(np.abs(tails)) > run.rad:
                run.labels[i] = ESCAPED
            elif tails.shape[0] >= 3:
                run.classify(np.array([i]), tails, s.periods)
            run.used[i] = s.periods
            bar.update()


def _refine_attractors(run: _BasinRun, refine: bool) -> tuple[list[np.ndarray], np.ndarray]:
    """Step 3 of :func:`basins`: with ``refine``, settle each attractor with the accurate
    flow and merge coincident ones; the final cycles and the map old -> final index."""
    cycles, flow, mtol = run.cycles, run.flow, run.mtol
    final: list[np.ndarray] = []
    remap = np.arange(len(cycles))
    if not (refine and flow is not None):
        return list(cycles), remap
    # the batch cycles are good to the RK4 error: settle much tighter with the accurate flow
    rtol_ = max(run.tol * 1e-3, 1e-13)
    for a, cyc in enumerate(cycles):
        m = cyc.shape[0]
        s = _settle(flow, cyc[-1], 0.0, run.T, max_periods=run.maxp, tol=rtol_, max_period=run.mp)
        mm = s.period or m
        ref = np.asarray(s.strobe)[-mm:]
        for b, other in enumerate(final):
            if other.shape[0] == mm:
                scale = 1.0 + float(np.max(np.abs(ref)))
                if np.min(np.max(np.abs(other - ref[-1]), axis=1)) <= mtol * scale:
                    remap[a] = b
                    break
        else:
            remap[a] = len(final)
            final.append(ref)
    return final, remap


# --------------------------------------------------------------------------------------------
# Lyapunov exponents
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class LyapunovResult:
    r"""Largest Lyapunov exponent of the orbit through ``y0``.

    Attributes
    ----------
    value
        :math:`\lambda_1 = \frac{1}{nT}\sum_{j=1}^{n}\ln r_j` with :math:`r_j` the growth of
        the renormalised tangent vector over period :math:`j`.
    spread
        :math:`\max - \min` of the running estimate :math:`\lambda_1^{(k)}` over the last half
        of the periods (a convergence measure; :math:`\to 0` as :math:`O(1/n)` for a periodic
        orbit, slower for a chaotic one).
    exponents
        :math:`(\lambda_1, \lambda_2)` from the QR (Gram–Schmidt) method; for
        :math:`x'' + \mu x' + g(x) = f(t)` with continuous :math:`g`, :math:`\lambda_1 +
        \lambda_2 = -\mu` exactly (Liouville), a check on the tangent dynamics.
    running
        :math:`\lambda_1^{(k)}`, k = 1..n.
    n_periods, period, transient
        Periods averaged, forcing period, periods discarded first.
    """

    value: float
    spread: float
    exponents: tuple[float, float]
    running: np.ndarray
    n_periods: int
    period: float
    transient: int

    def __repr__(self) -> str:
        return (
            f"LyapunovResult(lambda1={self.value:.6g} +/- {self.spread:.2g} (spread over the "
            f"last half), exponents=({self.exponents[0]:.6g}, {self.exponents[1]:.6g}), "
            f"{self.n_periods} periods of T={self.period:.6g} after {self.transient})"
        )


def lyapunov_exponent(
    flow_or_osc: Flow | Oscillator,
    y0: ArrayLike,
    n_periods: int,
    *,
    transient: int = 200,
    period: float | None = None,
    tangent0: ArrayLike | None = None,
    method: FlowMethod = "auto",
    progress: bool | None = None,
) -> LyapunovResult:
    r"""Largest Lyapunov exponent from the tangent dynamics (Benettin renormalisation).

    After ``transient`` periods from ``y0`` (at ``t = 0``), each forcing period
    :math:`[t_j, t_j + T]` is propagated with ``sensitivity=True``, giving
    :math:`\Phi_j = \partial y(t_j + T)/\partial y(t_j)` (saltation matrices included when
    the flow includes them); the tangent frame :math:`Q` is advanced by
    :math:`\Phi_j Q_{j-1} = Q_j R_j` (QR) and

    .. math::

        \lambda_i = \frac{1}{nT} \sum_{j=1}^{n} \ln |(R_j)_{ii}|.

    The first column of :math:`Q` is the renormalised tangent vector of the classical
    method, so :math:`\lambda_1` is the largest exponent.  For a periodic orbit with
    diagonalisable monodromy (eigenvector matrix :math:`V`) the estimate is within
    :math:`\ln\kappa(V)/(nT)` of :math:`\ln|\mu_{\max}|/T_{\text{orbit}}`.

    Parameters
    ----------
    flow_or_osc
        A flow with sensitivities, or an oscillator (flow from :func:`make_flow`).
    y0
        State at ``t = 0``.
    n_periods
        Periods averaged (``>= 2``).
    transient
        Periods discarded first.
    period
        Renormalisation period; default the forcing period (required for autonomous flows).
    tangent0
        Initial tangent vector (first column of the frame); default ``(cos 0.4, sin 0.4)``,
        a generic direction (an axis could be invariant, e.g. for a decoupled model).
    method, progress
        Flow selection when an oscillator is given; progress line.

    Raises
    ------
    ParameterError
        Bad arguments, or an autonomous flow without ``period``.
    PerturbError
        The flow returns no sensitivity, or the orbit or its tangent dynamics overflow.
    """
    flow = _flow_argument(flow_or_osc, "flow_or_osc", method)
    y = _state("y0", y0)
    n = _int("n_periods", n_periods, 2)
    tr = _int("transient", transient, 0)
    T = _period_of(flow, period)
    if tangent0 is None:
        # a generic initial frame: an axis-aligned one could start in an invariant direction
        w0 = np.array([math.cos(0.4), math.sin(0.4)])
    else:
        w0 = _state("tangent0", tangent0)
        if not np.any(w0):
            raise ParameterError("tangent0 = [0, 0]: expected a nonzero vector")
        w0 = w0 / np.linalg.norm(w0)
    Q = np.array([[w0[0], -w0[1]], [w0[1], w0[0]]])
    logs = np.empty((n, 2))
    with Progress(tr + n, "Lyapunov exponent", enabled=progress) as bar:
        for k in range(tr):
            y = _step(flow, y, k * T, (k + 1) * T).y
            bar.update()
        for j in range(n):
            t0 = (tr + j) * T
            res = _step(flow, y, t0, t0 + T, sensitivity=True)
            if res.sensitivity is None:
                raise PerturbError("the flow did not return the sensitivity matrix")
            Q, R = np.linalg.qr(res.sensitivity @ Q)
            d = np.abs(np.diag(R))
            if not np.all(np.isfinite(d)) or np.any(d == 0.0):
                raise PerturbError(
                    f"the tangent dynamics degenerated at t = {t0:.6g} (diag R = {d.tolist()})"
                )
            logs[j] = np.log(d)
            y = res.y
            bar.update()
    running = np.cumsum(logs[:, 0]) / (T * np.arange(1, n + 1))
    half = running[n // 2 :]
    lam = logs.sum(axis=0) / (n * T)
    return LyapunovResult(
        value=float(lam[0]),
        spread=float(half.max() - half.min()),
        exponents=(float(lam[0]), float(lam[1])),
        running=_frozen(running),
        n_periods=n,
        period=T,
        transient=tr,
    )
