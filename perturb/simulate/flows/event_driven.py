r"""Event-driven integration of piecewise-smooth oscillators, with Filippov sliding.

The oscillator ``x'' + g(x, x', t) = f(t)`` may mix smooth terms (polynomials, ``sin x``,
parametric ``cos(2t) x``) with *switch functions* — ``Heaviside``, ``sign``, ``Abs``, ``Max``,
``Min``, ``Piecewise`` — whose arguments (or argument differences, or relational conditions)
are linear in the state.  With :math:`y = (x, v)`, :math:`v = x'`, the first-order system is
:math:`y' = f_\sigma(t, y) = (v,\ a_\sigma(t, x, v))`.

Switching surfaces and modes
----------------------------
Every switch decision is a linear function :math:`h_j(y) = a_j x + b_j v + c_j` (scaled so that
:math:`\max(|a_j|, |b_j|) = 1`, oriented so the first non-zero of :math:`(a_j, b_j)` is
positive; equal decisions share one surface).  A *mode* is a sign vector
:math:`\sigma \in \{-1, +1\}^m`; in a mode every switch function is *frozen* at the value it
takes where :math:`\operatorname{sign} h_j = \sigma_j` (``sign`` becomes :math:`\pm 1`,
``Heaviside`` 0 or 1, ``Abs(h)`` :math:`\pm h`, ``Max``/``Min`` the winning argument,
``Piecewise`` the first true branch).  The frozen field :math:`a_\sigma` is smooth (analytic
in the state), so the integrator's trial stages may overshoot a surface harmlessly; it is
compiled once per mode and cached.  Nested switches (``Max(-d, Min(d, x))``) are frozen from
the inside out; a surface is *active* in a mode when a switch decision reads it.

Integration
-----------
In a mode the frozen field is integrated by Chebyshev collocation steps
(:mod:`perturb.simulate.flows.spectral`, ``integrator="chebyshev"``, the default): each step is
one polynomial of degree 24 found by Newton's method, accepted on the decay of its Chebyshev
coefficients (the error estimate, at ``rtol``/``atol``), with the sensitivity from the same
factorised Jacobian.  Every active surface is sampled on ``2N + 1`` points of each step with
its rate :math:`\dot h_j`: a sample beyond the surface is a crossing (root refined on the
polynomial), a turn of :math:`\dot h_j` from approaching to receding a closest approach,
refined on the polynomial when it could reach the surface (beyond it: a crossing at the zero
before it; within the graze depth below: a graze; inside: nothing).  A field that does not
evaluate on arrays, a step length that collapses, sliding segments and
``integrator="dop853"`` use :func:`scipy.integrate.solve_ivp` (DOP853) instead, with two
terminal events per active surface: :math:`h_j` with direction :math:`-\sigma_j` (only exits
count), and
:math:`\dot h_j = n^T f_\sigma` at a *closest approach* (:math:`\dot h_j` turning from
approaching to receding).  ``solve_ivp`` only compares event signs at step ends, so an orbit
that crosses and comes back inside one step is invisible to the first event; at its closest
approach :math:`h_j` is then beyond zero and the crossing is found by integrating the same
smooth field backwards.  A closest approach still inside just restarts the segment.  At a
crossing (located by ``solve_ivp`` to a few ulps of time on the dense output) the state is
projected onto the surface and classified with the *normal speeds* :math:`w = n^T f` of the
two neighbouring fields, :math:`n = \nabla h_j = (a_j, b_j)`:

* ``cross``: both fields carry the orbit through — restart in the new mode;
* ``stick``: the field on the far side points back into the surface (attracting sliding
  region, possible only when :math:`b_j \neq 0`) — switch to the Filippov sliding mode;
* ``graze``: the orbit touches the surface and turns back: zero normal speed to rounding, or
  an excursion :math:`w^2/(2|\ddot h|)` beyond the surface shallower than 10 local errors
  (``atol + rtol |h terms|``), i.e. not resolved by the integration — the mode is *not*
  toggled.

The surface just left is masked at the restart instant (its event function returns the inside
sign there), so a restart exactly on the surface is never mistaken for a new crossing, while
a genuine quick return is still found inside the first step.  Signs of surfaces a mode does
not read are refreshed from the state at every restart.

Filippov sliding
----------------
On :math:`h_j = 0` with :math:`n^T f^- > 0 > n^T f^+` (:math:`f^\pm` the fields of the modes
with :math:`\sigma_j = \pm 1`) the motion follows the convex combination
:math:`f_s = (1-\lambda) f^- + \lambda f^+`, :math:`\lambda = n^T f^-/(n^T f^- - n^T f^+)`;
for ``sign(h)`` this is the equivalent control :math:`u = 2\lambda - 1 \in [-1, 1]`.  Because
both fields have first component :math:`v`, :math:`f_s` keeps the orbit on the surface:
:math:`v = -(a_j x + c_j)/b_j` and :math:`x' = -(a_j x + c_j)/b_j`, a scalar linear ODE that is
integrated as such (for Coulomb friction, :math:`h = v`, this is *sticking*: :math:`v = 0` and
:math:`x` constant, both exactly).  The sliding mode ends when :math:`u` leaves
:math:`[-1, 1]`, i.e. when :math:`n^T f^-` falls to 0 (the orbit leaves into
:math:`h_j < 0`) or :math:`n^T f^+` rises to 0 (into :math:`h_j > 0`); both are events of the
sliding segment, as are crossings of the other active surfaces (which only change the exit
conditions).  An orbit reaching a *repelling* sliding region (:math:`n^T f^- < 0 < n^T f^+`)
has no unique continuation and raises :class:`~perturb.errors.PerturbError`; so does sliding
on two surfaces at once (codimension 2), e.g. a relay ``sign(x)`` held at ``x = x' = 0``.

Sensitivity (monodromy)
-----------------------
Inside a mode the variational equation :math:`\Phi' = J_\sigma(t, y)\Phi`,
:math:`J_\sigma = \begin{pmatrix}0 & 1\\ \partial_x a_\sigma & \partial_v a_\sigma
\end{pmatrix}`, is integrated with the state.  At a transversal crossing at :math:`t_e`,
:math:`\Phi \leftarrow S\Phi` with the saltation matrix

.. math::

    S = I + \frac{(f_{\text{after}} - f_{\text{before}})\, n^T}{n^T f_{\text{before}}},

which is :math:`I` when the field is continuous (kinks of a PWL force).  Entering a sliding
mode uses the same formula with :math:`f_{\text{after}} = f_s`; it simplifies to
:math:`S = I + (f^+ - f^-) n^T / (n^T f^- - n^T f^+)`, the same from either side, and
:math:`n^T S = 0`: perturbations are projected onto the surface.  During sliding
:math:`\delta x' = s\,\delta x`, :math:`\delta v = s\,\delta x` with
:math:`s = -a_j/b_j`, so :math:`\Phi \leftarrow \begin{pmatrix} e^{s\tau} & 0\\
s e^{s\tau} & 0\end{pmatrix}\Phi`; for sticking (:math:`h = v`) this is
:math:`\operatorname{diag}(1, 0)`: **the sensitivity of v is reset to zero and that of x is
frozen**.  Leaving a sliding mode is tangential (:math:`f_s = f^\mp` at the exit point), so
its saltation is :math:`I`.  At a graze the saltation of a discontinuous field is singular
(square-root map); it is not applied (sensitivities are then unreliable, as for any
method).  A start on an attracting sliding surface applies the entry projection at ``t0``.

Limitations
-----------
Switching arguments must be linear in :math:`(x, x')` and free of time (``sign(x - cos t)``
raises :class:`~perturb.errors.ModelError`); coefficients of switch functions may depend on
time.  ``DiracDelta`` is rejected.  Sliding is codimension 1 only.  An excursion in which
:math:`\dot h` changes sign twice inside one integrator step is not seen.  Near grazing the
crossing time inherits position errors amplified by :math:`1/|w|` (the square-root
sensitivity of grazing, not a defect of the method).
"""

from __future__ import annotations

import copy
import itertools
import math
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
import sympy as sp
from numpy.typing import ArrayLike
from scipy.integrate import solve_ivp
from sympy.core.relational import Relational
from sympy.logic.boolalg import BooleanFalse, BooleanTrue

from perturb.errors import ModelError, ParameterError, PerturbError
from perturb.model.oscillator import Oscillator, validate_parameter_value
from perturb.simulate.flows.base import Flow, FlowResult
from perturb.simulate.flows.spectral import (
    ChebyshevStep,
    Chunk,
    chebyshev_rule,
    interpolation_matrix,
    interpolation_row,
)
from perturb.simulate.flows.system import first_order_rhs, forcing_period_expr, parameter_values

__all__ = [
    "Surface",
    "EventRecord",
    "EventTrajectory",
    "EventFlow",
    "simulate",
    "switching_surfaces",
]

_EPS = float(np.finfo(float).eps)
#: switch functions frozen per mode (their arguments define the surfaces)
_SWITCHES = (sp.Heaviside, sp.sign, sp.Abs, sp.Max, sp.Min, sp.Piecewise)
#: relative tolerance (in rounding units) of "zero" normal speeds and on-surface tests
_ZERO_ULPS = 64.0
#: largest number of nested switch decisions enumerated when collecting surfaces
_MAX_NESTED = 12
#: surfaces equal to this relative tolerance are merged
_MERGE_TOL = 1e-12
#: a crossing shallower than this many local errors (atol + rtol*|h terms|) is a graze
_GRAZE_LOCAL_ERRORS = 10.0
#: this many events within a time window of _ZENO_WINDOW * (1 + |t|) is Zeno behaviour
_ZENO_COUNT, _ZENO_WINDOW = 200, 1e-9
#: sliding segments take at most this fraction of the forcing period per step: in sticking
#: x' = 0 has no error to control the step, and the exit condition, driven by the forcing,
#: must be sampled often enough for its sign changes and closest approaches to be seen
_SLIDE_STEPS_PER_PERIOD = 64

EventKind = Literal["cross", "stick", "slip", "graze"]


