r"""Event-driven flow of a piecewise-smooth system of several coordinates.

:class:`SystemEventFlow` propagates a :class:`~perturb.model.system.System` (``n`` states
``y = (q, q', p)``) whose elements may switch (PWL springs, gaps, steps, Stribeck friction, any
``Heaviside``/``sign``/``Abs``/``Max``/``Min``/``Piecewise`` of a linear combination) and whose
stops and friction contacts may stick, slide or impact.

Modes
    A *mode* fixes, for every switching element, the segment of its function between two
    breakpoints (the element is then a smooth function: every switch atom is replaced by the
    branch it takes inside the segment, extended analytically beyond it), for every friction
    contact whether it sticks at one of its discontinuities, and for every stop whether it is
    free or resting on its lower / upper limit. In a mode the field is smooth,

    .. math:: y' = \bigl(P_v q',\; P B^{-1} (F(t) - L y
              - \textstyle\sum_e w_e f_{e,\sigma}(c_e\cdot y))\bigr),

    with ``P``, ``P_v`` the constraint projections of the active stops / sticking contacts
    (:meth:`System.constraint_projection <perturb.model.system.System.constraint_projection>`).
    It is integrated by DOP853 (:class:`scipy.integrate.DOP853`, stepped here so that every
    step's dense output is inspected).

Events (guards ``g >= 0`` inside the mode)
    * a switching element's combination reaching the breakpoints bounding its segment;
    * a free stop's combination reaching a limit (impact);
    * a resting stop's free acceleration (the acceleration of its combination were it free)
      turning away from the stop (it lifts off when the constraint force would pull);
    * a sticking contact's Filippov condition failing: with ``a_\pm`` the acceleration of the
      contact's velocity combination under the friction force of the segment above / below the
      discontinuity, sticking lasts while ``a_+ <= 0 <= a_-`` (the force needed to stick lies
      within the friction bounds); when ``a_+`` reaches 0 the contact slips upwards, when
      ``a_-`` does, downwards.

    After every accepted step each guard is sampled on the step's dense output, and for a guard
    linear in the state the rate :math:`\dot g = n\cdot f` at the step ends is compared: a rate
    turning from approaching to receding is a closest approach inside the step, located by
    ``brentq`` on the rate; a guard beyond zero there is a crossing (an orbit that crosses and
    comes back inside one step is never missed). The earliest crossing of the step is located
    by ``brentq`` on the dense output, the state placed on the surface.

Transitions
    * crossing a breakpoint: the next segment; at a friction discontinuity Filippov's rule: if
      the field beyond pushes back the contact sticks (sliding mode, equivalent-control force);
    * impact on a stop with restitution ``e``: the combination's velocity jumps by
      ``-(1 + e)`` times itself, the impulse distributed through the stop's force vector:
      :math:`(q', p)^+ = (I + (1 + e)(P - I))(q', p)^-` with the stop's projection ``P``. With
      ``e = 0``, or a rebound velocity below ``rest_velocity`` (the accumulation of impacts a
      restitution law produces under a pushing load), the stop then rests if its free
      acceleration pushes into it.

Sensitivity
    With ``sensitivity=True`` the variational equations :math:`\Phi' = J_\sigma \Phi` of each
    mode's field are integrated along, and at each transition
    :math:`\Phi \leftarrow S\Phi` with the saltation matrix

    .. math:: S = R + \frac{(f^+ - R f^-)\, n^T}{n^T f^-}

    (``R`` the Jacobian of the state jump: identity except at impacts; ``n`` the guard's
    gradient; ``f^\mp`` the fields before / after). Entering a sticking mode this is the
    projection onto the sliding surface (:math:`n^T f^+ = 0`); lift-off and the end of sticking
    have :math:`f^+ = f^-` (the guard is the normal rate itself) and ``S = I``.

Bounds: ``max_events`` transitions and ``max_steps`` integrator steps per call (default in
proportion to the span); exceeding either raises :class:`EventFlowError` naming the time reached.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import sympy as sp
from numpy.typing import ArrayLike
from scipy.integrate import DOP853
from scipy.optimize import brentq

from perturb.checks import finite, state
from perturb.errors import ModelError, ParameterError, PerturbError
from perturb.model.system import S, System, common_period
from perturb.simulate.flows.base import Flow, FlowResult

__all__ = ["EventFlowError", "SystemEventFlow", "EventLog"]

_SWITCHES = (sp.Heaviside, sp.Max, sp.Min, sp.Abs, sp.sign, sp.Piecewise)
#: nesting depth of switch atoms that the segment analysis unfolds
_MAX_DEPTH = 6
#: steps per forcing period (per 2 pi when autonomous) of the default step budget, and its base
_STEPS_PER_PERIOD, _STEPS_BASE = 20_000, 50_000
_MAX_SPAN = 1e6  # forcing periods (or 2 pi time units) per call without an explicit max_steps
#: relative size of the band around a surface inside which a state counts as on it
_ON_SURFACE = 1e-10


class EventFlowError(PerturbError):
    """The event-driven integration could not continue (budget exhausted, an unsupported
    sliding mode, a state violating a stop)."""


# ------------------------------------------------------------------ element analysis --
def _innermost(expr: sp.Expr) -> list[sp.Basic]:
    return [
        a
        for a in sp.preorder_traversal(expr)
        if isinstance(a, _SWITCHES)
        and not any(isinstance(b, _SWITCHES) for arg in a.args for b in sp.preorder_traversal(arg))
    ]


def _roots(g: sp.Expr, what: str) -> list[float]:
    """Real roots of ``g(s)`` (a polynomial in ``s``)."""
    g = sp.expand(g)
    if not g.has(S):
        return []
    try:
        poly = sp.Poly(g, S)
    except sp.PolynomialError:
        raise ModelError(
            f"{what}: the switch argument {g} is not a polynomial in the combination s; "
            "expected switches of (piecewise) polynomial arguments"
        ) from None
    if poly.degree() == 1:
        a, b = (float(v) for v in poly.all_coeffs())
        return [-b / a]
    return [
        float(r.real)
        for r in np.roots([float(v) for v in poly.all_coeffs()])
        if abs(r.imag) < 1e-12
    ]


def _decisions(atom: sp.Basic) -> list[sp.Expr]:
    if isinstance(atom, sp.Heaviside | sp.sign | sp.Abs):
        return [atom.args[0]]
    if isinstance(atom, sp.Max | sp.Min):
        a = list(atom.args)
        return [a[i] - a[j] for i in range(len(a)) for j in range(i + 1, len(a))]
    out = []
    for _e, cond in atom.args:  # Piecewise
        if isinstance(cond, sp.core.relational.Relational):
            out.append(cond.lhs - cond.rhs)
    return out


def _freeze_atom(atom: sp.Basic, u: float) -> sp.Expr:
    """The branch ``atom`` takes at ``s = u`` (u inside a segment: no ties)."""

    def val(e: sp.Expr) -> float:
        return float(sp.sympify(e).subs(S, u))

    if isinstance(atom, sp.Heaviside):
        return sp.S.One if val(atom.args[0]) > 0 else sp.S.Zero
    if isinstance(atom, sp.sign):
        return sp.S.One if val(atom.args[0]) > 0 else -sp.S.One
    if isinstance(atom, sp.Abs):
        return atom.args[0] if val(atom.args[0]) >= 0 else -atom.args[0]
    if isinstance(atom, sp.Max):
        return max(atom.args, key=val)
    if isinstance(atom, sp.Min):
        return min(atom.args, key=val)
    for e, cond in atom.args:  # Piecewise
        if bool(sp.sympify(cond).subs(S, u)):
            return e
    raise ModelError(f"{atom}: no branch holds at s = {u}")


def _freeze(f: sp.Expr, u: float) -> sp.Expr:
    for _ in range(_MAX_DEPTH + 1):
        atoms = _innermost(f)
        if not atoms:
            return f
        f = f.xreplace({a: _freeze_atom(a, u) for a in atoms})
    raise ModelError(f"{f}: switch atoms nested deeper than {_MAX_DEPTH}")


def _representatives(bps: list[float]) -> list[float]:
    if not bps:
        return [0.0]
    out = [bps[0] - 1.0 - abs(bps[0])]
    out += [0.5 * (a + b) for a, b in zip(bps[:-1], bps[1:], strict=True)]
    out.append(bps[-1] + 1.0 + abs(bps[-1]))
    return out


def _merge(values: list[float]) -> list[float]:
    out: list[float] = []
    for b in sorted(values):
        if out and abs(b - out[-1]) <= 1e-12 * max(1.0, abs(b)):
            continue
        out.append(b)
    return out


def _segments(f: sp.Expr, what: str) -> tuple[list[float], list[sp.Expr]]:
    """Breakpoints of ``f(s)`` and its smooth expression on each segment."""
    bps: list[float] = []
    for _ in range(_MAX_DEPTH + 1):
        found = list(bps)
        for u in _representatives(bps):
            g = f
            # freeze the atoms whose decisions are all known inside this segment, collect the
            # roots of the next layer
            for _layer in range(_MAX_DEPTH + 1):
                atoms = _innermost(g)
                if not atoms:
                    break
                for a in atoms:
                    for d in _decisions(a):
                        found.extend(_roots(d, what))
                g = g.xreplace({a: _freeze_atom(a, u) for a in atoms})
        new = _merge(found)
        if new == bps:
            break
        bps = new
    pieces = [_freeze(f, u) for u in _representatives(bps)]
    # a breakpoint where neither the value nor a derivative changes is not a switch
    keep = []
    for i in range(len(bps)):
        if sp.simplify(pieces[i] - pieces[i + 1]) != 0:
            keep.append(i)
    if len(keep) != len(bps):
        bps = [bps[i] for i in keep]
        pieces = [_freeze(f, u) for u in _representatives(bps)]
    return bps, pieces


def _compile(expr: sp.Expr):
    fn = sp.lambdify([S], expr, modules="math")
    d = sp.lambdify([S], sp.diff(expr, S), modules="math")
    return fn, d


@dataclass
class _Switch:
    name: str
    friction: bool
    c: np.ndarray
    w: np.ndarray
    bps: np.ndarray
    f: list  # per segment: f_i(s)
    df: list  # per segment: f_i'(s)


@dataclass
class _Stop:
    name: str
    cq: np.ndarray  # the position combination on y
    cv: np.ndarray  # the same combination on the velocities
    lower: float
    upper: float
    e: float


@dataclass(frozen=True)
class EventLog:
    """One transition: time, kind (``'cross'``, ``'stick'``, ``'slip'``, ``'impact'``,
    ``'rest'``, ``'lift'``), the element's name and the state after it."""

    t: float
    kind: str
    element: str
    y: np.ndarray


