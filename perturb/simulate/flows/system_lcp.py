r"""Moreau–Jean time-stepping for systems of several coordinates with unilateral contacts.

A :class:`~perturb.model.system.System` may declare rigid **stops** (``lower <= c . q <= upper``
on a combination of positions, with a restitution coefficient ``e``) and **friction contacts**
(``F sign(c . q' - v0)`` on a velocity combination). Several of them may be closed at once (a
mass between two walls, a chain of balls in contact): the event-driven approach then has to
decide which impacts happen first and how simultaneous impacts combine. The Moreau–Jean scheme
does neither: it works on velocities and impulses over a time step and solves **one linear
complementarity problem (LCP) per step** for all the contacts together.

The scheme
----------
The state is ``y = (q, v, p)``: positions ``q``, their velocities ``v = q'`` and the first-order
states ``p``; ``u = (v, p)`` are the variables whose rates the matrix ``B = [M D]`` multiplies,

.. math::

    B\,u' = r(t, y) + \sum_\alpha R_\alpha \lambda_\alpha,\qquad
    r(t, y) = F(t) - L y - \sum_e w_e f_e(c_e\cdot y),

with the contact forces :math:`\lambda_\alpha` entering along their distribution vectors. On the
grid :math:`t_k = t_0 + kh` (θ-method, :math:`\bar\theta = 1 - \theta`; the force at the new
time linearised about :math:`y_k` with the exact Jacobian :math:`J` of ``r``, so that one step
is one linear solve),

.. math::

    B(u_{k+1} - u_k) &= h\big[\bar\theta\, r(t_k, y_k) + \theta\big(r(t_{k+1}, y_k)
        + J (y_{k+1} - y_k)\big)\big] + \sum_\alpha R_\alpha \Lambda_\alpha,\\
    q_{k+1} &= q_k + h\big(\bar\theta v_k + \theta v_{k+1}\big),

where :math:`\Lambda_\alpha` is the *impulse* of contact :math:`\alpha` over the step (a finite
force times ``h``, or the percussion of an impact). Eliminating :math:`q_{k+1}` gives
:math:`u_{k+1} = u^{\rm free} + W^{-1}\sum_\alpha R_\alpha\Lambda_\alpha` with the iteration
matrix :math:`W = B - h\theta \hat J` (:math:`\hat J` the columns of ``J`` on ``u``, the position
columns added with the factor :math:`h\theta`).

Contacts. A finite limit of a stop is one contact with the gap :math:`g_\alpha \ge 0`
(``c . q - lower`` or ``upper - c . q``) and the normal velocity :math:`U_\alpha = \dot g_\alpha`.
It is *active* in step ``k`` when the predicted gap :math:`g_\alpha(q_k) + \gamma h U_{\alpha,k}
\le 0` (``gamma = 1/2``, the usual choice); an active contact obeys **Newton's impact law** at the
velocity level,

.. math::

    0 \le U_{\alpha,k+1} + e_\alpha U_{\alpha,k} \;\perp\; \Lambda_\alpha \ge 0,

which covers impact (the post-impact velocity is ``-e`` times the pre-impact one), resting
contact (``U = 0`` and ``Lambda = h`` times the contact force) and release in one condition. A
friction contact is always active: with :math:`\sigma = c\cdot v_{k+1} - v_0` and the level
:math:`a = h|f|` (``|f|`` at the previous step's slip velocity; Coulomb's law has a constant
level), the friction impulse :math:`\beta` obeys :math:`\beta \in a\,\mathrm{Sign}(\sigma)`,
i.e. sticks (:math:`\sigma = 0`, :math:`|\beta| \le a`) or slides with :math:`|\beta| = a`
against :math:`\sigma`. Together the contacts form a *box* complementarity problem in the
impulses, :math:`w = A x + b` with :math:`x_i \in [l_i, u_i]` (``[0, inf)`` for a stop, ``[-a,
a]`` for friction); a friction row is written as two complementarity pairs (``x = l + zeta``,
``zeta`` complementary to ``w + eta``, ``eta`` complementary to ``u - x``), giving the LCP
:math:`\begin{pmatrix} A & E\\ -E^T & 0\end{pmatrix}`, positive semidefinite when the Delassus
matrix ``A`` is (it is symmetric positive definite when every contact's force acts along its
own combination, the default). It is solved by **Lemke's complementary pivoting** with a cap on
the pivots; the answer is checked (feasibility and complementarity) before it is used.

Energy. With ``theta = 1/2`` the step's energy balance for a linear structure is
:math:`E_{k+1} - E_k = \sum_\alpha \Lambda_\alpha (U_{\alpha,k+1} + U_{\alpha,k})/2` (plus the
damping's and the forcing's work): an elastic impact (``e = 1``) works nothing and the energy
is conserved to rounding through it; ``e < 1`` dissipates. ``theta > 1/2`` damps between
impacts, but an impact then works :math:`\Lambda U_{k+1} = e\Lambda|U_k| \ge 0`: with ``e > 0``
it can *gain* energy at an impact.

Accuracy. Between impacts the scheme is the trapezoidal rule (``theta = 1/2``): second order,
A-stable, energy-conserving for an undamped linear structure. An impact inside a step is placed
at the step's end, so with impacts the global error of the positions is first order in ``h``
(``benchmarks/bench_lcp_nd.py`` measures it against an event-located reference); the scheme's
strengths are robustness (no event location, accumulations of impacts and simultaneous contacts
handled by construction) and a bounded cost per step.

Limitations
-----------
* No sensitivity (the discrete map is not differentiable at contact switches): ``sensitivity=True``
  is refused.
* Friction levels that depend on the slip velocity (Stribeck) are taken explicitly from the
  previous step; a friction level that depends on a normal force is not modelled (the systems
  declare the normal load in the element).
* Penetration of order ``h`` times the impact velocity is inherent in the velocity-level scheme.
* ``theta = 1/2`` is A-stable but not L-stable: a mode far faster than ``1/h`` (a near-singular
  mass matrix, a very stiff spring) is not damped but rings with alternating sign from step to
  step (the positions, averaged by the trapezoidal update, stay right; the velocities do not).
  ``theta > 1/2`` damps it (``theta = 1``: backward Euler, first order).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import sympy as sp
from numpy.typing import ArrayLike

from perturb.checks import finite, state
from perturb.errors import ModelError, ParameterError, PerturbError
from perturb.model.system import S, System, common_period
from perturb.simulate.flows.base import Flow, FlowResult

__all__ = [
    "SystemContact",
    "SystemLCPTrajectory",
    "SystemLCPFlow",
    "simulate_system_lcp",
    "solve_lcp",
]

#: largest number of steps of one call (a guard against a mistyped ``h``)
MAX_STEPS = 5_000_000
#: pivots of Lemke's method per LCP, at least (the bound is max(this, 50 m^2))
_MIN_PIVOTS = 200
_EPS = float(np.finfo(float).eps)


# --------------------------------------------------------------------------------------------
# Lemke's method
# --------------------------------------------------------------------------------------------
def solve_lcp(
    M: ArrayLike, q: ArrayLike, *, max_pivots: int | None = None
) -> tuple[np.ndarray, np.ndarray, int]:
    r"""Solve the linear complementarity problem ``w = M z + q``, ``0 <= z ⊥ w >= 0``.

    Lemke's complementary pivoting with the covering vector of ones (ties in the ratio test
    broken lexicographically, so a degenerate problem cannot cycle); the problem is scaled
    symmetrically by its diagonal first (the solution set does not change). It terminates with
    a solution for a P-matrix (a unique solution for every ``q``) and for a positive
    semidefinite ``M`` whenever the LCP is feasible.

    Parameters
    ----------
    M : array_like, shape (m, m)
    q : array_like, shape (m,)
    max_pivots : int, optional
        Upper bound of the pivots (default ``max(200, 50 m^2)``).

    Returns
    -------
    z, w : ndarray, shape (m,)
    pivots : int

    Raises
    ------
    ParameterError
        Non-finite or mismatched input.
    PerturbError
        Ray termination (the LCP has no solution, or ``M`` is not of a class Lemke's method
        handles), more than ``max_pivots`` pivots, or a computed solution that fails the
        feasibility / complementarity check.

    Examples
    --------
    >>> z, w, _ = solve_lcp([[2.0, -1.0], [-1.0, 2.0]], [-2.0, 0.0])
    >>> np.round(z, 12).tolist(), np.round(w, 12).tolist()
    ([1.333333333333, 0.666666666667], [0.0, 0.0])
    """
    Ma = np.array(M, dtype=float)
    qa = np.array(q, dtype=float).reshape(-1)
    m = qa.size
    if Ma.shape != (m, m) or not (np.all(np.isfinite(Ma)) and np.all(np.isfinite(qa))):
        raise ParameterError(
            f"LCP with M of shape {Ma.shape} and q of size {m}: expected a finite square M "
            "matching q"
        )
    cap = max(_MIN_PIVOTS, 50 * m * m) if max_pivots is None else int(max_pivots)
    if m == 0 or np.all(qa >= 0.0):
        return np.zeros(m), qa.copy(), 0
    # symmetric diagonal scaling z = D z', w' = D w (contact rows of very different masses)
    diag = np.abs(np.diag(Ma))
    scale = np.where(diag > 0.0, 1.0 / np.sqrt(np.where(diag > 0.0, diag, 1.0)), 1.0)
    Ms = Ma * scale[:, None] * scale[None, :]
    qs = qa * scale
    # tableau rows: w_basic = ... ; columns: w (m), z (m), z0 (1); right-hand side separate
    T = np.hstack([np.eye(m), -Ms, -np.ones((m, 1))])
    rhs = qs.copy()
    basis = list(range(m))  # variable index per row: w_i = i, z_i = m + i, z0 = 2m
    lex = np.eye(m)  # lexicographic tie-breaking columns (the initial basis inverse)
    z0 = 2 * m

    def pivot(row: int, col: int) -> None:
        nonlocal rhs
        piv = T[row, col]
        T[row] /= piv
        rhs[row] /= piv
        lex[row] /= piv
        for i in range(m):
            if i != row and T[i, col] != 0.0:
                f = T[i, col]
                T[i] -= f * T[row]
                rhs[i] -= f * rhs[row]
                lex[i] -= f * lex[row]
        basis[row] = col

    row = int(np.argmin(rhs))
    pivot(row, z0)
    leaving = row  # w_row left the basis: its complement enters
    entering = m + leaving
    tol = 1e-12
    for n_piv in range(1, cap + 1):
        col = T[:, entering]
        candidates = np.flatnonzero(col > tol * max(1.0, float(np.abs(col).max())))
        if candidates.size == 0:
            raise PerturbError(
                "Lemke's method ended on a ray: the contact LCP has no solution (the contact "
                "matrix is not positive semidefinite or the constraints are incompatible, e.g. "
                "two stops that cannot both hold); check the stops' limits and force "
                "distributions"
            )
        ratios = rhs[candidates] / col[candidates]
        best = float(ratios.min())
        ties = candidates[ratios <= best + 1e-13 * max(1.0, abs(best))]
        if ties.size > 1:
            z0_rows = [int(r) for r in ties if basis[r] == z0]
            if z0_rows:
                r = z0_rows[0]
            else:  # lexicographic minimum of lex[r] / col[r] among the ties
                keys = lex[ties] / col[ties, None]
                order = np.lexsort(keys.T[::-1])
                r = int(ties[order[0]])
        else:
            r = int(ties[0])
        out = basis[r]
        pivot(r, entering)
        if out == z0:
            z = np.zeros(2 * m + 1)
            z[basis] = rhs
            zs = z[m : 2 * m]
            zz = np.maximum(zs * scale, 0.0)
            ww = Ma @ zz + qa
            _check_solution(Ma, qa, zz, ww)
            return zz, ww, n_piv
        entering = out + m if out < m else out - m
    raise PerturbError(
        f"Lemke's method did not finish within max_pivots = {cap} pivots on a contact LCP of "
        f"size {m} (degenerate or badly scaled contact matrix); reduce the step h or check "
        "the contact data"
    )


def _check_solution(M: np.ndarray, q: np.ndarray, z: np.ndarray, w: np.ndarray) -> None:
    """Feasibility and complementarity of an LCP solution, to the rounding of the data."""
    size = (
        float(np.abs(q).max(initial=0.0))
        + float(np.abs(M).max(initial=0.0)) * float(np.abs(z).max(initial=0.0))
        + 1e-300
    )
    tol = 1e-9 * size
    if np.any(w < -tol) or float(np.abs(z * w).max(initial=0.0)) > tol * max(
        1.0, float(np.abs(z).max(initial=0.0))
    ):
        raise PerturbError(
            f"the contact LCP solution fails its check (min w = {float(w.min()):.3g}, max "
            f"|z w| = {float(np.abs(z * w).max()):.3g}, scale {size:.3g}): the contact matrix is "
            "too ill-conditioned for this step; reduce h or rescale the model"
        )


# --------------------------------------------------------------------------------------------
# the model in numbers
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SystemContact:
    """One contact of the scheme: a finite limit of a stop, or a friction contact.

    Attributes
    ----------
    name : str
        ``"<stop>:lower"`` / ``"<stop>:upper"`` or the friction element's name.
    kind : str
        ``"stop"`` or ``"friction"``.
    element : str
        The element of the system.
    normal : ndarray, shape (n2 + n1,)
        ``U = normal . u`` (the gap rate of a stop limit, pointing into the free side; a
        friction contact's velocity combination).
    limit : float
        The stop's limit (NaN for friction); the gap is ``sign * (c . q - limit)``.
    sign : float
        ``+1`` for a lower limit, ``-1`` for an upper one (0 for friction).
    restitution : float
    offset : float
        ``v0`` of a friction contact (its sticking velocity), else 0.
    """

    name: str
    kind: str
    element: str
    normal: np.ndarray
    limit: float
    sign: float
    restitution: float
    offset: float = 0.0


class _Model:
    """The numbers one step needs: ``B``, ``L``, the forcing, the force elements with their
    derivatives, and the contacts with their force directions."""

    def __init__(self, system: System) -> None:
        if not isinstance(system, System):
            raise ParameterError(f"system = {system!r}: expected a System")
        num = system.numeric_form()  # ParameterError for free parameters, ModelError singular
        self.system = system
        self.B = np.asarray(num["B"], dtype=float)
        self.L = np.asarray(num["L"], dtype=float)
        self.n2 = int(num["n2"])
        self.neq = self.B.shape[0]
        self.n = system.n
        self.harmonics = [
            (float(om), np.asarray(cu, float), np.asarray(cv, float))
            for om, cu, cv in num["harmonics"]
        ]
        omegas = [om for om, _, _ in self.harmonics if om != 0.0]
        self.period = common_period(omegas)
        vals = num["vals"]
        n2 = self.n2
        self.forces: list[tuple[np.ndarray | None, np.ndarray, Any, Any]] = []
        contacts: list[SystemContact] = []
        directions: list[np.ndarray] = []
        levels: list[Any] = []
        for e in system.elements:
            c, w = num["comb"][e.name]
            w = np.asarray(w, dtype=float)
            if e.kind in ("stop", "friction"):
                c = np.asarray(c, dtype=float)
                cq, cv, cp = c[:n2], c[n2 : 2 * n2], c[2 * n2 :]
                stop = e.kind == "stop"
                if np.any(cp) or (stop and np.any(cv)) or (not stop and np.any(cq)):
                    raise ModelError(
                        f"element {e.name!r}: a {e.kind} contact must act on "
                        f"{'positions' if stop else 'velocities'} of second-order coordinates "
                        "only (the Moreau scheme imposes it on their velocities)"
                    )
                normal = np.concatenate([cq if stop else cv, np.zeros(self.neq - n2)])
                if stop:
                    lo, hi = (float(sp.sympify(v).xreplace(vals)) for v in e.limits)
                    if not lo <= hi:
                        raise ModelError(
                            f"stop {e.name!r}: lower = {lo!r} > upper = {hi!r}; expected "
                            "lower <= upper"
                        )
                    for side, lim in ((1.0, lo), (-1.0, hi)):
                        if math.isfinite(lim):
                            label = "lower" if side > 0 else "upper"
                            contacts.append(
                                SystemContact(
                                    f"{e.name}:{label}",
                                    "stop",
                                    e.name,
                                    side * normal,
                                    lim,
                                    side,
                                    float(e.restitution),
                                )
                            )
                            directions.append(side * w)
                            levels.append(None)
                    if not (math.isfinite(lo) or math.isfinite(hi)):
                        raise ModelError(
                            f"stop {e.name!r} has no finite limit: expected lower or upper finite"
                        )
                else:
                    v0 = _friction_offset(e.function.xreplace(vals), e.name)
                    f = sp.lambdify([S], e.function.xreplace(vals), modules="numpy")
                    contacts.append(
                        SystemContact(e.name, "friction", e.name, normal, math.nan, 0.0, 0.0, v0)
                    )
                    # the friction impulse beta opposes sigma = U - v0: force -w beta
                    directions.append(-w)
                    levels.append(f)
                continue
            fexpr = e.function.xreplace(vals)
            if e.combination is None:
                states = list(system.states)
                f = sp.lambdify(states, fexpr, modules="numpy")
                grad = [_no_dirac(sp.diff(fexpr, s)) for s in states]
                df = sp.lambdify(states, grad, modules="numpy")
                self.forces.append((None, w, f, df))
            else:
                f = sp.lambdify([S], fexpr, modules="numpy")
                df = sp.lambdify([S], _no_dirac(sp.diff(fexpr, S)), modules="numpy")
                self.forces.append((np.asarray(c, dtype=float), w, f, df))
        if not contacts:
            raise ModelError(
                f"system {system.name!r} has no stop and no friction contact: the Moreau LCP "
                "scheme is for unilateral contacts; use the exact flow (make_flow(system, "
                "method='exact')) or the ODE flow"
            )
        self.contacts = tuple(contacts)
        self.H = np.array([ct.normal for ct in contacts])  # (m, neq)
        self.R = np.array(directions).T  # (neq, m)
        self.levels = levels
        Binv_R = np.linalg.solve(self.B, self.R)
        # the diagonal of the contact matrix (module docstring: a friction row is w = -sigma)
        row_sign = np.array([1.0 if ct.kind == "stop" else -1.0 for ct in contacts])
        G = row_sign * np.einsum("ij,ji->i", self.H, Binv_R)
        for ct, gii in zip(contacts, G, strict=True):
            if not gii > 0.0:
                raise ModelError(
                    f"contact {ct.name!r}: its force does not act against its own motion "
                    f"(diagonal of the contact matrix {gii:.6g} <= 0): expected a force "
                    "distribution that opens a closed stop or opposes a slip (the default: along "
                    "the contact's own combination)"
                )
        self.stops = np.array([ct.kind == "stop" for ct in contacts])
        self.stop_idx = np.flatnonzero(self.stops)
        self.fric_idx = np.flatnonzero(~self.stops)
        # the gap's gradient in q (the normal already carries the limit's side)
        self.Cq = np.array([ct.normal[:n2] for ct in contacts])
        self.limits = np.array([ct.limit for ct in contacts])
        self.signs = np.array([ct.sign for ct in contacts])
        self.e = np.array([ct.restitution for ct in contacts])
        self.offsets = np.array([ct.offset for ct in contacts])

    def forcing(self, t: float) -> np.ndarray:
        out = np.zeros(self.neq)
        for om, cu, cv in self.harmonics:
            out += cu * math.cos(om * t) + cv * math.sin(om * t) if om else cu
        return out

    def force_and_jacobian(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``-L y - sum w f(c . y)`` (no forcing) and its Jacobian."""
        r = -self.L @ y
        J = -self.L.copy()
        for c, w, f, df in self.forces:
            if c is None:
                r -= w * float(f(*y))
                J -= np.outer(w, np.asarray(df(*y), dtype=float))
            else:
                s = float(c @ y)
                r -= w * float(f(s))
                J -= float(df(s)) * np.outer(w, c)
        return r, J

    def gaps(self, q: np.ndarray) -> np.ndarray:
        """``g >= 0`` of every stop contact (NaN for friction)."""
        with np.errstate(invalid="ignore"):
            return self.Cq @ q - self.signs * self.limits

    def friction_level(self, k: int, sigma: float) -> float:
        """``|f|`` of friction contact ``k`` at the slip velocity ``sigma`` (both sides at the
        sticking velocity itself: the static level)."""
        f = self.levels[k]
        v0 = self.contacts[k].offset
        d = max(abs(sigma), 1e-12 * (1.0 + abs(v0)))
        return max(abs(float(f(v0 + d))), abs(float(f(v0 - d))))


def _no_dirac(expr: sp.Expr) -> sp.Expr:
    # the derivative of a kink or a jump: the Dirac term is the switch itself, which the
    # scheme steps across (first order at a kink); the Jacobian keeps the segment's slope
    return expr.replace(lambda a: isinstance(a, sp.DiracDelta), lambda a: sp.S.Zero)


def _friction_offset(f: sp.Expr, name: str) -> float:
    """The sticking velocity ``v0`` of a friction law: the root of its ``sign`` argument."""
    roots = set()
    for atom in f.atoms(sp.sign):
        arg = atom.args[0]
        if not arg.has(S):
            continue
        a = sp.diff(arg, S)
        if a.has(S) or a == 0:
            raise ModelError(
                f"friction element {name!r}: sign({arg}) is not of an affine argument; "
                "expected F*sign(s - v0)"
            )
        roots.add(float(-(arg.subs(S, 0)) / a))
    if len(roots) != 1:
        raise ModelError(
            f"friction element {name!r}: f(s) = {f} has {len(roots)} switching velocities: "
            "expected one sign(s - v0)"
        )
    return roots.pop()


# --------------------------------------------------------------------------------------------
# trajectory
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class SystemLCPTrajectory:
    r"""Result of :func:`simulate_system_lcp` on the grid :math:`t_k = t_0 + kh`.

    Attributes
    ----------
    t : ndarray, shape (N + 1,)
    y : ndarray, shape (N + 1, n)
        States ``(q, q', p)`` (order :attr:`System.state_names`).
    impulses : ndarray, shape (N + 1, m)
        The impulse of each contact over the step ending at ``t[k]`` (row 0: zeros): a stop's
        percussion (``>= 0``; ``h`` times the contact force while resting), a friction
        contact's impulse ``beta`` (its force on the equations is ``-w beta / h``).
    contacts : tuple of SystemContact
    h : float
        The step used, ``(t1 - t0) / N``.
    theta, gamma : float
    n_pivots : int
        Lemke pivots in all.
    n_lcp : int
        Steps that solved an LCP (at least one contact active).
    state_names : tuple of str
    """

    t: np.ndarray
    y: np.ndarray
    impulses: np.ndarray
    contacts: tuple[SystemContact, ...]
    h: float
    theta: float
    gamma: float
    n_pivots: int
    n_lcp: int
    state_names: tuple[str, ...]

    @property
    def n_steps(self) -> int:
        return int(self.t.size - 1)

    def gaps(self, system: System) -> np.ndarray:
        """Gap ``g >= 0`` of every stop contact at every grid time, shape (N + 1, m) (NaN for
        friction contacts); negative values are the scheme's penetration."""
        model = _Model(system)
        n2 = model.n2
        return np.array([model.gaps(yk[:n2]) for yk in self.y])


def _check_y0(model: _Model, y0: ArrayLike) -> np.ndarray:
    return state(y0, model.n, names=model.system.state_names)


def _check_options(h: Any, theta: Any, gamma: Any, max_steps: Any) -> tuple[float, float, float]:
    hh = finite(h, "h")
    if hh <= 0.0:
        raise ParameterError(f"h = {h!r}: expected a step size h > 0")
    th = finite(theta, "theta")
    if not 0.5 <= th <= 1.0:
        raise ParameterError(
            f"theta = {theta!r}: expected 1/2 <= theta <= 1 (1/2 trapezoidal, 1 backward Euler)"
        )
    ga = finite(gamma, "gamma")
    if not 0.0 <= ga <= 1.0:
        raise ParameterError(f"gamma = {gamma!r}: expected 0 <= gamma <= 1")
    if isinstance(max_steps, bool) or not isinstance(max_steps, int | np.integer) or max_steps < 1:
        raise ParameterError(f"max_steps = {max_steps!r}: expected a positive integer")
    return hh, th, ga


def _steps(t0: float, t1: float, h: float, max_steps: int) -> int:
    if not (math.isfinite(t0) and math.isfinite(t1) and t1 > t0):
        raise ParameterError(f"(t0, t1) = ({t0!r}, {t1!r}): expected finite t1 > t0")
    span = t1 - t0
    steps = max(1, math.ceil(span / h * (1.0 - 8.0 * _EPS)))
    if steps > max_steps:
        raise ParameterError(
            f"h = {h!r} over ({t0!r}, {t1!r}) needs {steps} steps: more than max_steps = "
            f"{max_steps}; use a larger h or raise max_steps"
        )
    return steps


class _Stepper:
    """The Moreau–Jean step of one model, step size and theta (iteration matrices cached per
    Jacobian: a piecewise-linear model has one per region)."""

    def __init__(self, model: _Model, h: float, theta: float, gamma: float) -> None:
        self.model, self.h, self.theta, self.gamma = model, h, theta, gamma
        self._inv: dict[bytes, tuple[np.ndarray, np.ndarray]] = {}
        self.n_pivots = 0
        self.n_lcp = 0

    def _matrices(self, J: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
        key = J.tobytes()
        hit = self._inv.get(key)
        if hit is not None:
            return hit
        m, h, th = self.model, self.h, self.theta
        n2 = m.n2
        Jhat = J[:, n2:].copy()
        Jhat[:, :n2] += h * th * J[:, :n2]
        W = m.B - h * th * Jhat
        cond = np.linalg.cond(W)
        if not np.isfinite(cond) or cond > 1e15:
            raise PerturbError(
                f"the iteration matrix B - h theta J of the Moreau step is singular at t = "
                f"{t!r} (condition number {cond:.3g}) for h = {h!r}, theta = {th!r}: a "
                "negative stiffness makes it singular at this step size; change h slightly"
            )
        Winv = np.linalg.inv(W)
        out = (Winv, Winv @ m.R)
        if len(self._inv) > 256:
            self._inv.clear()
        self._inv[key] = out
        return out

    def step(self, t: float, y: np.ndarray, lam_out: np.ndarray) -> np.ndarray:
        m, h, th = self.model, self.h, self.theta
        n2 = m.n2
        q, v = y[:n2], y[n2 : 2 * n2]
        u = y[n2:]
        r, J = m.force_and_jacobian(y)
        Winv, WinvR = self._matrices(J, t)
        f0, f1 = m.forcing(t), m.forcing(t + h)
        rhs = h * (r + (1.0 - th) * f0 + th * f1 + th * h * (J[:, :n2] @ v))
        u_free = u + Winv @ rhs
        U_k = m.H @ u
        g_k = m.gaps(q)
        active = np.zeros(len(m.contacts), dtype=bool)
        active[m.stop_idx] = g_k[m.stop_idx] + self.gamma * h * U_k[m.stop_idx] <= 0.0
        active[m.fric_idx] = True
        lam_out[:] = 0.0
        if np.any(active):
            idx = np.flatnonzero(active)
            x = self._contact_impulses(idx, u_free, U_k, WinvR, t)
            lam_out[idx] = x
            u_new = u_free + WinvR[:, idx] @ x
        else:
            u_new = u_free
        v_new = u_new[:n2]
        q_new = q + h * ((1.0 - th) * v + th * v_new)
        out = np.concatenate([q_new, u_new])
        if not np.all(np.isfinite(out)):
            raise PerturbError(
                f"the discrete orbit overflowed near t = {t!r} (non-finite state): the orbit "
                "escapes to infinity or h is far too large; shorten t_span or reduce h"
            )
        return out

    def _contact_impulses(
        self, idx: np.ndarray, u_free: np.ndarray, U_k: np.ndarray, WinvR: np.ndarray, t: float
    ) -> np.ndarray:
        m, h = self.model, self.h
        # rows: w = s * (H u_new) + extra, s = +1 stop, -1 friction (w = -(U - v0))
        s = np.where(m.stops[idx], 1.0, -1.0)
        Hs = m.H[idx]
        A = s[:, None] * (Hs @ WinvR[:, idx])
        b = s * (Hs @ u_free)
        is_stop = m.stops[idx]
        b = b + np.where(is_stop, m.e[idx] * U_k[idx], m.offsets[idx])
        lower = np.zeros(idx.size)
        upper = np.full(idx.size, math.inf)
        for i, k in enumerate(idx):
            if not is_stop[i]:
                a = h * m.friction_level(int(k), float(U_k[k] - m.offsets[k]))
                lower[i], upper[i] = -a, a
        x = np.zeros(idx.size)
        free = upper > lower  # a friction contact of zero level exerts nothing
        sel = np.flatnonzero(free)
        if sel.size == 0:
            return x
        A, b, lo, hi = A[np.ix_(sel, sel)], b[sel], lower[sel], upper[sel]
        box = np.flatnonzero(np.isfinite(hi))
        nb = box.size
        # the box rows as two complementarity pairs (module docstring): z = (zeta, eta)
        E = np.zeros((sel.size, nb))
        E[box, np.arange(nb)] = 1.0
        M = np.block([[A, E], [-E.T, np.zeros((nb, nb))]])
        qv = np.concatenate([A @ lo + b, hi[box] - lo[box]])
        try:
            z, _, piv = solve_lcp(M, qv)
        except PerturbError as exc:
            names = ", ".join(m.contacts[int(k)].name for k in idx[sel])
            raise PerturbError(f"contact LCP at t = {t!r} (contacts {names}): {exc}") from None
        self.n_pivots += piv
        self.n_lcp += 1
        xs = lo + z[: sel.size]
        xs[box] = np.minimum(xs[box], hi[box])
        x[sel] = xs
        return x


def simulate_system_lcp(
    system: System,
    y0: ArrayLike,
    t_span: Sequence[float],
    h: float,
    *,
    theta: float = 0.5,
    gamma: float = 0.5,
    max_steps: int = MAX_STEPS,
) -> SystemLCPTrajectory:
    r"""Integrate a system with stops and friction contacts by the Moreau–Jean scheme, one LCP
    per step (see the module docstring).

    Parameters
    ----------
    system : System
        With all parameter values set and at least one stop or friction contact.
    y0 : array_like, shape (n,)
        Initial state ``(q, q', p)`` at ``t_span[0]``.
    t_span : (t0, t1)
        ``t1 > t0``.
    h : float
        Requested step; the step used is ``(t1 - t0) / ceil((t1 - t0) / h) <= h``.
    theta : float
        ``1/2`` (default; trapezoidal between impacts) to ``1`` (backward Euler, dissipative).
    gamma : float
        A stop limit enters the LCP of a step when ``g + gamma h U <= 0`` (default 1/2).
    max_steps : int
        Upper limit of the number of steps.

    Returns
    -------
    SystemLCPTrajectory

    Raises
    ------
    ParameterError
        Bad ``y0``, ``t_span``, ``h <= 0``, ``theta`` outside ``[1/2, 1]``, ``gamma`` outside
        ``[0, 1]``, too many steps, not a ``System``, free parameters.
    ModelError
        No stop and no friction contact; a contact on the wrong kind of combination; a stop
        with ``lower > upper``; a contact force that does not oppose its contact's motion.
    PerturbError
        A singular iteration matrix, an LCP that Lemke's method cannot solve within its pivot
        cap, overflow.

    Examples
    --------
    >>> from perturb.model.system import System, stop
    >>> sys_ = System.from_matrices([[1]], [[0]], [[1]], elements=[stop("x1", -1, 0.5)])
    >>> traj = simulate_system_lcp(sys_, [0.0, 1.0], (0.0, 3.0), 0.01)
    >>> bool(traj.y[:, 0].max() < 0.51), traj.impulses.shape[1]
    (True, 2)
    """
    model = _Model(system)
    y = _check_y0(model, y0)
    try:
        t0, t1 = (float(v) for v in t_span)
    except (TypeError, ValueError):
        raise ParameterError(f"t_span = {t_span!r}: expected (t0, t1) with t1 > t0") from None
    hh, th, ga = _check_options(h, theta, gamma, max_steps)
    steps = _steps(t0, t1, hh, int(max_steps))
    return _integrate(model, y, t0, t1, steps, th, ga)


def _integrate(
    model: _Model, y: np.ndarray, t0: float, t1: float, steps: int, theta: float, gamma: float
) -> SystemLCPTrajectory:
    h = (t1 - t0) / steps
    stepper = _Stepper(model, h, theta, gamma)
    t = t0 + (t1 - t0) * (np.arange(steps + 1) / steps)
    t[-1] = t1
    ys = np.empty((steps + 1, model.n))
    lam = np.zeros((steps + 1, len(model.contacts)))
    ys[0] = y
    for k in range(steps):
        ys[k + 1] = stepper.step(float(t[k]), ys[k], lam[k + 1])
    for arr in (t, ys, lam):
        arr.setflags(write=False)
    return SystemLCPTrajectory(
        t=t,
        y=ys,
        impulses=lam,
        contacts=model.contacts,
        h=h,
        theta=theta,
        gamma=gamma,
        n_pivots=stepper.n_pivots,
        n_lcp=stepper.n_lcp,
        state_names=model.system.state_names,
    )


class SystemLCPFlow(Flow):
    r"""The Moreau–Jean time-stepper as a :class:`~perturb.simulate.flows.base.Flow`.

    Each call integrates on its own uniform grid with the step ``(t1 - t0) / ceil((t1 - t0) /
    h)``; ``t_eval`` values are interpolated linearly between grid points (the scheme is first
    order with impacts, so the interpolation costs no order). No sensitivity: the discrete map
    is not differentiable where contacts open or close.

    Parameters
    ----------
    system : System
        With stops and/or friction contacts and all parameter values set.
    h : float
        Largest step.
    theta, gamma, max_steps
        As :func:`simulate_system_lcp`.

    Attributes
    ----------
    model_system : System
    n_states : int
    period : float or None
        The forcing period (``None`` without harmonic forcing).
    contacts : tuple of SystemContact
    rtol : float
        ``inf``: a fixed-step scheme has no tolerance (its error is first order in ``h``).

    Examples
    --------
    >>> from perturb.model.system import System, stop
    >>> sys_ = System.from_matrices([[1]], [[0]], [[1]], elements=[stop("x1", -1, 0.5)])
    >>> flow = SystemLCPFlow(sys_, 0.01)
    >>> flow([0.0, 1.0], 0.0, 3.0).y.shape
    (2,)
    """

    rtol = math.inf

    def __init__(
        self,
        system: System,
        h: float,
        *,
        theta: float = 0.5,
        gamma: float = 0.5,
        max_steps: int = MAX_STEPS,
    ) -> None:
        self._model = _Model(system)
        self.h, self.theta, self.gamma = _check_options(h, theta, gamma, max_steps)
        self.max_steps = int(max_steps)
        self.model_system = system
        self.n_states = int(system.n)
        self.period = self._model.period
        self.contacts = self._model.contacts

    @property
    def autonomous(self) -> bool:
        """No harmonic forcing."""
        return self.period is None

    def __repr__(self) -> str:
        return (
            f"SystemLCPFlow({self.model_system.name}, h={self.h:g}, theta={self.theta:g}, "
            f"contacts={len(self.contacts)})"
        )

    def vector_field(self, t: float, y: ArrayLike) -> np.ndarray:
        """The free-flight field (every stop open, no friction contact sticking)."""
        return np.asarray(self.model_system.field(float(t), np.asarray(y, dtype=float)))

    def trajectory(self, y0: ArrayLike, t0: float, t1: float) -> SystemLCPTrajectory:
        """The discrete trajectory on ``[t0, t1]``."""
        y = _check_y0(self._model, y0)
        steps = _steps(float(t0), float(t1), self.h, self.max_steps)
        return _integrate(self._model, y, float(t0), float(t1), steps, self.theta, self.gamma)

    def __call__(
        self,
        y0: ArrayLike,
        t0: float,
        t1: float,
        *,
        sensitivity: bool = False,
        t_eval: ArrayLike | None = None,
    ) -> FlowResult:
        """Propagate ``y0`` from ``t0`` to ``t1``; see the class docstring.

        Raises
        ------
        ParameterError
            ``sensitivity=True``; bad ``y0``, interval or ``t_eval`` (outside ``[t0, t1]``).
        PerturbError
            As :func:`simulate_system_lcp`.
        """
        if sensitivity:
            raise ParameterError(
                "sensitivity = True: the Moreau LCP time-stepper has no sensitivity (its "
                "discrete map is not differentiable where contacts open or close); use the "
                "exact flow (make_flow(system, method='exact', active=...)) for monodromy "
                "matrices"
            )
        traj = self.trajectory(y0, t0, t1)
        stops = np.array([c.kind == "stop" for c in traj.contacts], dtype=bool)
        t_out = ys = None
        if t_eval is not None:
            t_out = np.asarray(t_eval, dtype=float).reshape(-1)
            slack = 1e-12 * max(1.0, abs(t0), abs(t1))
            if not np.all(np.isfinite(t_out)) or np.any(
                (t_out < t0 - slack) | (t_out > t1 + slack)
            ):
                raise ParameterError(
                    f"t_eval outside ({t0!r}, {t1!r}): expected finite times in the interval"
                )
            ys = np.column_stack([np.interp(t_out, traj.t, col) for col in traj.y.T])
        return FlowResult(
            t0=float(t0),
            t1=float(t1),
            y=traj.y[-1].copy(),
            sensitivity=None,
            t=t_out,
            ys=ys,
            n_events=int(np.count_nonzero(np.any(traj.impulses[:, stops] > 0.0, axis=1))),
        )
