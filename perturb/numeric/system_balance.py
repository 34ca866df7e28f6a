r"""Numeric multi-harmonic balance for systems of several coordinates.

The system (:class:`~perturb.model.system.System`, ``n2`` second-order coordinates ``q`` and
``n1`` first-order states ``p``, one equation each)

.. math::

    M q'' + D p' + C q' + K q + E p + \sum_e w_e f_e(c_e\cdot y) = F(t),
    \qquad y = (q, q', p),

forced at frequencies that are multiples of the parameter :math:`\Omega` (``"Omega"``), with a
period of ``m`` forcing periods and :math:`\theta = \Omega t/m`, :math:`\omega = \Omega/m`.

Unknowns
--------
Every coordinate and first-order state ``z_j`` (``j = 0..n2+n1-1``, ``q`` first) is a truncated
series in the :class:`~perturb.fourier.projection.HarmonicBasis` ``1, cos k theta, sin k theta``
(``k = 1..H``): coefficients ``U[j] = [a0, a_1, b_1, ...]``; the unknown vector is ``U``
flattened coordinate by coordinate (``u[j*size:(j+1)*size] = U[j]``).

Residual
--------
The Galerkin projection of each equation on the basis,

.. math::

    R = \omega^2 M U_q D_\theta^{2T} + \omega (C U_q + D U_p) D_\theta^T + K U_q + E U_p
        + \sum_e w_e \otimes P_e(S_e) - \hat F,

with :math:`D_\theta` the derivative matrix of the basis (``2x2`` blocks), :math:`\hat F` the
coefficients of the forcing and :math:`S_e = \sum_j (\alpha_{ej} I + \omega\beta_{ej}
D_\theta) U_j` the coefficients of the element's scalar signal :math:`s_e = c_e\cdot y`
(``alpha`` the position / state part of ``c_e``, ``beta`` its velocity part). ``P_e`` is

* for a piecewise-linear element (any ``"nonsmooth"`` element whose function has a PWL form):
  the **exact** Galerkin projection of :class:`~perturb.fourier.projection.ExactProjector`
  (switching angles of ``s_e`` by certified isolation, closed-form spectra, exact Jacobian
  including the moving switches of a discontinuous force);
* for any other element on a combination: AFT (``samples`` points, default ``4H + 1``, which
  projects cubic terms exactly) with the sampled derivative ``f'(s)``;
* for a smooth term that is no function of one combination: AFT in the states, with the
  sampled gradient.

Rigid stops are refused (their impacts are no force: use the exact solvers).

Jacobian (block structure)
--------------------------
The linear part is :math:`A_0\otimes I + \omega A_1\otimes D_\theta + \omega^2 A_2\otimes
D_\theta^2` over (coordinates x harmonics): a ``2x2`` block per harmonic and nonzero matrix
entry, assembled once per system as a sparse pattern and rescaled per :math:`\Omega`. An
element adds, for each equation ``i`` with ``w_ei != 0`` and each coordinate ``j`` with
``alpha_ej`` or ``beta_ej != 0``, the block :math:`w_{ei}\,J_e(\alpha_{ej} I + \omega
\beta_{ej} D_\theta)` with :math:`J_e = \partial P_e/\partial S_e` (``size x size``, ``size =
2H + 1``; the product with :math:`D_\theta` is a column swap and scale): the cost per element
is ``nnz(w) nnz(c)`` blocks of ``O(H^2)``, growing like ``n H^2`` for an element touching all
``n`` coordinates and like ``H^2`` for a local one (a gap between two masses), never like
``(n H)^2``. :meth:`SystemBalance.evaluate` returns the Jacobian dense (what the continuation
core takes) or as a ``scipy.sparse`` CSC matrix (``sparse=True``; :meth:`SystemBalance.solve`
then factors it with SuperLU, so the solve too stays far below ``(nH)^3`` for a chain).

Stability
---------
Floquet multipliers of the HB orbit from the monodromy of the linearisation about it: for
piecewise-linear elements the Jacobian of the vector field is piecewise constant in
:math:`\theta`, switching at the crossings of each ``s_e`` (the same certified crossings as
the projection), so the monodromy is a product of matrix exponentials (with the saltation
matrix of a force that jumps); smooth elements are handled by a midpoint rule on
``8 H`` sub-intervals per period (second order). Stable when every multiplier has modulus at
most ``1 + 1e-6``. Near a fold of the truncated branch the multiplier that crosses +1 does
so within the truncation error of the fold (the HB fold and the orbit's differ by that much).

Frequency continuation uses THE continuation core (:func:`perturb.numeric.continuation.
continue_curve`, Hermite predictor, early acceptance, folds located), as the SDOF
:mod:`perturb.numeric.harmonic_balance` does: :func:`system_balance_branch` one branch from
the start; :func:`system_balance_response` every branch it can reach in a window (seeds at
both edges, interior and fold frequencies, every HB solution there from segment orbits, the
linearisation and a bounded multi-start; branch switching at branch points; retraces dropped
by a point-on-curve test; odd-symmetry mirrors added; detached loops closed).

Starting without a guess
------------------------
At one frequency: the steady states of the linear systems with every PWL element frozen on one
of its segments (those that stay inside their segments are exact orbits, and exact HB
solutions for any ``H``), the linearisation about zero, the frozen slopes through the origin;
at most six capped Newton runs, then a Newton homotopy :math:`R(u) - (1 - \lambda) R(u_g)` from
two of them by the continuation core. A branch starts from a stable one when there is one.
Every branch in a window (:func:`system_balance_response`) also starts from the
describing-function orbits (each PWL element replaced by its equivalent slope at the
self-consistent signal level): they reach the impacting orbits of the impact pair, which no
frozen segment does. Known limit: a clearance that leaves a coordinate without stiffness away
from contact (the ``impact_pair`` off resonance) has a family of non-isolated orbits there
(any position of the free mass in the gap): the HB Jacobian is singular, and neither the start
nor the continuation works in that regime (the impacting branches are traced up to it). The
multi-impact orbits of the lightly damped pair (``mu2 = 0.01``, Omega 0.8..1.0: loops with
8-14 switches per period) are reached by the attractor stage (Newton from the orbits a
vectorised RK4 simulation settles on, frequencies 2 % apart; ``attractors=True``): measured by
``benchmarks/bench_system_balance_attractors.py`` (every 8th exact point; missed = no HB
solution within 2.5e-2 of it), H = 15, over (0.8, 1.3) 120 -> 43 of 1097 points missed, CPU
2.6 -> 8.4 s; over (0.6, 1.4) 104 -> 2 of 998, 2.3 -> 8.1 s; H = 31, over (0.8, 1.3) 130 -> 20
of 1097, 89 -> 12 s; over (0.6, 1.4) no start at any seed frequency (SystemBalanceError) -> 0
of 998 missed, 20 s (16 branches, the cap ``max_branches``); nsd2 (0.5, 2) 0 of 628 missed
either way, 1.20 -> 1.56 s (load 4-7). With the step of 0.6 over the field's largest
eigenvalue modulus (0.3 before; same bench, load ~3): 22, 0, 6 and 0 missed in the four impact
pair cases, nsd2 0, with the stage 2.6, 4.5, 5.6, 4.1 and 0.46 s. Which orbits the impact
pair's trajectories settle on is sensitive to rounding (a relative change of 1e-13 in the start
states changes most of its starts, either step): over the unchanged and two such perturbed
starts, H = 15, (0.8, 1.3) misses 22 / 47 / 44 points (the 0.3 step 43 / 43 / 43), (0.6, 1.4)
0 / 0 / 0 (2 / 0 / 84). Still missed: loops of the impact pair that no simulated trajectory
settles on (unstable all along, or basins the 12 states miss); the unstable multi-impact
mirror pair on 0.800..0.865 of (0.8, 1.3), which leaves and re-enters through the low edge, is
reached by stage 1b (branch ends traced past the edge, :mod:`perturb.numeric.edge_solutions`),
attractors or not.

Measured (``benchmarks/bench_system_balance.py --parts 1b --baseline FILE``, CPU, one
process, load average ~3 on 2 cores): nsd2, H = 15, every branch over (0.5, 2) with multipliers
at every point, called as ``system_balance_response(nsd2, (0.5, 2.0), harmonics=15)``
(4 branches, 700 points): 0.44 s against 0.54 s for the module before the attractor-step round
in the same process, both with the projection of commit d68d82b (responses bit-identical in
every window of part 1b; 0.36 s either way without the stage, so stage 4 costs 0.08 s against
0.18 s). Its simulation and the projection of its starts 0.043 s against 0.14 s (the impact
pair's over (0.8, 1.3) and (0.6, 1.4): 0.15 and 0.25 s against 0.54 and 0.89 s): 1360
sequential RK4 steps of 852 trajectories (2720 before: the step now 0.6 over the largest
eigenvalue modulus), each stage one product of the linear field, the forcing and the PWL
forces written as clipped pieces (~21 numpy calls a step on nsd2 against ~53); it is bound by call
overhead, not arithmetic. Earlier rounds: 0.72 -> 0.61 s (stage-4 and multiplier cuts),
responses bit-identical; before stage 4 existed, 0.79 -> 0.51 s with cached projections, dense
algebra below 400 unknowns, branch points watched only on symmetric branches of an odd system,
prepared polylines, a whole branch's crossings at once for the multipliers. Issue 16's 0.5 s
is reached with stage 4 on (0.44 s). Stability by the monodromy costs ~0.03 ms a point (a
whole branch's products stacked); the eigenvalue problem of a Hill matrix of the same balance
(124 x 124) alone ~3 ms (100x). A chain of n masses
with a gap each (``bench_system_balance_chain.py``): the assembly (residual, exact
projections, Jacobian) grows linearly in n; the dense bordered LU of the continuation core
(it takes dense matrices) is the cubic term from n ~ 16 at H = 15. Accuracy
(``bench_system_balance_accuracy.py``, H = 1..63): nsd2's max|x_j| errors within 1.35x of the
orbit's truncation floor at every H; the impact pair's (mu2 = 0.2, Omega = 1.2) 2-68x its
floor for H <= 22 and 2-22x at some H above (``bench_impact_pair_galerkin.py``): that is the
Galerkin solution itself -- an independent solver (switching points, Gauss quadrature, its own
Newton) gives the same coefficients to 7e-13 at every H = 1..63; the contact (~9x the forcing
frequency) is unresolved below H ~ 21, and in the sup norm of x - x_H the error is within 1.5x
of the tail's from H = 23 on.
"""

from __future__ import annotations

import math
import warnings
import weakref
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sps
import scipy.sparse.linalg as spla
import sympy as sp
from numpy.typing import ArrayLike

from perturb import checks
from perturb.errors import ModelError, NonsmoothError, ParameterError, PerturbError
from perturb.fourier.projection import (
    CrossingIntervals,
    ExactProjector,
    HarmonicBasis,
    TruncatedSeries,
    crossing_intervals,
)
from perturb.model.pwl import NumericPWL, to_pwl
from perturb.model.system import S as _S_SYMBOL
from perturb.model.system import System
from perturb.numeric.continuation import (
    BranchPoint,
    ContinuationCurve,
    ContinuationError,
    branch_off,
    continue_curve,
)
from perturb.numeric.edge_solutions import edge_solutions
from perturb.response import Branch, Response

__all__ = [
    "SystemBalance",
    "SystemBalanceSolution",
    "SystemBalanceBranch",
    "system_balance_orbit",
    "system_balance_branch",
    "SystemBalanceResponse",
    "system_balance_response",
    "system_balance_solutions_at",
    "SystemBalanceError",
]

_TWO_PI = 2.0 * math.pi
#: Modulus above which a Floquet multiplier makes the orbit unstable.
_UNIT_TOL = 1e-6
#: Sub-intervals per highest harmonic for the midpoint monodromy of smooth elements.
_SMOOTH_STEPS_PER_HARMONIC = 8
#: Newton runs from automatic starting guesses at one frequency.
_MAX_STARTS = 6
#: Projections kept per element (the last evaluations: a Newton step's residual and the next
#: step's Jacobian at the same iterate).
_PROJECTION_CACHE = 4
#: Unknowns up to which the Jacobian of the linear part is kept dense and Newton at fixed
#: frequency factors a dense matrix (below this a sparse LU costs more than it saves:
#: measured 0.23 ms sparse vs 0.14 ms dense per evaluation on nsd2, H = 15, 62 unknowns).
_DENSE_LIMIT = 400
#: Signal levels scanned by the describing-function starting guesses.
_DF_LEVELS = 16


class SystemBalanceError(PerturbError):
    """Harmonic balance of a system failed (no convergence, no start)."""


# =============================================================================================
# forcing in the continuation parameter
# =============================================================================================
@dataclass(frozen=True)
class _ForcingTerm:
    """``coef(Omega) * cos/sin(rate * Omega * t)`` in equation ``row``."""

    row: int
    rate: float
    is_sin: bool
    coef: Any  # callable Omega -> float
    dcoef: Any  # callable Omega -> float


def _forcing_terms(system: System, parameter: str) -> list[_ForcingTerm]:
    """The forcing ``F(t)`` as terms whose frequencies are fixed multiples of the parameter
    (every other parameter value substituted); the amplitudes may depend on it (a
    displacement input ``Omega * Xa``)."""
    W = sp.Symbol(parameter, real=True)
    vals = {
        k: v
        for k, v in system.numeric_form()["vals"].items()
        if getattr(k, "name", "") != parameter
    }
    t = system.t
    terms: list[_ForcingTerm] = []
    for r in range(system.F.shape[0]):
        expr = sp.expand(sp.sympify(system.F[r]).xreplace(vals))
        expr = expr.xreplace({s: W for s in expr.free_symbols if s.name == parameter})
        for term in sp.Add.make_args(expr):
            if term == 0:
                continue
            if not term.has(t):
                f = sp.lambdify([W], term, "math")
                df = sp.lambdify([W], sp.diff(term, W), "math")
                terms.append(_ForcingTerm(r, 0.0, False, f, df))
                continue
            trig = [a for a in term.atoms(sp.cos, sp.sin) if a.has(t)]
            ok = len(trig) == 1
            rate = None
            if ok:
                arg = sp.expand(trig[0].args[0])
                om = sp.diff(arg, t)
                coeff = sp.simplify(term / trig[0])
                rate_expr = sp.simplify(om / W)
                ok = (
                    not coeff.has(t)
                    and sp.simplify(arg - om * t) == 0
                    and not rate_expr.free_symbols
                    and float(rate_expr) != 0.0
                )
                if ok:
                    rate = float(rate_expr)
            if not ok or rate is None:
                raise ModelError(
                    f"forcing term {term} of {system.name!r}: expected constants and terms "
                    f"a*cos(r*{parameter}*t), a*sin(r*{parameter}*t) with a fixed number r"
                )
            sign = 1.0
            if rate < 0:  # cos(-x) = cos x, sin(-x) = -sin x
                rate = -rate
                sign = -1.0 if isinstance(trig[0], sp.sin) else 1.0
            c = sign * coeff
            terms.append(
                _ForcingTerm(
                    r,
                    rate,
                    isinstance(trig[0], sp.sin),
                    sp.lambdify([W], c, "math"),
                    sp.lambdify([W], sp.diff(c, W), "math"),
                )
            )
    return terms


# =============================================================================================
# elements
# =============================================================================================
@dataclass(eq=False)
class _Element:
    name: str
    kind: str  # "exact" | "aft_s" | "aft_y"
    alpha: np.ndarray  # (neq,) position / first-order part of c per coordinate
    beta: np.ndarray  # (neq,) velocity part of c per coordinate (0 for first-order states)
    w: np.ndarray  # (neq,)
    c: np.ndarray | None  # over the states y
    pwl: NumericPWL | None = None
    projector: ExactProjector | None = None
    f: Any = None  # f(s) or f(*y), vectorised
    df: Any = None  # f'(s), or the gradient list in y
    cache: dict = field(default_factory=dict)  # s.tobytes() -> (projection, Jacobian)

    def __post_init__(self) -> None:
        # the equations the element acts on, the coordinates its signal reads, and those
        # read through their velocity: the block structure of its Jacobian
        self.rows = np.flatnonzero(self.w)
        self.cols = np.flatnonzero((self.alpha != 0.0) | (self.beta != 0.0))
        self.cols_beta = np.flatnonzero(self.beta != 0.0)


def _vectorised(fn, n_args: int):
    """A lambdified function returning arrays shaped like its first argument (constants
    broadcast)."""

    def call(*args):
        out = fn(*args)
        return np.broadcast_to(np.asarray(out, dtype=float), np.shape(args[0])).astype(float)

    del n_args
    return call


