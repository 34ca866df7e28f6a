r"""Autonomous harmonic balance: limit cycles of a :class:`~perturb.model.system.System` whose
frequency is an unknown, continued in a parameter, with Floquet stability.

The system (no harmonic forcing; constant inputs allowed)

.. math::

    M q'' + D p' + C q' + K q + E p + \sum_e w_e f_e(c_e\cdot y) = F_0,
    \qquad y = (q, q', p),

is sought as a truncated series in :math:`\theta = \omega t` with the unknown frequency
:math:`\omega`: every coordinate and first-order state ``z_j`` has coefficients ``U[j] =
[a0, a_1, b_1, ..., a_H, b_H]`` in the :class:`~perturb.fourier.projection.HarmonicBasis`
(the layout of :mod:`perturb.numeric.system_balance`). The Galerkin residual is the one of
:class:`~perturb.numeric.system_balance.SystemBalance` with the forcing frequency replaced by
the unknown :math:`\omega`,

.. math::

    R(U, \omega) = \omega^2 M U_q D_\theta^{2T} + \omega (C U_q + D U_p) D_\theta^T + K U_q
        + E U_p + \sum_e w_e \otimes P_e(S_e) - \hat F_0 ,

and one more equation fixes the phase (an autonomous orbit shifted in time is an orbit): the
``sin theta`` coefficient of the *phase coordinate* (default: the coordinate with the largest
first harmonic in the start) is zero, ``b_1 = 0``. Unknowns ``x = (U flattened, omega)``,
``n (2H + 1) + 1`` equations. The Jacobian is analytic: ``dR/dU`` by coordinate blocks
(``w_i J_e (alpha_j I + omega beta_j D_theta)`` per element, assembled dense: the
continuation core takes dense matrices), ``dR/d omega`` in closed form; a jump's one-sided
values are extrapolated from ``1e-6`` beside the level (error ~1e-12).

Why not ``SystemBalance`` itself: it continues a forcing frequency and refuses a parameter
that enters the matrices or elements (a limit cycle is continued in a damping, a belt speed,
...), and it samples a non-PWL discontinuous force (Stribeck friction) by AFT. This module
compiles the system once per (system, parameter) with the parameter left as an argument (no
SymPy per evaluation) and reuses the public pieces of the Fourier layer: the basis, the
certified switching angles (:func:`~perturb.fourier.projection.switching_angles`) and the
exact PWL projector.

Projection of the elements
--------------------------
* **piecewise-linear** element whose function does not depend on the continuation parameter:
  the exact projector (:class:`~perturb.fourier.projection.ExactProjector`).
* **piecewise-smooth** element (``sign``, ``Abs``, ``Heaviside``, ``Max``, ``Min`` of
  arguments linear in ``s``, around smooth functions: the Stribeck law
  ``N [mu_k + (mu_s - mu_k) exp(-|s - v_b|/v_s)] sign(s - v_b)``): the switching angles of
  ``s(theta)`` at every switch level are found exactly (certified isolation of the Fourier
  layer), and each piece between two switches is integrated by Gauss–Legendre quadrature
  (``quadrature`` nodes per period shared by length, at least 8 per piece): each piece's
  integrand is analytic, so the projection converges exponentially in the nodes, not like
  the ``O(N^-1)`` of AFT sampling of a jump. The Jacobian includes the moving switches:
  ``(f(b+) - f(b-)) phi_k phi_j / |s'(theta_c)|`` per crossing.
* **smooth** element of a combination, or a term in the states (van der Pol's
  ``eps x^2 x'``): AFT with ``quadrature`` uniform samples (polynomials of degree 3 are
  projected exactly once ``quadrature >= 4H + 1``).

Friction jumps and sticking (what is done)
-----------------------------------------
A friction contact that sticks keeps ``s = v_b`` over an interval; a truncated series cannot,
so the HB orbit of the exact discontinuous law crosses ``s = v_b`` back and forth through
the sticking phase (the belt at H = 25: 14 crossings with ``|s'|`` down to ``5e-4``). Each
such crossing adds ``jump / |s'|`` to the Jacobian (condition number ~1e6 there), every birth
of a crossing pair is a grazing point where the residual has a square-root corner, and the
saltation of a crossing at a tiny rate makes the monodromy meaningless (multipliers ~1e36
measured). So by default each jump ``J`` at a level ``b`` is spread into
``J/2 tanh((s - b)/eps)`` (the smooth part of the law kept exactly, the switching angles still
splitting the quadrature) with the width ``eps = 0.05 d / H`` (``d``: distance from the
equilibrium's signal to the level; ``jump_width`` sets it): narrower than the resolution of
H harmonics, so the regularisation error falls with ``H`` like the truncation error; the
``tanh`` acts as the sticking force (its steep slope contracts the perturbations of ``s``, and
the multiplier of the sticking direction comes out near 0, as the exact cycle's).
``jump_width = 0`` keeps the exact law: the cycle is narrowed by continuation to a hundredth
of the start width and Newton on the exact law finishes (it converges at some ``H`` only: the
belt at H = 15 and 25, not at H = 9; where it converges its errors are those of the default
width within a factor 1.5, so the regularisation error does not dominate). Measured on the belt
(``benchmarks/bench_autonomous_balance.py``, against the event-driven exact cycle with
Filippov sticking): relative error of the period 1.1e-2 (H = 3), 8.4e-3 (9), 3.7e-3 (15),
7.1e-4 (25), 6.1e-4 (63), of ``max |x|`` 1.8e-2, 1.7e-2, 8.8e-3, 2.2e-3, 1.5e-3 (roughly
``1/H``, not monotone), in 0.10-1.1 s CPU (the exact search: 1.47 s).

Starting without a guess (the Hopf start)
-----------------------------------------
1. The equilibrium: damped Newton on the static equations (velocities zero) from the zero
   state and from the linear part's equilibrium.
2. Its linearisation ``A = df/dy`` (central differences of the vector field): the complex
   pair with the largest positive real part gives the frequency ``omega_0 = Im lambda`` and
   the shape of a small orbit (eigenvector). An unstable node (real eigenvalues only: van
   der Pol at ``eps >= 2``): the smallest artificial damping ``delta`` of step 3 that makes
   the equilibrium neutral is found (grid and bisection); when a complex pair crosses the
   imaginary axis there, it is the start (at that ``delta``). Otherwise no self-excited
   oscillation is found there, and :class:`AutonomousBalanceError` asks for a guess.
3. Artificial damping ``delta``: the residual ``R + delta G`` with ``G = M q'`` (second-order
   rows) and ``D p`` (first-order rows) has a small orbit of amplitude ``A_0`` (a thousandth
   of the equilibrium's scale, and well inside the switch levels) near the damping
   ``delta_1`` that moves the pair onto the imaginary axis: Newton on ``(U, omega,
   delta)`` with the amplitude fixed.
4. Continuation (THE core, :func:`~perturb.numeric.continuation.continue_curve`) of ``(U,
   omega)`` in ``delta`` from ``delta_1`` to ``0``, in the direction in which the orbit grows
   (a Stribeck law's negative damping first steepens: ``delta`` first rises): the amplitude
   grows along the way, folds are passed; the last point, placed on ``delta = 0``, is the
   limit cycle. A run that stalls (a grazing onset of a non-smoothed switch) is bridged by
   a fixed-amplitude solve at a larger amplitude and restarted (at most 6 times).
5. With friction jumps, steps 3-4 run at 4 times the default width and the cycle is then
   continued in the width down to the requested one (the same core).

Stability
---------
Floquet multipliers of the HB orbit: the monodromy of the variational equation
``dY/dtheta = A(theta) Y / omega`` over one period, by a fourth-order Magnus step (two Gauss
points) on ``monodromy_steps`` sub-intervals per period (default ``max(128, 16 H)``), split at
every switching angle; a force that jumps there adds its saltation matrix (exact law only;
a smoothed jump enters through the slope of its ``tanh``). The multiplier
closest to 1 is the trivial one (the phase direction; for the HB orbit it is 1 within the
truncation error) and is reported apart; the orbit is stable when every other multiplier has
modulus at most ``1 + 1e-6``.

Continuation in a parameter
---------------------------
:func:`autonomous_balance_branch` traces ``x(p)`` with the continuation core both ways from
the start and joins the two runs; ``dR/dp`` is a central difference of the residual (step
``1e-6 max(1, |p|)``; the parameter may move a switch level, whose exact derivative would need
the crossing terms again). A branch ending at a Hopf point (amplitude to zero, where the
frequency is no longer fixed by the equations) stops there, its stop reason reported.

Measured (``PYTHONPATH=. python benchmarks/bench_autonomous_balance.py``, CPU, one BLAS
thread, load ~10 on 2 cores; ``benchmarks/results/bench_autonomous_balance.md``): van der Pol
eps = 1, Hopf start and multipliers, H = 3 .. 31 in 0.021-0.046 s (95-217x faster than the
exact ``limit_cycles`` search, 4.7-10x faster than a DOP853 shooting polish alone); period
error 3e-4 (H = 3), 7e-13 (H = 15), 1e-16 (H = 21); nontrivial multiplier within 2e-6
(H = 15) of the shooting monodromy's.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import numpy as np
import scipy.linalg as sla
import sympy as sp
from numpy.typing import ArrayLike

from perturb import checks
from perturb.errors import ModelError, NonsmoothError, ParameterError, PerturbError
from perturb.fourier.projection import ExactProjector, HarmonicBasis, switching_angles
from perturb.model.pwl import to_pwl
from perturb.model.system import S as _S_SYMBOL
from perturb.model.system import System
from perturb.numeric.continuation import ContinuationError, continue_curve

__all__ = [
    "AutonomousBalance",
    "AutonomousBalanceSolution",
    "AutonomousBalanceBranch",
    "AutonomousBalanceError",
    "autonomous_balance_orbit",
    "autonomous_balance_branch",
]

_TWO_PI = 2.0 * math.pi
#: Modulus above which a nontrivial Floquet multiplier makes the orbit unstable.
_UNIT_TOL = 1e-6
#: Models (matrices and element data) kept per parameter value.
_MODEL_CACHE = 8
#: The artificial damping of the Hopf start may grow up to this multiple of its start value
#: before it turns back to zero.
_DAMPING_SPAN = 20.0
#: Restarts of the Hopf homotopy across a grazing onset, and the relative amplitude steps
#: tried for each.
_BRIDGES = 6
_BRIDGE_STEPS = (0.05, 0.15, 0.4, 1.0)
#: Default width of the tanh that replaces a jump: this fraction of the distance from the
#: equilibrium's signal to the level, divided by H; the Hopf start is made at
#: _START_WIDENING times it and the cycle narrowed by continuation.
_WIDTH_FACTOR = 0.05
_START_WIDENING = 4.0
#: Point cap of the continuation that narrows the jumps.
_NARROW_POINTS = 400
#: Largest H accepted: the Jacobian is dense (n (2H + 1) + 1 unknowns) and every evaluation
#: samples 8H + 1 points; at H = 200 one van der Pol cycle already takes ~23 s CPU.
MAX_HARMONICS = 256
_SWITCH_TYPES = (sp.Heaviside, sp.Abs, sp.sign, sp.Max, sp.Min, sp.Piecewise)


class AutonomousBalanceError(PerturbError):
    """Autonomous harmonic balance failed (no oscillation to start from, no convergence)."""


# =============================================================================================
# compiled elements
# =============================================================================================
@dataclass(eq=False)
class _Element:
    name: str
    kind: str  # "pwl" | "piecewise" | "smooth" (function of s) | "states"
    c: Any  # callable p -> (n,) combination over y
    w: Any  # callable p -> (neq,) distribution
    f: Any  # f(s, p) or f(*y, p), vectorised
    df: Any  # f'(s, p), or the gradient list in y
    levels: Any = None  # callable p -> sorted switch levels in s
    projector: ExactProjector | None = None


def _broadcast(fn):
    """A lambdified function whose result has the shape of its first argument."""

    def call(*args):
        out = fn(*args)
        return np.broadcast_to(np.asarray(out, dtype=float), np.shape(args[0])).astype(float)

    return call


def _switch_arguments(expr: sp.Expr) -> list[sp.Expr]:
    """The arguments whose sign switches a nonsmooth expression."""
    out: list[sp.Expr] = []
    for atom in expr.atoms(*_SWITCH_TYPES):
        if isinstance(atom, sp.Heaviside | sp.Abs | sp.sign):
            out.append(atom.args[0])
        elif isinstance(atom, sp.Max | sp.Min):
            a = atom.args
            out.extend(a[i] - a[j] for i in range(len(a)) for j in range(i + 1, len(a)))
        else:  # Piecewise: the sides of every relational condition
            for _, cond in atom.args:
                for rel in cond.atoms(sp.core.relational.Relational):
                    out.append(rel.lhs - rel.rhs)
    return out


# =============================================================================================
# the balance problem
# =============================================================================================
class AutonomousBalance:
    """Residual, Jacobian, solutions and Floquet multipliers of the autonomous harmonic
    balance of a :class:`~perturb.model.system.System` (module docstring).

    Parameters
    ----------
    system : System or Oscillator
        Autonomous (no harmonic forcing); every parameter needs a value (``parameter`` too,
        as its default). An SDOF ``Oscillator`` is converted by ``System.from_oscillator``.
    harmonics : int
        ``1 <= H <= MAX_HARMONICS`` (256).
    parameter : str, optional
        The parameter to continue in (kept as an argument of the compiled functions).
    quadrature : int, optional
        Quadrature nodes per period (AFT samples of smooth terms, Gauss nodes shared by the
        pieces of a piecewise-smooth element); default ``max(64, 8 H + 1)``.
    monodromy_steps : int, optional
        Magnus steps per period of the monodromy (default ``max(128, 16 H)``).
    jump_width : float, optional
        Width ``eps`` (in the element's signal) of the ``tanh`` that replaces each jump of a
        piecewise-smooth element (friction): default ``0.05 d / H`` (:meth:`auto_jump_width`);
        ``0`` keeps the exact discontinuous law (module docstring: ill-conditioned while
        the HB orbit chatters across a sticking phase).

    Attributes
    ----------
    basis : HarmonicBasis
    coordinates : tuple of str
        Names of the rows of the coefficients, ``(*system.coordinates, *system.first_order)``.
    size : int
        Coefficients per coordinate, ``2 H + 1``.
    n_unknowns : int
        ``len(coordinates) * size + 1`` (the frequency last).
    smoothing : float
        The width of the ``tanh`` of the jumps in force (0: exact law or no jumps).

    Raises
    ------
    ParameterError
        ``H < 1``, a parameter not in the system, missing values, bad ``quadrature``.
    ModelError
        A forced system, a rigid stop, a switch whose argument is not linear in ``s``, a
        nonsmooth term that is no function of one combination.
    """

    def __init__(
        self,
        system: Any,
        harmonics: int = 7,
        *,
        parameter: str | None = None,
        quadrature: int | None = None,
        monodromy_steps: int | None = None,
        jump_width: float | None = None,
    ) -> None:
        system = _as_system(system)
        self.basis = HarmonicBasis.make(harmonics)  # ParameterError for H < 1
        if harmonics > MAX_HARMONICS:
            raise ParameterError(
                f"harmonics = {harmonics!r}: expected at most {MAX_HARMONICS} (the Jacobian "
                "is dense, n (2H + 1) + 1 unknowns)"
            )
        self.H = int(harmonics)
        if parameter is not None:
            if not isinstance(parameter, str) or parameter not in system.params:
                raise ParameterError(
                    f"parameter {parameter!r} is not in system {system.name!r}: expected one "
                    f"of {', '.join(system.params) or 'none'}"
                )
        missing = [k for k, v in system.params.items() if v is None]
        if missing:
            raise ParameterError(
                f"system {system.name!r} needs values for {', '.join(missing)} "
                "(pass them with System.with_params)"
            )
        self.system, self.parameter = system, parameter
        self.value = float(system.params[parameter]) if parameter is not None else 0.0
        self.n2 = len(system.coordinates)
        self.n1 = len(system.first_order)
        self.neq = self.n2 + self.n1
        self.coordinates = (*system.coordinates, *system.first_order)
        self.size = self.basis.size
        self.n_unknowns = self.neq * self.size + 1
        self.quadrature = self._count(quadrature, max(64, 8 * self.H + 1), "quadrature")
        self.monodromy_steps = self._count(
            monodromy_steps, max(128, 16 * self.H), "monodromy_steps"
        )
        self._Dt = self.basis.derivative_matrix()
        self._compile()
        self._models: dict[float, dict] = {}
        self._gauss: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._last: tuple | None = None
        self.evaluations = 0
        #: Width of the tanh that replaces each jump of a piecewise-smooth element (0: the
        #: exact law with its switching angles).
        self.smoothing = 0.0
        if jump_width is None:
            self.smoothing = self.auto_jump_width()
        else:
            jw = checks.finite(jump_width, "jump_width")
            if jw < 0:
                raise ParameterError(
                    f"jump_width = {jump_width!r}: expected a number >= 0 (0: the exact law)"
                )
            self.smoothing = jw

    # ---------------------------------------------------------------- set-up ----------
    def _count(self, value, default: int, what: str) -> int:
        if value is None:
            return int(default)
        if isinstance(value, bool) or not isinstance(value, int | np.integer):
            raise ParameterError(f"{what} = {value!r}: expected an integer")
        low = 2 * self.H + 1 if what == "quadrature" else 8
        # each node holds a row of the (nodes, 2H + 1) design matrix: 10**7 entries = 80 MB
        # (10**6 nodes at H = 7 already took ~60 s CPU per cycle)
        high = max(low, min(1_000_000, 10**7 // self.size))
        if value < low or value > high:
            raise ParameterError(
                f"{what} = {value!r}: expected an integer in {low}..{high} (at most 10**7 "
                f"design-matrix entries for H = {self.H})"
            )
        return int(value)

    def _compile(self) -> None:
        """Lambdify the matrices, the constant input and the elements once, with the
        continuation parameter ``P`` as an argument and every other value substituted."""
        s = self.system
        vals = {sp.Symbol(k, real=True): sp.Float(v) for k, v in s.params.items()}
        P = sp.Symbol("_autonomous_parameter", real=True)
        if self.parameter is not None:
            vals[sp.Symbol(self.parameter, real=True)] = P
        t = s.t
        if any(sp.sympify(fi).xreplace(vals).has(t) for fi in s.F):
            raise ModelError(
                f"system {s.name!r} is forced (its inputs depend on {t}): autonomous harmonic "
                "balance is for limit cycles; use perturb.numeric.system_balance for forced "
                "responses"
            )

        def mat(m: sp.Matrix):
            fn = sp.lambdify([P], sp.Matrix(m).xreplace(vals), "numpy")
            shape = m.shape
            return lambda p: np.array(fn(p), dtype=float).reshape(shape)

        self._mats = {name: mat(getattr(s, name)) for name in ("M", "D", "C", "K", "E", "F")}
        states = list(s.states)
        self._elements: list[_Element] = []
        for e in s.elements:
            if e.kind == "stop":
                raise ModelError(
                    f"element {e.name!r} of {s.name!r} is a rigid stop: harmonic balance needs "
                    "a force (a contact spring); use the exact solvers for impacts"
                )
            fexpr = sp.sympify(e.function).xreplace(vals)
            w_fn = sp.lambdify([P], [sp.sympify(x).xreplace(vals) for x in e.distribution])
            w = (lambda fn: lambda p: np.array(fn(p), dtype=float).reshape(-1))(w_fn)
            if e.combination is None:
                if fexpr.atoms(*_SWITCH_TYPES):
                    raise ModelError(
                        f"element {e.name!r}: a nonsmooth term that is no function of one "
                        "combination of the states; expected switches of c.y only"
                    )
                grad = [sp.diff(fexpr, x) for x in states]
                self._elements.append(
                    _Element(
                        e.name,
                        "states",
                        None,
                        w,
                        _broadcast(sp.lambdify([*states, P], fexpr, "numpy")),
                        [_broadcast(sp.lambdify([*states, P], g, "numpy")) for g in grad],
                    )
                )
                continue
            c_fn = sp.lambdify([P], [sp.sympify(x).xreplace(vals) for x in e.combination])
            c = (lambda fn: lambda p: np.array(fn(p), dtype=float).reshape(-1))(c_fn)
            dexpr = sp.diff(fexpr, _S_SYMBOL).replace(sp.DiracDelta, lambda *a: sp.S.Zero)
            f = _broadcast(sp.lambdify([_S_SYMBOL, P], fexpr, "numpy"))
            df = _broadcast(sp.lambdify([_S_SYMBOL, P], dexpr, "numpy"))
            levels_expr = []
            for arg in _switch_arguments(fexpr):
                if not arg.has(_S_SYMBOL):
                    continue
                slope = sp.diff(arg, _S_SYMBOL)
                if slope.has(_S_SYMBOL) or slope == 0:
                    raise ModelError(
                        f"element {e.name!r}: switch argument {arg} is not linear in s; "
                        "expected switches at fixed levels of the combination"
                    )
                levels_expr.append(sp.simplify(-(arg - slope * _S_SYMBOL) / slope))
            if not levels_expr:
                self._elements.append(_Element(e.name, "smooth", c, w, f, df))
                continue
            lv_fn = sp.lambdify([P], levels_expr, "numpy")
            levels = (lambda fn: lambda p: np.unique(np.array(fn(p), dtype=float)))(lv_fn)
            projector = None
            if not fexpr.has(P):
                try:
                    projector = ExactProjector(to_pwl(fexpr, _S_SYMBOL).numeric(), self.basis)
                except (NonsmoothError, ModelError, ParameterError, TypeError, ValueError):
                    projector = None
            kind = "pwl" if projector is not None else "piecewise"
            self._elements.append(_Element(e.name, kind, c, w, f, df, levels, projector))

    def model(self, p: float | None = None) -> dict:
        """The numbers of the system at parameter value ``p`` (cached): the coordinate-level
        matrices ``A0 = [K E]``, ``A1 = [C D]``, ``A2 = [M 0]``, ``B = [M D]`` and its
        inverse, ``L = [K C E]``, the constant input, and each element's combination,
        distribution, switch levels and the one-sided values of its function there."""
        p = self.value if p is None else checks.finite(p, self.parameter or "parameter")
        hit = self._models.get(p)
        if hit is not None:
            return hit
        n2, n1, neq = self.n2, self.n1, self.neq
        M, D, C, K, E = (self._mats[k](p) for k in ("M", "D", "C", "K", "E"))
        F0 = self._mats["F"](p).reshape(-1)
        B = np.hstack([M, D])
        cond = np.linalg.cond(B) if B.size else 1.0
        if not np.isfinite(cond) or cond > 1e14:
            raise ModelError(
                f"the mass matrix [M D] = {B.tolist()} of {self.system.name!r} is singular"
                + (f" at {self.parameter} = {p:g}" if self.parameter is not None else "")
                + ": expected an invertible matrix"
            )
        els = []
        for el in self._elements:
            w = el.w(p)
            c = el.c(p) if el.c is not None else None
            entry: dict[str, Any] = {"el": el, "w": w, "c": c}
            if c is not None:
                entry["alpha"] = np.concatenate([c[:n2], c[2 * n2 :]])
                entry["beta"] = np.concatenate([c[n2 : 2 * n2], np.zeros(n1)])
                if not (np.any(c) and np.any(w)):
                    raise ModelError(
                        f"element {el.name!r}: combination {c.tolist()} / distribution "
                        f"{w.tolist()} is identically zero: expected a nonzero combination"
                    )
            if el.levels is not None:
                b = el.levels(p)
                h = 1e-6 * np.maximum(1.0, np.abs(b))
                # one-sided limits at the switch levels, extrapolated from just beside them
                # (error O(h^2 f''): the branches are smooth up to the level)
                fp = el.f(b + h, p) - h * el.df(b + h, p)
                fm = el.f(b - h, p) + h * el.df(b - h, p)
                entry["levels"], entry["jump"] = b, fp - fm
            els.append(entry)
        out = {
            "p": p,
            "A0": np.hstack([K, E]),
            "A1": np.hstack([C, D]),
            "A2": np.hstack([M, np.zeros((neq, n1))]),
            "B": B,
            "Binv": np.linalg.inv(B),
            "L": np.hstack([K, C, E]),
            "F0": F0,
            "elements": els,
        }
        if len(self._models) >= _MODEL_CACHE:
            self._models.pop(next(iter(self._models)))
        self._models[p] = out
        return out

    # ---------------------------------------------------------------- helpers ---------
    def unpack(self, x: ArrayLike) -> tuple[np.ndarray, float]:
        """``(U, omega)`` from the flat unknowns ``x`` (``U`` of shape ``(neq, size)``)."""
        arr = np.asarray(x, dtype=float).reshape(-1)
        if arr.size != self.n_unknowns:
            raise ParameterError(
                f"x of size {arr.size}: expected {self.n_unknowns} ({self.neq} coordinates x "
                f"{self.size} coefficients + the frequency)"
            )
        return arr[:-1].reshape(self.neq, self.size), float(arr[-1])

    def pack(self, U: ArrayLike, omega: float) -> np.ndarray:
        """The flat unknowns from ``U`` (``(neq, size)``) and ``omega``."""
        U = np.asarray(U, dtype=float).reshape(self.neq, self.size)
        return np.concatenate([U.reshape(-1), [float(omega)]])

    def _gauss_rule(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        hit = self._gauss.get(n)
        if hit is None:
            hit = np.polynomial.legendre.leggauss(n)
            self._gauss[n] = hit
        return hit

    def _norm(self) -> np.ndarray:
        """Galerkin normalisation: ``a0 = (1/2pi) int``, ``a_k, b_k = (1/pi) int``."""
        nm = np.full(self.size, 1.0 / math.pi)
        nm[0] = 1.0 / _TWO_PI
        return nm

    def _crossings(self, s: np.ndarray, levels: np.ndarray):
        """Sorted crossing angles of ``s(theta)`` with every level, the level index and
        ``s'`` there."""
        th, idx = [], []
        for i, b in enumerate(levels):
            a = switching_angles(self.basis, s, float(b))
            th.append(a)
            idx.append(np.full(a.size, i))
        theta = np.concatenate(th) if th else np.empty(0)
        index = np.concatenate(idx).astype(int) if idx else np.empty(0, dtype=int)
        order = np.argsort(theta, kind="stable")
        theta, index = theta[order], index[order]
        d1 = self.basis.evaluate(s, theta, 1) if theta.size else np.empty(0)
        return theta, index, d1

    def _nodes(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Quadrature nodes and weights over one period: uniform (trapezoid, spectrally
        accurate for a smooth periodic integrand) without switches, else Gauss–Legendre on
        each piece between consecutive switches."""
        N = self.quadrature
        if theta.size == 0:
            return _TWO_PI * np.arange(N) / N, np.full(N, _TWO_PI / N)
        starts = theta
        ends = np.concatenate([theta[1:], [theta[0] + _TWO_PI]])
        nodes, weights = [], []
        for a, b in zip(starts, ends, strict=True):
            L = b - a
            if L <= 0.0:
                continue
            n = max(8, math.ceil(N * L / _TWO_PI))
            x, wq = self._gauss_rule(n)
            nodes.append(a + 0.5 * L * (x + 1.0))
            weights.append(0.5 * L * wq)
        return np.concatenate(nodes), np.concatenate(weights)

    def project(
        self, name: str, s: ArrayLike, p: float | None = None, jacobian: bool = True
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """Galerkin projection of the force of the element ``name`` (a function of one
        combination) on the signal with coefficients ``s``, and its Jacobian ``dP/ds``.

        Raises
        ------
        ModelError
            For an unknown element or a term in the states.
        """
        mdl = self.model(p)
        for entry in mdl["elements"]:
            if entry["el"].name == name:
                if entry["c"] is None:
                    raise ModelError(f"element {name!r} is a term in the states, not of s")
                sv = self.basis.check(s).reshape(-1)
                return self._project(entry, sv, mdl["p"], jacobian)
        raise ModelError(
            f"no element {name!r}: expected one of " + ", ".join(e.name for e in self._elements)
        )

    def _project(self, entry: dict, s: np.ndarray, p: float, jacobian: bool):
        el = entry["el"]
        if el.kind == "pwl":
            P, Js, _ = el.projector.project(s, jacobian)
            return P, Js
        levels = entry.get("levels")
        theta = np.empty(0)
        if levels is not None:
            theta, index, d1 = self._crossings(s, levels)
        nodes, wq = self._nodes(theta)
        Phi = self.basis.design(nodes)
        sv = Phi @ s
        nm = self._norm()
        fv = el.f(sv, p)
        eps = self.smoothing
        smooth = eps > 0.0 and levels is not None and np.any(entry["jump"])
        if smooth:
            # the homotopy of the start: each jump J at level b spread into J/2 tanh((s-b)/eps)
            for b, J in zip(levels, entry["jump"], strict=True):
                th_ = np.tanh((sv - b) / eps)
                fv = fv + 0.5 * J * (th_ - np.sign(sv - b))
        P = nm * (Phi.T @ (wq * fv))
        if not jacobian:
            return P, None
        dfv = el.df(sv, p)
        if smooth:
            for b, J in zip(levels, entry["jump"], strict=True):
                dfv = dfv + (0.5 * J / eps) / np.cosh(np.clip((sv - b) / eps, -350, 350)) ** 2
        Js = nm[:, None] * (Phi.T @ ((wq * dfv)[:, None] * Phi))
        if theta.size and not smooth:
            # moving switches: (f(b+) - f(b-)) phi_k phi_j / |s'| at each crossing
            jump = entry["jump"][index]
            ok = d1 != 0.0
            if np.any(ok):
                Pc = self.basis.design(theta[ok])
                g = jump[ok] / np.abs(d1[ok])
                Js = Js + nm[:, None] * (Pc.T @ (g[:, None] * Pc))
        return P, Js

    # ---------------------------------------------------------------- evaluation ------
    def evaluate(
        self,
        U: ArrayLike,
        omega: float,
        p: float | None = None,
        jacobian: bool = True,
        *,
        damping: float = 0.0,
    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """The balance residual ``R`` (flat, ``neq * size``), ``dR/dU`` and ``dR/d omega``
        at the parameter value ``p``; ``damping`` adds the artificial term ``delta G`` of
        the Hopf start (module docstring)."""
        mdl = self.model(p)
        U = np.asarray(U, dtype=float).reshape(self.neq, self.size)
        w = float(omega)
        self.evaluations += 1
        Dt, size = self._Dt, self.size
        UD = U @ Dt.T
        UDD = UD @ Dt.T
        A0, A1, A2 = mdl["A0"], mdl["A1"], mdl["A2"]
        R = A0 @ U + w * (A1 @ UD) + w * w * (A2 @ UDD)
        R[:, 0] -= mdl["F0"]
        if damping:
            G, dGdw, G_U = self._damping_term(U, UD, w, mdl)
            R += damping * G
        if jacobian:
            I_ = np.eye(size)
            J = np.kron(A0, I_) + w * np.kron(A1, Dt) + (w * w) * np.kron(A2, Dt @ Dt)
            dW = A1 @ UD + 2.0 * w * (A2 @ UDD)
            if damping:
                J += damping * G_U
                dW += damping * dGdw
        p_val = mdl["p"]
        for entry in mdl["elements"]:
            el, wv = entry["el"], entry["w"]
            if el.kind == "states":
                Pv, blocks, dWe = self._aft_states(el, U, UD, w, p_val, jacobian)
                R += np.outer(wv, Pv)
                if jacobian:
                    dW += np.outer(wv, dWe)
                    for j, Jj in blocks:
                        J[:, j * size : (j + 1) * size] += np.kron(wv[:, None], Jj)
                continue
            alpha, beta = entry["alpha"], entry["beta"]
            s = alpha @ U + w * (beta @ UD)
            Pv, Js = self._project(entry, s, p_val, jacobian)
            R += np.outer(wv, Pv)
            if not jacobian:
                continue
            J += np.kron(np.outer(wv, alpha), Js)
            if np.any(beta):
                J += w * np.kron(np.outer(wv, beta), Js @ Dt)
                dW += np.outer(wv, Js @ (beta @ UD))
        if not jacobian:
            return R.reshape(-1), None, None
        return R.reshape(-1), J, dW.reshape(-1)

    def _damping_term(self, U, UD, w, mdl):
        """``G = M q'`` on second-order rows, ``D p`` on first-order rows (as coefficients),
        ``dG/d omega`` and ``dG/dU``."""
        n2, n1, size = self.n2, self.n1, self.size
        M, D = mdl["B"][:, :n2], mdl["B"][:, n2:]
        G = w * (M @ UD[:n2]) + D @ U[n2:]
        dG = M @ UD[:n2]
        GU = np.hstack(
            [
                np.kron(w * M, self._Dt) if n2 else np.zeros((self.neq * size, 0)),
                np.kron(D, np.eye(size)) if n1 else np.zeros((self.neq * size, 0)),
            ]
        )
        return G, dG, GU

    def _aft_states(self, el: _Element, U, UD, w, p, jacobian):
        N = self.quadrature
        th = _TWO_PI * np.arange(N) / N
        Phi = self.basis.design(th)
        nm = self._norm() * (_TWO_PI / N)
        Pi = Phi.T * nm[:, None]
        n2 = self.n2
        q = Phi @ U[:n2].T
        v = w * (Phi @ UD[:n2].T)
        pp = Phi @ U[n2:].T
        args = [*q.T, *v.T, *pp.T, p]
        P = Pi @ el.f(*args)
        if not jacobian:
            return P, [], None
        blocks = []
        dW = np.zeros(self.size)
        for j in range(self.neq):
            if j < n2:
                Jq = Pi @ (el.df[j](*args)[:, None] * Phi)
                gv = el.df[n2 + j](*args)
                Jv = Pi @ (gv[:, None] * Phi)
                blocks.append((j, Jq + w * (Jv @ self._Dt)))
                dW += Jv @ UD[j]
            else:
                gp = el.df[2 * n2 + (j - n2)](*args)
                blocks.append((j, Pi @ (gp[:, None] * Phi)))
        return P, blocks, dW

    # the augmented system (balance + phase condition) for Newton and the continuation core
    def phase_row(self, phase_index: int) -> int:
        """Index in the flat unknowns of ``b_1`` of the phase coordinate."""
        return int(phase_index) * self.size + int(self.basis.b_index[0])

    def residual(self, x: ArrayLike, p: float, phase_index: int = 0) -> np.ndarray:
        """``(R(U, omega; p), b_1 of the phase coordinate)``; caches the Jacobian."""
        U, w = self.unpack(x)
        R, J, dW = self.evaluate(U, w, p, True)
        k = self.phase_row(phase_index)
        F = np.concatenate([R, [float(np.asarray(x, dtype=float).reshape(-1)[k])]])
        self._last = (np.array(x, dtype=float), float(p), int(phase_index), J, dW, self.smoothing)
        return F

    def jacobian(
        self, x: ArrayLike, p: float, phase_index: int = 0, *, parameter_derivative=True
    ) -> tuple[np.ndarray, np.ndarray]:
        """``(dF/dx, dF/dp)`` of :meth:`residual` (``dF/dp`` by a central difference)."""
        x = np.asarray(x, dtype=float).reshape(-1)
        last = self._last
        if (
            last is not None
            and last[1] == float(p)
            and last[2] == int(phase_index)
            and last[5] == self.smoothing
            and np.array_equal(last[0], x)
        ):
            J, dW = last[3], last[4]
        else:
            U, w = self.unpack(x)
            _, J, dW = self.evaluate(U, w, p, True)
        n = self.n_unknowns
        Jx = np.zeros((n, n))
        Jx[:-1, :-1] = J
        Jx[:-1, -1] = dW
        Jx[-1, self.phase_row(phase_index)] = 1.0
        Fp = np.zeros(n)
        if parameter_derivative and self.parameter is not None:
            U, w = self.unpack(x)
            h = 1e-6 * max(1.0, abs(float(p)))
            rp = self.evaluate(U, w, float(p) + h, False)[0]
            rm = self.evaluate(U, w, float(p) - h, False)[0]
            Fp[:-1] = (rp - rm) / (2.0 * h)
        return Jx, Fp

    # ---------------------------------------------------------------- solutions -------
    def newton(
        self,
        x0: ArrayLike,
        p: float | None = None,
        phase_index: int = 0,
        *,
        tol: float = 1e-10,
        max_iterations: int = 50,
    ) -> np.ndarray:
        """Damped Newton on the balance and phase equations from ``x0``.

        Raises
        ------
        AutonomousBalanceError
            No convergence (the message gives the residual reached), or a collapse onto the
            equilibrium (zero amplitude) or a non-positive frequency.
        """
        p = self.value if p is None else float(p)
        x = np.array(x0, dtype=float).reshape(-1)
        best = np.inf
        for it in range(int(max_iterations)):
            F = self.residual(x, p, phase_index)
            Jx, _ = self.jacobian(x, p, phase_index, parameter_derivative=False)
            nF = float(np.linalg.norm(F))
            best = min(best, nF)
            if nF <= 1e-13 * max(1.0, float(np.abs(x).max())) and it:
                # converged on the residual: near a chattering friction phase the Jacobian
                # is ill-conditioned and the last corrections need not shrink below tol
                self._check_nontrivial(x, p, phase_index)
                return x
            try:
                dx = np.linalg.solve(Jx, -F)
            except np.linalg.LinAlgError:
                dx = np.linalg.lstsq(Jx, -F, rcond=None)[0]
            lam = 1.0
            for _ in range(12):
                xn = x + lam * dx
                if xn[-1] > 0:
                    Fn = self.residual(xn, p, phase_index)
                    if np.linalg.norm(Fn) < (1 - 1e-4 * lam) * nF or nF == 0.0:
                        break
                lam *= 0.5
            else:
                break
            x = xn
            scale = max(1e-12, float(np.abs(x).max()))
            if float(np.abs(lam * dx).max()) <= tol * scale:
                self._check_nontrivial(x, p, phase_index)
                return x
        raise AutonomousBalanceError(
            f"autonomous harmonic balance of {self.system.name!r} (H = {self.H}) did not "
            f"converge (damped Newton, at most {max_iterations} steps; best |R| = {best:.3g}): "
            "give a better guess (frequency and coefficients) or more iterations"
        )

    def _check_nontrivial(self, x: np.ndarray, p: float, phase_index: int) -> None:
        U, w = self.unpack(x)
        amp = float(np.abs(U[:, 1:]).max())
        scale = max(1.0, float(np.abs(U[:, 0]).max()))
        if not (w > 0 and np.isfinite(w)) or amp <= 1e-9 * scale:
            raise AutonomousBalanceError(
                f"autonomous harmonic balance of {self.system.name!r} converged to the "
                f"equilibrium (largest harmonic {amp:.3g}, frequency {w:.6g}), not a limit "
                "cycle: give a guess of the cycle"
            )
        del p, phase_index

    # ---------------------------------------------------------------- the Hopf start --
    def field(self, y: ArrayLike, p: float | None = None) -> np.ndarray:
        """The vector field ``y'`` of the system at the state ``y = (q, q', p)``."""
        mdl = self.model(p)
        y = np.asarray(y, dtype=float).reshape(-1)
        rhs = mdl["F0"] - mdl["L"] @ y
        for entry in mdl["elements"]:
            el = entry["el"]
            if entry["c"] is None:
                val = el.f(*[np.array([v]) for v in y], mdl["p"])[0]
            else:
                val = el.f(np.array([float(entry["c"] @ y)]), mdl["p"])[0]
            rhs = rhs - entry["w"] * float(val)
        return np.concatenate([y[self.n2 : 2 * self.n2], mdl["Binv"] @ rhs])

    def _field_jacobian_fd(self, y: np.ndarray, p: float) -> np.ndarray:
        n = y.size
        A = np.zeros((n, n))
        for j in range(n):
            h = 1e-6 * max(1.0, abs(y[j]))
            e = np.zeros(n)
            e[j] = h
            A[:, j] = (self.field(y + e, p) - self.field(y - e, p)) / (2 * h)
        return A

    def equilibrium(self, p: float | None = None) -> np.ndarray:
        """An equilibrium ``y_e`` (velocities zero): damped Newton on the static equations
        from the zero state and from the linear part's equilibrium.

        Raises
        ------
        AutonomousBalanceError
            When neither start converges (no isolated equilibrium).
        """
        mdl = self.model(p)
        n2, neq = self.n2, self.neq
        idx = [*range(n2), *range(2 * n2, 2 * n2 + self.n1)]

        def full(z):
            y = np.zeros(self.system.n)
            y[idx] = z
            return y

        def g(z):
            return (mdl["B"] @ self.field(full(z), mdl["p"])[n2:]).reshape(-1)

        starts = [np.zeros(neq)]
        try:
            starts.append(np.linalg.solve(mdl["A0"], mdl["F0"]))
        except np.linalg.LinAlgError:
            pass
        for z in starts:
            for _ in range(60):
                r = g(z)
                J = np.zeros((neq, neq))
                for j in range(neq):
                    h = 1e-7 * max(1.0, abs(z[j]))
                    e = np.zeros(neq)
                    e[j] = h
                    J[:, j] = (g(z + e) - g(z - e)) / (2 * h)
                try:
                    dz = np.linalg.solve(J, -r)
                except np.linalg.LinAlgError:
                    break
                lam = 1.0
                for _ in range(20):
                    if np.linalg.norm(g(z + lam * dz)) < np.linalg.norm(r) or not np.any(r):
                        break
                    lam *= 0.5
                z = z + lam * dz
                if np.abs(lam * dz).max() <= 1e-13 * max(1.0, np.abs(z).max()):
                    if np.linalg.norm(g(z)) <= 1e-9 * max(1.0, np.abs(mdl["F0"]).max()):
                        return full(z)
                    break
        raise AutonomousBalanceError(
            f"no isolated equilibrium of {self.system.name!r} found (Newton from zero and from "
            "the linear part's equilibrium): give guess= (frequency and coefficients)"
        )

    def jump_elements(self) -> tuple[str, ...]:
        """Names of the elements whose force jumps at a switch level (friction laws)."""
        mdl = self.model()
        return tuple(
            e["el"].name
            for e in mdl["elements"]
            if e.get("levels") is not None and e["el"].kind != "pwl" and np.any(e["jump"])
        )

    def auto_jump_width(self, p: float | None = None) -> float:
        """The default width of the jumps' ``tanh``: ``0.05 d / H`` with ``d`` the distance
        from the equilibrium's signal to the nearest jump level (the largest level's size
        when there is no equilibrium); 0 without jumps."""
        mdl = self.model(p)
        names = self.jump_elements()
        if not names:
            return 0.0
        try:
            ye = self.equilibrium(mdl["p"])
        except AutonomousBalanceError:
            ye = None
        d = np.inf
        for e in mdl["elements"]:
            if e["el"].name not in names:
                continue
            s0 = float(e["c"] @ ye) if ye is not None else 0.0
            dist = np.abs(e["levels"] - s0)
            dist = dist[dist > 0]
            d = min(d, float(dist.min()) if dist.size else 1.0)
        return _WIDTH_FACTOR * d / self.H

    def auto_start(self, p: float | None = None) -> tuple[np.ndarray, int]:
        """The limit cycle from the Hopf start (:meth:`hopf_start`). With friction jumps
        narrower than the automatic width (:meth:`auto_jump_width`; ``smoothing = 0``: the
        exact law), the start is made at the automatic width and the cycle is continued in
        the width down to the requested one by the continuation core (to a hundredth of the
        start for the exact law, where Newton on the exact law finishes)."""
        if not self.jump_elements():
            return self.hopf_start(p)
        target = self.smoothing
        start = _START_WIDENING * self.auto_jump_width(p)
        if target >= start:
            return self.hopf_start(p)
        try:
            self.smoothing = start
            x, j = self.hopf_start(p)
            x = self._narrow(x, j, p, start, target if target > 0 else start * 1e-2)
        finally:
            self.smoothing = target
        return self.newton(x, p, j), j

    def _narrow(self, x: np.ndarray, j: int, p: float | None, start: float, end: float):
        """Continue the cycle in the jump width from ``start`` down to ``end`` (the last
        point, on ``end``)."""
        p = self.model(p)["p"]

        def res(x, e):
            self.smoothing = float(e)
            return self.residual(x, p, j)

        def jac(x, e):
            self.smoothing = float(e)
            Jx, _ = self.jacobian(x, p, j, parameter_derivative=False)
            U, w = self.unpack(x)
            h = 1e-4 * float(e)
            self.smoothing = float(e) + h
            rp = self.evaluate(U, w, p, False)[0]
            self.smoothing = float(e) - h
            rm = self.evaluate(U, w, p, False)[0]
            self.smoothing = float(e)
            return Jx, np.concatenate([(rp - rm) / (2.0 * h), [0.0]])

        su = np.full(self.n_unknowns, max(1e-8, float(np.abs(x[:-1]).max())))
        try:
            curve = continue_curve(
                res,
                jac,
                x,
                start,
                (end, start),
                direction=-1,
                u_scale=su,
                lam_scale=start - end,
                adaptive_scale=True,
                correct_start=False,
                ds_max=0.1,
                tol=1e-10,
                max_points=_NARROW_POINTS,
                predictor="hermite",
            )
        except (ContinuationError, ParameterError) as exc:
            raise AutonomousBalanceError(
                f"narrowing the friction jumps of {self.system.name!r} from width {start:.3g} "
                f"to {end:.3g} failed ({exc}): give a larger jump_width"
            ) from exc
        if curve.stop_reason != "window" or abs(float(curve.lam[-1]) - end) > 1e-9 * start:
            raise AutonomousBalanceError(
                f"narrowing the friction jumps of {self.system.name!r} from width {start:.3g} "
                f"stopped ({curve.stop_reason}) at {float(curve.lam[-1]):.3g}, not {end:.3g}: "
                "give a larger jump_width"
            )
        return np.asarray(curve.u[-1])

    def hopf_start(
        self, p: float | None = None, *, max_points: int = 2000
    ) -> tuple[np.ndarray, int]:
        """The limit cycle born from the equilibrium's unstable complex pair, by the
        artificial-damping homotopy of the module docstring: ``(x, phase_index)``.

        Raises
        ------
        AutonomousBalanceError
            No unstable complex pair, and none that artificial damping brings onto the
            imaginary axis from an unstable node (no self-excited oscillation from this
            equilibrium), or the homotopy does not reach zero artificial damping.
        """
        mdl = self.model(p)
        p = mdl["p"]
        ye = self.equilibrium(p)
        A = self._field_jacobian_fd(ye, p)
        lam = np.linalg.eigvals(A)
        scale_t = max(1e-300, float(np.abs(lam).max()))
        cand = [z for z in lam if z.imag > 1e-9 * scale_t and z.real > 1e-12 * scale_t]
        shift = 0.0
        if not cand and lam.real.max() > 1e-12 * scale_t:
            # an unstable node (van der Pol at eps >= 2: real eigenvalues): the artificial
            # damping that first stabilises the equilibrium may put a complex pair on the
            # imaginary axis, and the homotopy then starts there
            shift = self._node_shift(A, scale_t)
            if shift > 0.0:
                A = A - shift * self._damping_projection()
                lam = np.linalg.eigvals(A)
                cand = [z for z in lam if z.imag > 1e-9 * scale_t and z.real > -1e-9 * scale_t]
        if not cand:
            listed = ", ".join(f"{z.real:.4g}{z.imag:+.4g}j" for z in lam)
            raise AutonomousBalanceError(
                f"{self.system.name!r} has no self-excited oscillation to start from: its "
                f"equilibrium y = {np.round(ye, 6).tolist()} has no unstable complex pair "
                f"(eigenvalues {listed}); give guess= (frequency and coefficients) of a cycle"
            )
        z = max(cand, key=lambda c: c.real)
        evals, vecs = np.linalg.eig(A)
        v = vecs[:, int(np.argmin(np.abs(evals - z)))]
        n2 = self.n2
        rows = np.concatenate([v[:n2], v[2 * n2 :]])
        j = int(np.argmax(np.abs(rows)))
        rows = rows / rows[j]
        ze = np.concatenate([ye[:n2], ye[2 * n2 :]])
        A0 = 1e-3 * max(1.0, float(np.abs(ze).max()))
        # keep every switch far from the small orbit: its signal must stay well inside the
        # segment of the equilibrium
        vfull = v / (np.concatenate([v[:n2], v[2 * n2 :]])[j])
        for entry in mdl["elements"]:
            if entry.get("levels") is None or entry["c"] is None:
                continue
            s0 = float(entry["c"] @ ye)
            gain = float(np.abs(entry["c"] @ vfull))
            dist = float(np.abs(entry["levels"] - s0).min())
            if gain > 0 and dist > 0:
                A0 = min(A0, 0.05 * dist / gain)
        U = np.zeros((self.neq, self.size))
        U[:, 0] = ze
        U[:, 1] = A0 * rows.real
        U[:, 2] = -A0 * rows.imag
        w0 = float(z.imag)
        delta0 = shift + (2.0 if self.n2 else 1.0) * float(z.real)
        k_b, k_a = self.phase_row(j), j * self.size + 1
        nU = self.neq * self.size

        def aug(X, jac, amp):
            Uu, w, d = X[:nU].reshape(self.neq, self.size), X[nU], X[nU + 1]
            R, J, dW = self.evaluate(Uu, w, p, jac, damping=d)
            G = self._damping_term(Uu, Uu @ self._Dt.T, w, mdl)[0].reshape(-1)
            F = np.concatenate([R, [X[k_b], X[k_a] - amp]])
            if not jac:
                return F, None
            Jx = np.zeros((nU + 2, nU + 2))
            Jx[:nU, :nU] = J
            Jx[:nU, nU] = dW
            Jx[:nU, nU + 1] = G
            Jx[nU, k_b] = 1.0
            Jx[nU + 1, k_a] = 1.0
            return F, Jx

        def small_orbit(amp, X):
            """Damped Newton on (U, omega, delta) with the first harmonic fixed at ``amp``
            (None when it does not converge)."""
            X = X.copy()
            X[k_a] = amp
            F, _ = aug(X, False, amp)
            for _ in range(40):
                F, Jx = aug(X, True, amp)
                nF = float(np.linalg.norm(F))
                if nF <= 1e-14 * max(1.0, float(np.abs(X).max())):
                    break  # converged to rounding (no decrease left for Armijo to find)
                try:
                    dX = np.linalg.solve(Jx, -F)
                except np.linalg.LinAlgError:
                    return None
                lam = 1.0
                for _ in range(12):
                    Fn, _ = aug(X + lam * dX, False, amp)
                    if np.linalg.norm(Fn) < (1 - 1e-4 * lam) * nF or nF == 0.0:
                        break
                    lam *= 0.5
                else:
                    return None
                X = X + lam * dX
                F = Fn
                if np.abs(lam * dX[:nU]).max() <= 1e-12 * max(1.0, np.abs(X[:nU]).max()) and abs(
                    lam * dX[nU:]
                ).max() <= 1e-12 * max(1.0, abs(X[nU])):
                    break
            if not np.all(np.isfinite(X)) or np.linalg.norm(F) > 1e-8 * max(1.0, amp):
                return None
            return X

        X = small_orbit(A0, np.concatenate([U.reshape(-1), [w0, delta0]]))
        if X is None or X[nU] <= 0:
            raise AutonomousBalanceError(
                f"the small orbit about the equilibrium of {self.system.name!r} (frequency "
                f"{w0:.6g}) did not converge: give guess= (frequency and coefficients)"
            )
        delta1 = float(X[nU + 1])
        if delta1 <= 0.0:  # already a cycle without artificial damping (a degenerate start)
            return self.newton(X[: nU + 1], p, j), j

        def res(x, d):
            Uu, w = self.unpack(x)
            R, J, dW = self.evaluate(Uu, w, p, True, damping=d)
            G = self._damping_term(Uu, Uu @ self._Dt.T, w, mdl)[0].reshape(-1)
            self._hopf_last = (np.array(x), d, J, dW, G)
            return np.concatenate([R, [x[k_b]]])

        def jac(x, d):
            last = getattr(self, "_hopf_last", None)
            if last is None or last[1] != d or not np.array_equal(last[0], x):
                res(x, d)
            _, _, J, dW, G = self._hopf_last
            n = self.n_unknowns
            Jx = np.zeros((n, n))
            Jx[:-1, :-1] = J
            Jx[:-1, -1] = dW
            Jx[-1, k_b] = 1.0
            return Jx, np.concatenate([G, [0.0]])

        window = (0.0, _DAMPING_SPAN * delta1)
        su = np.full(self.n_unknowns, max(A0, 1e-3 * max(1.0, float(np.abs(ze).max()))))
        reached = float(delta1)
        best = (X[: nU + 1], float(delta1))
        for _ in range(_BRIDGES + 1):
            amp = float(X[k_a])
            # which way the artificial damping moves as the orbit grows (a Stribeck law's
            # negative damping steepens towards the belt speed: it first grows)
            Xb = small_orbit(amp * 1.02, X)
            if Xb is None:
                break
            grows = float(Xb[nU + 1]) > float(X[nU + 1])
            try:
                curve = continue_curve(
                    res,
                    jac,
                    X[: nU + 1],
                    float(X[nU + 1]),
                    window,
                    direction=1 if grows else -1,
                    u_scale=su,
                    lam_scale=delta1,
                    adaptive_scale=True,
                    # converged by small_orbit; near the Hopf point the Jacobian is nearly
                    # singular along the amplitude and the core's correction test stalls
                    correct_start=False,
                    ds_max=0.1,
                    tol=1e-10,
                    max_points=int(max_points),
                    predictor="hermite",
                )
            except (ContinuationError, ParameterError):
                break
            reached = float(curve.lam[-1])
            if abs(reached) < abs(best[1]):
                best = (np.asarray(curve.u[-1]), reached)
            if curve.stop_reason == "window" and reached == 0.0:
                return self.newton(curve.u[-1], p, j), j
            if curve.stop_reason == "window":
                break
            # a grazing onset (a signal first touching a switch level) makes the curve turn
            # with a square-root corner that the corrector cannot follow: bridge it by a
            # larger orbit at fixed amplitude, then continue from there
            xl = np.asarray(curve.u[-1])
            last = np.concatenate([xl, [reached]])
            amp = float(xl[k_a])
            X = None
            for kappa in _BRIDGE_STEPS:
                X = small_orbit(amp * (1.0 + kappa), last)
                if X is not None:
                    break
            if X is None:
                break
        # the last resort: Newton on the cycle itself from the point of least damping reached
        if abs(best[1]) < _DAMPING_SPAN * delta1:
            try:
                return self.newton(best[0], p, j), j
            except AutonomousBalanceError:
                pass
        raise AutonomousBalanceError(
            f"the amplitude homotopy from the Hopf start of {self.system.name!r} stopped at "
            f"artificial damping {reached:.4g}, not 0 (started at {delta1:.4g}): give guess= "
            "(frequency and coefficients)"
        )

    def _damping_projection(self) -> np.ndarray:
        """``P`` with ``A - delta P`` the linearisation with the artificial damping
        ``delta G`` (``G = M q'``, ``D p``): the identity on the rows of ``q'`` and ``p``."""
        n = 2 * self.n2 + self.n1
        P = np.zeros((n, n))
        idx = np.arange(self.n2, n)
        P[idx, idx] = 1.0
        return P

    def _node_shift(self, A: np.ndarray, scale_t: float) -> float:
        """The smallest artificial damping ``delta`` at which the largest real part of the
        eigenvalues of ``A - delta P`` reaches zero, when a complex pair crosses there
        (0 otherwise): a grid of 400 steps up to ``4 |lambda|_max``, then 60 bisections."""
        P = self._damping_projection()

        def top(d: float) -> float:
            return float(np.linalg.eigvals(A - d * P).real.max())

        grid = np.linspace(0.0, 4.0 * scale_t, 401)
        lo = 0.0
        for d in grid[1:]:
            if top(d) <= 0.0:
                hi = float(d)
                break
            lo = float(d)
        else:
            return 0.0
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if top(mid) > 0.0 else (lo, mid)
        lam = np.linalg.eigvals(A - hi * P)
        crit = lam[int(np.argmax(lam.real))]
        return hi if abs(crit.imag) > 1e-9 * scale_t else 0.0

    # ---------------------------------------------------------------- stability -------
    def monodromy(self, x: ArrayLike, p: float | None = None) -> np.ndarray:
        """Monodromy (``n x n`` over one period) of the linearisation about the HB orbit
        (fourth-order Magnus steps between switches, saltation at a jump)."""
        mdl = self.model(p)
        p = mdl["p"]
        U, w = self.unpack(x)
        n2, n = self.n2, self.system.n
        UD = U @ self._Dt.T
        breaks = [np.array([0.0, _TWO_PI])]
        jumps = []  # (theta, entry, level index, s')
        for entry in mdl["elements"]:
            if entry.get("levels") is None:
                continue
            s = entry["alpha"] @ U + w * (entry["beta"] @ UD)
            th, idx, d1 = self._crossings(s, entry["levels"])
            breaks.append(th)
            for a, i, d in zip(th, idx, d1, strict=True):
                jumps.append((float(a), entry, int(i), float(d)))
        br = np.unique(np.concatenate(breaks))
        br = br[(br >= 0.0) & (br <= _TWO_PI)]
        # Magnus-4 steps on each piece
        lefts, hs = [], []
        for a, b in zip(br[:-1], br[1:], strict=True):
            L = b - a
            if L <= 0.0:
                continue
            m = max(2, math.ceil(self.monodromy_steps * L / _TWO_PI))
            h = L / m
            lefts.append(a + h * np.arange(m))
            hs.append(np.full(m, h))
        left, h = np.concatenate(lefts), np.concatenate(hs)
        g = 0.5 / math.sqrt(3.0)
        t1, t2 = left + (0.5 - g) * h, left + (0.5 + g) * h
        A1 = self._variational(U, UD, w, np.concatenate([t1, t2]), mdl) / w
        Aa, Ab = A1[: left.size], A1[left.size :]
        comm = Ab @ Aa - Aa @ Ab
        Om = (
            0.5 * h[:, None, None] * (Aa + Ab)
            + (math.sqrt(3.0) / 12.0) * (h[:, None, None] ** 2) * comm
        )
        E = sla.expm(Om)
        jumps.sort(key=lambda j: j[0])
        ji = 0
        Mono = np.eye(n)
        for k in range(left.size):
            while ji < len(jumps) and jumps[ji][0] <= left[k] + 1e-14:
                Mono = self._saltation(jumps[ji], w, n, mdl) @ Mono
                ji += 1
            Mono = E[k] @ Mono
        while ji < len(jumps):
            Mono = self._saltation(jumps[ji], w, n, mdl) @ Mono
            ji += 1
        del n2
        return Mono

    def _saltation(self, jump, w: float, n: int, mdl: dict) -> np.ndarray:
        _, entry, i, d1 = jump
        if d1 == 0.0 or (self.smoothing > 0.0 and entry["el"].kind != "pwl"):
            return np.eye(n)
        dj = float(entry["jump"][i]) * (1.0 if d1 > 0 else -1.0)  # after - before
        if dj == 0.0:
            return np.eye(n)
        dfield = np.zeros(n)
        dfield[self.n2 :] = -mdl["Binv"] @ entry["w"] * dj
        return np.eye(n) + np.outer(dfield, entry["c"]) / (w * d1)

    def _variational(self, U, UD, w, theta, mdl) -> np.ndarray:
        """``A(theta) = d y'/d y`` along the orbit, shape ``(len(theta), n, n)``."""
        n2, n = self.n2, self.system.n
        Phi = self.basis.design(theta)
        Lt = np.broadcast_to(mdl["L"], (theta.size, *mdl["L"].shape)).copy()
        ys = None
        for entry in mdl["elements"]:
            el = entry["el"]
            if entry["c"] is None:
                if ys is None:
                    q = Phi @ U[:n2].T
                    v = w * (Phi @ UD[:n2].T)
                    pp = Phi @ U[n2:].T
                    ys = [*q.T, *v.T, *pp.T]
                gr = np.stack([d(*ys, mdl["p"]) for d in el.df], axis=1)  # (T, n)
                Lt += entry["w"][None, :, None] * gr[:, None, :]
            else:
                s = Phi @ (entry["alpha"] @ U + w * (entry["beta"] @ UD))
                slope = el.df(s, mdl["p"])
                if self.smoothing > 0.0 and entry.get("levels") is not None and el.kind != "pwl":
                    for b, J in zip(entry["levels"], entry["jump"], strict=True):
                        z = np.clip((s - b) / self.smoothing, -350, 350)
                        slope = slope + (0.5 * J / self.smoothing) / np.cosh(z) ** 2
                Lt += slope[:, None, None] * np.outer(entry["w"], entry["c"])[None]
        A = np.zeros((theta.size, n, n))
        A[:, :n2, n2 : 2 * n2] = np.eye(n2)
        A[:, n2:, :] = -np.einsum("ij,tjk->tik", mdl["Binv"], Lt)
        return A

    def multipliers(self, x: ArrayLike, p: float | None = None) -> np.ndarray:
        """Floquet multipliers (eigenvalues of :meth:`monodromy`) by decreasing modulus.

        Raises
        ------
        AutonomousBalanceError
            The monodromy overflows (a stiff variational equation: a mass tending to 0).
        """
        with np.errstate(over="ignore", invalid="ignore"):  # an overflow is raised below
            mono = self.monodromy(x, p)
        if not np.all(np.isfinite(mono)):
            where = f" at {self.parameter} = {self.model(p)['p']:g}" if self.parameter else ""
            raise AutonomousBalanceError(
                f"the monodromy of the cycle of {self.system.name!r}{where} overflows "
                f"({self.monodromy_steps} Magnus steps per period on a stiff variational "
                "equation): pass stability=False or keep the parameter away from there"
            )
        mu = np.linalg.eigvals(mono)
        return mu[np.argsort(-np.abs(mu), kind="stable")]

    # ---------------------------------------------------------------- guesses ---------
    def guess_from(self, guess: Any) -> np.ndarray:
        """Flat unknowns from a solution (any ``H``: coefficients cut or padded) or a pair
        ``(frequency, coefficients)`` with coefficients of shape ``(neq, 2 H' + 1)``.

        Raises
        ------
        ParameterError
            For anything else.
        """
        if isinstance(guess, AutonomousBalanceSolution):
            w, U = guess.frequency, guess.coefficients
        elif isinstance(guess, Sequence) and not isinstance(guess, str) and len(guess) == 2:
            w = checks.finite(guess[0], "guess frequency")
            try:
                U = np.asarray(guess[1], dtype=float)
            except (TypeError, ValueError) as exc:
                raise ParameterError(f"guess coefficients: expected numbers ({exc})") from exc
        else:
            raise ParameterError(
                f"guess = {guess!r}: expected an AutonomousBalanceSolution or (frequency, "
                "coefficients) with coefficients of shape (coordinates, 2H + 1)"
            )
        U = np.atleast_2d(U)
        if (
            U.ndim != 2
            or U.shape[0] != self.neq
            or U.shape[1] % 2 != 1
            or not np.all(np.isfinite(U))
            or not w > 0
        ):
            raise ParameterError(
                f"guess: coefficients of shape {U.shape} and frequency {w!r}: expected a "
                f"positive frequency and finite coefficients of shape ({self.neq}, 2H + 1) "
                f"for the coordinates {self.coordinates}"
            )
        out = np.zeros((self.neq, self.size))
        k = min(self.size, U.shape[1])
        out[:, :k] = U[:, :k]
        return self.pack(out, w)

    def phase_index_of(self, x: np.ndarray) -> int:
        """The coordinate with the largest first harmonic."""
        U, _ = self.unpack(x)
        return int(np.argmax(np.hypot(U[:, 1], U[:, 2])))

    def rotate(self, x: np.ndarray, phase_index: int) -> np.ndarray:
        """The same orbit shifted in time so that ``b_1`` of the phase coordinate is zero
        (and ``a_1 >= 0``)."""
        U, w = self.unpack(x)
        phi = math.atan2(U[phase_index, 2], U[phase_index, 1])
        out = U.copy()
        for i, k in enumerate(self.basis.k):
            ia = self.basis.a_index[i]
            a, b = U[:, ia], U[:, ia + 1]
            c, s = math.cos(k * phi), math.sin(k * phi)
            # x(theta + phi/1...): a cos k(th + phi) + b sin k(th + phi), rotated back
            out[:, ia] = a * c + b * s
            out[:, ia + 1] = -a * s + b * c
        return self.pack(out, w)


# =============================================================================================
# results
# =============================================================================================
def _max_abs(basis: HarmonicBasis, u: np.ndarray) -> float:
    """``max |x(theta)|`` of one series: the best of a fine grid refined by Newton on
    ``x' = 0`` (at most 8 steps, each within one grid spacing)."""
    N = max(256, 32 * basis.kmax)
    th = _TWO_PI * np.arange(N) / N
    x = basis.evaluate(u, th)
    i = int(np.argmax(np.abs(x)))
    best, t = abs(float(x[i])), float(th[i])
    h = _TWO_PI / N
    for _ in range(8):
        d1 = float(basis.evaluate(u, np.array([t]), 1)[0])
        d2 = float(basis.evaluate(u, np.array([t]), 2)[0])
        if d2 == 0.0:
            break
        step = max(-h, min(h, d1 / d2))
        t -= step
        if abs(step) < 1e-15:
            break
    return max(best, abs(float(basis.evaluate(u, np.array([t]))[0])))


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.array(a)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class AutonomousBalanceSolution:
    """One limit cycle by autonomous harmonic balance.

    Attributes
    ----------
    system : str
        The system's name.
    parameters : Mapping[str, float]
        The parameter values it was computed at.
    frequency : float
        ``omega`` (rad per unit time); the period is ``2 pi / omega``.
    coefficients : numpy.ndarray
        ``(n, 2H + 1)`` read-only: ``[a0, a_1, b_1, ...]`` per coordinate, ``theta = omega t``.
    coordinates : tuple of str
    harmonics : int
    amplitudes : Mapping[str, float]
        ``max_t |z_j(t)|`` per coordinate.
    multipliers : numpy.ndarray or None
        Every Floquet multiplier of the HB orbit, by decreasing modulus (None without
        stability).
    trivial_multiplier : complex or None
        The multiplier closest to 1 (the phase direction), removed from
        :attr:`nontrivial_multipliers`.
    residual_norm : float
        ``|R|`` of the balance equations at the solution.
    n2 : int
        Second-order coordinates (the first rows).
    jump_width : float
        Width of the ``tanh`` that replaced the jumps of friction laws (0: exact law, or
        no jumps).
    """

    system: str
    parameters: Mapping[str, float]
    frequency: float
    coefficients: np.ndarray
    coordinates: tuple[str, ...]
    harmonics: int
    amplitudes: Mapping[str, float]
    multipliers: np.ndarray | None
    trivial_multiplier: complex | None
    residual_norm: float
    n2: int
    jump_width: float
    basis: HarmonicBasis = field(repr=False)

    @property
    def period(self) -> float:
        return _TWO_PI / self.frequency

    @property
    def nontrivial_multipliers(self) -> np.ndarray | None:
        if self.multipliers is None:
            return None
        i = int(np.argmin(np.abs(self.multipliers - 1.0)))
        return np.delete(self.multipliers, i)

    @property
    def max_multiplier(self) -> float | None:
        """Largest modulus of the nontrivial multipliers (0 for one state)."""
        mu = self.nontrivial_multipliers
        if mu is None:
            return None
        return float(np.abs(mu).max()) if mu.size else 0.0

    @property
    def stable(self) -> bool | None:
        m = self.max_multiplier
        return None if m is None else bool(m <= 1.0 + _UNIT_TOL)

    @property
    def mean(self) -> dict[str, float]:
        return {c: float(self.coefficients[j, 0]) for j, c in enumerate(self.coordinates)}

    def __call__(self, t: ArrayLike, coordinate: str | int = 0) -> np.ndarray:
        """The series of one coordinate at finite times ``t`` (ParameterError otherwise)."""
        j = _coordinate_index(self.coordinates, coordinate)
        th = _times(t) * self.frequency
        return self.basis.evaluate(self.coefficients[j], th.reshape(-1)).reshape(np.shape(th))

    def state(self, t: float = 0.0) -> np.ndarray:
        """The state ``y = (q, q', p)`` at time ``t`` (an initial state for shooting)."""
        th = np.array([checks.finite(t, "t") * self.frequency])
        ph, dph = self.basis.design(th)[0], self.basis.design(th, 1)[0]
        n2 = self.n2
        U = self.coefficients
        return np.concatenate([U[:n2] @ ph, self.frequency * (U[:n2] @ dph), U[n2:] @ ph])

    def __str__(self) -> str:
        pars = ", ".join(f"{k}={v:g}" for k, v in self.parameters.items())
        amps = ", ".join(f"max|{c}| = {a:.10g}" for c, a in self.amplitudes.items())
        lines = [
            f"limit cycle of {self.system!r} by autonomous harmonic balance, H = {self.harmonics}"
            f" [{pars}]",
            f"  frequency {self.frequency:.12g}, period {self.period:.12g}; {amps}",
        ]
        if self.multipliers is not None:
            nt = ", ".join(f"{m:.6g}" for m in self.nontrivial_multipliers)
            lines.append(
                f"  multipliers: trivial {self.trivial_multiplier:.6g}, others [{nt}] -> "
                + ("stable" if self.stable else "unstable")
            )
        tail = f"  |R| = {self.residual_norm:.3g}"
        if self.jump_width > 0:
            tail += f"; friction jumps spread into tanh of width {self.jump_width:.3g}"
        lines.append(tail)
        return "\n".join(lines)


def _times(t: ArrayLike) -> np.ndarray:
    """``t`` as a float array of finite times (a NaN would give a silent NaN series)."""
    try:
        out = np.asarray(t, dtype=float)
    except (TypeError, ValueError):
        raise ParameterError(f"t = {t!r}: expected finite real times") from None
    if not np.all(np.isfinite(out)):
        raise ParameterError(f"t = {t!r}: expected finite real times")
    return out


def _coordinate_index(coordinates: tuple[str, ...], coordinate: str | int) -> int:
    if isinstance(coordinate, str):
        if coordinate not in coordinates:
            raise ParameterError(
                f"coordinate {coordinate!r}: expected one of {', '.join(coordinates)}"
            )
        return coordinates.index(coordinate)
    j = int(coordinate)
    if not 0 <= j < len(coordinates):
        raise ParameterError(f"coordinate {coordinate!r}: expected 0..{len(coordinates) - 1}")
    return j


def _check_flag(value: Any, what: str) -> None:
    """A truth value given as text ("no") would count as True: refuse anything not a bool."""
    checks.flag(value, what)


def _solution(ab: AutonomousBalance, x: np.ndarray, p: float, stability: bool):
    U, w = ab.unpack(x)
    mu = trivial = None
    if stability:
        mu = ab.multipliers(x, p)
        trivial = complex(mu[int(np.argmin(np.abs(mu - 1.0)))])
        mu = _frozen(mu)
    R = ab.evaluate(U, w, p, False)[0]
    params = dict(ab.system.params)
    if ab.parameter is not None:
        params[ab.parameter] = float(p)
    return AutonomousBalanceSolution(
        system=ab.system.name,
        parameters=MappingProxyType({k: float(v) for k, v in params.items()}),
        frequency=float(w),
        coefficients=_frozen(U),
        coordinates=ab.coordinates,
        harmonics=ab.H,
        amplitudes=MappingProxyType(
            {c: _max_abs(ab.basis, U[j]) for j, c in enumerate(ab.coordinates)}
        ),
        multipliers=mu,
        trivial_multiplier=trivial,
        residual_norm=float(np.linalg.norm(R)),
        n2=ab.n2,
        jump_width=float(ab.smoothing),
        basis=ab.basis,
    )


def _as_system(system: Any) -> System:
    if isinstance(system, System):
        return system
    from perturb.model.oscillator import Oscillator

    if isinstance(system, Oscillator):
        return System.from_oscillator(system)
    raise ParameterError(f"system = {system!r}: expected a perturb System or Oscillator")


def _start(ab: AutonomousBalance, p: float, guess: Any, tol: float, max_iterations: int):
    if guess is None:
        x, j = ab.auto_start(p)
        # the Hopf start converges its own Newton at 1e-10; finish at the caller's tol
        return ab.newton(x, p, j, tol=tol, max_iterations=max_iterations), j
    x0 = ab.guess_from(guess)
    j = ab.phase_index_of(x0)
    if np.hypot(*ab.unpack(x0)[0][j, 1:3]) == 0.0:
        raise ParameterError("guess: expected coefficients with a nonzero first harmonic")
    x0 = ab.rotate(x0, j)
    return ab.newton(x0, p, j, tol=tol, max_iterations=max_iterations), j


def autonomous_balance_orbit(
    system: Any,
    harmonics: int = 7,
    *,
    guess: Any = None,
    stability: bool = True,
    tol: float = 1e-10,
    max_iterations: int = 50,
    quadrature: int | None = None,
    jump_width: float | None = None,
) -> AutonomousBalanceSolution:
    """One limit cycle of an autonomous ``system`` by harmonic balance, frequency unknown.

    Parameters
    ----------
    system : System or Oscillator
        Autonomous, every parameter valued.
    harmonics : int
        ``1 <= H <= MAX_HARMONICS`` (256).
    guess : AutonomousBalanceSolution or (frequency, coefficients), optional
        A start (a solution at another ``H`` or parameter; coefficients ``(n, 2H' + 1)``).
        Default: the Hopf start from the equilibrium's unstable complex pair (module
        docstring).
    stability : bool
        Compute the Floquet multipliers.
    tol, max_iterations
        Newton's scaled correction ``0 < tol < 1`` and iteration cap (from the guess, or
        the final Newton after the Hopf start).
    quadrature, jump_width : optional
        As :class:`AutonomousBalance`.

    Raises
    ------
    ParameterError, ModelError
        Bad input (``H < 1``, a forced system, a bad guess, ...).
    AutonomousBalanceError
        No oscillation to start from (no unstable complex pair, no guess) or no convergence.

    Examples
    --------
    >>> from perturb.model.system import System
    >>> vdp = System.parse(["x'' - eps*(1 - x**2)*x' + x = 0"], {"eps": 1.0})
    >>> round(autonomous_balance_orbit(vdp, 15).period, 6)
    6.663287
    """
    ab = AutonomousBalance(system, harmonics, quadrature=quadrature, jump_width=jump_width)
    _check_flag(stability, "stability")
    checks.whole(max_iterations, "max_iterations", 1, 10_000)
    tol = checks.finite(tol, "tol")
    if not 0.0 < tol < 1.0:
        raise ParameterError(f"tol = {tol!r}: expected a number in (0, 1)")
    x, _ = _start(ab, ab.value, guess, tol, max_iterations)
    return _solution(ab, x, ab.value, stability)


@dataclass(frozen=True, eq=False)
class AutonomousBalanceBranch:
    """Limit cycles by autonomous harmonic balance along a parameter.

    Attributes
    ----------
    system : str
    parameter : str
    values : numpy.ndarray
        ``(P,)`` parameter values along the curve (ordered along the arclength).
    frequency : numpy.ndarray
        ``(P,)``.
    coefficients : numpy.ndarray
        ``(P, n, 2H + 1)``.
    coordinates : tuple of str
    harmonics : int
    amplitudes : Mapping[str, numpy.ndarray]
        ``max |z_j|`` per coordinate along the branch.
    max_multiplier : numpy.ndarray or None
        Largest modulus of the nontrivial multipliers per point.
    stable : numpy.ndarray or None
    folds : tuple of float
        Parameter values of the folds the continuation located.
    stop_reasons : tuple of str
        Why each run (down, up from the start) stopped: ``'window'`` (at the window edge),
        ``'hopf at <parameter> = <value>'`` (the cycle shrank to the equilibrium; the run is
        cut there), or the continuation core's other reasons.
    """

    system: str
    parameter: str
    values: np.ndarray
    frequency: np.ndarray
    coefficients: np.ndarray
    coordinates: tuple[str, ...]
    harmonics: int
    amplitudes: Mapping[str, np.ndarray]
    max_multiplier: np.ndarray | None
    stable: np.ndarray | None
    folds: tuple[float, ...]
    stop_reasons: tuple[str, ...]

    def __len__(self) -> int:
        return int(self.values.size)

    @property
    def period(self) -> np.ndarray:
        return _TWO_PI / self.frequency

    def columns(self) -> dict[str, np.ndarray]:
        """``<parameter>, frequency, period, amplitude_<name>..., mean_<name>...,
        max_multiplier, stable`` (the last two NaN / False without stability)."""
        n = len(self)
        out = {
            self.parameter: self.values.copy(),
            "frequency": self.frequency.copy(),
            "period": self.period,
        }
        out.update({f"amplitude_{c}": np.array(self.amplitudes[c]) for c in self.coordinates})
        out.update(
            {f"mean_{c}": self.coefficients[:, j, 0].copy() for j, c in enumerate(self.coordinates)}
        )
        out["max_multiplier"] = (
            np.array(self.max_multiplier) if self.max_multiplier is not None else np.full(n, np.nan)
        )
        out["stable"] = np.array(self.stable) if self.stable is not None else np.zeros(n, bool)
        return out

    def __str__(self) -> str:
        lo, hi = float(self.values.min()), float(self.values.max())
        lines = [
            f"branch of limit cycles of {self.system!r} in {self.parameter} over "
            f"[{lo:.6g}, {hi:.6g}] by autonomous harmonic balance, H = {self.harmonics}: "
            f"{len(self)} points, stops {', '.join(self.stop_reasons)}"
        ]
        if self.folds:
            lines.append("  folds at " + ", ".join(f"{f:.6g}" for f in self.folds))
        head = f"  {self.parameter:>12} {'period':>14} " + " ".join(
            f"{'max|' + c + '|':>14}" for c in self.coordinates
        )
        lines.append(head + ("  stable" if self.stable is not None else ""))
        step = max(1, len(self) // 12)
        for i in [*range(0, len(self), step)][:12] + [len(self) - 1]:
            row = f"  {self.values[i]:12.6g} {self.period[i]:14.8g} " + " ".join(
                f"{self.amplitudes[c][i]:14.8g}" for c in self.coordinates
            )
            if self.stable is not None:
                row += f"  {bool(self.stable[i])}"
            lines.append(row)
        return "\n".join(lines)


def autonomous_balance_branch(
    system: Any,
    parameter: str,
    window: Sequence[float],
    harmonics: int = 7,
    *,
    start: float | None = None,
    guess: Any = None,
    stability: bool = True,
    ds_max: float = 0.05,
    max_points: int = 400,
    quadrature: int | None = None,
    jump_width: float | None = None,
) -> AutonomousBalanceBranch:
    """Continue a limit cycle by autonomous harmonic balance in ``parameter`` over ``window``.

    Parameters
    ----------
    system : System or Oscillator
    parameter : str
        A parameter of the system (it may enter the matrices, elements or constant inputs).
    window : (float, float)
        ``(low, high)``.
    harmonics : int
    start : float, optional
        Where the branch starts (default: the system's value when inside the window, else the
        lower edge); the cycle there comes from ``guess`` or the Hopf start.
    guess : AutonomousBalanceSolution or (frequency, coefficients), optional
    stability : bool
        Floquet multipliers at every point.
    ds_max, max_points
        Continuation step (scaled arclength) and point cap per direction.
    quadrature, jump_width : optional
        As :class:`AutonomousBalance`; the automatic jump width of a branch is four times an
        orbit's (``0.2 d / H`` at the start value, kept along the branch: a narrower ``tanh``
        makes the continuation take several times the points).

    Raises
    ------
    ParameterError
        A parameter not in the system, a bad window or start.
    AutonomousBalanceError
        No cycle at the start.

    Examples
    --------
    >>> from perturb.model.system_builtins import builtin_system
    >>> br = autonomous_balance_branch(builtin_system("belt"), "v_b", (0.15, 0.25), 15)
    """
    system = _as_system(system)
    if not isinstance(parameter, str) or parameter not in system.params:
        raise ParameterError(
            f"parameter {parameter!r} is not in system {system.name!r}: expected one of "
            f"{', '.join(system.params) or 'none'}"
        )
    lo, hi = checks.window(window, parameter, positive=False)
    _check_flag(stability, "stability")
    cur = system.params.get(parameter)
    if start is None:
        start = float(cur) if cur is not None and lo <= float(cur) <= hi else lo
    start = checks.finite(start, "start")
    if not lo <= start <= hi:
        raise ParameterError(f"start = {start!r}: expected a value inside the window ({lo}, {hi})")
    checks.whole(max_points, "max_points", 1, 100_000)
    ds_max = checks.finite(ds_max, "ds_max")
    if ds_max <= 0:
        raise ParameterError(f"ds_max = {ds_max!r}: expected a positive number")
    ab = AutonomousBalance(
        system.with_params({parameter: start}),
        harmonics,
        parameter=parameter,
        quadrature=quadrature,
        jump_width=jump_width,
    )
    if jump_width is None:
        # along a branch the jumps stay at the start width of the Hopf homotopy: with the
        # narrower default of a single orbit, the continuation takes several times the points
        ab.smoothing *= _START_WIDENING
    x0, j = _start(ab, start, guess, 1e-10, 50)

    def res(x, p):
        return ab.residual(x, p, j)

    def jac(x, p):
        return ab.jacobian(x, p, j)

    su = np.full(ab.n_unknowns, max(1e-8, float(np.abs(x0[:-1]).max())))
    su[-1] = max(1e-8, abs(float(x0[-1])))
    runs = []
    reasons = []
    folds: list[float] = []
    for direction in (-1, 1):
        if (direction < 0 and start <= lo) or (direction > 0 and start >= hi):
            runs.append((np.empty((0, ab.n_unknowns)), np.empty(0)))
            reasons.append("window")
            continue
        try:
            curve = continue_curve(
                res,
                jac,
                x0,
                start,
                (lo, hi),
                direction=direction,
                u_scale=su,
                lam_scale=hi - lo,
                adaptive_scale=True,
                ds_max=ds_max,
                tol=1e-10,
                max_points=int(max_points),
                predictor="hermite",
            )
        except ContinuationError as exc:
            runs.append((x0[None, :], np.array([start])))
            reasons.append(f"failed ({exc})")
            continue
        u_run, l_run = np.asarray(curve.u), np.asarray(curve.lam)
        reason = curve.stop_reason
        # through a Hopf point the curve passes zero amplitude (a1 of the phase coordinate
        # changes sign) and comes back as the same cycles shifted by half a period: cut there
        a1 = u_run[:, j * ab.size + 1]
        flip = np.flatnonzero(a1 * a1[0] <= 0.0)
        keep = u_run.shape[0]
        if flip.size:
            keep = int(flip[0])
            k = keep
            # near the Hopf point lam - lam_H ~ c a1^2: the parabola through both neighbours
            d2 = a1[k - 1] ** 2 - a1[k] ** 2
            c = (l_run[k - 1] - l_run[k]) / d2 if d2 != 0.0 else 0.0
            lam_h = float(l_run[k - 1] - c * a1[k - 1] ** 2)
            reason = f"hopf at {parameter} = {lam_h:.6g}"
            u_run, l_run = u_run[:keep], l_run[:keep]
        runs.append((u_run, l_run))
        reasons.append(reason)
        folds += [float(f.lam) for f in curve.folds if f.index + 1 < keep]
    (u_dn, l_dn), (u_up, l_up) = runs
    X = np.concatenate([u_dn[::-1], u_up[1:] if u_dn.size else u_up])
    lam = np.concatenate([l_dn[::-1], l_up[1:] if l_dn.size else l_up])
    if lam.size == 0:
        X, lam = x0[None, :], np.array([start])
    # the stability of each point; a point whose monodromy overflows (a mass continued
    # towards zero) ends the branch on that side, the reason reported
    i0 = max(l_dn.size - 1, 0)
    sols: list[Any] = [None] * lam.size
    keep_lo, keep_hi = 0, lam.size
    for side, indices in ((0, range(i0, -1, -1)), (1, range(i0, lam.size))):
        for i in indices:
            if sols[i] is not None:
                continue
            try:
                sols[i] = _solution(ab, X[i], float(lam[i]), stability)
            except AutonomousBalanceError as exc:
                if i == i0:
                    raise
                if side == 0:
                    keep_lo = i + 1
                else:
                    keep_hi = i
                reasons[side] = f"stability failed at {parameter} = {lam[i]:.6g} ({exc})"
                break
    sols, lam = sols[keep_lo:keep_hi], lam[keep_lo:keep_hi]
    return AutonomousBalanceBranch(
        system=system.name,
        parameter=parameter,
        values=_frozen(lam),
        frequency=_frozen([s.frequency for s in sols]),
        coefficients=_frozen(np.stack([s.coefficients for s in sols])),
        coordinates=ab.coordinates,
        harmonics=ab.H,
        amplitudes=MappingProxyType(
            {c: _frozen([s.amplitudes[c] for s in sols]) for c in ab.coordinates}
        ),
        max_multiplier=_frozen([s.max_multiplier for s in sols]) if stability else None,
        stable=_frozen([bool(s.stable) for s in sols]) if stability else None,
        folds=tuple(folds),
        stop_reasons=tuple(reasons),
    )