# --------------------------------------------------------------------------------------------
# public result types
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Surface:
    r"""A switching surface :math:`h(x, v) = a x + b v + c = 0`.

    Normalised so that :math:`\max(|a|, |b|) = 1` and the first non-zero of ``(a, b)`` is
    positive.  ``b != 0`` (the surface involves the velocity) is required for sliding.
    """

    a: float
    b: float
    c: float

    def __call__(self, x: float, v: float) -> float:
        return self.a * x + self.b * v + self.c

    @property
    def normal(self) -> np.ndarray:
        """The gradient :math:`n = (a, b)`."""
        return np.array([self.a, self.b])

    def __str__(self) -> str:
        terms = []
        for coeff, name in ((self.a, "x"), (self.b, "x'")):
            if coeff != 0:
                terms.append(name if coeff == 1 else f"{coeff:g}*{name}")
        if self.c != 0:
            terms.append(f"{self.c:g}")
        return " + ".join(terms).replace("+ -", "- ") + " = 0"


@dataclass(frozen=True)
class EventRecord:
    """One event of an event-driven run.

    Attributes
    ----------
    time
        Event time.
    surface
        Index into ``surfaces`` (of the flow or trajectory).
    kind
        ``'cross'`` (transversal crossing; the mode changes), ``'stick'`` (entry into a
        Filippov sliding mode, e.g. sticking under Coulomb friction), ``'slip'`` (exit from
        sliding, when the equivalent control leaves [-1, 1]) or ``'graze'`` (tangential
        touch; the mode is kept).
    x, v
        State at the event (on the surface for ``cross``/``stick``/``slip``).
    """

    time: float
    surface: int
    kind: EventKind
    x: float
    v: float


@dataclass(frozen=True, eq=False)
class EventTrajectory:
    """A time history from :func:`simulate`.

    Attributes
    ----------
    t, x, v
        Samples: at ``t_eval`` if it was given, else at every accepted integrator step
        (including the event times and the final time).
    events
        The :class:`EventRecord` log, in time order.
    n_restarts
        Number of integrator restarts (one per event, plus one per closest approach to a
        surface that stays clear of it).
    surfaces
        The switching surfaces the event indices refer to.
    """

    t: np.ndarray
    x: np.ndarray
    v: np.ndarray
    events: tuple[EventRecord, ...]
    n_restarts: int
    surfaces: tuple[Surface, ...]

    def of_kind(self, kind: EventKind) -> tuple[EventRecord, ...]:
        """The events of one kind."""
        return tuple(e for e in self.events if e.kind == kind)


# --------------------------------------------------------------------------------------------
# symbolic: decisions, surfaces, freezing
# --------------------------------------------------------------------------------------------
def _innermost(atoms: set[sp.Basic]) -> list[sp.Basic]:
    """Switch atoms whose arguments hold no other switch (sorted for determinism)."""
    inner = [a for a in atoms if not any(arg.has(*_SWITCHES) for arg in a.args)]
    return sorted(inner, key=sp.default_sort_key)


def _relationals(cond: sp.Basic) -> list[Relational]:
    if isinstance(cond, Relational):
        return [cond]
    if isinstance(cond, BooleanTrue | BooleanFalse):
        return []
    out: list[Relational] = []
    for arg in cond.args:
        out.extend(_relationals(arg))
    return out


def _decisions(atom: sp.Basic) -> list[sp.Expr]:
    """The expressions whose signs decide the value of a switch atom."""
    if isinstance(atom, sp.Heaviside | sp.sign | sp.Abs):
        return [atom.args[0]]
    if isinstance(atom, sp.Max | sp.Min):
        args = atom.args
        return [args[i] - args[j] for i in range(len(args)) for j in range(i + 1, len(args))]
    if isinstance(atom, sp.Piecewise):
        out: list[sp.Expr] = []
        for _, cond in atom.args:
            for rel in _relationals(cond):
                d = rel.lhs - rel.rhs
                if d not in out:
                    out.append(d)
        return out
    raise ModelError(f"unsupported switch function {atom}")  # pragma: no cover


_REL_TRUTH: dict[str, Callable[[int], bool]] = {
    "<": lambda s: s < 0,
    "<=": lambda s: s <= 0,
    ">": lambda s: s > 0,
    ">=": lambda s: s >= 0,
    "==": lambda s: s == 0,
    "!=": lambda s: s != 0,
}


def _resolve(atom: sp.Basic, signs: Sequence[int]) -> tuple[sp.Expr, list[int]]:
    """The value of a switch atom when its decisions have the given signs (each +-1), and
    the positions of the decisions that value depends on (a comparison between two losing
    arguments of ``Max`` cannot change it, so crossing its surface is no event)."""
    if isinstance(atom, sp.Heaviside):
        return sp.Integer(1 if signs[0] > 0 else 0), [0]
    if isinstance(atom, sp.sign):
        return sp.Integer(signs[0]), [0]
    if isinstance(atom, sp.Abs):
        return signs[0] * atom.args[0], [0]
    if isinstance(atom, sp.Max | sp.Min):
        args = atom.args
        n = len(args)
        want = 1 if isinstance(atom, sp.Max) else -1
        sign_of, position = {}, {}
        k = 0
        for i in range(n):
            for j in range(i + 1, n):
                sign_of[(i, j)], sign_of[(j, i)] = signs[k], -signs[k]
                position[(i, j)] = position[(j, i)] = k
                k += 1
        # a tournament: always consistent with the pairwise signs of a real state
        best = 0
        for i in range(1, n):
            if sign_of[(i, best)] == want:
                best = i
        return args[best], sorted(position[(best, j)] for j in range(n) if j != best)
    if isinstance(atom, sp.Piecewise):
        decisions = _decisions(atom)
        truth_of_sign = dict(zip(decisions, signs, strict=True))
        used: list[int] = []
        for expr, cond in atom.args:
            used.extend(decisions.index(rel.lhs - rel.rhs) for rel in _relationals(cond))
            reps = {
                rel: sp.true
                if _REL_TRUTH[rel.rel_op](truth_of_sign[rel.lhs - rel.rhs])
                else sp.false
                for rel in _relationals(cond)
            }
            value = cond.xreplace(reps) if reps else cond
            if value == sp.true:
                return expr, sorted(set(used))
        raise ModelError(
            f"{atom} is undefined in part of the state space (no condition holds there): "
            "expected a Piecewise with a final (expr, True) branch or conditions that cover "
            "every state"
        )
    raise ModelError(f"unsupported switch function {atom}")  # pragma: no cover


class _Registry:
    """The switching surfaces, deduplicated; maps a decision expression to a surface."""

    def __init__(self, x: sp.Symbol, v: sp.Symbol, t: sp.Symbol) -> None:
        self.x, self.v, self.t = x, v, t
        self.surfaces: list[Surface] = []
        self._memo: dict[sp.Expr, tuple[int, float] | tuple[None, float]] = {}

    def _coefficients(self, d: sp.Expr) -> tuple[float, float, float]:
        if d.has(self.t):
            raise ModelError(
                f"switching argument {d} depends on time {self.t}: only switching surfaces "
                f"fixed in the state plane (linear in {self.x} and {self.v}) are supported"
            )
        free = sorted(s.name for s in d.free_symbols - {self.x, self.v})
        if free:
            raise ParameterError(
                f"switching argument {d} needs values for {', '.join(free)}: set them on the "
                "oscillator (with_params)"
            )
        try:
            poly = sp.Poly(sp.expand(d), self.x, self.v)
        except sp.PolynomialError:
            poly = None
        if poly is None or poly.total_degree() > 1:
            raise ModelError(
                f"switching argument {d} is not linear in {self.x} and {self.v}: expected "
                f"a*{self.x} + b*{self.v} + c"
            )
        return (
            float(poly.coeff_monomial(self.x)),
            float(poly.coeff_monomial(self.v)),
            float(poly.coeff_monomial(1)),
        )

    def lookup(self, d: sp.Expr, register: bool = False) -> tuple[int | None, float]:
        """``(index, orientation)`` with ``d = orientation * h_index`` up to a positive
        factor, or ``(None, sign)`` for a state-free decision of fixed sign."""
        if d in self._memo:
            return self._memo[d]
        a, b, c = self._coefficients(d)
        if a == 0.0 and b == 0.0:
            # a decision of fixed sign (Max(1, 2) would have evaluated; a tie of equal
            # arguments gives the same value either way)
            out: tuple[int | None, float] = (None, 1.0 if c >= 0 else -1.0)
            self._memo[d] = out
            return out
        scale = max(abs(a), abs(b))
        a, b, c = a / scale, b / scale, c / scale
        orient = 1.0
        if a < 0 or (a == 0 and b < 0):
            a, b, c, orient = -a, -b, -c, -1.0
        for idx, s in enumerate(self.surfaces):
            if (
                abs(s.a - a) <= _MERGE_TOL
                and abs(s.b - b) <= _MERGE_TOL
                and abs(s.c - c) <= _MERGE_TOL * (1.0 + abs(c))
            ):
                self._memo[d] = (idx, orient)
                return idx, orient
        if not register:
            raise PerturbError(f"internal: switching argument {d} was not collected")
        self.surfaces.append(Surface(a + 0.0, b + 0.0, c + 0.0))
        self._memo[d] = (len(self.surfaces) - 1, orient)
        return len(self.surfaces) - 1, orient

    def collect(self, expr: sp.Expr, depth: int = 0) -> None:
        """Register every surface that any mode of ``expr`` can read."""
        atoms = expr.atoms(*_SWITCHES)
        if not atoms:
            return
        inner = _innermost(atoms)
        for atom in inner:
            for d in _decisions(atom):
                self.lookup(d, register=True)
        nested = [a for a in inner if any(o != a and o.has(a) for o in atoms)]
        if not nested:
            return
        surf: list[int] = []
        for atom in nested:
            for d in _decisions(atom):
                idx, _ = self.lookup(d)
                if idx is not None and idx not in surf:
                    surf.append(idx)
        if len(surf) > _MAX_NESTED or depth > 8:
            raise ModelError(
                f"{len(surf)} switching decisions nested inside other switch functions in "
                f"{expr}: at most {_MAX_NESTED} are supported"
            )
        for combo in itertools.product((-1, 1), repeat=len(surf)):
            sigma = dict(zip(surf, combo, strict=True))
            reps = {a: _resolve(a, self._signs(a, sigma))[0] for a in nested}
            self.collect(expr.xreplace(reps), depth + 1)

    def _signs(self, atom: sp.Basic, sigma: dict[int, int] | Sequence[int]) -> list[int]:
        out = []
        for d in _decisions(atom):
            idx, orient = self.lookup(d)
            out.append(int(orient) if idx is None else int(orient) * sigma[idx])
        return out

    def freeze(self, expr: sp.Expr, sigma: Sequence[int]) -> tuple[sp.Expr, frozenset[int]]:
        """``expr`` with every switch replaced by its value in mode ``sigma``, and the set of
        surfaces that were read."""
        active: set[int] = set()
        # each pass removes the innermost layer of switches: at most one pass per level
        for _ in range(_MAX_NESTED + 64):
            atoms = expr.atoms(*_SWITCHES)
            if not atoms:
                return expr, frozenset(active)
            reps = {}
            for atom in _innermost(atoms):
                value, used = _resolve(atom, self._signs(atom, sigma))
                decisions = _decisions(atom)
                for pos in used:
                    idx, _ = self.lookup(decisions[pos])
                    if idx is not None:
                        active.add(idx)
                reps[atom] = value
            expr = expr.xreplace(reps)
        raise ModelError(f"switch functions nested too deeply in {expr}")


