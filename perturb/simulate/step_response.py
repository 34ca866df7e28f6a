r"""Step responses of systems of several coordinates, by the toolkit's own solvers.

After a step of its input a system is time invariant: ``y' = A y + b`` when it is linear, a
piecewise-affine ``y' = A_r y + b_r`` region by region, or a piecewise-smooth system with
stops and friction contacts. :func:`step_response` samples the state at given times from a
given initial state (the state just after the step) by the solver that fits:

``"closed_form"``
    A linear time-invariant system (no switching surface, every stop held by ``active``):
    with :math:`y_{eq} = -A^{-1}b` (any equilibrium when ``A`` is singular and ``b`` in its
    range) and :math:`A = V\Lambda V^{-1}` (after a diagonal balancing of ``A``),

    .. math::

        y(t) = y_{eq} + V e^{\Lambda (t - t_0)} V^{-1}\,(y_0 - y_{eq}),

    exact to rounding. A drift (``b`` not in the range of a singular ``A``: a clock state) or
    ill-conditioned eigenvectors take the augmented matrix exponential
    :math:`(y, 1)(t) = \exp\big(\begin{smallmatrix}A & b\\ 0 & 0\end{smallmatrix}(t - t_0)\big)
    (y_0, 1)` instead (:func:`scipy.linalg.expm`, one per sample time).
``"exact"``
    A piecewise-affine system: the exact closed-form propagation, region by region, of
    :func:`perturb.simulate.flows.affine_exact.propagate` on ``system.piecewise_affine(active)``
    (switching times on the closed form, grazing-safe), sampled on its dense trajectory.
``"events"``
    Any system, stops (a resting decoupler plate, an impact) and friction contacts included:
    the event-driven integration of :mod:`perturb.simulate.flows.system_events`.
``"auto"``
    ``closed_form`` for a linear system, else ``exact`` when the system is piecewise affine
    and has no stop left free, else ``events``.

The result is a :class:`StepResponse`: times, states, named outputs (a state name, a linear
combination such as ``"V_i + V_d"``, or any expression of the states and parameters read by
the safe parser, e.g. the mount's PWL chamber pressure), the switching events, and the
times where chosen outputs cross zero (``crossings=``: extrema of a response are the zeros
of its rate), located on the solver's dense solution.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import numpy as np
import sympy as sp
from numpy.typing import ArrayLike
from scipy.linalg import expm, matrix_balance
from scipy.optimize import brentq

from perturb.checks import state
from perturb.errors import ModelError, ParameterError, PerturbError
from perturb.model.affine import PiecewiseAffineSystem
from perturb.model.parsing import parse_expression
from perturb.model.system import System

__all__ = ["METHODS", "StepEvent", "StepResponse", "step_response"]

#: The solvers :func:`step_response` takes (``"auto"`` picks one of the others).
METHODS = ("auto", "closed_form", "exact", "events")

#: Most sample times one call takes (the states are held in memory).
MAX_TIMES = 2_000_000

# eigenvectors worse conditioned than this, or an eigenvalue this small relative to the
# largest, send the closed form to the augmented exponential (the eigen form would lose more
# than ~1e-8 of its digits, or A^{-1} b would not exist)
_COND_MAX = 1e8
_SINGULAR = 1e-13


# --------------------------------------------------------------------------------------------
# results
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class StepEvent:
    """A switch (or a tangency) during a step response.

    Attributes
    ----------
    time : float
    kind : str
        ``"crossing"`` / ``"tangency"`` of a switching surface (``exact``), or the event-driven
        solver's kinds (``"impact"``, ``"stick"``, ``"release"``, ...).
    label : str
        What switched: the surface (``"V_i + V_d = -3.6e-06"``) or the contact's name.
    direction : int
        ``+1`` when the switching function increases through zero, ``-1`` when it decreases,
        ``0`` when it has no sign (a contact event).
    """

    time: float
    kind: str
    label: str
    direction: int = 0

    def __str__(self) -> str:
        arrow = {1: " (increasing)", -1: " (decreasing)"}.get(self.direction, "")
        return f"t = {self.time:.10g}: {self.kind} {self.label}{arrow}"


def _frozen(a: ArrayLike) -> np.ndarray:
    out = np.array(a, dtype=float)
    out.setflags(write=False)
    return out


@dataclass(frozen=True, eq=False)
class StepResponse:
    """The sampled step response of a system.

    Attributes
    ----------
    times : ndarray, shape (m,)
    states : ndarray, shape (m, n)
        The state at each time, columns in the order of ``state_names``.
    state_names : tuple of str
    outputs : Mapping[str, ndarray]
        Each requested output at ``times``.
    method : str
        The solver used (never ``"auto"``).
    events : tuple of StepEvent
        Switches in time order (``exact`` and ``events``; empty for ``closed_form``).
    crossings : Mapping[str, ndarray]
        For each output named in ``crossings=``, the times in ``(times[0], times[-1]]`` where
        it crosses zero.
    equilibrium : ndarray or None
        ``closed_form``: the equilibrium ``-A^{-1} b`` (``None`` when ``A`` is singular).
    eigenvalues : ndarray or None
        ``closed_form``: the eigenvalues of ``A`` (the response's modes).
    trajectory : callable or None
        The solver's dense solution: ``trajectory(t)`` is the state, shape ``(n,)`` for a
        scalar ``t`` and ``(n, k)`` for ``k`` times in ``[times[0], times[-1]]``; exact for
        ``closed_form`` and ``exact``; for ``events`` built on demand per interval of
        ``times`` (the flow restarted from the sample, ``refine`` sub-samples, cubic Hermite
        splines of states and fields split at the events).

    All arrays are read-only.
    """

    times: np.ndarray
    states: np.ndarray
    state_names: tuple[str, ...]
    outputs: Mapping[str, np.ndarray]
    method: str
    events: tuple[StepEvent, ...] = ()
    crossings: Mapping[str, np.ndarray] = field(default_factory=lambda: MappingProxyType({}))
    equilibrium: np.ndarray | None = None
    eigenvalues: np.ndarray | None = None
    trajectory: Callable[[ArrayLike], np.ndarray] | None = field(default=None, repr=False)

    def state(self, name: str) -> np.ndarray:
        """One state's samples, by name (``"V_i"``, ``"V_i'"``).

        Raises
        ------
        ModelError
            For a name that is not a state.
        """
        if name not in self.state_names:
            raise ModelError(f"state {name!r}: expected one of {', '.join(self.state_names)}")
        return self.states[:, self.state_names.index(name)]

    def __getitem__(self, name: str) -> np.ndarray:
        """An output or a state by name."""
        if name in self.outputs:
            return self.outputs[name]
        return self.state(name)

    def __str__(self) -> str:
        t0, t1 = float(self.times[0]), float(self.times[-1])
        lines = [
            f"step response ({self.method}): {len(self.times)} times in [{t0:.6g}, {t1:.6g}], "
            f"state ({', '.join(self.state_names)})"
        ]
        for name, vals in self.outputs.items():
            lines.append(
                f"  {name}: start {vals[0]:.6g}, end {vals[-1]:.6g}, "
                f"min {vals.min():.6g}, max {vals.max():.6g}"
            )
        kinds: dict[str, int] = {}
        for e in self.events:
            kinds[e.kind] = kinds.get(e.kind, 0) + 1
        if self.events:
            counts = ", ".join(f"{v} {k}" for k, v in kinds.items())
            lines.append(f"  events: {counts}; first {self.events[0]}")
        for name, tz in self.crossings.items():
            lines.append(f"  zeros of {name}: {len(tz)}")
        if self.eigenvalues is not None:
            slow = float(np.max(self.eigenvalues.real))
            lines.append(f"  slowest mode: Re(lambda) = {slow:.6g}")
        return "\n".join(lines)


# --------------------------------------------------------------------------------------------
# argument checks
# --------------------------------------------------------------------------------------------
def _check_times(times: Any) -> np.ndarray:
    try:
        t = np.array(times, dtype=float)
    except (TypeError, ValueError):
        raise ParameterError(
            f"times = {times!r}: expected an increasing sequence of finite numbers"
        ) from None
    if t.ndim != 1 or t.size < 2:
        raise ParameterError(
            f"times has shape {t.shape}: expected a 1-D sequence of at least two times"
        )
    if t.size > MAX_TIMES:
        raise ParameterError(f"times has {t.size} entries: expected at most {MAX_TIMES}")
    if not np.all(np.isfinite(t)):
        raise ParameterError("times: expected finite numbers (found nan or inf)")
    bad = np.nonzero(np.diff(t) <= 0)[0]
    if bad.size:
        i = int(bad[0])
        raise ParameterError(
            f"times are not strictly increasing: times[{i}] = {t[i]!r}, times[{i + 1}] = "
            f"{t[i + 1]!r}; expected t0 < t1 < ..."
        )
    return t


def _check_y0(y0: Any, names: Sequence[str]) -> np.ndarray:
    return np.zeros(len(names)) if y0 is None else state(y0, len(names), names=names)


def _check_system(system: Any) -> None:
    if not isinstance(system, System | PiecewiseAffineSystem):
        raise ParameterError(
            f"system = {system!r}: expected a System (perturb.model.system) or a "
            "PiecewiseAffineSystem"
        )


def _stops(system: System | PiecewiseAffineSystem) -> list[str]:
    if isinstance(system, PiecewiseAffineSystem):
        return []
    return [e.name for e in system.elements if e.kind in ("stop", "friction")]


def _affine(system: System | PiecewiseAffineSystem, active, method: str):
    """``system.piecewise_affine(active)`` with the error a step-response user needs."""
    if isinstance(system, PiecewiseAffineSystem):
        return system
    if active is not None and not isinstance(active, Mapping):
        raise ParameterError(f"active = {active!r}: expected a mapping name -> None, -1 or +1")
    act = dict(active or {})
    contacts = _stops(system)
    for key in act:
        if key not in contacts:
            raise ParameterError(
                f"active: {key!r} is not a stop or friction contact of system {system.name!r}: "
                f"expected one of {contacts or 'none'}"
            )
    free = [s for s in contacts if act.get(s) is None]
    if free:
        raise PerturbError(
            f"method {method!r}: system {system.name!r} has the stop(s) / friction contact(s) "
            f"{free} not held by active= (resting side -1/+1); a contact that may close or "
            "open during the response needs method='events'"
        )
    try:
        pa = system.piecewise_affine(act)
    except ModelError as exc:
        raise ModelError(
            f"method {method!r} needs a piecewise-linear system: {exc}; use method='events' "
            "for other nonlinear elements"
        ) from None
    if pa.inputs:
        raise ModelError(
            f"system {system.name!r} has harmonic inputs (forcing frequencies "
            f"{sorted(h.omega for h in pa.inputs)}): a step response needs a time-invariant "
            "system after the step (set the forcing amplitude to 0)"
        )
    return pa


def _is_linear(pa: PiecewiseAffineSystem) -> bool:
    """One region, or every region the same (a surface whose element has zero weight)."""
    regs = list(pa.regions.values())
    first = regs[0]
    return all(np.array_equal(r.A, first.A) and np.array_equal(r.b, first.b) for r in regs[1:])


# --------------------------------------------------------------------------------------------
# outputs
# --------------------------------------------------------------------------------------------
_PRIMED = re.compile(r"(?<![A-Za-z0-9_.])([A-Za-z][A-Za-z0-9_]*)\s*('+)")
_PRIME_TAG = "_prime_"


def _output_function(system, name: str, expr: str) -> Callable[[np.ndarray], np.ndarray]:
    """``states (m, n) -> values (m,)`` of one output: a state name, a linear combination
    (``System.output``), or any expression of the states and parameters (safe parser; PWL
    functions such as ``Heaviside`` allowed)."""
    names = list(system.state_names)
    if not isinstance(expr, str):
        raise ParameterError(
            f"output {name!r} = {expr!r}: expected a state name or an expression text"
        )
    if expr in names:
        j = names.index(expr)
        return lambda Y: Y[:, j]
    if isinstance(system, System):
        try:
            c = system.output(expr)
        except (ModelError, ParameterError):
            c = None
        if c is not None:
            return lambda Y: Y @ c
    # a general expression: primes become name suffixes before the safe parser sees the text
    # (it reads derivatives of one variable only); nothing is evaluated
    if _PRIME_TAG in expr:
        raise ParameterError(f"output {name!r} = {expr!r}: names with {_PRIME_TAG} are reserved")
    text = _PRIMED.sub(lambda m: m.group(1) + _PRIME_TAG * len(m.group(2)), expr)
    parsed = parse_expression(text)
    states = {
        n.replace("'", _PRIME_TAG): sp.Symbol(f"y{k}", real=True) for k, n in enumerate(names)
    }
    values = {}
    if isinstance(system, System):
        values = {k: v for k, v in system.params.items() if v is not None}
    reps: dict[sp.Symbol, Any] = {}
    unknown = []
    for sym in parsed.free_symbols:
        if sym.name in states:
            reps[sym] = states[sym.name]
        elif sym.name in values:
            reps[sym] = sp.Float(values[sym.name])
        else:
            unknown.append(sym.name.replace(_PRIME_TAG, "'"))
    if unknown:
        raise ModelError(
            f"output {name!r} = {expr!r}: unknown name(s) {sorted(unknown)}; expected states "
            f"({', '.join(names)}) and parameters with values"
        )
    e = parsed.xreplace(reps)
    syms = list(states.values())
    f = sp.lambdify(syms, e, modules="numpy")

    def evaluate(Y: np.ndarray) -> np.ndarray:
        out = f(*Y.T)
        return np.broadcast_to(np.asarray(out, dtype=float), (Y.shape[0],)).copy()

    return evaluate


def _outputs_table(outputs: Any) -> dict[str, str]:
    if outputs is None:
        return {}
    if isinstance(outputs, str):
        return {outputs: outputs}
    if isinstance(outputs, Mapping):
        table = {}
        for k, v in outputs.items():
            if not isinstance(k, str):
                raise ParameterError(f"outputs: name {k!r}: expected a string")
            table[k] = v
        return table
    if isinstance(outputs, Sequence):
        for v in outputs:
            if not isinstance(v, str):
                raise ParameterError(f"outputs: {v!r}: expected a state name or expression text")
        return {v: v for v in outputs}
    raise ParameterError(
        f"outputs = {outputs!r}: expected a mapping name -> expression or a list of names"
    )


# --------------------------------------------------------------------------------------------
# solvers
# --------------------------------------------------------------------------------------------
def _closed_form(A: np.ndarray, b: np.ndarray, y0: np.ndarray, t0: float):
    """The dense closed form ``t -> y(t)`` of ``y' = A y + b``, the equilibrium and the
    eigenvalues."""
    n = A.shape[0]
    # balance first (a diagonal similarity): the mount's pressures (1e5 Pa) next to its flows
    # (1e-5 m^3/s) give eigenvectors with condition 1e8 unbalanced, about 1 balanced
    Ab, T = matrix_balance(A, permute=False)
    d = np.diag(T).copy()
    bb, z0 = b / d, y0 / d
    lam, V = np.linalg.eig(Ab)
    scale = max(float(np.abs(lam).max()), 1e-300)
    singular = float(np.abs(lam).min()) <= _SINGULAR * scale
    cond = np.linalg.cond(V) if np.all(np.isfinite(V)) else math.inf
    z_eq = None
    if not singular:
        z_eq = -np.linalg.solve(Ab, bb)
    else:
        # an equilibrium exists when b is in the range of A (a conserved volume, no drift);
        # any one serves as the particular solution of the modal form
        zp = np.linalg.lstsq(Ab, -bb, rcond=None)[0]
        if np.abs(Ab @ zp + bb).max() <= 1e-13 * max(float(np.abs(bb).max()), 1e-300):
            z_eq = zp
    if z_eq is not None and cond <= _COND_MAX:
        coef = np.linalg.solve(V, (z0 - z_eq).astype(complex))
        y_eq = d * z_eq

        def traj(t: ArrayLike) -> np.ndarray:
            ta = np.asarray(t, dtype=float)
            tau = ta.reshape(-1) - t0
            Z = (V @ (coef[:, None] * np.exp(np.outer(lam, tau)))).real + z_eq[:, None]
            Y = d[:, None] * Z
            return Y[:, 0] if ta.ndim == 0 else Y

        return traj, (None if singular else y_eq), lam
    # augmented exponential: exact for any spectrum (zero and repeated eigenvalues included)
    M = np.zeros((n + 1, n + 1))
    M[:n, :n], M[:n, n] = Ab, bb
    w0 = np.append(z0, 1.0)
    y_eq = None if z_eq is None or singular else d * z_eq

    def traj_expm(t: ArrayLike) -> np.ndarray:
        ta = np.asarray(t, dtype=float)
        tau = ta.reshape(-1) - t0
        # one exponential per time, from t0 (no marching: no accumulated rounding)
        out = d[:, None] * np.array([(expm(M * h) @ w0)[:n] for h in tau]).T.reshape(n, tau.size)
        return out[:, 0] if ta.ndim == 0 else out

    return traj_expm, y_eq, lam


class _HermiteTrajectory:
    """Piecewise cubic Hermite interpolation of event-driven samples (states and fields),
    one spline per smooth segment between two events: error ``O(h^4)`` inside a segment
    (``h`` the sample spacing), and no interpolation across a jump (an impact) or a kink
    (a switch)."""

    def __init__(self, segments: list[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> None:
        from scipy.interpolate import CubicHermiteSpline

        self._starts = np.array([ts[0] for ts, _, _ in segments])
        self._n = segments[0][1].shape[1]
        self._splines: list[Any] = []
        for ts, ys, fs in segments:
            if ts.size >= 2:
                self._splines.append(CubicHermiteSpline(ts, ys, fs, axis=0))
            else:  # a zero-length segment (two events at one instant)
                self._splines.append(lambda tt, y=ys[0]: np.tile(y, (np.size(tt), 1)))

    def __call__(self, t: ArrayLike) -> np.ndarray:
        ta = np.asarray(t, dtype=float)
        flat = ta.reshape(-1)
        idx = np.clip(np.searchsorted(self._starts, flat, side="right") - 1, 0, None)
        out = np.empty((flat.size, self._n))
        for k in np.unique(idx):
            sel = idx == k
            out[sel] = np.asarray(self._splines[int(k)](flat[sel])).reshape(-1, self._n)
        return out[0] if ta.ndim == 0 else out.T


def _event_flow(system: System, options: Mapping[str, Any], max_events: int, span, y0):
    """The event-driven flow (``perturb.simulate.flows.system_events``) with the options of
    a step response; ``atol`` defaults to ``1e-3 rtol`` times the scale of the motion, the
    larger of ``|y0|`` and the initial rate times the span (its tolerances are absolute)."""
    from perturb.simulate.flows.system_events import SystemEventFlow

    known = ("rtol", "atol", "max_steps", "rest_velocity")
    unknown = sorted(set(options) - set(known))
    if unknown:
        raise ParameterError(
            f"unknown option(s) {unknown} for method 'events': expected some of {known}"
        )
    opts = dict(options)
    rtol = opts.pop("rtol", 1e-10)
    if "atol" not in opts:
        if isinstance(rtol, bool) or not isinstance(rtol, int | float) or not 0 < rtol < 1:
            raise ParameterError(f"rtol = {rtol!r}: expected a number in (0, 1)")
        rate = np.abs(np.asarray(system.field(span[0], y0), dtype=float)).max()
        scale = max(float(np.abs(y0).max()), float(rate) * (span[1] - span[0]), 1e-300)
        opts["atol"] = min(1e-3 * rtol * scale, 0.5)
    return SystemEventFlow(system, rtol=rtol, max_events=max(int(max_events), 1), **opts)


def _hermite_segments(flow, log, t0: float, y0: np.ndarray, ts, ys, t1: float):
    """Split samples ``(ts, ys)`` of one run from ``(t0, y0)`` to ``t1`` at its events
    ``log`` into smooth segments ``(times, states, fields)``: a segment starts at an event's
    state after it and ends at the sample just before the next event (the flow samples an
    event time on the step that ends there)."""
    segments = []
    start_t, start_y = t0, np.asarray(y0, dtype=float)
    k = 0
    for e in [*log, None]:
        end = t1 if e is None else float(e.t)
        seg_t, seg_y = [start_t], [start_y]
        while k < ts.size and ts[k] <= end:
            if ts[k] > seg_t[-1]:  # an event on a sample time is sampled twice: keep one
                seg_t.append(float(ts[k]))
                seg_y.append(ys[k])
            k += 1
        seg_f = [flow.vector_field(tt, yy) for tt, yy in zip(seg_t, seg_y, strict=True)]
        segments.append((np.array(seg_t), np.array(seg_y), np.array(seg_f)))
        if e is not None:
            start_t, start_y = float(e.t), np.asarray(e.y, dtype=float)
    return segments


class _EventTrajectory:
    """The dense solution of an event-driven run, built on demand between two sample times:
    the flow is restarted from the sample at ``times[k]`` over ``[times[k], times[k+1]]``,
    sampled ``refine`` times (and at its events), and interpolated by cubic Hermite splines
    of states and fields, one per smooth segment (error ``O(h^4)`` in the refined spacing
    ``h``; no interpolation across an impact or a switch)."""

    def __init__(self, flow, times: np.ndarray, states: np.ndarray, refine: int) -> None:
        self._flow, self._times, self._states, self._refine = flow, times, states, refine
        self._pieces: dict[int, _HermiteTrajectory] = {}

    def piece(self, k: int) -> _HermiteTrajectory:
        if k not in self._pieces:
            a, b = float(self._times[k]), float(self._times[k + 1])
            ya = self._states[k]
            fine = np.linspace(a, b, self._refine + 1)
            run = self._flow(ya, a, b, t_eval=fine)
            log = self._flow.events
            if log:  # again, sampling each event time too (same steps, same events)
                grid = np.sort(np.concatenate([fine, [e.t for e in log]]), kind="stable")
                run = self._flow(ya, a, b, t_eval=grid)
            segs = _hermite_segments(self._flow, log, a, ya, np.asarray(run.t), run.ys, b)
            self._pieces[k] = _HermiteTrajectory(segs)
        return self._pieces[k]

    def __call__(self, t: ArrayLike) -> np.ndarray:
        ta = np.asarray(t, dtype=float)
        flat = ta.reshape(-1)
        last = len(self._times) - 2
        idx = np.clip(np.searchsorted(self._times, flat, side="right") - 1, 0, last)
        out = np.empty((flat.size, self._states.shape[1]))
        for k in np.unique(idx):
            sel = idx == k
            out[sel] = self.piece(int(k))(flat[sel]).T.reshape(-1, self._states.shape[1])
        return out[0] if ta.ndim == 0 else out.T


def _events(system, t: np.ndarray, y0: np.ndarray, active, max_events, options, refine):
    """The event-driven step response: the dense trajectory (built on demand), the events,
    the states at ``t``."""
    if not isinstance(system, System):
        raise ParameterError(
            "method 'events' needs a System (a PiecewiseAffineSystem has no stops or "
            "friction contacts): use method='exact'"
        )
    if any(v is not None for v in dict(active or {}).values()):
        raise ParameterError(
            f"active = {dict(active)!r}: method 'events' finds the contact modes itself (a "
            "state on a stop limit, pushed into it, rests); pass active= only to "
            "'closed_form' or 'exact', which hold those stops"
        )
    flow = _event_flow(system, options, max_events, (float(t[0]), float(t[-1])), y0)
    run = flow(y0, float(t[0]), float(t[-1]), t_eval=t)
    log = flow.events
    num = system.numeric_form()
    events = []
    for e in log:
        c = num["comb"].get(e.element, (None, None))[0]
        direction = 0
        if e.kind == "cross" and c is not None:
            rate = float(c @ flow.vector_field(e.t, e.y))
            direction = 1 if rate > 0 else -1 if rate < 0 else 0
        events.append(StepEvent(float(e.t), e.kind, e.element, direction))
    Y = np.asarray(run.ys, dtype=float)
    return _EventTrajectory(flow, t, Y, refine), tuple(events), Y


def _refined(times: np.ndarray, refine: int) -> np.ndarray:
    return np.concatenate(
        [np.linspace(a, b, refine + 1)[:-1] for a, b in zip(times[:-1], times[1:], strict=True)]
        + [times[-1:]]
    )


def _zeros(traj, f, times: np.ndarray, refine: int, coarse=None, event_times=()) -> np.ndarray:
    """Zeros of ``f(traj(t))`` in ``(times[0], times[-1]]``: sign changes on ``times``
    refined ``refine`` times, each polished by Brent's method on the dense solution.

    With ``coarse`` (the output at ``times``; event-driven runs, whose dense solution costs
    an integration per interval) only the intervals of ``times`` with a sign change or an
    event are refined.
    """
    if coarse is None:
        fine = _refined(times, refine)
        vals = f(traj(fine).T)
    else:
        cand = np.sign(coarse[:-1]) * np.sign(coarse[1:]) <= 0
        for te in event_times:
            k = int(np.searchsorted(times, te, side="right")) - 1
            if 0 <= k < len(cand):
                cand[k] = True
        pieces = [np.linspace(times[k], times[k + 1], refine + 1) for k in np.nonzero(cand)[0]]
        if not pieces:
            return np.empty(0)
        fine = np.concatenate(pieces)
        # consecutive pieces repeat an end point (skipped below); between two pieces that are
        # not consecutive no interval of times changes sign, so neither does the output
        vals = f(traj(fine).T)

    def g(tt: float) -> float:
        return float(f(traj(np.array([tt])).T)[0])

    size = max(float(np.abs(vals).max()), 1e-300)
    out = []
    for i in np.nonzero(np.sign(vals[:-1]) * np.sign(vals[1:]) < 0)[0]:
        a, b = float(fine[i]), float(fine[i + 1])
        if not a < b:
            continue
        root = brentq(g, a, b, xtol=1e-15 * max(1.0, abs(b)), rtol=1e-15)
        # a sign change across a jump of the output (an impact stopping a flow) is no zero
        if abs(g(root)) <= 1e-8 * size:
            out.append(root)
    for i in np.nonzero(vals[1:] == 0)[0]:
        if fine[i + 1] > times[0]:
            out.append(float(fine[i + 1]))
    return np.unique(np.array(out, dtype=float))


# --------------------------------------------------------------------------------------------
# the front door
# --------------------------------------------------------------------------------------------
def step_response(
    system: System | PiecewiseAffineSystem,
    times: ArrayLike,
    *,
    y0: ArrayLike | None = None,
    method: str = "auto",
    active: Mapping[str, int | None] | None = None,
    outputs: Mapping[str, str] | Sequence[str] | None = None,
    crossings: Sequence[str] = (),
    refine: int = 8,
    max_events: int = 100_000,
    **options: Any,
) -> StepResponse:
    r"""The response of a time-invariant system from ``y0`` at ``times[0]``, sampled at
    ``times``.

    Parameters
    ----------
    system : System or PiecewiseAffineSystem
        The system after the step (its forcing constant: a step of amplitude ``X`` enters as
        a parameter, e.g. ``builtin_system("mount", X=-2.4e-3)``).
    times : array_like
        Strictly increasing sample times; ``times[0]`` is the start (the instant after the
        step).
    y0 : array_like, optional
        The state at ``times[0]`` in the order of ``system.state_names`` (default: zero, the
        rest state before a step of a system in displacement-like coordinates).
    method : {"auto", "closed_form", "exact", "events"}
        See the module docstring.
    active : mapping, optional
        Stops / friction contacts held for the whole response (side ``-1`` / ``+1``, ``None``
        free), as in :meth:`System.piecewise_affine`; ``closed_form`` and ``exact`` need every
        stop named. ``events``: the initial contact modes.
    outputs : mapping or sequence of str, optional
        Name -> expression (a state name, a linear combination such as ``"V_i + V_d"``, or an
        expression of states and parameters, e.g. a PWL pressure with ``Heaviside``), or a
        list of expressions (each its own name).
    crossings : sequence of str
        Names of ``outputs`` (or state names) whose zeros are located on the dense solution
        (sign changes on ``times`` refined ``refine`` times, then Brent's method). Zeros
        closer together than the refined spacing may be missed.
    refine : int
        Subdivisions of each interval of ``times`` when scanning for ``crossings``.
    max_events : int
        Most switches (``exact``, ``events``) before giving up.
    **options
        Passed to the event-driven solver (``method="events"``): its tolerances.

    Returns
    -------
    StepResponse

    Raises
    ------
    ParameterError
        Times not strictly increasing, fewer than two or not finite; a bad ``y0``; an unknown
        method; an output or crossing that names nothing.
    ModelError
        ``closed_form`` on a system that is not linear, ``exact`` on one that is not piecewise
        linear (named element), harmonic inputs.
    PerturbError
        ``closed_form`` / ``exact`` with a stop or friction contact not held by ``active``;
        the solvers' own limits (``max_events``, sliding for ``exact``).

    Examples
    --------
    >>> from perturb.model.system_builtins import builtin_system
    >>> r = step_response(builtin_system("mount_fixed_linear"), np.linspace(0, 0.5, 101),
    ...                   outputs={"p1": "(A_r*X - V_i)/C1"})
    >>> r.method
    'closed_form'
    """
    _check_system(system)
    if method not in METHODS:
        raise ParameterError(f"method = {method!r}: expected one of {', '.join(METHODS)}")
    t = _check_times(times)
    names = tuple(system.state_names)
    y = _check_y0(y0, names)
    if (
        isinstance(refine, bool)
        or not isinstance(refine, int | np.integer)
        or not (1 <= refine <= 1000)
    ):
        raise ParameterError(f"refine = {refine!r}: expected a whole number in [1, 1000]")
    if (
        isinstance(max_events, bool)
        or not isinstance(max_events, int | np.integer)
        or (max_events < 0)
    ):
        raise ParameterError(f"max_events = {max_events!r}: expected a non-negative integer")
    table = _outputs_table(outputs)
    funcs = {k: _output_function(system, k, v) for k, v in table.items()}
    if isinstance(crossings, str):
        cross = [crossings]
    else:
        try:
            cross = list(crossings)
        except TypeError:
            raise ParameterError(
                f"crossings = {crossings!r}: expected output names (a string or a sequence "
                "of strings)"
            ) from None
    for c in cross:
        if c not in funcs:
            if not isinstance(c, str):
                raise ParameterError(f"crossings: {c!r}: expected an output name")
            funcs[c] = _output_function(system, c, c)
    if method == "auto":
        method = _choose(system, active)
    if options and method != "events":
        raise ParameterError(
            f"unknown option(s) {sorted(options)} for method {method!r}: only method='events' "
            "takes solver options (rtol, atol, max_steps, rest_velocity)"
        )

    events: tuple[StepEvent, ...] = ()
    y_eq = lam = None
    if method in ("closed_form", "exact"):
        pa = _affine(system, active, method)
        if method == "closed_form":
            if not _is_linear(pa):
                labels = ", ".join(s.label for s in pa.surfaces)
                raise ModelError(
                    f"method 'closed_form' needs a linear system: {_name(system)} switches "
                    f"on {labels}; use method='exact' (piecewise linear) or 'events'"
                )
            reg = next(iter(pa.regions.values()))
            traj, y_eq, lam = _closed_form(reg.A, reg.b, y, float(t[0]))
        else:
            from perturb.simulate.flows.affine_exact import propagate

            run = propagate(pa, y, float(t[0]), float(t[-1]), dense=True, max_events=max_events)
            traj = run.trajectory
            events = tuple(
                StepEvent(
                    float(e.time),
                    "tangency" if e.tangency else "crossing",
                    pa.surfaces[e.surface].label,
                    int(e.direction),
                )
                for e in run.events
            )
        Y = np.asarray(traj(t), dtype=float).T
    else:
        traj, events, Y = _events(system, t, y, active, max_events, options, int(refine))
    if not np.all(np.isfinite(Y)):
        bad = float(t[int(np.argmax(~np.all(np.isfinite(Y), axis=1)))])
        raise PerturbError(
            f"the step response of {system.name!r} overflows at t = {bad!r} (from y0 = "
            f"{y.tolist()}): no finite states to return"
        )
    out_values = {k: _frozen(funcs[k](Y)) for k in table}
    zeros = {}
    for c in cross:
        coarse = funcs[c](Y) if method == "events" else None
        te = [e.time for e in events]
        zeros[c] = _frozen(_zeros(traj, funcs[c], t, int(refine), coarse, te))
    return StepResponse(
        times=_frozen(t),
        states=_frozen(Y),
        state_names=names,
        outputs=MappingProxyType(out_values),
        method=method,
        events=events,
        crossings=MappingProxyType(zeros),
        equilibrium=None if y_eq is None else _frozen(y_eq),
        eigenvalues=None if lam is None else np.array(lam, copy=True),
        trajectory=traj,
    )


def _name(system) -> str:
    return f"system {system.name!r}" if isinstance(system, System) else "the system"


def _choose(system, active) -> str:
    if active is not None and not isinstance(active, Mapping):
        raise ParameterError(f"active = {active!r}: expected a mapping name -> None, -1 or +1")
    act = dict(active or {})
    if isinstance(system, System):
        if any(act.get(s) is None for s in _stops(system)) or not system.is_piecewise_linear:
            return "events"
    pa = _affine(system, active, "auto")
    return "closed_form" if _is_linear(pa) else "exact"