# =============================================================================================
# the balance system
# =============================================================================================
class SystemBalance:
    """Residual, Jacobian, solutions and Floquet multipliers of the harmonic balance of a
    :class:`~perturb.model.system.System` (module docstring).

    Parameters
    ----------
    system : System
        Every parameter but ``parameter`` needs a value (``parameter`` may have one); the
        parameter may enter the forcing only (frequencies proportional to it).
    harmonics : int
        ``H >= 1``: harmonics ``1..H`` of the response frequency ``Omega/m``, plus the bias.
    m : int
        Forcing periods per response period (``m > 1``: subharmonic responses); the forcing's
        harmonics ``m r`` must be in the basis.
    parameter : str
        The continuation parameter, default ``"Omega"``.
    samples : int, optional
        AFT samples per period for non-PWL elements (default ``4 H + 1``).
    projection : {"exact", "aft"}
        ``"aft"`` samples the PWL elements too (the comparison option: slowly convergent and
        aliased for nonsmooth forces).

    Attributes
    ----------
    basis : HarmonicBasis
    coordinates : tuple of str
        The series' names, ``(*system.coordinates, *system.first_order)``.
    size : int
        Coefficients per coordinate (``2 H + 1``).
    n_unknowns : int

    Raises
    ------
    ParameterError
        ``H < 1``, ``m < 1``, a parameter that is not in the system, bad ``samples``.
    ModelError
        A stop, an element whose combination is identically zero, a parameter that enters
        more than the forcing, forcing harmonics the basis cannot represent.
    """

    def __init__(
        self,
        system: System,
        harmonics: int = 7,
        *,
        m: int = 1,
        parameter: str = "Omega",
        samples: int | None = None,
        projection: str = "exact",
    ) -> None:
        if not isinstance(system, System):
            raise ParameterError(f"system = {system!r}: expected a perturb System")
        if isinstance(m, bool) or not isinstance(m, int | np.integer) or m < 1:
            raise ParameterError(f"m = {m!r}: expected an integer >= 1 (forcing periods)")
        self.basis = HarmonicBasis.make(harmonics)  # ParameterError for H < 1
        self.H, self.m = int(harmonics), int(m)
        if parameter not in system.params:
            raise ParameterError(
                f"parameter {parameter!r} is not in system {system.name!r}: expected one of "
                + (", ".join(system.params) or "none")
            )
        missing = [k for k, v in system.params.items() if v is None and k != parameter]
        if missing:
            raise ParameterError(f"system {system.name!r} needs values for {', '.join(missing)}")
        if system.params.get(parameter) is None:
            system = system.with_params({parameter: 1.0})
        self.system, self.parameter = system, parameter
        self._check_parameter_in_forcing_only()
        num = system.numeric_form()  # ModelError for a zero combination or a singular [M D]
        self.n2 = n2 = int(num["n2"])
        self.n1 = n1 = len(system.first_order)
        self.neq = neq = n2 + n1
        self.coordinates = (*system.coordinates, *system.first_order)
        self.size = self.basis.size
        self.n_unknowns = neq * self.size
        self.samples = self._samples(samples)
        if projection not in ("exact", "aft"):
            raise ParameterError(f"projection = {projection!r}: expected 'exact' or 'aft'")
        self.projection = projection
        B, L = num["B"], num["L"]
        self._Binv = num["Binv"]
        self._L = L
        # coordinate-level matrices of the residual, columns (q, p)
        M, Dm = B[:, :n2], B[:, n2:]
        K, C, E = L[:, :n2], L[:, n2 : 2 * n2], L[:, 2 * n2 :]
        self._A0 = np.hstack([K, E])
        self._A1 = np.hstack([C, Dm])
        self._A2 = np.hstack([M, np.zeros((neq, n1))])
        self._build_linear_pattern()
        self.elements = [self._element(e, num) for e in system.elements]
        self._forcing = _forcing_terms(system, parameter)
        for ft in self._forcing:
            k = ft.rate * self.m
            if ft.rate == 0.0:
                continue
            if abs(k - round(k)) > 1e-9 * max(1.0, k) or self.basis.index_of(round(k)) is None:
                raise ModelError(
                    f"forcing at {ft.rate:g} x {parameter} is harmonic {k:g} of the response "
                    f"frequency {parameter}/{self.m}: expected an integer harmonic within "
                    f"1..{self.H} (raise harmonics= or choose m so that m*rate is an integer)"
                )
        self._cache: tuple | None = None
        self._eig_cache: dict = {}
        self._forcing_last: tuple | None = None
        self._all_pwl = all(el.kind == "exact" for el in self.elements)
        self._df_cache: dict = {}
        self.evaluations = 0

    # ---------------------------------------------------------------- set-up ----------
    def _check_parameter_in_forcing_only(self) -> None:
        s, p = self.system, self.parameter
        mats = (s.M, s.D, s.C, s.K, s.E)
        syms = set()
        for mat in mats:
            syms |= {x.name for x in mat.free_symbols}
        for e in s.elements:
            syms |= {x.name for x in sp.sympify(e.function).free_symbols}
            for v in (*(e.combination or ()), *e.distribution):
                syms |= {x.name for x in sp.sympify(v).free_symbols}
        if p in syms:
            raise ModelError(
                f"parameter {p!r} of {s.name!r} enters the matrices or elements: the harmonic "
                "balance of a system continues a forcing frequency only"
            )

    def _samples(self, samples: int | None) -> int:
        if samples is None:
            return max(16, 4 * self.basis.kmax + 1)
        if isinstance(samples, bool) or not isinstance(samples, int | np.integer):
            raise ParameterError(f"samples = {samples!r}: expected an integer")
        if samples < 2 * self.basis.kmax + 1:
            raise ParameterError(
                f"samples = {samples}: expected at least 2H + 1 = {2 * self.basis.kmax + 1}"
            )
        return int(samples)

    def _build_linear_pattern(self) -> None:
        I_ = sps.identity(self.size, format="csr")
        Dt = sps.csr_matrix(self.basis.derivative_matrix())
        self._Dtheta = self.basis.derivative_matrix()
        S0 = sps.kron(sps.csr_matrix(self._A0), I_, format="csr")
        S1 = sps.kron(sps.csr_matrix(self._A1), Dt, format="csr")
        S2 = sps.kron(sps.csr_matrix(self._A2), Dt @ Dt, format="csr")
        pattern = (abs(S0) + abs(S1) + abs(S2) + sps.identity(self.n_unknowns)).tocoo()
        r, c = pattern.row, pattern.col
        self._lin_rows, self._lin_cols = r, c
        self._lin_vals = [np.asarray(S[r, c]).reshape(-1) for S in (S0, S1, S2)]
        self._S = (S0, S1, S2)
        self._DtT = np.ascontiguousarray(self._Dtheta.T)
        ii, jj = np.meshgrid(np.arange(self.size), np.arange(self.size), indexing="ij")
        self._block_index = (ii.reshape(-1), jj.reshape(-1))
        self._lin_dense = None
        if self.n_unknowns <= _DENSE_LIMIT:
            # the same entries as the sparse pattern (explicit zeros included), so the dense
            # and sparse Jacobians are equal to the last bit
            dense = []
            for vals in self._lin_vals:
                D = np.zeros((self.n_unknowns, self.n_unknowns))
                D[r, c] = vals
                dense.append(D)
            self._lin_dense = tuple(dense)

    def _element(self, e, num) -> _Element:
        if e.kind == "stop":
            raise ModelError(
                f"element {e.name!r} of {self.system.name!r} is a rigid stop: harmonic balance "
                "needs a force (a contact spring); use the exact solvers for impacts"
            )
        n2, neq = self.n2, self.neq
        c, w = num["comb"][e.name]
        vals = num["vals"]
        if c is None:
            fexpr = e.function.xreplace(vals)
            states = list(self.system.states)
            f = sp.lambdify(states, fexpr, "numpy")
            grad = [sp.lambdify(states, sp.diff(fexpr, s), "numpy") for s in states]
            return _Element(
                e.name,
                "aft_y",
                np.zeros(neq),
                np.zeros(neq),
                w,
                None,
                f=_vectorised(f, len(states)),
                df=[_vectorised(g, len(states)) for g in grad],
            )
        alpha = np.concatenate([c[:n2], c[2 * n2 :]])
        beta = np.concatenate([c[n2 : 2 * n2], np.zeros(self.n1)])
        if not (np.any(alpha) or np.any(beta)) or not np.any(w):
            raise ModelError(
                f"element {e.name!r}: combination {c.tolist()} / distribution {w.tolist()} is "
                "identically zero: expected a nonzero combination of the states"
            )
        fexpr = e.function.xreplace(vals)
        pwl = None
        if e.kind != "smooth":
            try:
                pwl = to_pwl(fexpr, _S_SYMBOL).numeric()
            except (NonsmoothError, ModelError, ParameterError, TypeError, ValueError):
                pwl = None
        if pwl is not None and self.projection == "aft":
            # the comparison option: the same PWL force sampled (no Dirac terms of jumps)
            def f_pwl(x, pwl=pwl):
                seg = pwl.segment_index(x)
                return pwl.slopes[seg] * x + pwl.offsets[seg]

            def df_pwl(x, pwl=pwl):
                return pwl.slopes[pwl.segment_index(x)]

            return _Element(e.name, "aft_s", alpha, beta, w, c, f=f_pwl, df=df_pwl)
        if pwl is not None:
            return _Element(
                e.name,
                "exact",
                alpha,
                beta,
                w,
                c,
                pwl=pwl,
                projector=ExactProjector(pwl, self.basis),
            )
        f = sp.lambdify([_S_SYMBOL], fexpr, "numpy")
        df = sp.lambdify([_S_SYMBOL], sp.diff(fexpr, _S_SYMBOL), "numpy")
        return _Element(
            e.name, "aft_s", alpha, beta, w, c, f=_vectorised(f, 1), df=_vectorised(df, 1)
        )

    # ---------------------------------------------------------------- helpers ---------
    def _omega(self, Omega: float) -> float:
        W = checks.finite(Omega, self.parameter)
        if W <= 0:
            raise ParameterError(f"{self.parameter} = {Omega!r}: expected a positive number")
        return W / self.m

    def unpack(self, u: ArrayLike) -> np.ndarray:
        """``U`` of shape ``(n2 + n1, size)`` from the flat unknowns."""
        arr = np.asarray(u, dtype=float).reshape(-1)
        if arr.size != self.n_unknowns:
            raise ParameterError(
                f"u of size {arr.size}: expected {self.n_unknowns} "
                f"({self.neq} coordinates x {self.size} coefficients)"
            )
        return arr.reshape(self.neq, self.size)

    def forcing(self, Omega: float) -> tuple[np.ndarray, np.ndarray]:
        """Coefficients of ``F`` and their derivative in the parameter, ``(neq, size)``."""
        W = float(Omega)
        last = self._forcing_last
        if last is not None and last[0] == W:
            return last[1].copy(), last[2].copy()
        F = np.zeros((self.neq, self.size))
        dF = np.zeros((self.neq, self.size))
        for ft in self._forcing:
            if ft.rate == 0.0:
                col = 0
            else:
                ia = self.basis.index_of(round(ft.rate * self.m))
                col = ia + 1 if ft.is_sin else ia
            F[ft.row, col] += float(ft.coef(W))
            dF[ft.row, col] += float(ft.dcoef(W))
        self._forcing_last = (W, F.copy(), dF.copy())
        return F, dF

    def _DT(self, U: np.ndarray) -> np.ndarray:
        """Rows of ``U`` differentiated in theta."""
        return U @ self._Dtheta.T

    def _jd(self, J: np.ndarray, k: np.ndarray) -> np.ndarray:
        """``J @ D_theta`` by a column swap and scale (``O(size^2)``)."""
        b = self.basis
        out = np.zeros_like(J)
        out[:, b.b_index] = J[:, b.a_index] * k
        out[:, b.a_index] = -J[:, b.b_index] * k
        return out

    def signal(self, U: np.ndarray, Omega: float, vector: np.ndarray) -> np.ndarray:
        """Coefficients of the combination ``vector . y`` (``vector`` over the system's
        ``state_names``: positions, velocities, first-order states)."""
        w = self._omega(Omega)
        n2 = self.n2
        alpha = np.concatenate([vector[:n2], vector[2 * n2 :]])
        beta = np.concatenate([vector[n2 : 2 * n2], np.zeros(self.n1)])
        return alpha @ U + w * (beta @ self._DT(U))

    # ---------------------------------------------------------------- evaluation ------
    def evaluate(
        self, u: ArrayLike, Omega: float, jacobian: bool = True, *, sparse: bool = False
    ) -> tuple[np.ndarray, Any, np.ndarray | None]:
        """Residual, ``dR/du`` (dense, or CSC with ``sparse``) and ``dR/dOmega``.

        Parameters
        ----------
        u : array_like
            Flat unknowns (``n_unknowns``).
        Omega : float
        jacobian : bool
            Also the derivatives (else ``None, None``).
        sparse : bool
            Return ``dR/du`` as a ``scipy.sparse.csc_matrix``.
        """
        U = self.unpack(u)
        W = float(Omega)
        w = self._omega(W)
        self.evaluations += 1
        size = self.size
        F, dF = self.forcing(W)
        UD = U @ self._DtT
        UDD = UD @ self._DtT
        A1UD, A2UDD = self._A1 @ UD, self._A2 @ UDD
        R = self._A0 @ U + w * A1UD + w * w * A2UDD - F
        dRdW = None
        if jacobian:
            dRdW = (A1UD + 2.0 * w * A2UDD) / self.m - dF
        blocks: list[tuple[int, int, np.ndarray]] = []
        k = self.basis.k.astype(float)
        for el in self.elements:
            if el.kind == "aft_y":
                P, JB, dW = self._aft_states(el, U, UD, w, jacobian)
                R += np.outer(el.w, P)
                if jacobian:
                    dRdW += np.outer(el.w, dW)
                    for j, Jj in JB:
                        for i in np.flatnonzero(el.w):
                            blocks.append((i, j, el.w[i] * Jj))
                continue
            has_beta = el.cols_beta.size > 0
            s = el.alpha @ U + w * (el.beta @ UD) if has_beta else el.alpha @ U
            if el.kind == "exact":
                P, Js = self._project(el, s, jacobian)
            else:
                P, Js = self._aft_s(el, s, jacobian)
            R[el.rows] += el.w[el.rows, None] * P
            if not jacobian:
                continue
            if has_beta:
                JsD = self._jd(Js, k)
                dRdW[el.rows] += el.w[el.rows, None] * (Js @ (el.beta @ UD)) / self.m
            for j in el.cols:
                a, b = el.alpha[j], el.beta[j]
                Jj = a * Js if b == 0.0 else (a * Js + (w * b) * JsD)
                for i in el.rows:
                    blocks.append((i, j, el.w[i] * Jj))
        r = R.reshape(-1)
        if not jacobian:
            return r, None, None
        if sparse:
            lin = self._lin_vals[0] + w * self._lin_vals[1] + (w * w) * self._lin_vals[2]
            rows = [self._lin_rows]
            cols = [self._lin_cols]
            vals = [lin]
            ii, jj = self._block_index
            for i, j, blk in blocks:
                rows.append(i * size + ii)
                cols.append(j * size + jj)
                vals.append(blk.reshape(-1))
            J = sps.csc_matrix(
                (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                shape=(self.n_unknowns, self.n_unknowns),
            )
        else:
            if self._lin_dense is not None:
                D0, D1, D2 = self._lin_dense
                J = D0 + w * D1 + (w * w) * D2
            else:
                lin = self._lin_vals[0] + w * self._lin_vals[1] + (w * w) * self._lin_vals[2]
                J = np.zeros((self.n_unknowns, self.n_unknowns))
                J[self._lin_rows, self._lin_cols] = lin
            for i, j, blk in blocks:
                J[i * size : (i + 1) * size, j * size : (j + 1) * size] += blk
        return r, J, dRdW.reshape(-1)

    def _project(self, el: _Element, s: np.ndarray, jacobian: bool):
        """The exact projection of one element's signal and its Jacobian, from a small
        cache keyed by the signal's coefficients: a damped Newton step evaluates the residual
        at the accepted iterate and then the Jacobian at the same point (for a continuous
        force the Jacobian costs nothing beyond the projection, so it is always kept)."""
        key = s.tobytes()
        cache = el.cache
        hit = cache.get(key)
        if hit is not None and (hit[1] is not None or not jacobian):
            return hit
        want = jacobian or el.projector.continuous
        P, Js, _ = el.projector.project(s, want)
        if len(cache) >= _PROJECTION_CACHE:
            cache.pop(next(iter(cache)))
        cache[key] = (P, Js)
        return P, Js

    def _aft_grid(self):
        key = ("grid", self.samples)
        if self._cache is not None and self._cache[0] == key:
            return self._cache[1]
        N = self.samples
        th = _TWO_PI * np.arange(N) / N
        Phi = self.basis.design(th)
        wts = np.full(self.size, 2.0 / N)
        wts[0] = 1.0 / N
        Pi = Phi.T * wts[:, None]
        self._cache = (key, (Phi, Pi))
        return Phi, Pi

    def _aft_s(self, el: _Element, s: np.ndarray, jacobian: bool):
        Phi, Pi = self._aft_grid()
        sv = Phi @ s
        P = Pi @ el.f(sv)
        if not jacobian:
            return P, None
        return P, Pi @ (el.df(sv)[:, None] * Phi)

    def _aft_states(self, el: _Element, U, UD, w, jacobian):
        Phi, Pi = self._aft_grid()
        n2 = self.n2
        q = Phi @ U[:n2].T
        v = w * (Phi @ UD[:n2].T)
        p = Phi @ U[n2:].T
        args = [*q.T, *v.T, *p.T]
        P = Pi @ el.f(*args)
        if not jacobian:
            return P, [], None
        k = self.basis.k.astype(float)
        blocks = []
        dW = np.zeros(self.size)
        for j in range(self.neq):
            if j < n2:
                gq = el.df[j](*args)
                gv = el.df[n2 + j](*args)
                Jq = Pi @ (gq[:, None] * Phi)
                Jv = Pi @ (gv[:, None] * Phi)
                blocks.append((j, Jq + w * self._jd(Jv, k)))
                dW += Jv @ UD[j] / self.m
            else:
                gp = el.df[n2 + (j - n2) + n2](*args)
                blocks.append((j, Pi @ (gp[:, None] * Phi)))
        return P, blocks, dW

    # continuation callables (the Jacobian right after the residual at the same point)
    def residual(self, u: ArrayLike, Omega: float) -> np.ndarray:
        """``R(u, Omega)`` (flat); caches the derivatives for :meth:`jacobian`."""
        r, J, dW = self.evaluate(u, Omega, True)
        self._last = (np.array(u, dtype=float), float(Omega), J, dW)
        return r

    def jacobian(self, u: ArrayLike, Omega: float) -> tuple[np.ndarray, np.ndarray]:
        """``(dR/du, dR/dOmega)``, dense."""
        last = getattr(self, "_last", None)
        if (
            last is not None
            and last[1] == float(Omega)
            and np.array_equal(last[0], np.asarray(u, dtype=float))
        ):
            return last[2], last[3]
        _, J, dW = self.evaluate(u, Omega, True)
        return J, dW

    # ---------------------------------------------------------------- solutions -------
    def linear_guess(self, Omega: float) -> np.ndarray:
        """One Newton step from the zero series: the steady state of the system linearised
        about ``y = 0`` (each PWL element on the segment of ``s = 0``)."""
        u0 = np.zeros(self.n_unknowns)
        try:
            du, _ = self._newton_step(u0, Omega)
        except (RuntimeError, ValueError, np.linalg.LinAlgError):
            return u0
        return u0 + du if np.all(np.isfinite(du)) else u0

    def _frozen_solve(
        self, Omega: float, frozen: dict[int, tuple[float, float]]
    ) -> np.ndarray | None:
        """The steady state (flat coefficients) of the linear system with each element
        ``idx`` of ``frozen`` replaced by ``slope * s + offset``, the other AFT elements
        linearised at zero and terms in the states left out; None when it is singular."""
        w = self._omega(Omega)
        F, _ = self.forcing(Omega)
        k = self.basis.k.astype(float)
        size = self.size
        eye = np.eye(size)
        blocks: list[tuple[int, int, np.ndarray]] = []
        rhs = F.copy()
        for idx, el in enumerate(self.elements):
            if idx in frozen:
                slope, offset = frozen[idx]
                rhs[:, 0] -= el.w * offset
                Js = slope * eye
            elif el.kind == "aft_s":
                P, Js = self._aft_s(el, np.zeros(size), True)
                rhs -= np.outer(el.w, P)
            else:
                continue  # a term in the states: left out of the guess
            JsD = self._jd(Js, k)
            for j in el.cols:
                Jj = el.alpha[j] * Js + (w * el.beta[j]) * JsD
                for i in el.rows:
                    blocks.append((i, j, el.w[i] * Jj))
        if self._lin_dense is not None:
            D0, D1, D2 = self._lin_dense
            A = D0 + w * D1 + (w * w) * D2
            for i, j, blk in blocks:
                A[i * size : (i + 1) * size, j * size : (j + 1) * size] += blk
            try:
                u = np.linalg.solve(A, rhs.reshape(-1))
            except np.linalg.LinAlgError:
                return None  # a frozen free segment of a clearance: singular, skipped
            return u if np.all(np.isfinite(u)) else None
        lin = self._lin_vals[0] + w * self._lin_vals[1] + (w * w) * self._lin_vals[2]
        ii, jj = self._block_index
        rows, cols, vals = [self._lin_rows], [self._lin_cols], [lin]
        for i, j, blk in blocks:
            rows.append(i * size + ii)
            cols.append(j * size + jj)
            vals.append(blk.reshape(-1))
        A = sps.csc_matrix(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
            shape=(self.n_unknowns, self.n_unknowns),
        )
        with warnings.catch_warnings():
            # a frozen free segment of a clearance leaves a coordinate without stiffness:
            # singular, skipped (the result is not finite)
            warnings.simplefilter("ignore", spla.MatrixRankWarning)
            try:
                u = spla.spsolve(A, rhs.reshape(-1))
            except (RuntimeError, ValueError):
                return None
        return u if np.all(np.isfinite(u)) else None

    def segment_guesses(self, Omega: float, limit: int = 64) -> list[tuple[np.ndarray, bool]]:
        """Steady states of the linear systems obtained by freezing every PWL element on one
        of its segments (at most ``limit`` combinations), each with a flag telling whether
        every element's signal stays inside its frozen segment (then it is an exact orbit
        and an exact HB solution for any ``H``). Non-PWL elements are linearised at 0."""
        w = self._omega(Omega)
        exact = [i for i, el in enumerate(self.elements) if el.kind == "exact"]
        counts = [self.elements[i].pwl.slopes.size for i in exact]
        total = int(np.prod(counts)) if counts else 1
        out = []
        # every combination of segments with their offsets (candidate exact orbits), then the
        # same slopes through the origin: for a clearance whose free segment leaves a
        # coordinate without stiffness (an impact pair away from contact: a singular family
        # of orbits) the contact slope without its offset is the useful guess
        for combo in range(min(2 * total, int(limit))):
            with_offset = combo < total
            segs, rest = {}, combo % total
            for i, cnt in zip(exact, counts, strict=True):
                segs[i], rest = rest % cnt, rest // cnt
            frozen = {
                idx: (
                    float(self.elements[idx].pwl.slopes[seg]),
                    float(self.elements[idx].pwl.offsets[seg]) if with_offset else 0.0,
                )
                for idx, seg in segs.items()
            }
            u = self._frozen_solve(Omega, frozen)
            if u is None:
                continue
            U = u.reshape(self.neq, self.size)
            UD = self._DT(U)
            inside = with_offset
            for idx, seg in segs.items() if with_offset else ():
                el = self.elements[idx]
                s = el.alpha @ U + w * (el.beta @ UD)
                pc = crossing_intervals(el.pwl, self.basis, TruncatedSeries(self.basis, s))
                if pc.d1.size or int(pc.segment[0]) != seg:
                    inside = False
                    break
            out.append((u, inside))
        out.sort(key=lambda p: not p[1])
        return out

    def describing_guesses(
        self, Omega: float, levels: int = _DF_LEVELS, limit: int = 4
    ) -> list[np.ndarray]:
        """Starting guesses for orbits that cross the breakpoints, from the describing
        function of every PWL element: with each element replaced by its equivalent slope
        at the signal ``S cos theta`` (the first cosine coefficient of its exact projection
        over ``S``) and its mean force, the linear steady state gives the element's signal
        a first-harmonic amplitude ``A(S)``; the guesses are the linear steady states at the
        self-consistent levels ``A(S) = S`` (sign changes of ``log(A/S)`` on a geometric grid
        of ``levels`` values of ``S / b`` from 1.001 to 30, ``b`` the element's largest
        breakpoint magnitude, refined by four regula falsi steps; with several elements the
        mean of their ``log(A/S)``), at most ``limit`` of them. These reach the impacting
        orbits of a clearance whose free segment leaves a coordinate without stiffness (the
        impact pair), which no frozen segment does."""
        pwl = [i for i, el in enumerate(self.elements) if el.kind == "exact"]
        if not pwl:
            return []
        w = self._omega(Omega)
        ia = self.basis.a_index[0]
        ib = self.basis.b_index[0]
        scales = []
        for idx in pwl:
            bps = self.elements[idx].pwl.breakpoints
            scales.append(float(np.abs(bps).max()) if bps.size else 1.0)

        def at(level: float) -> tuple[float, np.ndarray | None]:
            frozen = {}
            for idx, b in zip(pwl, scales, strict=True):
                key = (idx, level)
                if key not in self._df_cache:  # independent of Omega: once per balance
                    S = level * b
                    s = np.zeros(self.size)
                    s[ia] = S
                    P, _, _ = self.elements[idx].projector.project(s, False)
                    mean = float(P[0]) if self.basis.bias else 0.0
                    if len(self._df_cache) < 4096:
                        self._df_cache[key] = (float(P[ia]) / S, mean)
                    else:
                        frozen[idx] = (float(P[ia]) / S, mean)
                        continue
                frozen[idx] = self._df_cache[key]
            u = self._frozen_solve(Omega, frozen)
            if u is None:
                return math.nan, None
            U = u.reshape(self.neq, self.size)
            UD = self._DT(U)
            logs = []
            for idx, b in zip(pwl, scales, strict=True):
                el = self.elements[idx]
                s = el.alpha @ U + w * (el.beta @ UD)
                amp = math.hypot(float(s[ia]), float(s[ib]))
                logs.append(math.log(max(amp, 1e-300) / (level * b)))
            return float(np.mean(logs)), u

        grid = np.geomspace(1.001, 30.0, int(levels))
        values = [at(float(v)) for v in grid]
        out: list[np.ndarray] = []
        for i in range(len(grid) - 1):
            (g0, _), (g1, _) = values[i], values[i + 1]
            if not (math.isfinite(g0) and math.isfinite(g1)) or (g0 > 0) == (g1 > 0):
                continue
            lo, hi, glo, ghi = math.log(grid[i]), math.log(grid[i + 1]), g0, g1
            u_best = values[i][1] if abs(g0) < abs(g1) else values[i + 1][1]
            for _ in range(4):
                x = lo - glo * (hi - lo) / (ghi - glo)
                gx, ux = at(math.exp(x))
                if not math.isfinite(gx) or ux is None:
                    break
                u_best = ux
                if (gx > 0) == (glo > 0):
                    lo, glo = x, gx
                else:
                    hi, ghi = x, gx
            if u_best is not None:
                out.append(u_best)
            if len(out) >= limit:
                break
        return out

    def solve(
        self,
        Omega: float,
        guess: ArrayLike | None = None,
        *,
        tol: float = 1e-10,
        max_iterations: int = 60,
    ) -> np.ndarray:
        """Damped Newton at fixed ``Omega`` (sparse LU), from ``guess`` or the linear guess.

        Returns
        -------
        numpy.ndarray
            Flat coefficients.

        Raises
        ------
        SystemBalanceError
            No convergence within ``max_iterations`` (the message has the residual reached).
        """
        if guess is None:
            # exact segment orbits first, then the linearisation about zero, then the other
            # segment guesses: at most _MAX_STARTS Newton runs (each capped), then the
            # homotopy from the first two (a chain of n gaps has 3^n combinations)
            seg = self.segment_guesses(Omega, limit=4 * _MAX_STARTS)
            starts = [u for u, inside in seg if inside]
            starts.append(self.linear_guess(Omega))
            starts += [u for u, inside in seg if not inside]
            starts = starts[:_MAX_STARTS]
            last: SystemBalanceError | None = None
            for u0 in starts:
                try:
                    return self.solve(Omega, u0, tol=tol, max_iterations=min(30, max_iterations))
                except SystemBalanceError as exc:
                    last = exc
            # Newton homotopy from a guess: R(u) - (1 - lam) R(u_g) = 0 traced from lam = 0
            # to 1 by the continuation core, which passes the folds where damped Newton stalls
            for u0 in starts[:2]:
                u = self._homotopy(Omega, u0, tol)
                if u is not None:
                    return u
            assert last is not None
            raise last
        u, it, best = self._newton(
            Omega, self.unpack(guess).reshape(-1).copy(), tol, max_iterations
        )
        if u is not None:
            return u
        raise SystemBalanceError(
            f"harmonic balance of {self.system.name!r} at {self.parameter} = {Omega:g} did not "
            f"converge in {it + 1} of at most {max_iterations} Newton steps (|R| = {best:.3g}): "
            "give a guess or more iterations"
        )

    def _newton(
        self,
        Omega: float,
        u: np.ndarray,
        tol: float,
        max_iterations: int,
        abandon=None,
        abandon_after: int = 3,
        halvings: int = 12,
        extend: bool = False,
    ) -> tuple[np.ndarray | None, int, float]:
        """Damped Newton from ``u``: ``(solution or None, last step index, best |R|)``;
        ``abandon(u)`` (when given) is asked after each step from ``abandon_after`` on whether
        to give up (the iterate is heading for a solution already known); at most
        ``halvings`` Armijo halvings per step. With ``extend`` a run that reaches its cap
        having reduced ``|R|`` by more than three decades gets ``max_iterations`` more steps
        once (a damped run closing in on a solution: the impact pair's impacting orbit at
        Omega = 1.0 from its describing-function guess reached |R| = 2e-6 in 12 steps)."""
        scale = max(1e-12, float(np.abs(u).max()))
        best = np.inf
        first = None
        it = 0
        cap = int(max_iterations)
        while it < cap:
            if abandon is not None and it >= abandon_after and abandon(u):
                return None, it, best
            du, r = self._newton_step(u, Omega)
            nr = float(np.linalg.norm(r))
            if first is None:
                first = nr
            # Armijo halving: a poor guess may overshoot across a switching angle
            lam = 1.0
            decreased = False
            for _ in range(int(halvings)):
                un = u + lam * du
                rn = self.evaluate(un, Omega, False)[0]
                if np.linalg.norm(rn) < (1 - 1e-4 * lam) * nr or nr == 0.0:
                    decreased = True
                    break
                lam *= 0.5
            if not decreased:
                if float(np.abs(du).max()) <= tol * scale:
                    # the residual is at rounding level, where no step decreases it: the
                    # full Newton correction is below the tolerance, so u is the solution
                    # (nsd2, H = 1, AFT: |R| = 2.3e-16, |du| = 1e-15 was reported unconverged)
                    return u, it, min(best, nr)
                break  # stalled: a local minimum of |R| (the caller tries another start)
            u = un
            best = min(best, float(np.linalg.norm(rn)))
            scale = max(scale, float(np.abs(u).max()))
            if float(np.abs(lam * du).max()) <= tol * scale:
                return u, it, best
            it += 1
            if it == cap == int(max_iterations) and extend and best < 1e-3 * first:
                cap += int(max_iterations)
        return None, max(0, it - 1), best

    def _newton_step(self, u: np.ndarray, Omega: float) -> tuple[np.ndarray, np.ndarray]:
        """``(-J^-1 R, R)`` at ``u``: a dense LU for small balances, SuperLU on the sparse
        Jacobian otherwise (least squares when singular)."""
        dense = self._lin_dense is not None
        r, J, _ = self.evaluate(u, Omega, True, sparse=not dense)
        try:
            if dense:
                du = np.linalg.solve(J, -r)
            else:
                du = spla.splu(J.tocsc()).solve(-r)
            if np.all(np.isfinite(du)):
                return du, r
        except (RuntimeError, np.linalg.LinAlgError):
            pass
        Jd = J if dense else J.toarray()
        return np.linalg.lstsq(Jd, -r, rcond=None)[0], r

    def _homotopy(self, Omega: float, u0: np.ndarray, tol: float) -> np.ndarray | None:
        """A solution by the Newton homotopy from ``u0`` (None when it does not reach 1)."""
        r0 = self.evaluate(u0, Omega, False)[0]

        def residual(u, lam):
            return self.evaluate(u, Omega, False)[0] - (1.0 - lam) * r0

        def jacobian(u, lam):
            _, J, _ = self.evaluate(u, Omega, True)
            return J, r0

        scale = max(1e-10, float(np.abs(u0).max()))
        try:
            curve = continue_curve(
                residual,
                jacobian,
                u0,
                0.0,
                (0.0, 1.0),
                direction=1,
                u_scale=1e-2 * scale,
                lam_scale=1.0,
                adaptive_scale=True,
                ds_max=0.1,
                tol=1e-9,
                max_points=400,
                predictor="hermite",
            )
        except (ContinuationError, ParameterError):
            return None
        if curve.lam.size == 0 or abs(float(curve.lam[-1]) - 1.0) > 1e-12:
            return None
        try:
            return self.solve(Omega, np.asarray(curve.u[-1]), tol=tol, max_iterations=20)
        except SystemBalanceError:
            return None

    # ---------------------------------------------------------------- stability -------
    def _field_jacobian(self, slopes: dict[int, float], y: np.ndarray | None = None, w=None):
        """``A = d y'/d y`` with each element's slope (or sampled gradient)."""
        n2, n = self.n2, self.system.n
        Lt = self._L.copy()
        for idx, el in enumerate(self.elements):
            if el.kind == "aft_y":
                g = np.array([float(d(*y)) for d in el.df])
                Lt += np.outer(el.w, g)
            else:
                Lt += np.outer(el.w, slopes[idx] * el.c)
        A = np.zeros((n, n))
        A[:n2, n2 : 2 * n2] = np.eye(n2)
        A[n2:, :] = -self._Binv @ Lt
        return A

    def monodromy(self, u: ArrayLike, Omega: float) -> np.ndarray:
        """Monodromy (``n x n``, over one response period ``2 pi m / Omega``) of the
        linearisation about the HB orbit (module docstring)."""
        U = self.unpack(u)
        w = self._omega(Omega)
        UD = self._DT(U)
        if self._all_pwl:
            return self._monodromy_pwl(U, UD, w)
        n2 = self.n2
        cuts = [np.zeros(1), np.array([_TWO_PI])]
        pieces = {}
        smooth = False
        for idx, el in enumerate(self.elements):
            if el.kind == "exact":
                s = el.alpha @ U + w * (el.beta @ UD)
                pc = crossing_intervals(el.pwl, self.basis, TruncatedSeries(self.basis, s))
                pieces[idx] = pc
                if pc.d1.size:
                    cuts.append(pc.start)
            else:
                smooth = True
        th = np.unique(np.concatenate(cuts))
        if smooth:
            nsub = _SMOOTH_STEPS_PER_HARMONIC * self.basis.kmax
            fine = np.linspace(0.0, _TWO_PI, nsub + 1)
            th = np.unique(np.concatenate([th, fine]))
        th = th[(th >= 0.0) & (th <= _TWO_PI)]
        n = self.system.n
        Mono = np.eye(n)
        for a, b in zip(th[:-1], th[1:], strict=True):
            if b - a <= 0.0:
                continue
            mid = 0.5 * (a + b)
            slopes = {}
            for idx, el in enumerate(self.elements):
                if el.kind == "exact":
                    pc = pieces[idx]
                    if pc.d1.size == 0:
                        seg = int(pc.segment[0])
                    else:
                        j = int(np.searchsorted(pc.start, mid, side="right")) - 1
                        seg = int(pc.segment[j % pc.segment.size])
                    slopes[idx] = float(el.pwl.slopes[seg])
                elif el.kind == "aft_s":
                    s = el.alpha @ U + w * (el.beta @ UD)
                    sv = float(self.basis.evaluate(s, np.array([mid]))[0])
                    slopes[idx] = float(el.df(np.array([sv]))[0])
            y = None
            if any(el.kind == "aft_y" for el in self.elements):
                ph = self.basis.design(np.array([mid]))[0]
                y = np.concatenate([U[:n2] @ ph, w * (UD[:n2] @ ph), U[n2:] @ ph])
            Mono = self._expm(slopes, y, w, (b - a) / w) @ Mono
            Mono = self._saltation(pieces, b, U, UD, w) @ Mono
        return Mono

    def _monodromy_pwl(
        self, U: np.ndarray, UD: np.ndarray, w: float, given: dict | None = None
    ) -> np.ndarray:
        """The monodromy when every element is piecewise linear (the same product as the
        general loop, with the segments of every element found for all intervals at once
        and the saltations only where a force jumps); ``given`` the crossing intervals of
        the elements when already known."""
        pieces = {}
        cuts = [np.zeros(1), np.array([_TWO_PI])]
        for idx, el in enumerate(self.elements):
            pc = None if given is None else given.get(idx)
            if pc is None:
                s = el.alpha @ U + w * (el.beta @ UD)
                pc = crossing_intervals(el.pwl, self.basis, TruncatedSeries(self.basis, s))
            pieces[idx] = pc
            if pc.d1.size:
                cuts.append(pc.start)
        a, b, rows = _segment_intervals(cuts, pieces, len(self.elements))
        jumps = any(not el.projector.continuous for el in self.elements)
        dts = (b - a) / w
        Mono = np.eye(self.system.n)
        for p, (row, dt) in enumerate(zip(rows, dts.tolist(), strict=True)):
            A, lam, V, Vinv = self._pwl_field(tuple(row))
            if Vinv is None:
                E = sla.expm(A * dt)
            else:
                E = ((V * np.exp(lam * dt)[None, :]) @ Vinv).real
            Mono = E @ Mono
            if jumps:
                Mono = self._saltation(pieces, float(b[p]), U, UD, w) @ Mono
        return Mono

    def _pwl_field(self, segments: tuple[int, ...]):
        """``(A, eigenvalues, eigenvectors, inverse or None)`` of the field's Jacobian with
        each PWL element on the given segment (cached: finitely many, independent of
        ``Omega``; None for the inverse of a defective or ill-conditioned one)."""
        key = ("segments", segments)
        ent = self._eig_cache.get(key)
        if ent is None:
            slopes = {
                idx: float(el.pwl.slopes[seg])
                for idx, (el, seg) in enumerate(zip(self.elements, segments, strict=True))
            }
            A = self._field_jacobian(slopes, None, None)
            lam, V = np.linalg.eig(A)
            ok = np.linalg.cond(V) < 1e8
            ent = (A, lam, V, np.linalg.inv(V) if ok else None)
            if len(self._eig_cache) < 4096:
                self._eig_cache[key] = ent
        return ent

    def _expm(self, slopes: dict[int, float], y, w, dt: float) -> np.ndarray:
        """``expm(A dt)``; for piecewise-linear elements only ``A`` is one of finitely many
        matrices (one per combination of segments, independent of ``Omega``), so its
        eigen-decomposition is computed once and cached (a Pade ``expm`` per interval cost
        ~1 ms, more than the whole Newton step); defective or ill-conditioned ones use
        ``expm``."""
        if y is not None or any(el.kind == "aft_s" for el in self.elements):
            return sla.expm(self._field_jacobian(slopes, y, w) * dt)
        key = tuple(sorted(slopes.items()))
        ent = self._eig_cache.get(key)
        if ent is None:
            A = self._field_jacobian(slopes, None, w)
            lam, V = np.linalg.eig(A)
            ok = np.linalg.cond(V) < 1e8
            ent = (A, lam, V, np.linalg.inv(V) if ok else None)
            if len(self._eig_cache) < 4096:
                self._eig_cache[key] = ent
        A, lam, V, Vinv = ent
        if Vinv is None:
            return sla.expm(A * dt)
        E = (V * np.exp(lam * dt)[None, :]) @ Vinv
        return E.real if np.isrealobj(A) else E

    def _saltation(self, pieces, theta, U, UD, w) -> np.ndarray:
        """Saltation at ``theta`` of the discontinuous PWL elements crossing there."""
        n = self.system.n
        S = np.eye(n)
        for idx, pc in pieces.items():
            el = self.elements[idx]
            if el.projector.continuous or pc.d1.size == 0:
                continue
            hit = np.flatnonzero(np.abs(pc.start - theta) <= 1e-13 * _TWO_PI)
            for c in hit:
                before, after = int(pc.segment[c - 1]), int(pc.segment[c])
                if before == after:
                    continue
                xb = float(el.pwl.breakpoints[min(before, after)])
                jump = (el.pwl.slopes[after] - el.pwl.slopes[before]) * xb + (
                    el.pwl.offsets[after] - el.pwl.offsets[before]
                )
                dfield = np.zeros(n)
                dfield[self.n2 :] = -self._Binv @ el.w * jump
                sdot = w * float(pc.d1[c])
                if sdot != 0.0:
                    S = (np.eye(n) + np.outer(dfield, el.c) / sdot) @ S
        return S

    def _max_multipliers(self, Us: np.ndarray, Ws: np.ndarray) -> np.ndarray:
        """``max |mu|`` at each point ``(Us[p], Ws[p])`` of a branch: :meth:`multipliers`,
        with the crossings of every PWL element found for all points at once
        (:func:`_crossings_batch`) when every element is piecewise linear."""
        P = Ws.size
        if not self._all_pwl or P < 2:
            return np.array([float(np.abs(self.multipliers(Us[p], Ws[p])).max()) for p in range(P)])
        U3 = Us.reshape(P, self.neq, self.size)
        w = np.array([self._omega(float(W)) for W in Ws])
        UD3 = U3 @ self._DtT
        given: list[dict] = [{} for _ in range(P)]
        for idx, el in enumerate(self.elements):
            S = np.einsum("j,pjk->pk", el.alpha, U3)
            if np.any(el.beta):
                S = S + w[:, None] * np.einsum("j,pjk->pk", el.beta, UD3)
            for p, pc in enumerate(_crossings_batch(el.pwl, self.basis, S)):
                given[p][idx] = pc
        batched = self._max_multipliers_stacked(w, given)
        if batched is not None:
            return batched
        out = np.empty(P)
        for p in range(P):
            mono = self._monodromy_pwl(U3[p], UD3[p], float(w[p]), given[p])
            out[p] = float(np.abs(np.linalg.eigvals(mono)).max())
        return out

    def _max_multipliers_stacked(self, w: np.ndarray, given: list[dict]) -> np.ndarray | None:
        """:meth:`_monodromy_pwl` for every point at once when no force jumps (no saltation)
        and every segment combination met has an eigen-decomposition: the intervals of each
        point as there, the exponentials of all intervals of one combination in one stacked
        product, the monodromies multiplied interval by interval for all points together
        (identities after a point's last interval) and their eigenvalues in one call. The
        same products as the loop (stacked ``matmul`` multiplies slice by slice); None
        otherwise (the loop)."""
        if any(not el.projector.continuous for el in self.elements):
            return None
        P, n = len(given), self.system.n
        combos: dict[tuple[int, ...], int] = {}
        k_combo, k_dt, k_point, k_pos = [], [], [], []
        for p in range(P):
            pieces = given[p]
            cuts = [np.zeros(1), np.array([_TWO_PI])]
            for idx in range(len(self.elements)):
                if pieces[idx].d1.size:
                    cuts.append(pieces[idx].start)
            a, b, rows = _segment_intervals(cuts, pieces, len(self.elements))
            dts = (b - a) / float(w[p])
            for q, (row, dt) in enumerate(zip(rows, dts.tolist(), strict=True)):
                key = tuple(row)
                ci = combos.get(key)
                if ci is None:
                    ci = combos[key] = len(combos)
                k_combo.append(ci)
                k_dt.append(dt)
                k_point.append(p)
                k_pos.append(q)
        if not k_dt:
            return None
        k_combo_a, k_dt_a = np.array(k_combo), np.array(k_dt)
        E = np.empty((k_dt_a.size, n, n))
        for key, ci in combos.items():
            _, lam, V, Vinv = self._pwl_field(key)
            if Vinv is None:
                return None
            sel = np.flatnonzero(k_combo_a == ci)
            scaled = V[None, :, :] * np.exp(lam[None, :] * k_dt_a[sel][:, None])[:, None, :]
            E[sel] = (scaled @ Vinv).real
        M = max(k_pos) + 1
        eye = np.eye(n)
        stack = np.empty((P, M, n, n))
        stack[:] = eye
        stack[np.array(k_point), np.array(k_pos)] = E
        mono = np.empty((P, n, n))
        mono[:] = eye
        for m in range(M):
            mono = stack[:, m] @ mono
        if not np.all(np.isfinite(mono)):
            return None
        return np.abs(np.linalg.eigvals(mono)).max(axis=1)

    def multipliers(self, u: ArrayLike, Omega: float) -> np.ndarray:
        """Floquet multipliers (eigenvalues of :meth:`monodromy`), by decreasing modulus."""
        mu = np.linalg.eigvals(self.monodromy(u, Omega))
        return mu[np.argsort(-np.abs(mu), kind="stable")]

    # ---------------------------------------------------------------- measures --------
    def max_abs(self, u: ArrayLike, Omega: float, output: str | ArrayLike) -> float:
        """``max_t |o(t)|`` of an output (coordinate name, combination text or vector over
        ``system.state_names``), refined by Newton on the extrema of the series."""
        vec = self.output_vector(output)
        s = self.signal(self.unpack(u), Omega, vec)
        return _series_max_abs(self.basis, s)

    def output_vector(self, output: str | ArrayLike) -> np.ndarray:
        """The combination vector of ``output`` over ``system.state_names``.

        Raises
        ------
        ModelError
            For an output that is no coordinate or linear combination of the states.
        """
        if isinstance(output, str):
            return self.system.output(output)
        vec = np.asarray(output, dtype=float).reshape(-1)
        if vec.size != self.system.n or not np.any(vec) or not np.all(np.isfinite(vec)):
            raise ModelError(
                f"output vector {output!r}: expected {self.system.n} finite numbers over "
                f"{self.system.state_names}, not all zero"
            )
        return vec


_EPS = float(np.finfo(float).eps)
_BATCH_GRIDS: dict = {}


def _segment_intervals(cuts: list, pieces, n_elements: int):
    """The intervals of one period between the crossings ``cuts`` of every element (angles,
    with 0 and 2 pi among them) and, per interval, the segment of each element: ``(a, b,
    rows)``, ``rows[p]`` the tuple-able list of segment indices on ``[a[p], b[p]]``."""
    th = np.unique(np.concatenate(cuts))
    th = th[(th >= 0.0) & (th <= _TWO_PI)]
    a, b = th[:-1], th[1:]
    keep = b > a
    a, b = a[keep], b[keep]
    mid = 0.5 * (a + b)
    segs = []
    for idx in range(n_elements):
        pc = pieces[idx]
        if pc.d1.size == 0:
            segs.append(np.full(mid.size, int(pc.segment[0])))
        else:
            j = np.searchsorted(pc.start, mid, side="right") - 1
            segs.append(pc.segment[j % pc.segment.size])
    rows = np.array(segs).T.tolist() if segs else [[]] * mid.size
    return a, b, rows


def _batch_grid(basis: HarmonicBasis):
    """Design matrices of the isolation grid of :func:`_crossings_batch` (cached)."""
    g = _BATCH_GRIDS.get(basis)
    if g is None:
        N = max(16, 4 * basis.kmax)
        h = _TWO_PI / N
        points = h * np.arange(N + 1)
        points[-1] = _TWO_PI
        mids = points[:-1] + 0.5 * h
        end = np.ascontiguousarray(basis.design(points[:-1]).T)
        mid = [np.ascontiguousarray(basis.design(mids, j).T) for j in range(3)]
        g = _BATCH_GRIDS[basis] = (h, points, end, mid)
    return g


def _crossings_batch(pwl: NumericPWL, basis: HarmonicBasis, S: np.ndarray) -> list:
    """The crossing intervals of each row of ``S`` (coefficients of one signal per row) at
    the breakpoints of ``pwl``: :func:`~perturb.fourier.projection.crossing_intervals`
    vectorised over the rows (the multipliers of a whole branch).

    The same certified isolation: on a grid of ``max(16, 4H)`` cells, a cell is excluded
    when the third-order Taylor bound about its midpoint (with ``B_3 = sum k^3 |c_k|``) keeps
    ``x - d`` away from zero, holds exactly one root when ``x`` is monotone there (bound
    with ``B_3`` on ``x''``) and changes sign, and is *hard* otherwise; roots are polished by
    Halley's iteration from the regula falsi point to rounding level, then one Newton step.
    A row with a hard cell, or whose polish does not reach rounding level inside its
    bracket, is handed to ``crossing_intervals`` itself. Measured equal to it (angles to
    1e-15) on the nsd2 and impact-pair branches."""
    S = np.asarray(S, dtype=float)
    P = S.shape[0]
    levels = pwl.breakpoints
    out: list = [None] * P
    if levels.size == 0:
        return [crossing_intervals(pwl, basis, TruncatedSeries(basis, S[p])) for p in range(P)]
    h, points, end, mid = _batch_grid(basis)
    r = 0.5 * h
    ks = basis.k.astype(float)
    a0 = S[:, 0] if basis.bias else np.zeros(P)
    C = S[:, basis.a_index] - 1j * S[:, basis.b_index]  # x = a0 + Re sum C e^{ik theta}
    absC = np.abs(C)
    B3 = absC @ ks**3
    scale = np.abs(a0) + absC.sum(axis=1)
    # einsum, not BLAS: a threaded BLAS made these products of a few hundred rows 10x
    # slower on a loaded machine (the single-signal routine's products stay below its
    # threading threshold)
    XE = np.einsum("pk,kn->pn", S, end)
    x0m, x1m, x2m = (np.einsum("pk,kn->pn", S, m) for m in mid[:3])
    dmax = float(np.abs(levels).max())
    slack = (64 * _EPS * (scale + dmax))[:, None]
    r2 = 0.5 * r * r
    monotone = np.abs(x1m) > r * np.abs(x2m) + r2 * B3[:, None] + slack
    bad = np.zeros(P, dtype=bool)
    rows, cells, lvl = [], [], []
    for li, d in enumerate(levels):
        e0 = x0m - d
        excluded = (
            np.abs(e0) > r * np.abs(x1m) + r2 * np.abs(x2m) + (r * r2 / 3.0) * B3[:, None] + slack
        )
        bad |= np.any(~excluded & ~monotone, axis=1)
        e_end = XE - d
        e_next = np.roll(e_end, -1, axis=1)
        p_i, c_i = np.nonzero(~excluded & monotone & ((e_end >= 0.0) != (e_next >= 0.0)))
        rows.append(p_i)
        cells.append(c_i)
        lvl.append(np.full(p_i.size, li))
    p_i, c_i, l_i = np.concatenate(rows), np.concatenate(cells), np.concatenate(lvl)
    keep = ~bad[p_i]
    p_i, c_i, l_i = p_i[keep], c_i[keep], l_i[keep]
    if p_i.size:
        d = levels[l_i]
        lo, hi = points[c_i], points[c_i + 1]
        elo = XE[p_i, c_i] - d
        ehi = XE[p_i, (c_i + 1) % XE.shape[1]] - d
        ftol = 64 * _EPS * (scale[p_i] + dmax)
        Cp, a0p = C[p_i], a0[p_i]
        ik = 1j * ks

        def values(t):
            E = np.exp(np.multiply.outer(t, ik)) * Cp
            return (
                a0p + E.sum(axis=1).real,
                (E * ik).sum(axis=1).real,
                (E * (ik * ik)).sum(axis=1).real,
            )

        t = lo - elo * (hi - lo) / (ehi - elo)
        with np.errstate(all="ignore"):
            for _ in range(7):
                x, x1, x2 = values(t)
                f = x - d
                if bool(np.all(np.abs(f) <= ftol)):
                    break
                t = t - 2.0 * f * x1 / (2.0 * x1 * x1 - f * x2)
            t_new = t - f / x1
        margin = 1e-12 * (hi - lo)
        fail = (np.abs(f) > ftol) | ~((t_new >= lo - margin) & (t_new <= hi + margin))
        bad[p_i[fail]] = True
        theta = np.mod(t_new, _TWO_PI)
    # the roots grouped by row, sorted by angle within each row
    by_row = np.lexsort((theta, p_i)) if p_i.size else np.empty(0, dtype=int)
    starts = np.searchsorted(p_i[by_row], np.arange(P + 1)) if p_i.size else np.zeros(P + 1, int)
    for p in range(P):
        if bad[p]:
            out[p] = crossing_intervals(pwl, basis, TruncatedSeries(basis, S[p]))
            continue
        sel = by_row[starts[p] : starts[p + 1]]
        if sel.size == 0:
            seg = pwl.segment_index(np.array([a0[p]]))
            out[p] = CrossingIntervals(np.zeros(1), np.array([_TWO_PI]), seg, np.zeros(0))
            continue
        order = sel
        th, d1 = theta[order], x1[order]
        length = np.empty(th.size)
        length[:-1] = th[1:] - th[:-1]
        length[-1] = th[0] + _TWO_PI - th[-1]
        out[p] = CrossingIntervals(th, length, l_i[order] + (d1 > 0.0), d1)
    return out


def _series_max_abs(basis: HarmonicBasis, s: np.ndarray) -> float:
    """``max |x(theta)|`` of one series (:func:`_max_abs_many`)."""
    return float(_max_abs_many(basis, np.asarray(s, dtype=float)[None, :])[0])


def _max_abs_many(basis: HarmonicBasis, S: np.ndarray) -> np.ndarray:
    """``max |x(theta)|`` of each row of ``S`` (coefficients): the best of ``16 H`` samples
    (at least 64), refined by Newton on ``x' = 0`` (steps kept within one sample spacing),
    vectorised over the rows."""
    S = np.asarray(S, dtype=float)
    N = max(64, 16 * basis.kmax)
    th = _TWO_PI * np.arange(N) / N
    X = S @ basis.design(th).T
    i = np.argmax(np.abs(X), axis=1)
    best = np.abs(X[np.arange(S.shape[0]), i])
    t = th[i]
    h = _TWO_PI / N
    ks = basis.k.astype(float)
    a, b = S[:, basis.a_index], S[:, basis.b_index]
    a0 = S[:, 0] if basis.bias else 0.0
    # harmonics 1..K contiguous (the usual basis): cos/sin of k t by a running product of
    # exp(i t) (rounding ~K eps) instead of P x K transcendental calls
    contiguous = bool(np.array_equal(basis.k, np.arange(1, basis.kmax + 1)))

    def trig(t):
        if contiguous:
            Z = np.cumprod(np.repeat(np.exp(1j * t)[:, None], ks.size, axis=1), axis=1)
            return Z.real, Z.imag
        return np.cos(np.outer(t, ks)), np.sin(np.outer(t, ks))

    for _ in range(8):
        c, sn = trig(t)
        d1 = np.sum((-a * sn + b * c) * ks, axis=1)
        d2 = np.sum((-a * c - b * sn) * ks**2, axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            step = np.where(d2 != 0.0, d1 / d2, 0.0)
        t = t - np.clip(step, -h, h)
        if np.all(np.abs(step) < 1e-14):
            break
    c, sn = trig(t)
    x = a0 + np.sum(a * c + b * sn, axis=1)
    return np.maximum(best, np.abs(x))


# =============================================================================================
# results and front functions
# =============================================================================================
@dataclass(frozen=True, eq=False)
class SystemBalanceSolution:
    """One harmonic-balance orbit of a system.

    Attributes
    ----------
    Omega : float
    U : numpy.ndarray
        ``(n2 + n1, size)`` coefficients, one row per name of :attr:`coordinates`.
    coordinates : tuple of str
    basis : HarmonicBasis
    m : int
    multipliers : numpy.ndarray or None
        Floquet multipliers (monodromy of the linearisation), by decreasing modulus.
    n2 : int
        Number of second-order coordinates (the first ``n2`` rows of ``U``).
    """

    Omega: float
    U: np.ndarray
    coordinates: tuple[str, ...]
    basis: HarmonicBasis
    m: int
    multipliers: np.ndarray | None
    n2: int

    @property
    def stable(self) -> bool | None:
        if self.multipliers is None:
            return None
        return bool(np.abs(self.multipliers).max() <= 1.0 + _UNIT_TOL)

    def __call__(self, t: ArrayLike, coordinate: str | int = 0) -> np.ndarray:
        """The series of one coordinate at times ``t``."""
        j = self.coordinates.index(coordinate) if isinstance(coordinate, str) else int(coordinate)
        th = np.asarray(t, dtype=float) * self.Omega / self.m
        return self.basis.evaluate(self.U[j], th.reshape(-1)).reshape(np.shape(th))

    def max_abs(self) -> dict[str, float]:
        """``max_t |z_j(t)|`` per coordinate."""
        return {c: _series_max_abs(self.basis, self.U[j]) for j, c in enumerate(self.coordinates)}

    def state(self, t: float = 0.0) -> np.ndarray:
        """The full state ``y = (q, q', p)`` at time ``t`` (an initial state for shooting)."""
        th = float(t) * self.Omega / self.m
        w = self.Omega / self.m
        ph = self.basis.design(np.array([th]))[0]
        dph = self.basis.design(np.array([th]), 1)[0]
        n2 = self.n2
        q = self.U[:n2] @ ph
        v = w * (self.U[:n2] @ dph)
        p = self.U[n2:] @ ph
        return np.concatenate([q, v, p])


def _solution(sb: SystemBalance, u: np.ndarray, W: float, stability: bool):
    mu = sb.multipliers(u, W) if stability else None
    return SystemBalanceSolution(
        float(W), sb.unpack(u).copy(), sb.coordinates, sb.basis, sb.m, mu, sb.n2
    )


def system_balance_orbit(
    system: System,
    Omega: float,
    *,
    harmonics: int = 7,
    m: int = 1,
    guess: ArrayLike | None = None,
    stability: bool = True,
    tol: float = 1e-10,
    max_iterations: int = 60,
    projection: str = "exact",
) -> SystemBalanceSolution:
    """One harmonic-balance orbit of ``system`` at the frequency ``Omega``.

    Parameters
    ----------
    system : System
    Omega : float
    harmonics : int
        ``H >= 1``.
    m : int
        Response period in forcing periods.
    guess : array_like, optional
        Flat coefficients (``SystemBalance.n_unknowns``) or ``(n2 + n1, 2H + 1)``; default
        the steady state of the system linearised about zero.
    stability : bool
        Compute the Floquet multipliers.
    tol, max_iterations
        Newton's tolerance (scaled correction) and iteration cap.
    projection : {"exact", "aft"}
        As :class:`SystemBalance`.

    Raises
    ------
    ParameterError, ModelError
        Bad input (``H < 1``, a zero combination, ...).
    SystemBalanceError
        No convergence.
    """
    sb = SystemBalance(system, harmonics, m=m, projection=projection)
    g = None if guess is None else np.asarray(guess, dtype=float).reshape(-1)
    u = sb.solve(Omega, g, tol=tol, max_iterations=max_iterations)
    return _solution(sb, u, Omega, stability)


@dataclass(frozen=True, eq=False)
class SystemBalanceBranch:
    """A continued branch of harmonic-balance orbits.

    Attributes
    ----------
    Omega : numpy.ndarray
        ``(P,)`` parameter values along the curve.
    U : numpy.ndarray
        ``(P, n2 + n1, size)`` coefficients.
    coordinates : tuple of str
    amplitudes : dict of str to numpy.ndarray
        ``max_t |z_j(t)|`` per coordinate along the branch.
    output : str
    output_amplitude : numpy.ndarray
        ``max_t |o(t)|`` of the output along the branch.
    max_multiplier : numpy.ndarray or None
        ``max |mu|`` per point (None without stability).
    stable : numpy.ndarray or None
    folds : tuple of float
        Parameter values of the folds the continuation located.
    curve : ContinuationCurve or None
        The raw continuation result (the downward run of a branch traced both ways; None for
        a single solution at a listed frequency).
    output_coefficients : numpy.ndarray
        ``(P, size)`` coefficients of the output.
    m : int
    model : str
        The system's name.
    n2 : int
        Second-order coordinates (the first ``n2`` rows of each ``U[p]``).
    """

    Omega: np.ndarray
    U: np.ndarray
    coordinates: tuple[str, ...]
    amplitudes: dict
    output: str
    output_amplitude: np.ndarray
    max_multiplier: np.ndarray | None
    stable: np.ndarray | None
    folds: tuple[float, ...]
    curve: ContinuationCurve | None
    output_coefficients: np.ndarray
    m: int = 1
    model: str = ""
    n2: int = 0

    def __len__(self) -> int:
        return int(self.Omega.size)

    @property
    def output_first_harmonic(self) -> np.ndarray:
        """Amplitude of the output's component at the forcing frequency (harmonic ``m``)."""
        a = self.output_coefficients[:, 2 * self.m - 1]
        b = self.output_coefficients[:, 2 * self.m]
        return np.hypot(a, b)

    @property
    def output_mean(self) -> np.ndarray:
        return self.output_coefficients[:, 0].copy()

    def states(self, t: float = 0.0) -> np.ndarray:
        """``(P, n)``: the full state ``y = (q, q', p)`` of every point's orbit at time ``t``
        (initial states for shooting the exact orbit)."""
        n2 = int(self.n2)
        size = self.U.shape[2]
        basis = HarmonicBasis.make((size - 1) // 2)
        out = np.empty((len(self), 2 * n2 + self.U.shape[1] - n2))
        for p in range(len(self)):
            w = float(self.Omega[p]) / self.m
            th = np.array([float(t) * w])
            ph, dph = basis.design(th)[0], basis.design(th, 1)[0]
            out[p] = np.concatenate(
                [self.U[p, :n2] @ ph, w * (self.U[p, :n2] @ dph), self.U[p, n2:] @ ph]
            )
        return out

    def columns(self) -> dict[str, np.ndarray]:
        """``amplitude_<name>`` (max |z_j|) and ``mean_<name>`` per coordinate, as the exact
        response of a System names them."""
        out = {f"amplitude_{c}": self.amplitudes[c] for c in self.coordinates}
        out.update({f"mean_{c}": self.U[:, j, 0].copy() for j, c in enumerate(self.coordinates)})
        return out

    def to_branch(self) -> Branch:
        """The standard :class:`~perturb.response.Branch` of the output (stability columns
        NaN-free only when the branch was computed with ``stability=True``)."""
        n = len(self)
        stable = self.stable if self.stable is not None else np.zeros(n, dtype=bool)
        mm = self.max_multiplier if self.max_multiplier is not None else np.full(n, np.nan)
        return Branch(
            self.Omega.copy(),
            self.output_amplitude.copy(),
            self.output_first_harmonic,
            self.output_mean,
            stable.copy(),
            mm.copy(),
        )

    def to_response(self) -> Response:
        """A one-branch :class:`~perturb.response.Response` (method ``"hb-system"``)."""
        folds = []
        for lam in self.folds:
            i = int(np.argmin(np.abs(self.Omega - lam)))
            folds.append((float(lam), float(self.output_amplitude[i])))
        return Response(
            (self.to_branch(),),
            "hb-system",
            self.model,
            folds=tuple(folds),
            notes=(
                f"harmonic balance of {len(self.coordinates)} coordinates, H = "
                f"{(self.U.shape[2] - 1) // 2}, m = {self.m}; output {self.output}; "
                "continuation stopped: "
                + (self.curve.stop_reason if self.curve is not None else "-"),
            ),
        )


def _stable_start(sb: SystemBalance, W: float) -> np.ndarray:
    """A solution at ``W`` from the segment guesses, a stable one when there is one (the
    exact segment orbits first)."""
    found: list[np.ndarray] = []
    seg = sb.segment_guesses(W, limit=4 * _MAX_STARTS)
    starts = [u for u, inside in seg if inside] + [sb.linear_guess(W)]
    starts += [u for u, inside in seg if not inside]
    for g in starts[:_MAX_STARTS]:
        try:
            u = sb.solve(W, g, max_iterations=30)
        except SystemBalanceError:
            continue
        if any(np.abs(u - v).max() <= 1e-7 * max(1.0, np.abs(v).max()) for v in found):
            continue
        if np.abs(sb.multipliers(u, W)).max() <= 1.0 + _UNIT_TOL:
            return u
        found.append(u)
    if found:
        return found[0]
    return sb.solve(W)


def system_balance_branch(
    system: System,
    window: Sequence[float],
    *,
    harmonics: int = 7,
    m: int = 1,
    output: str | ArrayLike | None = None,
    start: ArrayLike | None = None,
    direction: int = -1,
    stability: bool = True,
    ds_max: float = 0.05,
    tol: float = 1e-9,
    max_points: int = 2000,
    balance: SystemBalance | None = None,
) -> SystemBalanceBranch:
    """Continue harmonic-balance orbits of ``system`` through a frequency window.

    Starts at the high end (``direction=-1``; low end with ``1``) from ``start`` or Newton from
    the linearised steady state there, and follows the branch through folds with the
    continuation core (:func:`perturb.numeric.continuation.continue_curve`, Hermite predictor,
    early acceptance). Branches not connected to the start are not searched for.

    Parameters
    ----------
    system : System
    window : (float, float)
        ``0 < low < high``.
    harmonics, m
        As :class:`SystemBalance`.
    output : str or array_like, optional
        The measured output (default the first coordinate): a coordinate name, combination
        text or a vector over ``system.state_names``.
    start : array_like, optional
        Coefficients of a solution (or a guess) at the starting end.
    direction : {-1, 1}
    stability : bool
        Floquet multipliers at every point.
    ds_max, tol, max_points
        Continuation step cap (scaled arclength), corrector tolerance, points cap.
    balance : SystemBalance, optional
        A prepared balance (same ``harmonics``/``m``) to reuse its set-up.

    Raises
    ------
    ParameterError, ModelError
        Bad input: a window that is not ``0 < low < high``, an output that is not a coordinate
        or combination of the states, ...
    SystemBalanceError
        No start.
    """
    try:
        lo, hi = (float(v) for v in window)
    except (TypeError, ValueError):
        raise ParameterError(f"window = {window!r}: expected (low, high)") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo < hi):
        raise ParameterError(f"window = {window!r}: expected finite 0 < low < high")
    if direction not in (1, -1):
        raise ParameterError(f"direction = {direction!r}: expected 1 or -1")
    sb = balance if balance is not None else SystemBalance(system, harmonics, m=m)
    out_name, vec = _output(sb, output)
    W0 = hi if direction == -1 else lo
    if start is None:
        u0 = _stable_start(sb, W0)
    else:
        u0 = sb.solve(W0, np.asarray(start, dtype=float).reshape(-1))
    try:
        curve = _frequency_run(sb, u0, W0, (lo, hi), direction, ds_max, tol, max_points)
    except ContinuationError as exc:
        raise SystemBalanceError(f"continuation of {system.name!r} failed: {exc}") from None
    return _make_branch(
        sb,
        np.asarray(curve.lam, dtype=float),
        np.asarray(curve.u),
        tuple(float(f.lam) for f in curve.folds),
        curve,
        out_name,
        vec,
        stability,
    )


def _output(sb: SystemBalance, output: str | ArrayLike | None) -> tuple[str, np.ndarray]:
    """The output's name and its vector over the states (default the first coordinate)."""
    if output is None:
        out_name = sb.coordinates[0]
    elif isinstance(output, str):
        out_name = output
    else:
        out_name = "output"
    return out_name, sb.output_vector(out_name if output is None else output)


def _make_branch(
    sb: SystemBalance,
    Ws: np.ndarray,
    Us: np.ndarray,
    folds: tuple[float, ...],
    curve: ContinuationCurve | None,
    out_name: str,
    vec: np.ndarray,
    stability: bool,
    mm: np.ndarray | None = None,
) -> SystemBalanceBranch:
    """A :class:`SystemBalanceBranch` from points ``(Ws, Us)`` (flat coefficients); the
    multipliers' moduli ``mm`` when known (a mirror image has its source's)."""
    U3 = Us.reshape(Ws.size, sb.neq, sb.size)
    amps = {c: _max_abs_many(sb.basis, U3[:, j, :]) for j, c in enumerate(sb.coordinates)}
    # the output's coefficients at every point at once (sb.signal vectorised over points)
    n2 = sb.n2
    alpha = np.concatenate([vec[:n2], vec[2 * n2 :]])
    beta = np.concatenate([vec[n2 : 2 * n2], np.zeros(sb.n1)])
    out_coef = np.einsum("j,pjk->pk", alpha, U3)
    if np.any(beta):
        w = np.array([sb._omega(W) for W in Ws])
        out_coef = out_coef + w[:, None] * (np.einsum("j,pjk->pk", beta, U3) @ sb._Dtheta.T)
    out_amp = _max_abs_many(sb.basis, out_coef)
    st = None
    if stability and mm is None:
        mm = sb._max_multipliers(np.asarray(Us, dtype=float), np.asarray(Ws, dtype=float))
    if not stability:
        mm = None
    if mm is not None:
        st = mm <= 1.0 + _UNIT_TOL
    return SystemBalanceBranch(
        Ws,
        U3,
        sb.coordinates,
        amps,
        out_name,
        out_amp,
        mm,
        st,
        folds,
        curve,
        out_coef,
        sb.m,
        sb.system.name,
        sb.n2,
    )


# =============================================================================================
# attractor starts (stage 4 of system_balance_response)
# =============================================================================================
_ATTRACTOR_SPACING = 0.02  # relative spacing of the simulated frequencies
_ATTRACTOR_STATES = 12  # initial states per frequency (the zero state and a Halton set)
_ATTRACTOR_PERIODS = 40  # forcing periods simulated before the last one is read
#: RK4 step times the largest field eigenvalue modulus (the stiffest segment, at the lowest
#: frequency): inside RK4's stability interval (2.8 on the imaginary axis) with a phase error
#: ~(h lam)^5 / 120 = 6e-4 rad and an amplitude loss ~(h lam)^6 / 144 = 3e-4 a step there
_ATTRACTOR_STEP = 0.6
_ATTRACTOR_MIN_STEPS = 32  # steps a period at least (the forcing's phase resolution)
_ATTRACTOR_MAX_WORK = 6 * 10**7  # cap on (state components x trajectories x steps)


def _halton(count: int, dim: int) -> np.ndarray:
    """``count`` points of the Halton sequence in ``[0, 1)^dim`` (deterministic)."""
    primes = [2, 3, 5, 7, 11, 13, 17, 19, 23, 29, 31, 37, 41, 43, 47, 53][:dim]
    out = np.zeros((count, dim))
    for d, p in enumerate(primes):
        for i in range(count):
            f, r, k = 1.0, 0.0, i + 1
            while k > 0:  # at most log_p(count) + 1 digits
                f /= p
                r += f * (k % p)
                k //= p
            out[i, d] = r
    return out


def _attractor_run(
    sb: SystemBalance, Omegas: np.ndarray, box: np.ndarray, per: int, periods: int
) -> np.ndarray:
    """The positions after each step of the last two of ``periods`` forcing periods,
    ``(2 per, n2, len(Omegas) * len(box))``, of the classical RK4 run of ``sb``'s field from
    every state of ``box`` (rows) at every frequency of ``Omegas`` (column ``c``: state
    ``c % len(box)`` at ``Omegas[c // len(box)]``), ``per`` steps a period (each column its
    own step, so all see the same forcing phase at every step). A system of
    :func:`_attractor_guesses` (second-order states, every element PWL)."""
    n2, n = sb.n2, sb.system.n
    count, states = len(Omegas), len(box)
    cols = count * states
    steps = per * periods
    Y = np.tile(box.T, (1, count))  # (n, cols): column c is state c % states at Omega c // states
    W = np.repeat(Omegas, states)
    h = (_TWO_PI / W) / per  # each column's step
    # the forcing's coefficients per column and harmonic (few are nonzero)
    Fs = np.stack([sb.forcing(float(w))[0] for w in Omegas])  # (count, neq, size)
    used = np.flatnonzero(np.any(Fs != 0.0, axis=(0, 1)))
    b = sb.basis
    terms = []
    for i in used:
        col = np.repeat(Fs[:, :, i], states, axis=0).T  # (neq, cols)
        if i == 0:
            terms.append((0, 0, col))
            continue
        j = int(np.flatnonzero((b.a_index == i) | (b.b_index == i))[0])
        terms.append((int(b.k[j]), 1 if b.a_index[j] == i else 2, col))
    # The field is linear but for the PWL forces: y' = M(theta) [y; C; 1; P] - sum_e b_e
    # g_e(c_e y) over the elements not written as pieces, M = [A | G(theta) | d | S]: A the
    # field without the elements (velocities; -Binv L), C the forcing amplitudes per column
    # (one row per nonzero row of each forcing term) with G their phase factors times Binv,
    # and a continuous PWL force g(s) = sl_0 min(s, b_1) + sl_j clip(s, b_j, b_j+1) + ... +
    # sl_p max(s, b_p) + const written as its pieces P (rows computed from the state at each
    # stage) with S = -b sl_j and d = -b const (b = Binv w): the linear field, the forcing and
    # the forces in one product a stage. A discontinuous PWL force is evaluated by its table.
    A = np.zeros((n, n))
    A[:n2, n2 : 2 * n2] = np.eye(n2)
    A[n2:, :] = -sb._Binv @ sb._L
    crow, cinfo = [], []  # forcing rows: (term kind, k, equation row)
    for k, kind, col in terms:
        for r in np.flatnonzero(np.any(col != 0.0, axis=1)):
            crow.append(col[r])
            cinfo.append((kind, k, int(r)))
    m = len(crow)
    const = np.zeros(n)  # d
    pieces = []  # (element source, kind, bounds, its column of S)
    tables = []  # (source, breakpoints, slopes, offsets, acceleration rows, their weights)
    for el in sb.elements:
        nz = np.flatnonzero(el.c)
        src = int(nz[0]) if nz.size == 1 and el.c[nz[0]] == 1.0 else el.c
        bw = np.zeros(n)
        bw[n2:] = sb._Binv @ el.w
        bp, sl, of = el.pwl.breakpoints, el.pwl.slopes, el.pwl.offsets
        jump = np.abs(sl[:-1] * bp + of[:-1] - (sl[1:] * bp + of[1:]))
        scale = 1.0 + np.abs(sl[:-1] * bp).max(initial=0.0) + np.abs(of).max(initial=0.0)
        if bp.size and not np.all(jump <= 1e-14 * scale):
            rows = np.flatnonzero(bw)
            tables.append((src, bp, sl, of, [(int(r), float(bw[r])) for r in rows]))
            continue
        if not bp.size:
            A -= np.outer(bw, sl[0] * el.c)
            const -= bw * of[0]
            continue
        const -= bw * (of[0] - float(np.dot(sl[1:], bp)))
        p = bp.size
        for j in range(p + 1):
            if sl[j] == 0.0:
                continue
            if j == 0:
                kind, lo_b, hi_b = "min", float(bp[0]), None
            elif j == p:
                kind, lo_b, hi_b = "max", float(bp[p - 1]), None
            else:
                kind, lo_b, hi_b = "clip", float(bp[j - 1]), float(bp[j])
            pieces.append((src, kind, lo_b, hi_b, -bw * sl[j]))
    one = 1 if np.any(const) else 0
    width = n + m + one + len(pieces)

    def product_at(theta: float) -> np.ndarray:
        M = np.zeros((n, width))
        M[:, :n] = A
        for q, (kind, k, r) in enumerate(cinfo):
            f = 1.0 if kind == 0 else (math.cos if kind == 1 else math.sin)(k * theta)
            M[n2:, n + q] = sb._Binv[:, r] * f
        if one:
            M[:, n + m] = const
        for q, piece in enumerate(pieces):
            M[:, n + m + one + q] = piece[4]
        return M

    # the products at the three phases of each step, once (theta = j dth, + dth / 2, + dth)
    dth = _TWO_PI / per
    m_start = [product_at(j * dth) for j in range(per)]
    m_half = [product_at(j * dth + 0.5 * dth) for j in range(per)]
    m_end = [product_at(j * dth + dth) for j in range(per)]
    srcbuf = np.empty(cols)
    first_piece = n + m + one

    def field(Yc: np.ndarray, M: np.ndarray, out: np.ndarray) -> None:
        """The field at the states ``Yc[:n]`` (rows below: the forcing amplitudes, ones and
        the force pieces, written here) into ``out``."""
        for q, (src, kind, lo_b, hi_b, _) in enumerate(pieces):
            if isinstance(src, int):
                s = Yc[src]
            else:
                s = np.matmul(src, Yc[:n], out=srcbuf)
            row = Yc[first_piece + q]
            if kind == "min":
                np.minimum(s, lo_b, out=row)
            elif kind == "max":
                np.maximum(s, lo_b, out=row)
            else:
                np.clip(s, lo_b, hi_b, out=row)
        np.matmul(M, Yc, out=out)
        for src, bp, sl, of, dist in tables:
            s = Yc[src] if isinstance(src, int) else src @ Yc[:n]
            i = np.searchsorted(bp, s, side="right")
            force = sl[i] * s
            force += of[i]
            for r, wr in dist:
                out[r] -= wr * force

    # classical RK4, Y + h/6 (k1 + 2 k2 + 2 k3 + k4), in preallocated arrays; the states
    # carry the forcing rows below them (constant), the stages stacked for one combination
    Yc = np.empty((width, cols))
    Yc[:n] = Y
    Yc[n : n + m] = np.array(crow).reshape(m, cols)
    Yc[n + m : n + m + one] = 1.0
    Zc = Yc.copy()
    Y, Z = Yc[:n], Zc[:n]
    hh, h6 = 0.5 * h, h / 6.0
    K = np.empty((4, n, cols))
    K1, K2, K3, K4 = K
    Kflat = K.reshape(4, n * cols)
    weights = np.array([[1.0, 2.0, 2.0, 1.0]])
    acc = np.empty((n, cols))
    acc_flat = acc.reshape(1, n * cols)
    nb = n2
    keep = np.empty((2 * per, nb, cols))
    with np.errstate(all="ignore"):
        for i in range(steps):
            j = i % per
            field(Yc, m_start[j], K1)
            np.multiply(hh, K1, out=Z)
            Z += Y
            field(Zc, m_half[j], K2)
            np.multiply(hh, K2, out=Z)
            Z += Y
            field(Zc, m_half[j], K3)
            np.multiply(h, K3, out=Z)
            Z += Y
            field(Zc, m_end[j], K4)
            np.matmul(weights, Kflat, out=acc_flat)
            acc *= h6
            Y += acc
            if i >= steps - 2 * per:
                keep[i - (steps - 2 * per)] = Y[:nb]
    return keep


def _attractor_guesses(
    sb: SystemBalance, window: tuple[float, float], states: int = _ATTRACTOR_STATES
) -> list[tuple[float, np.ndarray]]:
    """``(Omega, u)`` Newton starts from the orbits a simulation settles on (module docstring
    of :func:`system_balance_response`, stage 4).

    One vectorised fixed-step RK4 run of the system's field for every frequency (2 % apart
    across ``window``) and initial state at once (the rest state and ``states - 1`` Halton
    points in a box of three times the largest breakpoint, at least 1, per position and
    velocity), each trajectory with its own step, ``1/N`` of its forcing period, so that every
    column sees the same forcing phase at every step; ``_ATTRACTOR_PERIODS`` periods, the last
    one read when it repeats the one before within 5 % of its range and projected on the basis
    (``N`` samples, more than twice the highest harmonic). Only a start: the step is coarse,
    ``_ATTRACTOR_STEP`` over the field's largest eigenvalue modulus (every PWL segment) at the
    lowest frequency, at least ``_ATTRACTOR_MIN_STEPS`` a period (:func:`_attractor_run`).
    Empty for a system with a first-order state, a smooth element, ``m > 1``, or when the
    work would exceed ``_ATTRACTOR_MAX_WORK``; at most one start per orbit (1 % apart) and
    frequency."""
    lo, hi = window
    if sb.m != 1 or sb.n1 or not sb._all_pwl or not sb.elements:
        return []
    n2, n = sb.n2, sb.system.n
    count = max(1, math.floor(math.log(hi / lo) / math.log1p(_ATTRACTOR_SPACING))) + 1
    Omegas = np.geomspace(lo, hi, count)
    # the largest eigenvalue modulus of the field over every combination of segments
    counts = [el.pwl.slopes.size for el in sb.elements]
    if int(np.prod(counts)) > 256:
        return []
    lam = 0.0
    for segs in np.ndindex(*counts):
        lam = max(lam, float(np.abs(sb._pwl_field(tuple(int(s) for s in segs))[1]).max()))
    # steps a period: the stiffest time scale at the lowest frequency, the forcing's phase
    # resolution, and more samples of the last period than twice the highest harmonic
    per = max(
        _ATTRACTOR_MIN_STEPS,
        2 * int(sb.basis.k.max(initial=0)) + 2,
        math.ceil(_TWO_PI / float(Omegas[0]) * lam / _ATTRACTOR_STEP),
    )
    steps = per * _ATTRACTOR_PERIODS
    cols = count * states
    if n * cols * steps > _ATTRACTOR_MAX_WORK:
        return []
    bps = [np.abs(el.pwl.breakpoints) for el in sb.elements if el.pwl.breakpoints.size]
    ext = max([1.0] + [3.0 * float(b.max()) for b in bps])
    box = np.vstack([np.zeros((1, n)), (2.0 * _halton(states - 1, n) - 1.0) * ext])
    keep = _attractor_run(sb, Omegas, box, per, _ATTRACTOR_PERIODS)
    b = sb.basis
    nb = n2  # the coordinates of the balance: the positions (no first-order state here)
    dth = _TWO_PI / per
    last, before = keep[per:], keep[:per]  # the samples end at theta = 0 (mod 2 pi)
    theta = dth * (np.arange(per) + 1)
    ks = b.k.astype(float)
    cosm, sinm = np.cos(np.outer(theta, ks)), np.sin(np.outer(theta, ks))
    out: list[tuple[float, np.ndarray]] = []
    # settled: finite, and the last period repeats the one before within 5 % of its range
    # (not settled, or not of the forcing's period, otherwise); every column at once
    finite = np.isfinite(last).all(axis=(0, 1))
    with np.errstate(invalid="ignore"):
        rng = np.maximum(1e-12, np.ptp(last, axis=0).max(axis=0))
        drift = np.abs(last - before).max(axis=(0, 1))
        settled = finite & ~(drift > 0.05 * rng)
    for f in range(count):
        mine: list[np.ndarray] = []
        for c in range(f * states, (f + 1) * states):
            if not settled[c]:
                continue
            x = last[:, :, c]
            U = np.zeros((nb, b.size))
            U[:, 0] = x.mean(axis=0)
            U[:, b.a_index] = (2.0 / per) * (x.T @ cosm)
            U[:, b.b_index] = (2.0 / per) * (x.T @ sinm)
            scale = max(1e-12, float(np.abs(U).max()))
            if any(float(np.abs(U - V).max()) <= 1e-2 * scale for V in mine):
                continue
            mine.append(U)
            out.append((float(Omegas[f]), U.reshape(-1)))
    return out


# =============================================================================================
# every branch in a window
# =============================================================================================
#: Interior seed frequencies of :func:`system_balance_response` (besides the two edges).
_INTERIOR_SEEDS = 3
#: Scale factors of the linear guess in the bounded multi-start at one frequency.
_MULTI_START_SCALES = (0.5, 2.0, 4.0)
#: Point-on-curve tolerance (scaled distance: coefficients over the point's largest, Omega
#: over the window width) below which a solution is taken to lie on a traced branch.
_ON_CURVE = 0.02
#: Scaled distance from a traced branch at which a seed's Newton iterate (from its second
#: step on) is abandoned as bound for that branch.
_NEAR_CURVE = 0.05
#: Fold frequencies of traced branches seeded again (at most).
_FOLD_SEEDS = 6
#: Newton steps per seed start, and Armijo halvings per step.
_SEED_NEWTON = 12
_SEED_HALVINGS = 6
#: Window edges: rounds of outward tracing per edge (each from the edge ends of the branches
#: the round before added), and how far past the edge, as a fraction of the window's width.
_EDGE_ROUNDS = 3
_EDGE_MARGIN = 0.1


def _mirror_operator(sb: SystemBalance) -> np.ndarray:
    """``Q`` (``size x size``) with ``mirror(U) = -U Q^T`` row by row: the image
    ``z(theta) -> -z(theta + pi/m)`` (half a forcing period later, sign flipped)."""
    delta = math.pi / sb.m
    Q = np.zeros((sb.size, sb.size))
    if sb.basis.bias:
        Q[0, 0] = 1.0
    for k, ia, ib in zip(sb.basis.k, sb.basis.a_index, sb.basis.b_index, strict=True):
        c, s = math.cos(k * delta), math.sin(k * delta)
        # z(theta + d): a_k' = a_k cos kd + b_k sin kd, b_k' = -a_k sin kd + b_k cos kd
        Q[ia, ia], Q[ia, ib] = c, s
        Q[ib, ia], Q[ib, ib] = -s, c
    return Q


def _odd_symmetry(sb: SystemBalance, window: tuple[float, float]) -> np.ndarray | None:
    """The mirror operator when the balance is equivariant under it (``R(M u) = M R(u)``,
    checked on the residual itself at two random points: an odd system whose forcing changes
    sign over half a period, such as nsd2), else None."""
    Q = _mirror_operator(sb)
    rng = np.random.default_rng(12345)

    def mirror(u):
        return -(sb.unpack(u) @ Q.T).reshape(-1)

    for W in (window[0] + 0.37 * (window[1] - window[0]), window[1]):
        decay = np.ones(sb.size)  # a smooth-ish random orbit: harmonics decaying like 1/k
        decay[sb.basis.a_index] = decay[sb.basis.b_index] = 1.0 / sb.basis.k
        u = rng.standard_normal(sb.n_unknowns) * np.tile(decay, sb.neq)
        r = sb.residual(u, W)
        rm = sb.residual(mirror(u), W)
        if np.abs(rm - mirror(r)).max() > 1e-9 * (1.0 + np.abs(r).max()):
            return None
    return Q


class _Polyline:
    """A branch's points ``(U_p, Omega_p)`` prepared for the point-on-curve test: the
    segment vectors and the dot products that do not depend on the query, so that the
    distance of a point from every segment costs two matrix-vector products."""

    def __init__(self, Ws: np.ndarray, Us: np.ndarray) -> None:
        self.A = np.ascontiguousarray(Us[:-1]) if len(Ws) > 1 else Us
        self.Aw = Ws[:-1] if len(Ws) > 1 else Ws
        self.single = len(Ws) == 1
        if not self.single:
            self.D = np.ascontiguousarray(np.diff(Us, axis=0))
            self.Dw = np.diff(Ws)
            self.DD = np.einsum("ij,ij->i", self.D, self.D)
            self.AD = np.einsum("ij,ij->i", self.A, self.D)
        self.AA = np.einsum("ij,ij->i", self.A, self.A)
        self.w_range = (float(Ws.min()), float(Ws.max()))

    def distance(self, u: np.ndarray, W: float, width: float) -> float:
        """Scaled distance of ``(u, W)`` from the polyline (coefficients over ``max|u|``,
        Omega over the window width): the same number as measuring in scaled coordinates,
        expanded in dot products (the rounding, ~1e-16 of ``|u|^2``, is far below the test
        tolerances of 1e-2)."""
        scale = max(1e-12, float(np.abs(u).max()))
        c_u, c_w = 1.0 / (scale * scale), 1.0 / (width * width)
        Au = self.A @ u
        # |q - a|^2 in the scaled metric, per segment start
        qa2 = (float(u @ u) - 2.0 * Au + self.AA) * c_u + (W - self.Aw) ** 2 * c_w
        if self.single:
            return float(np.sqrt(max(0.0, float(qa2[0]))))
        Du = self.D @ u
        qad = (Du - self.AD) * c_u + (W - self.Aw) * self.Dw * c_w
        dd = self.DD * c_u + self.Dw * self.Dw * c_w
        t = np.clip(qad / np.where(dd > 0.0, dd, 1.0), 0.0, 1.0)
        e2 = qa2 - 2.0 * t * qad + t * t * dd
        return float(np.sqrt(max(0.0, float(np.min(e2)))))


_POLYLINES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _polyline(branch) -> _Polyline:
    """The prepared polyline of a branch (built once per branch object)."""
    pl = _POLYLINES.get(branch)
    if pl is None:
        pl = _POLYLINES[branch] = _Polyline(
            np.asarray(branch.Omega, dtype=float), branch.U.reshape(len(branch), -1)
        )
    return pl


def _on_any(branches, u: np.ndarray, W: float, width: float, rtol: float) -> bool:
    for b in branches:
        pl = _polyline(b)
        lo, hi = pl.w_range
        # the frequency alone is farther than rtol from every point of the branch
        if W < lo - rtol * width or W > hi + rtol * width:
            continue
        if pl.distance(u, W, width) <= rtol:
            return True
    return False


def _duplicate(br: SystemBalanceBranch, found, width: float, rtol: float) -> bool:
    """Whether nine points spread along ``br`` all lie on branches of ``found``."""
    flat = br.U.reshape(len(br), -1)
    idx = np.unique(np.linspace(0, len(br) - 1, 9).round().astype(int))
    return all(_on_any(found, flat[i], float(br.Omega[i]), width, rtol) for i in idx)


def _solutions_at(sb: SystemBalance, W: float, skip, max_starts: int, near=None):
    """Distinct HB solutions at ``W`` from the frozen-segment orbits, the linearisation
    about zero and a bounded multi-start (the linear guess scaled), at most ``max_starts``
    capped Newton runs; guesses for which ``skip(u)`` holds (on a traced branch) are not
    solved, and a run whose iterate satisfies ``near(u)`` after two steps is abandoned.
    A generator: each new solution is yielded as found."""
    seg = sb.segment_guesses(W, limit=64)
    lin = sb.linear_guess(W)
    starts = [u for u, inside in seg if inside] + [lin]
    # the linear guess moved onto the mean position of each frozen-segment orbit: the
    # asymmetric orbits (biased towards one side of a clearance or negative-stiffness
    # region) that Newton from a zero-mean guess never reaches
    L = sb.unpack(lin)
    biases: list[np.ndarray] = []
    for u, _ in seg:
        b = sb.unpack(u)[:, 0]
        if np.any(b) and not any(np.allclose(b, c) for c in biases):
            biases.append(b)
    for b in biases:
        V = L.copy()
        V[:, 0] = b
        starts.append(V.reshape(-1))
    # describing-function guesses: orbits across the breakpoints that no frozen segment
    # reaches (the impacting orbits of the impact pair), asked for where some frozen segment
    # leaves the system singular (a free segment of a clearance: no stiffness); where every
    # frozen system is regular (nsd2) its orbits already cover the segments
    counts = [el.pwl.slopes.size for el in sb.elements if el.kind == "exact"]
    if len(seg) < min(2 * int(np.prod(counts)), 64) if counts else False:
        starts += sb.describing_guesses(W)
    starts += [u for u, inside in seg if not inside]
    starts += [c * lin for c in _MULTI_START_SCALES]
    out: list[np.ndarray] = []
    tried: list[np.ndarray] = []
    runs = 0
    for g in starts:
        if runs >= max_starts:
            break
        if skip(g):
            continue
        runs += 1
        # a start equal to one already run (the linear guess is the frozen orbit of a
        # segment through the origin; a segment's orbit with and without its offset
        # coincide when the offset is 0, and two segments of equal slope give the same
        # orbit without offsets: three starts at every nsd2 frequency) repeats that run's
        # iterates: it ends where that run ended (a solution already in ``out``, or none),
        # or is abandoned sooner (the known branches only grow), so it cannot give a new
        # solution; it still counts as a run, so the starts that follow are the same
        if any(np.array_equal(g, t) for t in tried):
            continue
        tried.append(g)
        # from these guesses Newton converges in a few steps or not at all (measured on nsd2:
        # converged runs took <= 10 steps), so failing runs are cut short (and so are their
        # Armijo halvings); from the second step on an iterate already close to a traced
        # branch is abandoned (it would land on it)
        u = sb._newton(
            W,
            np.asarray(g, dtype=float).copy(),
            1e-10,
            _SEED_NEWTON,
            abandon=near,
            abandon_after=1,
            halvings=_SEED_HALVINGS,
            extend=True,
        )[0]
        if u is None:
            continue
        if any(np.abs(u - v).max() <= 1e-7 * max(1.0, np.abs(v).max()) for v in out):
            continue
        out.append(u)
        yield u  # the caller traces it before the next start: later starts bound for it stop


def _frequency_run(
    sb: SystemBalance,
    u: np.ndarray,
    W: float,
    window: tuple[float, float],
    direction: int,
    ds_max: float,
    tol: float,
    max_points: int,
    branch_points: bool = False,
) -> ContinuationCurve:
    """One run of the continuation core in the forcing frequency from the solution ``(u, W)``
    (the harmonics scaled by the solution's size, the frequency by the window's width)."""
    lo, hi = window
    return continue_curve(
        sb.residual,
        sb.jacobian,
        u,
        W,
        (lo, hi),
        direction=direction,
        u_scale=1e-2 * max(1e-10, float(np.abs(u).max())),
        lam_scale=hi - lo,
        adaptive_scale=True,
        ds_max=ds_max,
        tol=tol,
        max_points=max_points,
        predictor="hermite",
        early_accept=True,
        detect_branch_points=branch_points,
    )


def _trace_through(
    sb: SystemBalance,
    u: np.ndarray,
    W: float,
    window: tuple[float, float],
    ds_max: float,
    tol: float,
    max_points: int,
    branch_points: list | None = None,
) -> tuple[np.ndarray, np.ndarray, tuple[float, ...], ContinuationCurve] | None:
    """The branch through the solution ``(u, W)``: traced down, then up unless the first run
    closed on itself (a detached loop). Points in order from the low-frequency end of the
    downward run; None when the continuation fails at once. With a list ``branch_points``
    the runs watch for branch points and append them to it."""
    lo, hi = window
    runs = []
    for direction in (-1, 1):
        if (direction == -1 and W <= lo) or (direction == 1 and W >= hi):
            continue
        try:
            curve = _frequency_run(
                sb, u, W, (lo, hi), direction, ds_max, tol, max_points, branch_points is not None
            )
        except (ContinuationError, ParameterError):
            continue
        if branch_points is not None:
            branch_points.extend(curve.branch_points)
        runs.append((direction, curve))
        if curve.stop_reason == "closed":
            break
    if not runs:
        return None
    Ws_parts, Us_parts, folds = [], [], []
    for direction, curve in runs:
        lam = np.asarray(curve.lam, dtype=float)
        uu = np.asarray(curve.u)
        if direction == -1:
            Ws_parts.insert(0, lam[::-1])
            Us_parts.insert(0, uu[::-1])
        else:
            skip = 1 if Ws_parts else 0  # the shared start point
            Ws_parts.append(lam[skip:])
            Us_parts.append(uu[skip:])
        for f in curve.folds:
            # a closed loop passes its first fold again; a start on a fold is met by both runs
            if all(abs(float(f.lam) - g) > 1e-9 * max(1.0, abs(g)) for g in folds):
                folds.append(float(f.lam))
    return np.concatenate(Ws_parts), np.concatenate(Us_parts), tuple(folds), runs[0][1]


@dataclass(frozen=True, eq=False)
class SystemBalanceResponse:
    """Every harmonic-balance branch of a system found in a window
    (:func:`system_balance_response`).

    Attributes
    ----------
    branches : tuple of SystemBalanceBranch
    origins : tuple of str
        Per branch: ``'edge'`` (seeded at a window edge), ``'interior'`` (seeded inside),
        ``'fold'`` (seeded at another branch's fold), ``'branch point'`` (switched onto),
        ``'edge trace'`` (reached by tracing a branch past a window edge and back),
        ``'attractor'`` (from a simulation's settled orbit),
        ``'mirror'`` (odd-symmetry image of another branch, not traced), ``'listed'`` (a
        solution at a listed frequency).
    window : (float, float)
    harmonics, m : int
    output : str
    odd : bool
        Whether the balance is odd-symmetric (mirror images added).
    model : str
    """

    branches: tuple[SystemBalanceBranch, ...]
    origins: tuple[str, ...]
    window: tuple[float, float]
    harmonics: int
    m: int
    output: str
    odd: bool
    model: str = ""

    def __len__(self) -> int:
        return len(self.branches)

    def __iter__(self):
        return iter(self.branches)

    def columns(self) -> tuple[dict[str, np.ndarray], ...]:
        """Per branch, ``amplitude_<name>`` and ``mean_<name>`` per coordinate."""
        return tuple(b.columns() for b in self.branches)

    def closed(self) -> tuple[bool, ...]:
        """Per branch, whether it is a detached loop (its continuation closed on itself)."""
        return tuple(b.curve is not None and b.curve.stop_reason == "closed" for b in self.branches)

    def to_response(self) -> Response:
        """The standard :class:`~perturb.response.Response` (method ``"hb-system"``), one
        :class:`~perturb.response.Branch` per branch, folds of every branch."""
        folds: list[tuple[float, float]] = []
        for b in self.branches:
            for lam in b.folds:
                i = int(np.argmin(np.abs(b.Omega - lam)))
                f = (float(lam), float(b.output_amplitude[i]))
                if f not in folds:  # a mirror image's folds are its source's (same max|.|)
                    folds.append(f)
        return Response(
            tuple(b.to_branch() for b in self.branches),
            "hb-system",
            self.model,
            folds=tuple(folds),
            notes=(
                f"harmonic balance of {len(self.branches[0].coordinates) if self.branches else 0}"
                f" coordinates, H = {self.harmonics}, m = {self.m}; output {self.output}; "
                f"{len(self.branches)} branches ({', '.join(self.origins)})"
                + (
                    f"; odd system: {self.origins.count('mirror')} mirror images added"
                    if self.odd
                    else ""
                ),
            ),
        )


def system_balance_response(
    system: System,
    window: Sequence[float],
    *,
    harmonics: int = 15,
    m: int = 1,
    output: str | ArrayLike | None = None,
    interior: int = _INTERIOR_SEEDS,
    stability: bool = True,
    mirror: bool = True,
    ds_max: float = 0.05,
    tol: float = 1e-9,
    max_points: int = 2000,
    max_branches: int = 16,
    max_starts: int = 10,
    branch_points: bool = True,
    balance: SystemBalance | None = None,
    attractors: bool = True,
) -> SystemBalanceResponse:
    """Every harmonic-balance branch of ``system`` in a frequency window.

    1. Seeds at both window edges and at ``interior`` frequencies evenly inside: at each,
       every HB solution that Newton reaches from the frozen-segment linear orbits of every
       region, the linearisation about zero, the describing-function orbits
       (:meth:`SystemBalance.describing_guesses`: orbits across the breakpoints, such as the
       impacting orbits of the impact pair) and a bounded multi-start (the linear guess moved
       onto the mean of each frozen-segment orbit, then scaled by 0.5, 2, 4), at most
       ``max_starts`` Newton runs per frequency (a run whose iterate comes within 0.05 of a
       traced branch from its second step on is abandoned). Each solution that lies on no
       branch traced so far (point-on-curve test: scaled distance to the branch's polyline,
       coefficients over their largest and Omega over the window width, at most 0.02) is
       continued both ways with the continuation core (one run when it closes on itself: a
       detached loop); a branch whose nine sample points all lie on known branches is
       dropped (a retrace). The fold frequencies of every branch kept are seeded again (at
       most 6, half the starts): detached loops cluster where other branches turn.
       Then every branch end on a window edge is traced out of the window, at most 10 % of
       its width past the edge (:func:`perturb.numeric.edge_solutions.edge_solutions`); a
       run that turns outside and comes back to the edge ends on a branch that leaves and
       re-enters the window there, which no seed may reach (the unstable multi-impact pair
       of the impact pair on 0.800..0.865 of (0.8, 1.3)); it is traced
       (``origin='edge trace'``), and so are the edge ends of the branches this adds (at
       most 3 rounds per edge).
    2. Branch switching (``branch_points``): every branch is traced with the branch-point
       test of the continuation core; at each branch point a point on the other curve on
       each side (:func:`perturb.numeric.continuation.branch_off`) is traced unless it lies
       on another known branch or the mirror image of one. This reaches the asymmetric
       branches born at symmetry-breaking pitchforks, also those that leave the window at an
       edge (on nsd2, Omega in 0.3..0.3077) and loops joined to them.
    3. For an odd system (checked on the residual: ``R(M u) = M R(u)`` with ``M`` the image
       ``y -> -y``, ``t -> t + T/2``) the mirror image of every branch is added, without
       continuation, unless it is a known branch.

    4. Attractors (``attractors``): one vectorised fixed-step RK4 simulation of the system's
       field at frequencies 2 % apart across the window, from the rest state and 11 Halton
       states in a box of three times the largest breakpoint, 40 forcing periods; the last
       period of each trajectory that repeats the one before (within 5 %) is projected on the
       basis and starts Newton (abandoned near a known branch); a solution on no known branch
       is traced as in 1 (``origin='attractor'``). Systems of PWL elements without first-order
       states, ``m = 1``, at most 6e7 state-steps (the impact pair over (0.6, 1.4): 1.6e7,
       0.25 s); otherwise skipped. It reaches the multi-impact orbits of a lightly damped
       clearance that no frozen segment or describing function does (module docstring).

    A detached loop that no seed frequency meets and no branch point reaches is missed (raise
    ``interior``). Measured on nsd2 (H = 15, tests/test_system_balance_branches.py and
    bench_system_balance.py): every branch of the exact response over (0.62, 0.75) (3),
    (0.5, 2.0) (4: two closed loops, one born at the high edge) and (0.3, 1.5) (4: one born
    at the low edge) has an HB branch within the polyline's chord error, stability agreeing;
    over (0.2, 2.0) 6 of 6.

    Parameters
    ----------
    system : System
    window : (float, float)
        ``0 < low < high``.
    harmonics, m
        As :class:`SystemBalance`.
    output : str or array_like, optional
        As :func:`system_balance_branch`.
    interior : int
        Seed frequencies inside the window (0..50).
    stability : bool
        Floquet multipliers at every point.
    mirror : bool
        Add the odd-symmetry images.
    branch_points : bool
        Switch branches at the branch points met.
    ds_max, tol, max_points
        Continuation settings (per run).
    max_branches : int
        Cap on the branches kept.
    max_starts : int
        Newton runs per seed frequency.
    balance : SystemBalance, optional
        A prepared balance (same ``harmonics``/``m``).
    attractors : bool
        Stage 4: starts from the orbits a simulation settles on.

    Returns
    -------
    SystemBalanceResponse
        Branches in the order found.

    Raises
    ------
    ParameterError, ModelError
        Bad input (window, output, counts).
    SystemBalanceError
        No HB solution at any seed frequency.
    """
    try:
        lo, hi = (float(v) for v in window)
    except (TypeError, ValueError):
        raise ParameterError(f"window = {window!r}: expected (low, high)") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo < hi):
        raise ParameterError(f"window = {window!r}: expected finite 0 < low < high")
    for name, value, low, top in (
        ("interior", interior, 0, 50),
        ("max_branches", max_branches, 1, 1000),
        ("max_starts", max_starts, 0, 100),
        ("max_points", max_points, 2, 1_000_000),
    ):
        if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= top:
            raise ParameterError(f"{name} = {value!r}: expected an integer in {low}..{top}")
    for name, value in (
        ("attractors", attractors),
        ("stability", stability),
        ("mirror", mirror),
        ("branch_points", branch_points),
    ):
        checks.flag(value, name)
    # a bad step or tolerance made every seed fail, reported as 'no solution' of the model
    for name, value, top in (("ds_max", ds_max, math.inf), ("tol", tol, 1.0)):
        v = checks.finite(value, name)
        if not 0.0 < v < top:
            bound = "0 < ds_max" if top == math.inf else "0 < tol < 1"
            raise ParameterError(f"{name} = {value!r}: expected {bound}")
    if balance is not None and (
        not isinstance(system, System)
        or (balance.system.name, balance.system.state_names) != (system.name, system.state_names)
    ):
        raise ParameterError(
            f"balance = {balance!r:.80}: built for another system than {system!r:.80}"
        )
    sb = balance if balance is not None else SystemBalance(system, harmonics, m=m)
    out_name, vec = _output(sb, output)
    width = hi - lo
    found: list[SystemBalanceBranch] = []
    origins: list[str] = []
    freqs = [hi, lo] + [float(v) for v in np.linspace(lo, hi, interior + 2)[1:-1]]
    kinds = ["edge", "edge"] + ["interior"] * interior
    fold_seeds = 0
    pending: list[tuple[BranchPoint, int]] = []  # (branch point met, its branch's index)
    switched: list[BranchPoint] = []
    Q = _odd_symmetry(sb, (lo, hi)) if mirror else None
    images: dict[int, SystemBalanceBranch] = {}

    def image(i: int) -> SystemBalanceBranch:
        """The mirror image of ``found[i]`` (points only: for the point-on-curve tests)."""
        if i not in images:
            b = found[i]
            images[i] = replace(b, U=-(b.U @ Q.T))
        return images[i]

    def known(u: np.ndarray, W: float, parent: int) -> bool:
        """Whether a point stepped off the branch ``parent`` lies on another known branch or
        on the mirror image of one (the other side of a symmetry-breaking pitchfork is the
        image of the first). The parent itself is left out: the point is one step from it."""
        others = [b for i, b in enumerate(found) if i != parent]
        if Q is not None:
            others += [image(i) for i in range(len(found)) if i != parent]
        return _on_any(others, u, W, width, _ON_CURVE)

    def symmetric(u: np.ndarray) -> bool:
        """Whether ``u`` is its own mirror image (a symmetric orbit of an odd system)."""
        scale = max(1e-12, float(np.abs(u).max()))
        return float(np.abs(u + (sb.unpack(u) @ Q.T).reshape(-1)).max()) <= 1e-6 * scale

    def add(u: np.ndarray, W: float, kind: str) -> bool:
        """Trace the branch through (u, W); keep it unless it retraces a known one."""
        nonlocal fold_seeds
        bps: list[BranchPoint] = []
        # in an odd system the branch points of a branch without the symmetry are not
        # generic (a one-parameter family meets them only where it meets a symmetric
        # branch, at that branch's symmetry-breaking pitchforks, which its own trace
        # locates): an asymmetric branch is traced without the test (on nsd2 (0.5, 2.0) 5
        # of 10 branch points were such re-locations, ~55 evaluations each)
        watch = branch_points and (Q is None or symmetric(u))
        traced = _trace_through(sb, u, W, (lo, hi), ds_max, tol, max_points, bps if watch else None)
        if traced is None:
            return False
        Ws, Us, folds, curve = traced
        br = _make_branch(sb, Ws, Us, folds, curve, out_name, vec, stability)
        if found and _duplicate(br, found, width, _ON_CURVE):
            return False
        found.append(br)
        origins.append(kind)
        pending.extend((bp, len(found) - 1) for bp in bps)
        # detached branches cluster where others turn: seed again at this branch's folds
        # (on nsd2 the loop on 0.6447..0.7199 holds the fold 0.7031 of the loop on
        # 0.7031..1.2147, and no grid frequency of a wide window falls inside it)
        for f in br.folds:
            if fold_seeds < _FOLD_SEEDS and all(abs(f - g) > 1e-3 * width for g in freqs):
                freqs.append(float(f))
                kinds.append("fold")
                fold_seeds += 1
        return True

    def switch() -> None:
        """Branch switching at every branch point met (each once: it is met from both
        branches through it): a point on the other curve on each side, traced."""
        while pending and len(found) < max_branches:
            bp, parent = pending.pop(0)
            scale = max(1e-12, float(np.abs(bp.u).max()))
            if any(
                abs(d.lam - bp.lam) <= 1e-6 * width
                and float(np.abs(d.u - bp.u).max()) <= 1e-4 * scale
                for d in switched
            ):
                continue
            switched.append(bp)
            try:
                sides = branch_off(sb.residual, sb.jacobian, bp, step=ds_max, tol=tol)
            except (ContinuationError, ParameterError):
                continue
            for u, W in sides:
                u = np.asarray(u, dtype=float)
                if len(found) >= max_branches or not lo <= W <= hi or known(u, W, parent):
                    continue
                add(u, float(W), "branch point")

    idx = 0
    while idx < len(freqs):  # grows by the folds found (at most _FOLD_SEEDS of them)
        W, kind = freqs[idx], kinds[idx]
        idx += 1
        if len(found) >= max_branches:
            break

        # in an odd system a start bound for the mirror image of a traced branch is as
        # useless as one bound for the branch (the images are added at the end)
        def targets():
            return found + ([image(i) for i in range(len(found))] if Q is not None else [])

        def skip(g, W=W):
            return _on_any(targets(), g, W, width, _ON_CURVE)

        def near(g, W=W):
            return _on_any(targets(), g, W, width, _NEAR_CURVE)

        # a fold seed looks for a neighbour of a known branch: half the starts
        starts = max_starts if kind != "fold" else (max_starts + 1) // 2
        for u in _solutions_at(sb, W, skip, starts, near):
            if len(found) >= max_branches:
                break
            if _on_any(targets(), u, W, width, _ON_CURVE):
                continue
            add(u, W, kind)
        switch()
    # stage 1b: branches that leave and re-enter the window through an edge, which no seed
    # there may reach: the branch ends on the edge traced a margin past it; a run that comes
    # back to the edge ends on such a branch (perturb.numeric.edge_solutions)
    for W, side in ((lo, -1), (hi, 1)):
        start = 0
        for _ in range(_EDGE_ROUNDS):
            ends = [
                br.U.reshape(len(br), -1)[j]
                for br in found[start:]
                for j in (0, -1)
                if abs(float(br.Omega[j]) - W) <= 1e-9 * width
            ]
            start = len(found)
            if not ends or len(found) >= max_branches:
                break
            for u in edge_solutions(
                sb,
                W,
                known=ends,
                outward=side,
                margin=_EDGE_MARGIN * width,
                homotopy_points=0,
                ds_max=ds_max,
                tol=tol,
            ):
                if len(found) >= max_branches:
                    break
                traced = found + ([image(i) for i in range(len(found))] if Q is not None else [])
                if not _on_any(traced, u, W, width, _ON_CURVE):
                    add(u, W, "edge trace")
                    switch()
            if len(found) == start:
                break
    if attractors and len(found) < max_branches:
        # stage 4: the orbits a simulation settles on, at frequencies 2 % apart (the
        # multi-impact orbits of a lightly damped clearance, which no frozen segment or
        # describing function reaches)
        for W, g in _attractor_guesses(sb, (lo, hi)):
            if len(found) >= max_branches:
                break
            targets = found + ([image(i) for i in range(len(found))] if Q is not None else [])
            if _on_any(targets, g, W, width, _ON_CURVE):
                continue
            u = sb._newton(
                W,
                g.copy(),
                1e-10,
                _SEED_NEWTON,
                abandon=lambda v, W=W, t=targets: _on_any(t, v, W, width, _NEAR_CURVE),
                abandon_after=1,
                halvings=_SEED_HALVINGS,
                extend=True,
            )[0]
            if u is None or _on_any(targets, u, W, width, _ON_CURVE):
                continue
            add(u, W, "attractor")
            switch()
    if not found:
        raise SystemBalanceError(
            f"harmonic balance of {system.name!r}: no solution at any of the seed frequencies "
            f"{', '.join(f'{w:g}' for w in freqs)}"
        )
    if Q is not None:
        for br in list(found):
            if len(found) >= max_branches:
                break
            Um = -(br.U @ Q.T)
            flat = Um.reshape(len(br), -1)
            idx = np.unique(np.linspace(0, len(br) - 1, 9).round().astype(int))
            if all(_on_any(found, flat[i], float(br.Omega[i]), width, _ON_CURVE) for i in idx):
                continue  # the image is a known branch (or the branch itself)
            image = _make_branch(
                sb,
                br.Omega.copy(),
                Um.reshape(len(br), -1),
                br.folds,
                br.curve,
                out_name,
                vec,
                stability,
                mm=None if br.max_multiplier is None else br.max_multiplier.copy(),
            )
            found.append(image)
            origins.append("mirror")
    return SystemBalanceResponse(
        tuple(found),
        tuple(origins),
        (lo, hi),
        (sb.size - 1) // 2,
        sb.m,
        out_name,
        Q is not None,
        system.name,
    )


def system_balance_solutions_at(
    system: System,
    frequencies: Sequence[float],
    *,
    harmonics: int = 15,
    m: int = 1,
    output: str | ArrayLike | None = None,
    stability: bool = True,
    max_starts: int = 10,
    balance: SystemBalance | None = None,
) -> SystemBalanceResponse:
    """Every HB solution found at each listed frequency (the starts of
    :func:`system_balance_response`: frozen-segment orbits, the linearisation, the bounded
    multi-start), each a one-point branch, frequencies in the order given.

    Raises
    ------
    ParameterError, ModelError
        Bad input.
    SystemBalanceError
        No solution at some frequency.
    """
    sb = balance if balance is not None else SystemBalance(system, harmonics, m=m)
    out_name, vec = _output(sb, output)
    found: list[SystemBalanceBranch] = []
    try:
        given = list(frequencies)
    except TypeError:
        raise ParameterError(f"frequencies = {frequencies!r}: expected a list of numbers") from None
    if not given:
        raise ParameterError("frequencies = []: expected at least one frequency")
    for w in given:
        W = checks.finite(w, "frequency")
        if W <= 0:
            raise ParameterError(f"frequency {w!r}: expected a finite positive number")
        sols = list(_solutions_at(sb, W, lambda g: False, max_starts))
        if not sols:
            raise SystemBalanceError(
                f"harmonic balance of {system.name!r}: no solution at {sb.parameter} = {W:g} "
                f"from {max_starts} starts"
            )
        for u in sols:
            found.append(
                _make_branch(sb, np.array([W]), u[None, :], (), None, out_name, vec, stability)
            )
    lo = min(float(w) for w in given)
    hi = max(float(w) for w in given)
    return SystemBalanceResponse(
        tuple(found),
        ("listed",) * len(found),
        (lo, hi),
        (sb.size - 1) // 2,
        sb.m,
        out_name,
        False,
        system.name,
    )