# --------------------------------------------------------------------------------------------
# numeric modes
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Mode:
    """The compiled frozen field of one mode: ``acc(t, x, v)`` and
    ``derivs(t, x, v) = (acc, d acc/dx, d acc/dv, d acc/dt)``."""

    acc: Callable[[float, float, float], float]
    derivs: Callable[[float, float, float], tuple[float, float, float, float]]
    active: frozenset[int]
    #: the collocation stepper of the frozen field (None: not vectorisable, DOP853 is used)
    stepper: ChebyshevStep | None = None


@dataclass
class _State:
    t: float
    y: np.ndarray
    phi: np.ndarray | None
    sigma: list[int]
    slide: int | None
    guard: dict[int, float]
    #: the next collocation step length (carried from segment to segment within one call,
    #: never between calls: a flow's result depends on its arguments only)
    h: float | None = None


def _check_tol(name: str, value: object) -> float:
    out = validate_parameter_value(name, value)
    if not (out > 0):
        raise ParameterError(f"{name} = {value!r}: expected a positive number")
    return out


class EventFlow(Flow):
    r"""Event-driven flow of a piecewise-smooth oscillator (a :class:`~.base.Flow`).

    Parameters
    ----------
    oscillator
        Any oscillator with all parameter values set; switch functions must have arguments
        linear in ``x`` and ``x'`` (see the module docstring).
    Omega
        Override of the forcing frequency.
    rtol, atol
        Tolerances of DOP853 in every smooth segment (state and variational equations).
    max_events
        Largest number of events per call before giving up.
    parameter
        A parameter kept as an argument of the compiled fields (flows at other values by
        :meth:`at` share them).
    integrator
        ``"chebyshev"`` (default): collocation steps between the events (module docstring),
        several times faster than DOP853 in Python for the same accuracy, with the
        sensitivity almost free; ``"dop853"``: :func:`scipy.integrate.solve_ivp` in every
        segment (the reference of earlier versions).

    Attributes
    ----------
    surfaces : tuple of Surface
        The switching surfaces (event indices refer to them).
    period : float or None
        The forcing period (None for autonomous systems).

    Examples
    --------
    >>> from perturb.model.oscillator import Oscillator
    >>> osc = Oscillator.parse("x'' + x + 0.2*sign(x') = 0")
    >>> flow = EventFlow(osc)
    >>> res = flow([1.0, 0.0], 0.0, 10.0)   # sticks at x = 0.2 after two half cycles
    >>> round(float(res.y[0]), 9), float(res.y[1]), res.n_events
    (0.2, 0.0, 2)
    """

    def __init__(
        self,
        oscillator: Oscillator,
        Omega: float | None = None,
        *,
        rtol: float = 1e-11,
        atol: float = 1e-12,
        max_events: int = 100_000,
        parameter: str | None = None,
        integrator: Literal["chebyshev", "dop853"] = "chebyshev",
    ) -> None:
        if not isinstance(oscillator, Oscillator):
            raise ParameterError(f"oscillator = {oscillator!r}: expected an Oscillator")
        if integrator not in ("chebyshev", "dop853"):
            raise ParameterError(f"integrator = {integrator!r}: expected 'chebyshev' or 'dop853'")
        self.integrator = integrator
        self.oscillator = oscillator
        self.rtol = _check_tol("rtol", rtol)
        self.atol = _check_tol("atol", atol)
        if self.rtol < 100 * _EPS:
            raise ParameterError(f"rtol = {rtol!r}: expected at least 100 eps = {100 * _EPS:.3g}")
        if isinstance(max_events, bool) or not isinstance(max_events, int) or max_events < 1:
            raise ParameterError(f"max_events = {max_events!r}: expected a positive integer")
        self.max_events = max_events
        osc = oscillator
        subs = parameter_values(osc, Omega)
        # ``parameter``: one parameter kept as an argument of the compiled fields, so that
        # flows at other values (:meth:`at`) share the surfaces and the compiled modes
        self._p: sp.Symbol | None = None
        self._p_value = 0.0
        self._period_fn: Callable[[float], float] | None = None
        if parameter is not None:
            psym = next((q for q in subs if q.name == parameter), None)
            if psym is None:
                raise ParameterError(f"parameter {parameter!r} has no value in {osc.name!r}")
            self._p, self._p_value = psym, float(subs.pop(psym))
        g = osc.g.xreplace(subs)
        forcing = osc.forcing.expr(osc.t).xreplace(subs)
        own = {osc.x, osc.v, osc.t} | ({self._p} if self._p is not None else set())
        free = sorted(s.name for s in (g.free_symbols | forcing.free_symbols) - own)
        if free:
            raise ParameterError(
                f"model {osc.name!r} needs values for {', '.join(free)}: pass them as params"
            )
        if g.has(sp.DiracDelta):
            raise ModelError(
                f"model {osc.name!r} contains DiracDelta (an impulsive force): not supported by "
                "the event-driven integrator"
            )
        self._x, self._v, self._t = osc.x, osc.v, osc.t
        self._acc_expr = sp.expand(forcing) - g
        self._registry = _Registry(osc.x, osc.v, osc.t)
        self._registry.collect(g)
        self.surfaces: tuple[Surface, ...] = tuple(self._registry.surfaces)
        if self._p is None:
            self.period: float | None = first_order_rhs(osc, Omega).period
        else:
            period = forcing_period_expr(osc)
            if period is not None:
                period = period.xreplace(subs)
                if period.free_symbols - {self._p}:
                    raise ParameterError(f"the forcing period of {osc.name!r} needs values")
                self._period_fn = sp.lambdify(self._p, period, modules="math")
            self.period = self._period_at(self._p_value)
        self._modes: dict[tuple[int, ...], _Mode] = {}
        # shared with the flows of at(): frozen fields per mode, compiled fields per field
        self._frozen: dict[tuple[int, ...], tuple[sp.Expr, frozenset[int]]] = {}
        self._compiled: dict[sp.Expr, tuple[Callable, Callable]] = {}
        self._vectorised: dict[sp.Expr, Callable | None] = {}
        #: the last run made of collocation steps only: ((y0, t0, t1), y1, events, chunks)
        self._memo: tuple | None = None
        self._slide_max_step = (
            self.period / _SLIDE_STEPS_PER_PERIOD if self.period is not None else np.inf
        )

    def _period_at(self, value: float) -> float | None:
        if self._period_fn is None:
            return None
        period = float(self._period_fn(value))
        if not (math.isfinite(period) and period > 0.0):
            raise ParameterError(
                f"{self._p} = {value!r} gives the forcing period {period!r}: expected a positive "
                "finite period"
            )
        return period

    def at(self, value: float) -> EventFlow:
        """The flow at another value of the ``parameter`` given at construction, sharing the
        surfaces and the compiled modes (nothing is recompiled)."""
        if self._p is None:
            raise ParameterError("EventFlow.at needs a flow built with parameter=")
        value = validate_parameter_value(self._p.name, value)
        new = copy.copy(self)
        new._p_value = float(value)
        new.period = self._period_at(new._p_value)
        new._modes = {}
        new._memo = None
        new._slide_max_step = (
            new.period / _SLIDE_STEPS_PER_PERIOD if new.period is not None else np.inf
        )
        return new

    def __repr__(self) -> str:
        return (
            f"EventFlow({self.oscillator.name}, surfaces={len(self.surfaces)}, "
            f"period={self.period}, rtol={self.rtol:g})"
        )

    # ------------------------------------------------------------------------ modes --
    def _mode(self, sigma: Sequence[int]) -> _Mode:
        key = tuple(sigma)
        mode = self._modes.get(key)
        if mode is None:
            hit = self._frozen.get(key)
            if hit is None:
                hit = self._frozen[key] = self._registry.freeze(self._acc_expr, key)
            frozen, active = hit
            fns = self._compiled.get(frozen)
            if fns is None:
                x, v, t = self._x, self._v, self._t
                derivs = [frozen, sp.diff(frozen, x), sp.diff(frozen, v), sp.diff(frozen, t)]
                mods = ["math", "numpy"]
                args = (t, x, v) if self._p is None else (t, x, v, self._p)
                fns = (
                    sp.lambdify(args, frozen, modules=mods),
                    sp.lambdify(args, derivs, modules=mods),
                )
                self._compiled[frozen] = fns
            stepper = self._stepper(frozen)
            if self._p is None:
                mode = _Mode(acc=fns[0], derivs=fns[1], active=active, stepper=stepper)
            else:
                acc_p, derivs_p, pv = fns[0], fns[1], self._p_value

                def acc(t: float, x: float, v: float) -> float:
                    return acc_p(t, x, v, pv)

                def derivs_fn(t: float, x: float, v: float):
                    return derivs_p(t, x, v, pv)

                mode = _Mode(acc=acc, derivs=derivs_fn, active=active, stepper=stepper)
            self._modes[key] = mode
        return mode

    def _stepper(self, frozen: sp.Expr) -> ChebyshevStep | None:
        """The collocation stepper of a frozen field, or None (DOP853 then) when the flow
        uses DOP853 or the field does not evaluate on arrays."""
        if self.integrator != "chebyshev":
            return None
        if frozen not in self._vectorised:
            x, v, t = self._x, self._v, self._t
            args = (t, x, v) if self._p is None else (t, x, v, self._p)
            try:
                fn = sp.lambdify(args, [frozen, sp.diff(frozen, x), sp.diff(frozen, v)], "numpy")
                # a trial on arrays: every output must broadcast to the nodes' shape
                probe = np.linspace(0.1, 0.3, 3)
                extra = () if self._p is None else (self._p_value,)
                with np.errstate(all="ignore"):
                    out = fn(probe, probe, probe, *extra)
                for q in out:
                    np.broadcast_to(np.asarray(q, dtype=float), probe.shape)
            except Exception:  # noqa: BLE001 - any failure means: not vectorisable
                fn = None
            self._vectorised[frozen] = fn
        fn = self._vectorised[frozen]
        if fn is None:
            return None
        if self._p is not None:
            pv, fn_p = self._p_value, fn

            def fn(t, x, v):  # noqa: F811 - the parameter bound
                return fn_p(t, x, v, pv)

        return ChebyshevStep(fn, self.rtol, self.atol)

    def _field(self, sigma: Sequence[int], t: float, y: np.ndarray) -> np.ndarray:
        return np.array([y[1], float(self._mode(sigma).acc(t, y[0], y[1]))])

    def _normal_rates(
        self, sigma: Sequence[int], j: int, t: float, y: np.ndarray
    ) -> tuple[float, float, float, float]:
        r"""For surface ``j`` along mode ``sigma``: :math:`\dot h`, :math:`\ddot h` and
        rounding scales of each."""
        s = self.surfaces[j]
        x, v = float(y[0]), float(y[1])
        acc, ax, av, at = (float(q) for q in self._mode(sigma).derivs(t, x, v))
        hd = s.a * v + s.b * acc
        jerk = at + ax * v + av * acc
        hdd = s.a * acc + s.b * jerk
        hd_scale = abs(s.a * v) + abs(s.b * acc)
        hdd_scale = abs(s.a * acc) + abs(s.b) * (abs(at) + abs(ax * v) + abs(av * acc))
        return hd, hdd, hd_scale, hdd_scale

    @staticmethod
    def _flip(sigma: Sequence[int], j: int, value: int) -> list[int]:
        out = list(sigma)
        out[j] = value
        return out

    def _goes_into(self, sigma: Sequence[int], j: int, side: int, t: float, y: np.ndarray) -> int:
        """+1 if the field of mode ``sigma`` (with ``sigma[j] = side``) carries a state on
        surface ``j`` into that side, -1 if back across, 0 if tangent to second order."""
        hd, hdd, hd_scale, hdd_scale = self._normal_rates(self._flip(sigma, j, side), j, t, y)
        if abs(hd) > _ZERO_ULPS * _EPS * hd_scale:
            return 1 if side * hd > 0 else -1
        if abs(hdd) > _ZERO_ULPS * _EPS * hdd_scale:
            return 1 if side * hdd > 0 else -1
        return 0

    def _side_on_surface(self, sigma: Sequence[int], j: int, t: float, y: np.ndarray) -> int:
        """Where a state on surface ``j`` goes: +1, -1, or 0 for an attracting sliding mode.

        Raises
        ------
        PerturbError
            On a repelling surface (both sides pull away: non-unique) and on a stationary
            point of a discontinuity that would need codimension-2 sliding.
        """
        up = self._goes_into(sigma, j, 1, t, y)
        down = self._goes_into(sigma, j, -1, t, y)
        if up > 0 and down <= 0:
            return 1
        if down > 0 and up <= 0:
            return -1
        s = self.surfaces[j]
        if up > 0 and down > 0:
            raise PerturbError(
                f"{_where(t, y)} lies on the repelling "
                f"switching surface {s}: both neighbouring fields point away from it, so the "
                "continuation is not unique; start off the surface"
            )
        if s.b != 0.0:
            return 0
        f_up = self._field(self._flip(sigma, j, 1), t, y)
        f_down = self._field(self._flip(sigma, j, -1), t, y)
        if np.allclose(f_up, f_down, rtol=1e-12, atol=0.0):
            return 1  # continuous field at a point of tangency: either side is the same
        raise PerturbError(
            f"{_where(t, y)} is held on the surface {s} by "
            "both neighbouring fields at zero velocity (a pseudo-equilibrium needing sliding "
            "on two surfaces at once); not supported: start off the surface"
        )

    def _tol_h(self, j: int, y: np.ndarray) -> float:
        s = self.surfaces[j]
        return _ZERO_ULPS * _EPS * (abs(s.a * y[0]) + abs(s.b * y[1]) + abs(s.c))

    def _initial(self, t: float, y: np.ndarray) -> tuple[list[int], int | None, list[int]]:
        """Mode at a state: signs, the sliding surface (or None), the surfaces it lies on."""
        sigma, on = [], []
        for j, s in enumerate(self.surfaces):
            h = s(y[0], y[1])
            if abs(h) <= self._tol_h(j, y):
                on.append(j)
                sigma.append(1)
            else:
                sigma.append(1 if h > 0 else -1)
        slide = None
        for j in on:
            side = self._side_on_surface(sigma, j, t, y)
            if side == 0:
                if slide is not None:
                    raise PerturbError(
                        f"{_where(t, y)} would slide on two "
                        f"surfaces ({self.surfaces[slide]} and {self.surfaces[j]}) at once: "
                        "codimension-2 sliding is not supported"
                    )
                slide = j
            else:
                sigma[j] = side
        return sigma, slide, on

    def _slide_fields(self, sigma: Sequence[int], j: int) -> tuple[_Mode, _Mode]:
        return self._mode(self._flip(sigma, j, -1)), self._mode(self._flip(sigma, j, 1))

    def _slide_entry(self, sigma: Sequence[int], j: int, t: float, y: np.ndarray) -> np.ndarray:
        r"""Saltation into sliding: :math:`I + (f^+ - f^-) n^T/(n^T f^- - n^T f^+)`."""
        n = self.surfaces[j].normal
        fm = self._field(self._flip(sigma, j, -1), t, y)
        fp = self._field(self._flip(sigma, j, 1), t, y)
        den = float(n @ fm - n @ fp)
        if den == 0.0:
            raise PerturbError(
                f"sensitivity undefined at t = {t!r}: sliding on {self.surfaces[j]} entered "
                "with both fields tangent to it"
            )
        return np.eye(2) + np.outer(fp - fm, n) / den

    def vector_field(self, t: float, y: ArrayLike) -> np.ndarray:
        """The Filippov vector field at ``(t, y)``: the field of the region containing
        ``y``; on a surface, the field of the side the orbit enters, or the sliding field."""
        yy = _state("y", y)
        sigma, slide, _ = self._initial(float(t), yy)
        if slide is not None:
            s = self.surfaces[slide]
            v = -(s.a * yy[0] + s.c) / s.b
            return np.array([v, -s.a / s.b * v])
        return self._field(sigma, float(t), yy)

    # ----------------------------------------------------------------- integration --
    def __call__(
        self,
        y0: ArrayLike,
        t0: float,
        t1: float,
        *,
        sensitivity: bool = False,
        t_eval: ArrayLike | None = None,
    ) -> FlowResult:
        """Propagate ``y0`` from ``t0`` to ``t1``; see :class:`~.flow.Flow`.

        Returns
        -------
        FlowResult
            ``sensitivity`` is ``dy(t1)/dy(t0)`` with saltation matrices at the switches and
            the sliding projections (module docstring); ``n_events`` counts all events.
        """
        y = _state("y0", y0)
        t0, t1 = _span(t0, t1)
        te = _times(t_eval, t0, t1)
        memo = self._memo
        if (
            te is not None
            and not sensitivity
            and memo is not None
            and memo[0] == (y.tobytes(), t0, t1)
        ):
            # samples of the run just made from the same state over the same span (e.g. an
            # orbit's statistics after its last shooting iteration): the collocation steps'
            # polynomials, the same numbers a new run would produce (its steps do not depend
            # on the sensitivity), without integrating again
            return FlowResult(
                t0=t0,
                t1=t1,
                y=memo[1].copy(),
                t=te.copy(),
                ys=_memo_samples(memo[3], te),
                n_events=memo[2],
            )
        run = self._run(y, t0, t1, bool(sensitivity), te, dense=te is not None)
        self._memo = (
            None
            if run.chunks is None
            else ((y.tobytes(), t0, t1), run.y.copy(), len(run.events), run.chunks)
        )
        return FlowResult(
            t0=t0,
            t1=t1,
            y=run.y,
            sensitivity=run.phi,
            t=None if te is None else run.ts,
            ys=None if te is None else np.column_stack([run.xs, run.vs]),
            n_events=len(run.events),
        )

    def simulate(
        self, y0: ArrayLike, t_span: Sequence[float], *, t_eval: ArrayLike | None = None
    ) -> EventTrajectory:
        """A time history; see :func:`simulate`."""
        y = _state("y0", y0)
        try:
            t0, t1 = (float(q) for q in t_span)
        except (TypeError, ValueError):
            raise ParameterError(f"t_span = {t_span!r}: expected (t0, t1)") from None
        t0, t1 = _span(t0, t1)
        te = _times(t_eval, t0, t1)
        run = self._run(y, t0, t1, False, te, dense=True)
        for arr in (run.ts, run.xs, run.vs):
            arr.setflags(write=False)
        return EventTrajectory(
            t=run.ts,
            x=run.xs,
            v=run.vs,
            events=tuple(run.events),
            n_restarts=run.n_restarts,
            surfaces=self.surfaces,
        )

    def _run(
        self,
        y0: np.ndarray,
        t0: float,
        t1: float,
        sensitivity: bool,
        t_eval: np.ndarray | None,
        dense: bool,
    ) -> _Run:
        sigma, slide, on = self._initial(t0, y0)
        phi = np.eye(2) if sensitivity else None
        y = y0.copy()
        if slide is not None:
            s = self.surfaces[slide]
            y = np.array([y[0], -(s.a * y[0] + s.c) / s.b + 0.0])
            if phi is not None:
                phi = self._slide_entry(sigma, slide, t0, y) @ phi
        st = _State(t0, y, phi, sigma, slide, {j: t0 for j in on})
        out = _Run(t0, t_eval, dense)
        recent: deque[float] = deque(maxlen=_ZENO_COUNT)
        while True:
            if st.slide is None:
                done = self._region_segment(st, t1, out)
            else:
                done = self._slide_segment(st, t1, out)
            if done:
                break
            if not (math.isfinite(st.t) and np.all(np.isfinite(st.y))):
                raise PerturbError(
                    f"integration of {self.oscillator.name!r} produced t = {st.t!r}, "
                    f"y = {st.y.tolist()!r} (overflow or NaN: the orbit may escape to infinity)"
                )
            out.advance(st.t)
            out.n_restarts += 1
            if out.n_restarts > 10 * self.max_events:
                raise PerturbError(
                    f"more than {10 * self.max_events} restarts before t = {t1!r} (reached "
                    f"t = {st.t!r}); raise max_events or shorten the interval"
                )
            recent.append(st.t)
            if len(out.events) > self.max_events:
                raise PerturbError(
                    f"more than max_events = {self.max_events} events before t = {t1!r} "
                    f"(reached t = {st.t!r}); raise max_events or shorten the interval"
                )
            if len(recent) == _ZENO_COUNT and recent[-1] - recent[0] <= _ZENO_WINDOW * (
                1.0 + abs(st.t)
            ):
                raise PerturbError(
                    f"{_ZENO_COUNT} restarts within {recent[-1] - recent[0]:.3g} time units "
                    f"near t = {st.t!r} (Zeno behaviour: switching accumulates at a point, "
                    "e.g. a damped relay settling at x = 0); not supported"
                )
        out.y = st.y
        out.phi = st.phi
        out.finish()
        return out

    def _ivp(self, fun, t: float, t1: float, z0: np.ndarray, events, t_eval, max_step=np.inf):
        try:
            sol = solve_ivp(
                fun,
                (t, t1),
                z0,
                method="DOP853",
                rtol=self.rtol,
                atol=self.atol,
                events=events or None,
                t_eval=t_eval,
                max_step=max_step,
            )
        except (OverflowError, ZeroDivisionError, FloatingPointError, ValueError) as exc:
            raise PerturbError(
                f"integration of {self.oscillator.name!r} failed after t = {t!r}: {exc} "
                "(the orbit may escape to infinity)"
            ) from exc
        if sol.status == -1 or (len(sol.t) and not np.all(np.isfinite(sol.y))):
            raise PerturbError(
                f"integration of {self.oscillator.name!r} failed after t = {t!r}: "
                f"{sol.message} (the orbit may escape to infinity)"
            )
        return sol

    def _segment(
        self,
        fun: Callable[[float, np.ndarray], np.ndarray],
        t: float,
        t1: float,
        z0: np.ndarray,
        monitors: list[_Monitor],
        out: _Run,
        xv: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
        max_step: float = np.inf,
    ) -> tuple[int | None, str, float, np.ndarray]:
        """Integrate one smooth segment until a monitor leaves its side.

        Every monitor ``g`` has two terminal events: ``g`` itself (direction out of its
        side) and its time derivative ``g'`` at a closest approach (``g'`` changing from
        approaching to receding).  The second catches a double crossing inside one step
        (both step ends inside, so ``solve_ivp`` sees no sign change of ``g``): at the
        closest approach ``g`` is then beyond zero, and the crossing is found by integrating
        backwards.  A closest approach still inside just restarts the segment there; one at
        zero (to rounding) is a graze.

        Returns
        -------
        (index, kind, t, z)
            The monitor that fired (None at ``t1``), ``'cross'``/``'graze'``/``'end'``, the
            time and the augmented state there.
        """
        t_turn = t
        while True:
            events = []
            for m in monitors:
                events.append(_crossing_event(m))
                events.append(_turning_event(m, t_turn))
            te, extra = out.request(t1)
            sol = self._ivp(fun, t, t1, z0, events, te, max_step)
            k = next((i for i, tev in enumerate(sol.t_events or []) if len(tev)), None)
            if k is None:
                out.add(sol.t, sol.y, xv, t1, drop_last=extra)
                z1 = sol.y[:, -1].copy() if len(sol.t) else z0
                return None, "end", t1, z1
            i, turn = divmod(k, 2)
            m = monitors[i]
            t_e = float(sol.t_events[k][0])
            z_e = np.array(sol.y_events[k][0], dtype=float)
            if not turn:
                out.add(sol.t, sol.y, xv, t_e)
                return i, "cross", t_e, z_e
            g_e, tol = m.g(t_e, z_e), m.tol(t_e, z_e)
            graze_tol = tol if m.graze_depth is None else max(tol, m.graze_depth(t_e, z_e))
            if m.side * g_e > tol:
                # closest approach still inside: nothing happened, go on from there
                out.add(sol.t, sol.y, xv, t_e)
                out.advance(t_e)
                out.n_restarts += 1
                if out.n_restarts > 10 * self.max_events:
                    raise PerturbError(
                        f"more than {10 * self.max_events} restarts before t = {t1!r} (reached "
                        f"t = {t_e!r}): the orbit keeps turning near a switching surface; "
                        "raise max_events or shorten the interval"
                    )
                t, z0, t_turn = t_e, z_e, t_e
                continue
            if abs(g_e) <= graze_tol:
                # touched, or went beyond by less than the integration error: a graze
                out.add(sol.t, sol.y, xv, t_e)
                return i, "graze", t_e, z_e
            t_c, z_c = self._backward(fun, t_e, z_e, t, m)
            out.add(sol.t, sol.y, xv, t_c)
            return i, "cross", t_c, z_c

    def _backward(
        self,
        fun: Callable[[float, np.ndarray], np.ndarray],
        t_e: float,
        z_e: np.ndarray,
        t_lo: float,
        m: _Monitor,
    ) -> tuple[float, np.ndarray]:
        """The last zero of ``m.g`` before ``t_e`` (where ``g`` is beyond zero), found by
        integrating the same smooth field backwards from ``t_e`` towards ``t_lo``."""

        def ev(t: float, z: np.ndarray) -> float:
            return m.g(t, z)

        ev.terminal, ev.direction = True, 0  # type: ignore[attr-defined]
        sol = self._ivp(fun, t_e, t_lo, z_e, [ev], None)
        if len(sol.t_events[0]):
            return float(sol.t_events[0][0]), np.array(sol.y_events[0][0], dtype=float)
        # the segment started on the surface (masked) and never really left it
        return t_lo, sol.y[:, -1].copy()

    def _surface_monitor(self, j: int, side: int, guard: float, mode: _Mode) -> _Monitor:
        s = self.surfaces[j]
        a, b, c = s.a, s.b, s.c
        acc = mode.acc

        def g(t: float, z: np.ndarray) -> float:
            return a * z[0] + b * z[1] + c

        def gdot(t: float, z: np.ndarray) -> float:
            return a * z[1] + b * acc(t, z[0], z[1])

        def tol(t: float, z: np.ndarray) -> float:
            return _ZERO_ULPS * _EPS * (abs(a * z[0]) + abs(b * z[1]) + abs(c))

        def depth(t: float, z: np.ndarray) -> float:
            return self._graze_depth(s, z)

        return _Monitor(g, gdot, side, guard, tol, depth)

    def _refresh(self, st: _State) -> None:
        """Re-read the sign of every surface the state is clearly off: surfaces that are
        not active in a mode are not monitored, so their sign may be stale when a later
        mode reads them again."""
        y = st.y
        for k, s in enumerate(self.surfaces):
            if k == st.slide or st.guard.get(k, -np.inf) >= st.t:
                continue  # the surface just handled keeps the sign decided for it
            h = s(y[0], y[1])
            if abs(h) > self._tol_h(k, y):
                st.sigma[k] = 1 if h > 0 else -1

    def _region_segment(self, st: _State, t1: float, out: _Run) -> bool:
        self._refresh(st)
        mode = self._mode(st.sigma)
        active = sorted(mode.active)
        res = None
        t_start = st.t
        z0 = st.y if st.phi is None else np.concatenate([st.y, st.phi.ravel()])
        if mode.stepper is not None:
            res = self._segment_chebyshev(mode.stepper, st, t1, active, out)
            if res[1] == "fallback":
                # the collocation steps could not proceed (step length collapsed): DOP853
                # from where they stopped
                t_start, z0 = res[2], res[3]
                res = None
        if res is None:
            out.chunks = None
            monitors = [
                self._surface_monitor(j, st.sigma[j], st.guard.get(j, -np.inf), mode)
                for j in active
            ]
            res = self._segment(
                self._dop853_field(mode, st.phi is not None),
                t_start,
                t1,
                z0,
                monitors,
                out,
                _xv_state,
            )
        hit, kind, t_e, z_e = res
        y_e = z_e[:2].copy()
        phi = None if st.phi is None else z_e[2:].reshape(2, 2).copy()
        if hit is None:
            st.t, st.y, st.phi = t1, y_e, phi
            return True
        j = active[hit]
        if kind == "graze":
            out.events.append(EventRecord(t_e, j, "graze", float(y_e[0]), float(y_e[1])))
            st.t, st.y, st.phi = t_e, y_e, phi
            st.guard = {j: t_e}
            return False
        self._classify(st, j, t_e, y_e, phi, out)
        return False

    # ------------------------------------------------------- collocation segments --
    def _segment_chebyshev(
        self, stepper: ChebyshevStep, st: _State, t1: float, active: list[int], out: _Run
    ) -> tuple[int | None, str, float, np.ndarray]:
        """:meth:`_segment` by Chebyshev collocation steps (:mod:`.spectral`): the same
        events, found on each step's polynomial instead of DOP853's dense output.

        Every monitored surface ``h_j`` is sampled on ``2 N + 1`` points of each step,
        together with its rate ``h_j'``; a sign change of ``h_j`` out of its side is a
        crossing (root refined on the polynomial), a change of ``h_j'`` from approaching to
        receding a closest approach, refined when it could reach the surface: beyond it
        (more than the graze depth) it is a crossing at the last zero before it, within the
        graze depth a graze, inside nothing.  Returns what :meth:`_segment` returns, or
        ``(None, 'fallback', t, z)`` when the step length collapses (``z`` the augmented state
        reached, from which DOP853 goes on)."""
        t = float(st.t)
        x0, v0 = float(st.y[0]), float(st.y[1])
        phi = st.phi
        want = phi is not None
        span_total = t1 - t
        h_cap = self.period if self.period is not None else 2.0 * math.pi
        H = st.h if st.h is not None else _FIRST_CHUNK * h_cap
        surf = [(self.surfaces[j], float(st.sigma[j]), st.guard.get(j, -np.inf)) for j in active]
        n = stepper.rule.n
        # a bound on the steps of this segment: generous per forcing period of its span (a
        # period takes a handful), so only a collapsing step length reaches it
        max_chunks = int(_MAX_CHUNKS + _MAX_CHUNKS * min(span_total / h_cap, 1e6))
        for _ in range(max_chunks):
            span = t1 - t
            H = min(H, h_cap)
            last = H >= span * (1.0 - 1e-9)
            H_try = span if last else H
            chunk, ratio = stepper.attempt(t, x0, v0, H_try, want)
            if chunk is None:
                factor = 0.5 if not math.isfinite(ratio) else min(0.8, (0.05 / ratio) ** (1 / n))
                H = H_try * max(0.2, factor)
                if H < _MIN_CHUNK * max(1.0, abs(t), span_total):
                    return None, "fallback", t, _augmented(x0, v0, phi)
                continue
            if not last:
                # geometric convergence: the error scales like H**n
                H = H_try * min(2.0, (0.05 / max(ratio, 1e-300)) ** (1 / n))
            st.h = H
            hit = self._chunk_event(chunk, surf)
            t_end = t1 if last else chunk.t[-1]
            if hit is not None:
                k, kind, t_e = hit
                x_e, v_e, S = chunk.state(t_e)
                self._chunk_samples(chunk, out, t_e)
                if out.chunks is not None:
                    out.chunks.append((chunk, t_e))
                return k, kind, t_e, _augmented(x_e, v_e, None if phi is None else S @ phi)
            self._chunk_samples(chunk, out, t_end)
            if out.chunks is not None:
                out.chunks.append((chunk, t_end))
            x0, v0 = float(chunk.x[-1]), float(chunk.v[-1])
            if want:
                xx, xv, vx, vv = chunk.sens
                phi = np.array([[xx[-1], xv[-1]], [vx[-1], vv[-1]]]) @ phi
            t = t_end
            if last:
                return None, "end", t1, _augmented(x0, v0, phi)
        raise PerturbError(
            f"more than {max_chunks} collocation steps in one smooth segment of "
            f"{self.oscillator.name!r} after t = {st.t!r} (reached t = {t!r})"
        )

    @staticmethod
    def _chunk_samples(chunk: Chunk, out: _Run, upto: float) -> None:
        """Record the requested output times (or, for a dense run, the nodes) up to ``upto``."""
        if out.t_eval is not None:
            te = out.t_eval
            lo = int(np.searchsorted(te, chunk.ta, side="left"))
            hi = int(np.searchsorted(te, upto, side="right"))
            if hi > lo:
                sel = te[lo:hi]
                out.add(sel, chunk.states(sel), _xv_state, upto)
        elif out.dense:
            keep = chunk.t < upto
            times = np.append(chunk.t[keep], upto)
            out.add(times, chunk.states(times), _xv_state, upto)

    def _chunk_event(
        self, chunk: Chunk, surf: list[tuple[Surface, float, float]]
    ) -> tuple[int, str, float] | None:
        """The first event of a collocation step: ``(monitor index, 'cross' | 'graze', t)``,
        or None."""
        rule = chunk.rule
        L, s_f = _fine_samples(rule.n)
        tf = chunk.ta + (s_f + 1.0) * (0.5 * chunk.H)
        xf, vf, uf = L @ chunk.x, L @ chunk.v, L @ chunk.u
        # half a sample spacing times the largest |x'| and |x''|: how far below the lower of
        # two neighbouring samples h can dip between them (per unit of |a| and |b|)
        half = 0.25 * chunk.H / (len(tf) - 1)
        dip_v = half * float(np.max(np.abs(vf)))
        dip_u = half * float(np.max(np.abs(uf)))
        scale = _GRAZE_LOCAL_ERRORS * (self.atol + self.rtol * float(np.max(np.abs(xf))))
        best: tuple[int, str, float] | None = None
        for k, (s, side, guard) in enumerate(surf):
            a, b, c = s.a, s.b, s.c
            g = side * (a * xf + b * vf + c)
            if guard < tf[0]:
                valid = None
                low = float(g.min())
            else:
                valid = tf > guard
                g = np.where(valid, g, np.inf)
                low = float(g.min())
            reach = abs(a) * dip_v + abs(b) * dip_u
            if low > reach + scale * (abs(a) + abs(b) + abs(c)):
                continue  # no sample outside, and no dip between samples can get there
            if valid is None:
                valid = np.ones(len(tf), dtype=bool)
            dg = side * (a * vf + b * uf)
            # exact zeros count as inside (as the DOP853 path's events do)
            out_idx = np.flatnonzero(g < 0.0)
            stop = int(out_idx[0]) if out_idx.size else len(g)
            found: tuple[str, float] | None = None
            # closest approaches before the first sample outside: h' from approaching (< 0)
            # to receding (>= 0) between two valid samples
            turns = np.flatnonzero(
                (dg[:-1] < 0.0) & (dg[1:] >= 0.0) & valid[:-1] & (np.arange(len(g) - 1) < stop - 1)
            )
            for i in turns:
                lo_t, hi_t = float(tf[i]), float(tf[i + 1])
                # lowest the polynomial can dip between the samples (a bound, to skip the
                # refinement for approaches that stay clearly inside)
                reach = min(g[i], g[i + 1]) - 0.5 * (hi_t - lo_t) * max(-dg[i], dg[i + 1])
                tol, depth = self._chunk_tols(s, chunk, lo_t)
                if reach > tol:
                    continue
                t_min = self._chunk_zero(chunk, a, b, 0.0, side, lo_t, hi_t, derivative=True)
                g_min = side * self._chunk_h(chunk, a, b, c, t_min)
                if g_min > tol:
                    continue
                if g_min >= -depth:
                    found = ("graze", t_min)
                else:
                    t_c = self._chunk_zero(chunk, a, b, c, side, lo_t, t_min, derivative=False)
                    found = ("cross", t_c)
                break
            if found is None and out_idx.size:
                i = int(out_idx[0])
                lo_t = float(tf[i - 1]) if i > 0 else float(chunk.ta)
                hi_t = float(tf[i])
                if i == 0 or not valid[i - 1]:
                    # the bracket starts at the restart on the surface (h = 0 there): the
                    # orbit went out to this side and came back before the sample; the
                    # return crossing lies after the turn
                    lo_t = max(lo_t, float(guard)) if math.isfinite(guard) else lo_t
                    row = interpolation_row(rule, float(chunk.s_of(lo_t)))
                    if side * (a * float(row @ chunk.v) + b * float(row @ chunk.u)) > 0.0:
                        t_max = self._chunk_zero(chunk, a, b, 0.0, -side, lo_t, hi_t, True)
                        if side * self._chunk_h(chunk, a, b, c, t_max) > 0.0:
                            lo_t = t_max
                found = ("cross", self._chunk_zero(chunk, a, b, c, side, lo_t, hi_t))
            if found is not None and (best is None or found[1] < best[2]):
                best = (k, found[0], found[1])
        return best

    def _chunk_tols(self, s: Surface, chunk: Chunk, t: float) -> tuple[float, float]:
        """Rounding tolerance of ``h`` and the graze depth at a time of a step."""
        x, v = chunk.states(np.array([t]))[:, 0]
        y = np.array([x, v])
        tol = _ZERO_ULPS * _EPS * (abs(s.a * x) + abs(s.b * v) + abs(s.c))
        return tol, max(tol, self._graze_depth(s, y))

    @staticmethod
    def _chunk_h(chunk: Chunk, a: float, b: float, c: float, t: float) -> float:
        x, v = chunk.states(np.array([t]))[:, 0]
        return float(a * x + b * v + c)

    @staticmethod
    def _chunk_zero(
        chunk: Chunk,
        a: float,
        b: float,
        c: float,
        side: float,
        lo: float,
        hi: float,
        derivative: bool = False,
    ) -> float:
        """The first zero in ``[lo, hi]`` of ``side * h`` (``derivative``: of ``side * h'``)
        on the step's polynomial, where the function is >= 0 at ``lo`` and < 0 at ``hi``
        (``derivative``: < 0 at ``lo``, >= 0 at ``hi``): Newton steps on the polynomial
        (crossings), kept inside the bracket by Illinois regula falsi, to rounding of the
        time."""
        rule = chunk.rule
        # the function and (crossings only: the rate of h' would need the jerk, so closest
        # approaches use regula falsi alone) its rate at the nodes
        if derivative:
            g_nodes = -side * (a * chunk.v + b * chunk.u)
            d_nodes = None
        else:
            g_nodes = side * (a * chunk.x + b * chunk.v + c)
            d_nodes = side * (a * chunk.v + b * chunk.u)

        def f(t: float) -> tuple[float, float]:
            row = interpolation_row(rule, float(chunk.s_of(t)))
            if d_nodes is None:
                return float(row @ g_nodes), math.nan
            return float(row @ g_nodes), float(row @ d_nodes)

        f_lo, _ = f(lo)
        f_hi, d_hi = f(hi)
        if f_lo <= 0.0:
            return lo
        if f_hi >= 0.0:
            return hi
        kept = 0
        t, ft, dt_ = hi, f_hi, d_hi
        for _ in range(_MAX_ROOT_ITER):
            # Newton from the last point when it stays inside the bracket, else Illinois
            step = -ft / dt_ if (math.isfinite(dt_) and dt_ != 0.0) else math.nan
            t_new = t + step
            if math.isfinite(step) and abs(step) <= 4.0 * _EPS * max(1.0, abs(t)):
                return t_new  # converged to rounding of the time
            if not (lo < t_new < hi):
                t_new = hi - f_hi * (hi - lo) / (f_hi - f_lo)
                if not (lo < t_new < hi):
                    t_new = 0.5 * (lo + hi)
            t = t_new
            ft, dt_ = f(t)
            if ft == 0.0:
                return t
            if ft > 0.0:
                lo, f_lo = t, ft
                if kept == 1:
                    f_hi *= 0.5  # Illinois: the end kept twice is halved
                kept = 1
            else:
                hi, f_hi = t, ft
                if kept == -1:
                    f_lo *= 0.5
                kept = -1
            if hi - lo <= 4.0 * _EPS * max(1.0, abs(hi)):
                break
        # a crossing: the first time known beyond the surface (the state is then projected
        # onto it, as after DOP853's event location); a closest approach: either end
        return hi

    @staticmethod
    def _dop853_field(mode: _Mode, sensitivity: bool) -> Callable:
        """The frozen field of a mode for ``solve_ivp`` (with the variational equations)."""
        if not sensitivity:
            acc = mode.acc

            def fun(t: float, z: np.ndarray) -> np.ndarray:
                return np.array([z[1], acc(t, z[0], z[1])])

            return fun
        derivs = mode.derivs

        def fun_s(t: float, z: np.ndarray) -> np.ndarray:
            a, ax, av, _ = derivs(t, z[0], z[1])
            return np.array([z[1], a, z[4], z[5], ax * z[2] + av * z[4], ax * z[3] + av * z[5]])

        return fun_s

    def _classify(
        self, st: _State, j: int, t_e: float, y_e: np.ndarray, phi: np.ndarray | None, out: _Run
    ) -> None:
        """Decide cross / stick / graze at an exit event of surface ``j`` from a region."""
        s = self.surfaces[j]
        old = st.sigma[j]
        new_sigma = self._flip(st.sigma, j, -old)
        # outward normal speed and acceleration in the old field (positive: leaving)
        hd, hdd, hd_scale, hdd_scale = self._normal_rates(st.sigma, j, t_e, y_e)
        w_o, acc_o = -old * hd, -old * hdd
        tol_w = _ZERO_ULPS * _EPS * hd_scale
        depth_tol = self._graze_depth(s, y_e)
        graze = False
        guard_until = t_e
        if w_o <= tol_w:
            # touching: a graze unless the old field accelerates the orbit outwards
            graze = not (acc_o > _ZERO_ULPS * _EPS * hdd_scale)
        elif acc_o < 0 and w_o * w_o / (2.0 * -acc_o) <= depth_tol:
            # a crossing whose excursion (in the old field) would stay within the
            # integration error: the orbit only touches the surface
            graze = True
            guard_until = t_e + 4.0 * w_o / -acc_o
        if graze:
            out.events.append(EventRecord(t_e, j, "graze", float(y_e[0]), float(y_e[1])))
            st.t, st.y, st.phi = t_e, y_e, phi
            st.guard = {j: guard_until}
            return
        y_p = _project(s, y_e)
        into = self._goes_into(st.sigma, j, -old, t_e, y_p)
        if into < 0 and s.b != 0.0:
            # the far field pushes back: both fields point into the surface -> sliding
            y_s = np.array([y_p[0], -(s.a * y_p[0] + s.c) / s.b + 0.0])
            if phi is not None:
                phi = self._slide_entry(st.sigma, j, t_e, y_s) @ phi
            out.events.append(EventRecord(t_e, j, "stick", float(y_s[0]), float(y_s[1])))
            st.t, st.y, st.phi, st.slide = t_e, y_s, phi, j
            st.guard = {}
            return
        if phi is not None:
            phi = self._saltation(st.sigma, new_sigma, s.normal, t_e, y_p) @ phi
        out.events.append(EventRecord(t_e, j, "cross", float(y_p[0]), float(y_p[1])))
        st.t, st.y, st.phi, st.sigma = t_e, y_p, phi, new_sigma
        st.guard = self._restart_guard(new_sigma, t_e, y_p, j)

    def _graze_depth(self, s: Surface, y: np.ndarray) -> float:
        """Excursions across ``s`` shallower than this are grazes: a few local errors of
        the integrator, the level to which the position of the orbit is known."""
        scale = abs(s.a * y[0]) + abs(s.b * y[1]) + abs(s.c)
        return _GRAZE_LOCAL_ERRORS * (self.atol * (abs(s.a) + abs(s.b)) + self.rtol * scale)

    def _restart_guard(
        self, sigma: Sequence[int], t: float, y: np.ndarray, j: int
    ) -> dict[int, float]:
        """Mask the surface just crossed, and any other lying at the restart point."""
        guard = {j: t}
        for k in self._mode(sigma).active:
            if abs(self.surfaces[k](y[0], y[1])) <= self._tol_h(k, y):
                guard[k] = t
        return guard

    def _saltation(
        self,
        before: Sequence[int],
        after: Sequence[int],
        n: np.ndarray,
        t: float,
        y: np.ndarray,
    ) -> np.ndarray:
        r""":math:`S = I + (f_a - f_b) n^T / (n^T f_b)` for a crossing at ``(t, y)``."""
        fb = self._field(before, t, y)
        fa = self._field(after, t, y)
        jump = fa - fb
        if not np.any(jump):
            return np.eye(2)
        den = float(n @ fb)
        if den == 0.0:
            raise PerturbError(
                f"sensitivity undefined at t = {t!r}: the orbit crosses a discontinuity of the "
                "field tangentially (grazing)"
            )
        return np.eye(2) + np.outer(jump, n) / den

    def _slide_segment(self, st: _State, t1: float, out: _Run) -> bool:
        out.chunks = None
        j = st.slide
        assert j is not None
        s = self.surfaces[j]
        sa, sb, sc = s.a, s.b, s.c
        slope = -sa / sb
        self._refresh(st)
        fm, fp = self._slide_fields(st.sigma, j)

        def on_v(x):  # v on the surface (exactly 0.0 for sticking, h = v)
            return -(sa * x + sc) / sb + 0.0

        def exit_monitor(mode: _Mode, side: int) -> _Monitor:
            acc, derivs = mode.acc, mode.derivs

            def g(t: float, z: np.ndarray) -> float:
                v = on_v(z[0])
                return sa * v + sb * acc(t, z[0], v)

            def gdot(t: float, z: np.ndarray) -> float:
                v = on_v(z[0])
                _, ax, av, at = derivs(t, z[0], v)
                # along the sliding motion x' = v, v' = slope * v
                return sa * slope * v + sb * (at + ax * v + av * slope * v)

            def tol(t: float, z: np.ndarray) -> float:
                v = on_v(z[0])
                scale = abs(sa * v) + abs(sb) * (abs(fm.acc(t, z[0], v)) + abs(fp.acc(t, z[0], v)))
                return _ZERO_ULPS * _EPS * scale

            return _Monitor(g, gdot, side, st.t, tol)

        # n.f- > 0 > n.f+ while sliding; an exit when either reaches zero (the equivalent
        # control reaches -1 or +1)
        monitors = [exit_monitor(fm, 1), exit_monitor(fp, -1)]
        others = []
        for k in sorted((fm.active | fp.active) - {j}):
            sk = self.surfaces[k]
            rate = sk.a + sk.b * slope  # d h_k / dx along the surface
            if rate == 0.0:
                continue  # h_k is constant along this sliding surface
            others.append(k)

            def g(t: float, z: np.ndarray, sk: Surface = sk) -> float:
                return sk.a * z[0] + sk.b * on_v(z[0]) + sk.c

            def gdot(t: float, z: np.ndarray, rate: float = rate) -> float:
                return rate * on_v(z[0])

            def tol(t: float, z: np.ndarray, sk: Surface = sk) -> float:
                return _ZERO_ULPS * _EPS * (abs(sk.a * z[0]) + abs(sk.b * on_v(z[0])) + abs(sk.c))

            monitors.append(_Monitor(g, gdot, st.sigma[k], st.guard.get(k, -np.inf), tol))

        def fun(t: float, z: np.ndarray) -> np.ndarray:
            return np.array([on_v(z[0])])

        def xv(y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            return y[0], on_v(y[0])

        t_start = st.t
        hit, kind, t_end, z_e = self._segment(
            fun, st.t, t1, np.array([float(st.y[0])]), monitors, out, xv, self._slide_max_step
        )
        x_end = float(z_e[0])
        y_end = np.array([x_end, on_v(x_end)])
        if st.phi is not None:
            e = math.exp(slope * (t_end - t_start))
            st.phi = np.array([[e, 0.0], [slope * e, 0.0]]) @ st.phi
        st.t, st.y = t_end, y_end
        if hit is None:
            return True
        if kind == "graze":
            # the equivalent control touched -1 or +1, or another surface was touched: keep
            # sliding
            surf = j if hit < 2 else others[hit - 2]
            out.events.append(EventRecord(t_end, surf, "graze", x_end, float(y_end[1])))
            st.guard = {} if hit < 2 else {surf: t_end}
            return False
        if hit < 2:
            side = -1 if hit == 0 else 1
            out.events.append(EventRecord(t_end, j, "slip", x_end, float(y_end[1])))
            st.sigma = self._flip(st.sigma, j, side)
            st.slide = None
            st.guard = self._restart_guard(st.sigma, t_end, y_end, j)
            # leaving is tangential (f_s equals the exit field there): saltation I
            return False
        kk = others[hit - 2]
        st.sigma = self._flip(st.sigma, kk, -st.sigma[kk])
        out.events.append(EventRecord(t_end, kk, "cross", x_end, float(y_end[1])))
        side = self._side_on_surface(st.sigma, j, t_end, y_end)
        if side == 0:
            st.guard = {kk: t_end}
            return False
        # the crossing ended the sliding mode: the field jumps from f_s to f_side at h_k = 0
        st.sigma = self._flip(st.sigma, j, side)
        st.slide = None
        if st.phi is not None:
            nk = self.surfaces[kk].normal
            fs = np.array([y_end[1], slope * y_end[1]])
            fa = self._field(st.sigma, t_end, y_end)
            den = float(nk @ fs)
            if den == 0.0:
                raise PerturbError(f"sensitivity undefined at t = {t_end!r} (tangential exit)")
            st.phi = (np.eye(2) + np.outer(fa - fs, nk) / den) @ st.phi
        out.events.append(EventRecord(t_end, j, "slip", x_end, float(y_end[1])))
        st.guard = self._restart_guard(st.sigma, t_end, y_end, j)
        st.guard[kk] = t_end
        return False


#: the first collocation step of a call, as a fraction of the forcing period (2 pi when
#: autonomous); later steps follow the error estimate
_FIRST_CHUNK = 0.25
#: collocation steps allowed in one smooth segment, and per forcing period of its span (a
#: period takes a handful)
_MAX_CHUNKS = 10_000
#: the collocation step length may shrink to this fraction of max(1, |t|, span) before the
#: segment falls back to DOP853
_MIN_CHUNK = 1e-9
#: regula falsi iterations locating one event on a step's polynomial
_MAX_ROOT_ITER = 100


def _augmented(x: float, v: float, phi: np.ndarray | None) -> np.ndarray:
    """The state ``(x, v)``, followed by the sensitivity's entries when there is one."""
    if phi is None:
        return np.array([x, v])
    return np.concatenate([[x, v], phi.ravel()])


_FINE: dict[int, tuple[np.ndarray, np.ndarray]] = {}


def _fine_samples(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Interpolation matrix and points of the ``2 n + 1`` equally spaced samples of a step
    (events are looked for between them)."""
    hit = _FINE.get(n)
    if hit is None:
        s = np.linspace(-1.0, 1.0, 2 * n + 1)
        L = interpolation_matrix(chebyshev_rule(n), s)
        L.setflags(write=False)
        s.setflags(write=False)
        hit = _FINE[n] = (L, s)
    return hit


@dataclass(frozen=True)
class _Monitor:
    """A function ``g(t, z)`` that must keep the sign ``side`` during a segment, its time
    derivative along the segment's field, the time up to which it is masked (a restart on
    its zero set) and its rounding level."""

    g: Callable[[float, np.ndarray], float]
    gdot: Callable[[float, np.ndarray], float]
    side: int
    guard: float
    tol: Callable[[float, np.ndarray], float]
    graze_depth: Callable[[float, np.ndarray], float] | None = None


def _crossing_event(m: _Monitor):
    g, side, guard = m.g, float(m.side), m.guard

    def ev(t: float, z: np.ndarray) -> float:
        # masked at a restart on the zero set, so the restart point is never a root; an
        # exact zero counts as inside (solve_ivp's sign test is not strict, and a function
        # that stays 0, e.g. at rest on the surface, would fire at every step)
        if t <= guard:
            return side
        val = g(t, z)
        return val if val != 0.0 else side

    ev.terminal, ev.direction = True, -m.side  # type: ignore[attr-defined]
    return ev


def _turning_event(m: _Monitor, t_turn: float):
    gdot, side = m.gdot, float(m.side)
    # also masked while the monitor is (after a graze, the excursion's own turn is no event)
    t_turn = max(t_turn, m.guard)

    def ev(t: float, z: np.ndarray) -> float:
        # exact zeros count as receding: g' is identically 0 when g is constant (sticking
        # without forcing), which must not fire at every step
        if t <= t_turn:
            return side
        val = gdot(t, z)
        return val if val != 0.0 else side

    # closest approach: g' changes from approaching (-side) to receding (+side)
    ev.terminal, ev.direction = True, m.side  # type: ignore[attr-defined]
    return ev


def _xv_state(y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return y[0], y[1]


def _memo_samples(chunks: list[tuple[Chunk, float]], te: np.ndarray) -> np.ndarray:
    """States ``(len(te), 2)`` at times ``te`` from the steps of a run (each time from the
    first step whose piece ends at or after it)."""
    out = np.empty((len(te), 2))
    ends = np.array([t_end for _, t_end in chunks])
    which = np.minimum(np.searchsorted(ends, te, side="left"), len(chunks) - 1)
    for k in np.unique(which):
        sel = which == k
        out[sel] = chunks[int(k)][0].states(te[sel]).T
    return out


class _Run:
    """Accumulates the output of one :meth:`EventFlow._run`: samples at ``t_eval`` (or at
    every step when ``dense``), events, restarts, final state and sensitivity."""

    def __init__(self, t0: float, t_eval: np.ndarray | None, dense: bool) -> None:
        self.t_eval, self.dense = t_eval, dense
        self.t_lo, self.inclusive = t0, True
        self.y: np.ndarray | None = None
        self.phi: np.ndarray | None = None
        self.events: list[EventRecord] = []
        self.n_restarts = 0
        #: (chunk, t_end) of every collocation step taken, in time order; None once a
        #: segment was integrated otherwise (DOP853, sliding)
        self.chunks: list[tuple[Chunk, float]] | None = []
        self._t: list[np.ndarray] = []
        self._x: list[np.ndarray] = []
        self._v: list[np.ndarray] = []

    def request(self, t1: float) -> tuple[np.ndarray | None, bool]:
        """``t_eval`` for the next ``solve_ivp`` call, with ``t1`` appended (flag True) so
        that the final state is always returned."""
        if self.t_eval is None:
            return None, False
        te = self.t_eval
        te = te[np.searchsorted(te, self.t_lo, side="left" if self.inclusive else "right") :]
        if te.size and te[-1] == t1:
            return te, False
        return np.append(te, t1), True

    def add(self, t, y, xv, upto: float, drop_last: bool = False) -> None:
        """Record samples up to ``upto`` that are later than those already recorded."""
        if not (self.dense or self.t_eval is not None) or not len(t):
            return
        t = np.asarray(t, dtype=float)
        y = np.asarray(y, dtype=float)
        if drop_last:
            t, y = t[:-1], y[:, :-1]
        keep = (t <= upto) & ((t >= self.t_lo) if self.inclusive else (t > self.t_lo))
        x, v = xv(y[:, keep])
        self._t.append(t[keep])
        self._x.append(np.asarray(x, dtype=float))
        self._v.append(np.asarray(v, dtype=float) + 0.0)
        if keep.any():
            self.t_lo, self.inclusive = float(t[keep][-1]), False

    def advance(self, t: float) -> None:
        """Later samples must be after ``t`` (a restart time, already reported)."""
        self.t_lo, self.inclusive = t, False

    def finish(self) -> None:
        cat = np.concatenate
        self.ts = cat(self._t) if self._t else np.empty(0)
        self.xs = cat(self._x) if self._x else np.empty(0)
        self.vs = cat(self._v) if self._v else np.empty(0)


# --------------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------------
def _where(t: float, y: np.ndarray) -> str:
    return f"state (x, x') = ({float(y[0])!r}, {float(y[1])!r}) at t = {float(t)!r}"


def _project(s: Surface, y: np.ndarray) -> np.ndarray:
    """Put ``y`` exactly on the surface by moving the coordinate with the larger
    coefficient (the located root is off by a few ulps of time)."""
    x, v = float(y[0]), float(y[1])
    if abs(s.b) >= abs(s.a):
        v = -(s.a * x + s.c) / s.b + 0.0
    else:
        x = -(s.b * v + s.c) / s.a + 0.0
    return np.array([x, v])


def _state(name: str, y: ArrayLike) -> np.ndarray:
    try:
        arr = np.asarray(y, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ParameterError(f"{name} = {y!r}: expected two finite numbers (x, x')") from None
    if arr.size != 2 or not np.all(np.isfinite(arr)):
        raise ParameterError(
            f"{name} = {np.asarray(y).tolist()!r}: expected two finite numbers (x, x')"
        )
    return arr


def _span(t0: float, t1: float) -> tuple[float, float]:
    try:
        a, b = float(t0), float(t1)
    except (TypeError, ValueError):
        raise ParameterError(f"(t0, t1) = ({t0!r}, {t1!r}): expected two numbers") from None
    if not (math.isfinite(a) and math.isfinite(b) and b > a):
        raise ParameterError(f"(t0, t1) = ({t0!r}, {t1!r}): expected finite t1 > t0")
    return a, b


def _times(t_eval: ArrayLike | None, t0: float, t1: float) -> np.ndarray | None:
    if t_eval is None:
        return None
    try:
        te = np.asarray(t_eval, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ParameterError(f"t_eval = {t_eval!r}: expected an array of times") from None
    if not np.all(np.isfinite(te)):
        raise ParameterError("t_eval contains NaN or inf: expected finite times")
    if te.size and (te[0] < t0 or te[-1] > t1 or np.any(np.diff(te) <= 0)):
        raise ParameterError(
            f"t_eval spans [{te.min()!r}, {te.max()!r}]: expected strictly increasing times "
            f"inside [{t0!r}, {t1!r}]"
        )
    return te


# --------------------------------------------------------------------------------------------
# module-level front doors
# --------------------------------------------------------------------------------------------
def switching_surfaces(osc: Oscillator, Omega: float | None = None) -> tuple[Surface, ...]:
    """The switching surfaces of an oscillator (see :class:`EventFlow`)."""
    return EventFlow(osc, Omega).surfaces


def simulate(
    osc: Oscillator,
    y0: ArrayLike,
    t_span: Sequence[float],
    *,
    Omega: float | None = None,
    t_eval: ArrayLike | None = None,
    rtol: float = 1e-11,
    atol: float = 1e-12,
    max_events: int = 100_000,
) -> EventTrajectory:
    r"""Time history of a piecewise-smooth oscillator by event-driven integration.

    Parameters
    ----------
    osc
        Oscillator with all parameter values set.
    y0
        Initial ``(x, x')`` at ``t_span[0]``.  On a switching surface the mode is chosen by
        where the fields carry the orbit (an attracting sliding surface starts sliding).
    t_span
        ``(t0, t1)`` with ``t1 > t0``.
    Omega
        Override of the forcing frequency.
    t_eval
        Strictly increasing output times in ``[t0, t1]``; default: every accepted step.
    rtol, atol
        DOP853 tolerances per smooth segment.
    max_events
        Largest number of events before giving up.

    Returns
    -------
    EventTrajectory
        Samples, the event log (crossings, stick/slip, grazes) and the restart count.

    Raises
    ------
    ParameterError
        Bad ``y0``, ``t_span``, ``t_eval`` or tolerances.
    ModelError
        Switching arguments that are nonlinear in the state or depend on time; impulses.
    PerturbError
        Non-unique continuation (repelling sliding), codimension-2 sliding, Zeno behaviour,
        too many events, or an orbit escaping to infinity.

    Examples
    --------
    Coulomb friction, free: two half cycles, then sticking at ``x = 1 - 4(0.2) = 0.2``

    >>> from perturb.model.oscillator import Oscillator
    >>> osc = Oscillator.parse("x'' + x + 0.2*sign(x') = 0")
    >>> tr = simulate(osc, [1.0, 0.0], (0.0, 10.0))
    >>> [(e.kind, round(e.time, 9)) for e in tr.events]
    [('cross', 3.141592654), ('stick', 6.283185307)]
    """
    flow = EventFlow(osc, Omega, rtol=rtol, atol=atol, max_events=max_events)
    return flow.simulate(y0, t_span, t_eval=t_eval)