class _Mode:
    """A mode: segments of the switching elements (-1 - j: sticking at breakpoint j) and the
    stops' states (0 free, -1 / +1 resting on the lower / upper limit), with its cached
    projections and guards."""

    __slots__ = ("seg", "stops", "active", "PB", "Pv", "guards")

    def __init__(self, seg: tuple[int, ...], stops: tuple[int, ...]) -> None:
        self.seg, self.stops = seg, stops


# ----------------------------------------------------------------------------- flow --
class SystemEventFlow(Flow):
    r"""Event-driven flow of a piecewise-smooth :class:`~perturb.model.system.System`
    (module docstring: modes, events, sliding, impacts, saltation).

    Parameters
    ----------
    system
        The system, every parameter value set.
    Omega
        Sets the parameter ``Omega`` (forcing frequency) when given.
    rtol, atol
        Tolerances of DOP853 (for the state and, with ``sensitivity``, the variational
        equations).
    max_events
        Most transitions per call.
    max_steps
        Most integrator steps per call (default ``50 000 + 20 000`` per forcing period of the
        span, per ``2 pi`` for an autonomous system).
    rest_velocity
        Rebound speed of a stop's combination below which an impact ends at rest (when the free
        acceleration pushes into the stop); default ``100 atol``.

    Attributes
    ----------
    n_states, period, autonomous, system_model
        Declared for the orbit solvers (``period`` None without forcing).
    events
        The transitions of the last call (:class:`EventLog`), in order.

    Raises
    ------
    ParameterError
        Bad tolerances or budgets, an ``Omega`` for a system without that parameter.
    ModelError
        Free parameters, a switch of a non-polynomial argument.
    """

    def __init__(
        self,
        system: System,
        Omega: float | None = None,
        *,
        rtol: float = 1e-11,
        atol: float = 1e-12,
        max_events: int = 100_000,
        max_steps: int | None = None,
        rest_velocity: float | None = None,
    ) -> None:
        if not isinstance(system, System):
            raise ParameterError(f"system = {system!r}: expected a System")
        if Omega is not None:
            if "Omega" not in system.params:
                raise ParameterError(
                    f"Omega = {Omega!r}: system {system.name!r} has no parameter 'Omega'"
                )
            system = system.with_params(Omega=Omega)
        for name, value in (("rtol", rtol), ("atol", atol)):
            if isinstance(value, bool) or not (isinstance(value, int | float) and 0 < value < 1):
                raise ParameterError(f"{name} = {value!r}: expected a number in (0, 1)")
        if isinstance(max_events, bool) or not isinstance(max_events, int) or max_events < 1:
            raise ParameterError(f"max_events = {max_events!r}: expected an integer >= 1")
        if max_steps is not None and (
            isinstance(max_steps, bool) or not isinstance(max_steps, int) or max_steps < 1
        ):
            raise ParameterError(f"max_steps = {max_steps!r}: expected an integer >= 1 or None")
        self.system_model = system
        self.rtol, self.atol = float(rtol), float(atol)
        self.max_events, self.max_steps = max_events, max_steps
        self.rest_velocity = (
            100.0 * self.atol if rest_velocity is None else finite(rest_velocity, "rest_velocity")
        )
        if not (math.isfinite(self.rest_velocity) and self.rest_velocity >= 0):
            raise ParameterError(f"rest_velocity = {rest_velocity!r}: expected a number >= 0")
        num = system.numeric_form()
        self.n_states = n = int(system.n)
        self._n2 = n2 = int(num["n2"])
        self._Binv = np.asarray(num["Binv"], dtype=float)
        self._L = np.asarray(num["L"], dtype=float)
        self._harm = [(float(om), np.asarray(u), np.asarray(v)) for om, u, v in num["harmonics"]]
        self.period = common_period([om for om, _, _ in self._harm if om != 0.0])
        vals = num["vals"]
        self._switches: list[_Switch] = []
        self._smooth: list[tuple[np.ndarray, np.ndarray, Any, Any]] = []
        self._loose: list[tuple[np.ndarray, Any, Any]] = []
        self._stops: list[_Stop] = []
        for e in system.elements:
            c, w = num["comb"][e.name]
            if e.kind == "stop":
                cq = np.asarray(c, dtype=float)
                if np.any(cq[n2:]):
                    raise ModelError(f"stop {e.name!r}: expected a combination of positions only")
                cv = np.zeros(n)
                cv[n2 : 2 * n2] = cq[:n2]
                lo, hi = (float(sp.sympify(v).xreplace(vals)) for v in e.limits)
                if not lo < hi:
                    raise ModelError(
                        f"stop {e.name!r}: limits ({lo}, {hi}); expected lower < upper"
                    )
                self._stops.append(_Stop(e.name, cq, cv, lo, hi, float(e.restitution)))
                continue
            f = sp.sympify(e.function).xreplace(vals)
            if e.combination is None:
                states = list(system.states)
                fn = sp.lambdify(states, f, modules="math")
                grad = sp.lambdify(states, [sp.diff(f, s) for s in states], modules="math")
                self._loose.append((np.asarray(w, float), fn, grad))
                continue
            c = np.asarray(c, dtype=float)
            w = np.asarray(w, dtype=float)
            if e.kind == "smooth" or not any(
                isinstance(a, _SWITCHES) for a in sp.preorder_traversal(f)
            ):
                fn, d = _compile(f)
                self._smooth.append((c, w, fn, d))
                continue
            bps, pieces = _segments(f, f"element {e.name!r}")
            if not bps:
                fn, d = _compile(pieces[0])
                self._smooth.append((c, w, fn, d))
                continue
            comp = [_compile(p) for p in pieces]
            if (
                e.kind == "friction"
                and np.any(c[:n2])
                or (e.kind == "friction" and np.any(c[2 * n2 :]))
            ):
                raise ModelError(
                    f"friction element {e.name!r}: expected a combination of velocities of "
                    "second-order coordinates"
                )
            self._switches.append(
                _Switch(
                    e.name,
                    e.kind == "friction",
                    c,
                    w,
                    np.array(bps),
                    [p[0] for p in comp],
                    [p[1] for p in comp],
                )
            )
        self._modes: dict[tuple, _Mode] = {}
        self._proj: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}
        self.events: tuple[EventLog, ...] = ()

    # ------------------------------------------------------------------- basics --
    @property
    def autonomous(self) -> bool:
        return self.period is None

    def __repr__(self) -> str:
        return (
            f"SystemEventFlow({self.system_model.name}, n={self.n_states}, "
            f"switches={len(self._switches)}, stops={len(self._stops)}, period={self.period}, "
            f"rtol={self.rtol:g})"
        )

    def _forcing(self, t: float) -> np.ndarray:
        out = np.zeros(self._L.shape[0])
        for om, u, v in self._harm:
            out = out + (u * math.cos(om * t) + v * math.sin(om * t) if om else u)
        return out

    def _mode(self, seg: tuple[int, ...], stops: tuple[int, ...]) -> _Mode:
        key = (seg, stops)
        m = self._modes.get(key)
        if m is not None:
            return m
        m = _Mode(seg, stops)
        active: dict[str, int] = {}
        for sw, s in zip(self._switches, seg, strict=True):
            if s < 0:
                active[sw.name] = 1
        for st, s in zip(self._stops, stops, strict=True):
            if s:
                active[st.name] = s
        m.active = active
        pkey = tuple(sorted(active.items()))
        if pkey not in self._proj:
            P, Pv = self.system_model.constraint_projection(active)
            self._proj[pkey] = (P @ self._Binv, np.asarray(Pv, dtype=float))
        m.PB, m.Pv = self._proj[pkey]
        m.guards = self._build_guards(m)
        if len(self._modes) < 4096:
            self._modes[key] = m
        return m

    def _rhs(self, t: float, y: np.ndarray, mode: _Mode) -> np.ndarray:
        r = self._forcing(t) - self._L @ y
        for sw, s in zip(self._switches, mode.seg, strict=True):
            if s >= 0:
                r -= sw.w * sw.f[s](float(sw.c @ y))
        for c, w, fn, _d in self._smooth:
            r -= w * fn(float(c @ y))
        for w, fn, _g in self._loose:
            r -= w * fn(*y)
        return r

    def _field(self, t: float, y: np.ndarray, mode: _Mode) -> np.ndarray:
        n2 = self._n2
        return np.concatenate([mode.Pv @ y[n2 : 2 * n2], mode.PB @ self._rhs(t, y, mode)])

    def _jac(self, t: float, y: np.ndarray, mode: _Mode) -> np.ndarray:
        n, n2 = self.n_states, self._n2
        dr = -self._L.copy()
        for sw, s in zip(self._switches, mode.seg, strict=True):
            if s >= 0:
                dr -= np.outer(sw.w, sw.df[s](float(sw.c @ y)) * sw.c)
        for c, w, _fn, d in self._smooth:
            dr -= np.outer(w, d(float(c @ y)) * c)
        for w, _fn, g in self._loose:
            dr -= np.outer(w, np.asarray(g(*y), dtype=float))
        J = np.zeros((n, n))
        J[:n2, n2 : 2 * n2] = mode.Pv
        J[n2:, :] = mode.PB @ dr
        return J

    def _with(
        self,
        mode: _Mode,
        k: int | None = None,
        seg: int = 0,
        stop: int | None = None,
        side: int = 0,
    ) -> _Mode:
        s = list(mode.seg)
        st = list(mode.stops)
        if k is not None:
            s[k] = seg
        if stop is not None:
            st[stop] = side
        return self._mode(tuple(s), tuple(st))

    # -------------------------------------------------------------------- guards --
    def _build_guards(self, m: _Mode) -> list[tuple]:
        """Guards of mode ``m``: ``('lin', normal, offset, what)`` with ``g = normal . y -
        offset`` and ``('fun', callable(t, y), (normal, mode), what)`` (the rate of ``normal``
        in the hypothetical ``mode``, for its tolerance); ``what`` is the transition."""
        out: list[tuple] = []
        for k, (sw, s) in enumerate(zip(self._switches, m.seg, strict=True)):
            if s >= 0:
                if s > 0:
                    out.append(("lin", sw.c, float(sw.bps[s - 1]), ("down", k)))
                if s < len(sw.bps):
                    out.append(("lin", -sw.c, -float(sw.bps[s]), ("up", k)))
            else:
                j = -1 - s
                up, down = self._with(m, k, j + 1), self._with(m, k, j)
                c = sw.c

                def g_up(t, y, c=c, up=up):  # stay while a+ <= 0
                    return -float(c @ self._field(t, y, up))

                def g_down(t, y, c=c, down=down):  # stay while a- >= 0
                    return float(c @ self._field(t, y, down))

                out.append(("fun", g_up, (c, up), ("slip", k, j + 1)))
                out.append(("fun", g_down, (c, down), ("slip", k, j)))
        for i, (st, s) in enumerate(zip(self._stops, m.stops, strict=True)):
            if s == 0:
                if math.isfinite(st.lower):
                    out.append(("lin", st.cq, st.lower, ("impact", i, -1)))
                if math.isfinite(st.upper):
                    out.append(("lin", -st.cq, -st.upper, ("impact", i, 1)))
            else:
                free = self._with(m, stop=i, side=0)

                def g_lift(t, y, cv=st.cv, free=free, s=s):  # stay while pushed into the stop
                    return s * float(cv @ self._field(t, y, free))

                out.append(("fun", g_lift, (st.cv, free), ("lift", i)))
        return out

    def _guard_values(self, guards, t, y) -> np.ndarray:
        return np.array(
            [float(g[1] @ y) - g[2] if g[0] == "lin" else g[1](t, y) for g in guards], dtype=float
        )

    def _guard_tol(self, guards, t, y, f) -> np.ndarray:
        out = np.empty(len(guards))
        for i, g in enumerate(guards):
            if g[0] == "lin":
                out[i] = _ON_SURFACE * (float(np.abs(g[1]) @ np.abs(y)) + abs(g[2])) + 1e-300
            else:  # the size of the terms of the normal rate it compares
                normal, hyp = g[2]
                scale = float(np.abs(normal) @ np.abs(self._field(t, y, hyp)))
                out[i] = 1e-9 * scale + 1e-300
        return out

    # ------------------------------------------------------------ classification --
    def _classify(self, t: float, y: np.ndarray) -> tuple[_Mode, np.ndarray, list]:
        """The mode of a state (no history): segment of each switching element (on a
        breakpoint: the side the field goes to, Filippov sticking for friction), each stop free
        or resting. Returns the mode, the state (placed on surfaces it touches) and pending
        impacts ``[(stop index, side)]`` (a state on a stop moving into it)."""
        y = y.copy()
        seg = []
        ties = []
        for k, sw in enumerate(self._switches):
            s = float(sw.c @ y)
            i = bisect.bisect_right(sw.bps.tolist(), s)
            scale = _ON_SURFACE * (float(np.abs(sw.c) @ np.abs(y)) + 1e-300)
            j = None
            if i > 0 and abs(s - sw.bps[i - 1]) <= scale:
                j = i - 1
            elif i < len(sw.bps) and abs(s - sw.bps[i]) <= scale:
                j = i
            seg.append(i)
            if j is not None:
                ties.append((k, j))
        stops = []
        pending = []
        for i, st in enumerate(self._stops):
            p = float(st.cq @ y)
            v = float(st.cv @ y)
            width = st.upper - st.lower
            tol = _ON_SURFACE * (float(np.abs(st.cq) @ np.abs(y)) + abs(st.lower) + abs(st.upper))
            tol = max(tol, 1e-12 * width if math.isfinite(width) else tol)
            if p < st.lower - tol or p > st.upper + tol:
                raise EventFlowError(
                    f"the state {y.tolist()} violates the stop {st.name!r} "
                    f"({st.lower} <= {p!r} <= {st.upper} expected)"
                )
            side = -1 if p <= st.lower + tol else 1 if p >= st.upper - tol else 0
            stops.append(0)
            if side:
                y = y + st.cq * ((st.lower if side < 0 else st.upper) - p) / float(st.cq @ st.cq)
                # (side * v > 0: moving into the stop)
                if side * v < -self.rest_velocity:
                    continue  # leaving the stop
                pending.append((i, side))  # an impact, or at rest: decided by the caller
        mode = self._mode(tuple(seg), tuple(stops))
        for k, j in ties:
            sw = self._switches[k]
            s = float(sw.c @ y)
            y = y + sw.c * (float(sw.bps[j]) - s) / float(sw.c @ sw.c)
            below, above = self._with(mode, k, j), self._with(mode, k, j + 1)
            r_lo = float(sw.c @ self._field(t, y, below))
            r_hi = float(sw.c @ self._field(t, y, above))
            if r_hi > 0 or (r_hi >= 0 and r_lo >= 0):
                mode = above
            elif r_lo < 0:
                mode = below
            elif sw.friction:
                mode = self._with(mode, k, -1 - j)
            else:
                raise EventFlowError(
                    f"element {sw.name!r} at t = {t!r}: the field on both sides of its "
                    f"breakpoint {float(sw.bps[j])!r} points into it (a sliding mode); sliding "
                    "is supported on friction contacts only (declare the element as friction)"
                )
        return mode, y, pending

    # ------------------------------------------------------------ public interface --
    def vector_field(self, t: float, y: ArrayLike) -> np.ndarray:
        """The field of the mode of ``y`` at ``t`` (the mode decided from the state alone)."""
        yy = np.asarray(y, dtype=float).reshape(-1)
        mode, yy, pending = self._classify(float(t), yy)
        for i, side in pending:
            mode, yy = self._settle_stop(float(t), yy, mode, i, side)
        return self._field(float(t), yy, mode)

    def jacobian(self, t: float, y: ArrayLike) -> np.ndarray:
        """``df/dy`` of the mode of ``y`` at ``t``."""
        yy = np.asarray(y, dtype=float).reshape(-1)
        mode, yy, pending = self._classify(float(t), yy)
        for i, side in pending:
            mode, yy = self._settle_stop(float(t), yy, mode, i, side)
        return self._jac(float(t), yy, mode)

    def _settle_stop(self, t, y, mode, i, side):
        """A state on stop ``i`` without (significant) velocity into it: rest if the free
        acceleration pushes into the stop, else stay free."""
        st = self._stops[i]
        free = self._with(mode, stop=i, side=0)
        v = float(st.cv @ y)
        if side * v < -self.rest_velocity:
            return free, y
        if self._pushed(t, y, free, i, side):
            y = y - st.cv * v / float(st.cv @ st.cv)
            return self._with(mode, stop=i, side=side), y
        return free, y

    def _pushed(self, t, y, free, i, side) -> bool:
        """Whether the free acceleration of stop ``i``'s combination pushes into it (or
        vanishes, to rounding: then the stop rests and its lift-off guard decides)."""
        st = self._stops[i]
        f = self._field(t, y, free)
        a = float(st.cv @ f)
        return side * a >= -1e-12 * float(np.abs(st.cv) @ np.abs(f))

    def __call__(
        self,
        y0: ArrayLike,
        t0: float,
        t1: float,
        *,
        sensitivity: bool = False,
        t_eval: ArrayLike | None = None,
    ) -> FlowResult:
        """Propagate ``y0`` from ``t0`` to ``t1 > t0`` (see
        :class:`~perturb.simulate.flows.base.Flow`); ``sensitivity`` adds ``dy(t1)/dy(t0)``
        with saltation matrices. The transitions met are in :attr:`events`.

        Raises
        ------
        ParameterError
            Bad ``y0``, interval or ``t_eval``.
        EventFlowError
            The step or event budget ran out, an unsupported sliding mode, a state violating a
            stop, a failed integration.
        """
        y = state(y0, self.n_states)
        try:
            t0, t1 = float(t0), float(t1)
        except (TypeError, ValueError):
            raise ParameterError(f"(t0, t1) = ({t0!r}, {t1!r}): expected numbers") from None
        if not (math.isfinite(t0) and math.isfinite(t1) and t1 > t0):
            raise ParameterError(f"(t0, t1) = ({t0}, {t1}): expected finite t1 > t0")
        te = None
        if t_eval is not None:
            try:
                te = np.asarray(t_eval, dtype=float).reshape(-1)
            except (TypeError, ValueError):
                raise ParameterError(f"t_eval = {t_eval!r}: expected numbers") from None
            if te.size and (
                not np.all(np.isfinite(te)) or np.any(np.diff(te) < 0) or te[0] < t0 or te[-1] > t1
            ):
                raise ParameterError(f"t_eval: expected sorted finite times within [{t0}, {t1}]")
        return self._run(y, t0, t1, sensitivity, te)

    # ------------------------------------------------------------------ the loop --
    def _budget(self, t0: float, t1: float) -> int:
        if self.max_steps is not None:
            return self.max_steps
        span = (t1 - t0) / (self.period if self.period else 2.0 * math.pi)
        if span > _MAX_SPAN:
            # the budget would allow ~1e10 steps: hours of work, not a bound
            unit = "forcing periods" if self.period else "time units of 2 pi"
            raise ParameterError(
                f"t1 - t0 = {t1 - t0!r}: at most {_MAX_SPAN:g} {unit} per call (pass "
                "max_steps= to take longer spans on purpose)"
            )
        return int(_STEPS_BASE + _STEPS_PER_PERIOD * span)

    def _run(self, y, t0, t1, sens, te) -> FlowResult:
        n = self.n_states
        log: list[EventLog] = []
        Phi = np.eye(n) if sens else None
        t = t0
        mode, y, pending = self._classify(t, y)
        for i, side in pending:
            v = float(self._stops[i].cv @ y)
            if side * v > self.rest_velocity:
                mode, y, Phi = self._impact(t, y, mode, i, side, Phi, log)
            else:
                mode, y = self._settle_stop(t, y, mode, i, side)
        out_t: list[float] = []
        out_y: list[np.ndarray] = []
        k_out = 0
        if te is not None:
            while k_out < te.size and te[k_out] <= t0:
                out_t.append(float(te[k_out]))
                out_y.append(y.copy())
                k_out += 1
        budget = self._budget(t0, t1)
        steps = 0
        n_events = 0
        while t < t1:
            guards = mode.guards

            def fun(tt, z, mode=mode):
                if not sens:
                    return self._field(tt, z, mode)
                yy = z[:n]
                ph = z[n:].reshape(n, n)
                return np.concatenate(
                    [self._field(tt, yy, mode), (self._jac(tt, yy, mode) @ ph).ravel()]
                )

            z0 = np.concatenate([y, Phi.ravel()]) if sens else y.copy()
            solver = DOP853(fun, t, z0, t1, rtol=self.rtol, atol=self.atol)
            f0 = self._field(t, y, mode)
            g_prev = self._guard_values(guards, t, y)
            tol_g = self._guard_tol(guards, t, y, f0)
            armed = g_prev > tol_g
            rate_prev = np.array([float(g[1] @ f0) if g[0] == "lin" else 0.0 for g in guards])
            event = None
            while True:
                if steps >= budget:
                    raise EventFlowError(
                        f"{self.system_model.name!r}: {budget} integration steps on [{t0}, {t1}] "
                        f"reached t = {solver.t!r} without finishing (mode {mode.active or 'free'}"
                        "): raise max_steps, or the motion chatters at a switching surface"
                    )
                t_old, z_old = solver.t, solver.y.copy()
                msg = solver.step()
                steps += 1
                if solver.status == "failed" or not np.all(np.isfinite(solver.y)):
                    raise EventFlowError(
                        f"{self.system_model.name!r}: integration failed at t = {t_old!r} "
                        f"(mode {mode.active or 'free'}): {msg}"
                    )
                t_new = solver.t
                if t_new == t_old:
                    continue
                dense = solver.dense_output()
                y_new = solver.y[:n]
                event = self._find_event(
                    guards, dense, t_old, z_old[:n], t_new, y_new, armed, tol_g, rate_prev, mode
                )
                t_end = t_new if event is None else event[0]
                if te is not None:
                    while k_out < te.size and te[k_out] <= t_end:
                        out_t.append(float(te[k_out]))
                        out_y.append(np.asarray(dense(te[k_out]))[:n].copy())
                        k_out += 1
                if event is not None:
                    break
                g_now = self._guard_values(guards, t_new, y_new)
                armed |= g_now > tol_g
                f_new = self._field(t_new, y_new, mode)
                rate_prev = np.array(
                    [float(g[1] @ f_new) if g[0] == "lin" else 0.0 for g in guards]
                )
                if solver.status == "finished":
                    break
            if event is None:
                t = solver.t
                y = solver.y[:n].copy()
                if sens:
                    Phi = solver.y[n:].reshape(n, n).copy()
                break
            n_events += 1
            if n_events > self.max_events:
                raise EventFlowError(
                    f"{self.system_model.name!r}: more than {self.max_events} transitions on "
                    f"[{t0}, {t1}] (reached t = {event[0]!r}): an accumulation of events "
                    "(chattering impacts, a Zeno point); raise max_events or rest_velocity"
                )
            t_ev, z_ev, idx = event
            y = z_ev[:n].copy()
            if sens:
                Phi = z_ev[n:].reshape(n, n).copy()
            mode, y, Phi = self._transition(t_ev, y, mode, guards[idx], Phi, log)
            t = t_ev
        self.events = tuple(log)
        res_t = res_y = None
        if te is not None:
            res_t = np.array(out_t)
            res_y = np.array(out_y).reshape(-1, n)
        return FlowResult(
            t0=t0,
            t1=t1,
            y=y,
            sensitivity=Phi,
            t=res_t,
            ys=res_y,
            n_events=n_events,
        )

    def _find_event(self, guards, dense, t_old, y_old, t_new, y_new, armed, tol_g, rate_prev, mode):
        """The earliest guard crossing in the step ``[t_old, t_new]``: ``(t, z, index)``."""
        if not guards:
            return None
        n = self.n_states
        best = None
        fr = np.array([0.25, 0.5, 0.75, 1.0])
        ts = t_old + fr * (t_new - t_old)
        ts[-1] = t_new
        Z = np.asarray(dense(ts))
        Y = Z[:n]
        f_new = None
        for i, g in enumerate(guards):
            thr = 0.0 if armed[i] else -tol_g[i]

            def gval(tt, i=i, g=g):
                yy = np.asarray(dense(tt))[:n]
                return float(g[1] @ yy) - g[2] if g[0] == "lin" else g[1](tt, yy)

            if g[0] == "lin":
                vals = g[1] @ Y - g[2]
            else:
                vals = np.array([g[1](tt, Y[:, j]) for j, tt in enumerate(ts)])
            hit = np.flatnonzero(vals < thr)
            grid = [t_old, *ts.tolist()]
            gv = [gval(t_old), *vals.tolist()]
            if hit.size:
                j = int(hit[0]) + 1
                grid, gv = grid[: j + 1], gv[: j + 1]
            elif g[0] == "lin" and rate_prev[i] < 0:
                if f_new is None:
                    f_new = self._field(t_new, y_new, mode)
                if float(g[1] @ f_new) <= 0:
                    continue
                # closest approach inside the step: the rate's root, beyond the surface?

                def rate(tt, g=g):
                    yy = np.asarray(dense(tt))[:n]
                    return float(g[1] @ self._field(tt, yy, mode))

                try:
                    tm = brentq(rate, t_old, t_new, xtol=1e-15 * max(1.0, abs(t_new)), maxiter=200)
                except ValueError:
                    continue
                gm = gval(tm)
                if gm >= thr:
                    continue
                keep = [q for q, tq in enumerate(grid) if tq < tm]
                grid = [grid[q] for q in keep] + [tm]
                gv = [gv[q] for q in keep] + [gm]
            else:
                continue
            if best is not None and grid[0] >= best[0]:
                continue
            # the crossing of g = 0 itself (the band thr only decides that one happened): the
            # first sample below 0 and the one before it
            # (a disarmed guard starts on its surface, maybe a rounding error beyond it: zero
            # is then its starting value)
            base = min(gv[0], 0.0) if not armed[i] and gv[0] >= thr else 0.0
            q = next(q for q, v in enumerate(gv) if v < base)
            if q == 0:  # already beyond by more than the band: the crossing is at once
                tc = t_old
            else:
                lo, hi = grid[q - 1], grid[q]
                if q == 1 and not armed[i]:
                    # leaving the surface and coming back: bracket from the excursion's top
                    lo = self._excursion_top(g, gval, dense, lo, hi, mode)
                if gval(lo) - base <= 0.0:
                    tc = t_old
                    if best is None or tc < best[0]:
                        best = (tc, i)
                    continue
                tc = brentq(
                    lambda tt, base=base: gval(tt) - base,
                    lo,
                    hi,
                    xtol=1e-15 * max(1.0, abs(hi)),
                    maxiter=200,
                )
            if best is None or tc < best[0]:
                best = (tc, i)
        if best is None:
            return None
        tc, i = best
        return tc, np.asarray(dense(tc)).copy(), i

    def _excursion_top(self, g, gval, dense, lo, hi, mode) -> float:
        """The time of the largest ``g`` in ``[lo, hi]`` for a guard that starts on its
        surface and ends beyond it: the root of its rate for a linear guard, else the best of
        32 samples."""
        n = self.n_states
        if g[0] == "lin":

            def rate(tt):
                yy = np.asarray(dense(tt))[:n]
                return float(g[1] @ self._field(tt, yy, mode))

            if rate(lo) > 0.0 > rate(hi):
                return float(brentq(rate, lo, hi, xtol=1e-15 * max(1.0, abs(hi)), maxiter=200))
            return lo
        ts = np.linspace(lo, hi, 33)
        vals = [gval(tt) for tt in ts]
        return float(ts[int(np.argmax(vals))])

    # --------------------------------------------------------------- transitions --
    def _salt(self, Phi, R, f_minus, f_plus, normal):
        den = float(normal @ f_minus)
        if Phi is None:
            return None
        if den == 0.0:
            raise EventFlowError(
                "a transition with zero normal rate (a grazing contact): the saltation matrix "
                "is undefined there"
            )
        S = R + np.outer(f_plus - R @ f_minus, normal) / den
        return S @ Phi

    def _transition(self, t, y, mode, guard, Phi, log):
        what = guard[-1]
        kind = what[0]
        n = self.n_states
        eye = np.eye(n)
        if kind in ("up", "down"):
            k = what[1]
            sw = self._switches[k]
            cur = mode.seg[k]
            j = cur if kind == "up" else cur - 1  # the breakpoint crossed
            y = y + sw.c * (float(sw.bps[j]) - float(sw.c @ y)) / float(sw.c @ sw.c)
            f_minus = self._field(t, y, mode)
            new = self._with(mode, k, j + 1 if kind == "up" else j)
            r_new = float(sw.c @ self._field(t, y, new))
            sign = 1.0 if kind == "up" else -1.0
            if sign * r_new > 0 or not sw.friction and sign * r_new >= 0:
                target, label = new, "cross"
            elif sw.friction:
                target, label = self._with(mode, k, -1 - j), "stick"
            else:
                raise EventFlowError(
                    f"element {sw.name!r} at t = {t!r}: the field beyond its breakpoint "
                    f"{float(sw.bps[j])!r} points back (a sliding mode); sliding is supported on "
                    "friction contacts only"
                )
            Phi = self._salt(Phi, eye, f_minus, self._field(t, y, target), sw.c)
            log.append(EventLog(t, label, sw.name, y.copy()))
            return target, y, Phi
        if kind == "slip":
            k, new_seg = what[1], what[2]
            target = self._with(mode, k, new_seg)
            log.append(EventLog(t, "slip", self._switches[k].name, y.copy()))
            return target, y, Phi  # f+ = f- at the end of sticking: S = I
        if kind == "lift":
            i = what[1]
            log.append(EventLog(t, "lift", self._stops[i].name, y.copy()))
            return self._with(mode, stop=i, side=0), y, Phi
        if kind == "impact":
            return self._impact(t, y, mode, what[1], what[2], Phi, log)
        raise AssertionError(kind)  # pragma: no cover

    def _impact(self, t, y, mode, i, side, Phi, log):
        st = self._stops[i]
        n, n2 = self.n_states, self._n2
        limit = st.lower if side < 0 else st.upper
        y = y + st.cq * (limit - float(st.cq @ y)) / float(st.cq @ st.cq)
        f_minus = self._field(t, y, mode)
        key = ("impact", st.name, side)
        if key not in self._proj:
            P, _ = self.system_model.constraint_projection({st.name: side})
            self._proj[key] = (np.asarray(P, dtype=float), np.empty(0))
        P = self._proj[key][0]
        R = np.eye(n)
        R[n2:, n2:] = np.eye(n - n2) + (1.0 + st.e) * (P - np.eye(n - n2))
        y_plus = R @ y
        v = float(st.cv @ y_plus)
        free = self._with(mode, stop=i, side=0)
        target, label = free, "impact"
        if st.e == 0.0 or abs(v) <= self.rest_velocity:
            y_plus = y_plus - st.cv * v / float(st.cv @ st.cv)
            if self._pushed(t, y_plus, free, i, side):
                target, label = self._with(mode, stop=i, side=side), "rest"
        Phi = self._salt(Phi, R, f_minus, self._field(t, y_plus, target), st.cq)
        log.append(EventLog(t, label, st.name, y_plus.copy()))
        return target, y_plus, Phi
