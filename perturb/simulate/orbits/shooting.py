r"""Periodic orbits by shooting, with Floquet multipliers.

Every solver here works on any :class:`~perturb.simulate.flows.base.Flow` (the exact PWL flow
:class:`~perturb.simulate.flows.exact.ExactPWLFlow`, :class:`~perturb.simulate.flows.base.ODEFlow`,
an
event-driven flow) and returns the same immutable :class:`PeriodicOrbit`.

Single shooting, forced systems (:func:`periodic_orbit`)
    With :math:`T` the forcing period and :math:`P = mT`, solve

    .. math:: G(y_0) = \varphi_{t_0 \to t_0+P}(y_0) - y_0 = 0,\qquad
              G'(y_0) = M(y_0) - I,

    where :math:`M = \partial\varphi/\partial y_0` is the flow's sensitivity (the monodromy
    matrix at the solution; saltation included for nonsmooth flows).

Single shooting, autonomous systems (:func:`limit_cycle`)
    Unknowns :math:`(y_0, T)`; the period is not known and any point of the orbit is a
    solution, so a *phase condition* is added.  We use :math:`\dot x(0) = v_0 = 0` (the orbit
    starts at an extremum of :math:`x`; every periodic orbit of an oscillator has one), giving
    the bordered Newton system

    .. math::
        \begin{pmatrix} M - I & f(\varphi_T(y_0)) \\ e_2^T & 0 \end{pmatrix}
        \begin{pmatrix}\Delta y_0 \\ \Delta T\end{pmatrix}
        = -\begin{pmatrix}\varphi_T(y_0) - y_0 \\ v_0\end{pmatrix},

    since :math:`\partial\varphi_T/\partial T = f(\varphi_T)`.  Conservative systems have
    *families* of orbits (the bordered matrix is singular: energy conservation makes the two
    periodicity equations dependent); ``phase="anchor"`` keeps :math:`y_0 = (A, 0)` fixed and
    solves :math:`\varphi_T(y_0) = y_0` for :math:`T` alone (Gauss–Newton,
    :math:`\Delta T = -f^T G / f^T f`, quadratically convergent because the residual vanishes at
    the solution).

Multiple shooting (:func:`multiple_shooting`)
    :math:`N` nodes :math:`y_i` at :math:`t_i = t_0 + iP/N`, residuals
    :math:`r_i = \varphi_{t_i\to t_{i+1}}(y_i) - y_{(i+1) \bmod N}`.  The Jacobian is block
    bidiagonal with the cyclic closing block,

    .. math::
        \begin{pmatrix} M_0 & -I & & \\ & M_1 & -I & \\ & & \ddots & -I\\ -I & & & M_{N-1}
        \end{pmatrix}

    (plus the column :math:`f(\varphi_i)/N` and the phase row :math:`v_0 = 0` when the period is
    unknown), assembled in :mod:`scipy.sparse` and factorised by SuperLU.  The monodromy is
    :math:`M_{N-1}\cdots M_0`.  Sub-intervals keep the growth of perturbations per flow call
    bounded, which is what makes strongly unstable orbits computable.

Newton safeguard
    Every step is cut to at most ``10 max(1, |z|)`` and then damped by backtracking (halving)
    until the Armijo condition :math:`\|r(z+\alpha\Delta z)\|_2 \le (1 - 10^{-4}\alpha)\|r(z)\|_2`
    holds; a trial where the flow fails (escape, sticking) counts as a rejected step.
    Convergence: :math:`\|r\|_\infty \le \text{tol}\cdot\max(1, \|y\|_\infty)`, or a Newton
    correction :math:`\|\Delta z\|_\infty \le \text{tol}\cdot\max(1, \|y\|_\infty)` with
    :math:`\|r\|_\infty \le \sqrt{\text{tol}}\max(1, \|y\|_\infty)`: the residual of a strongly
    unstable orbit cannot fall below :math:`\sim\epsilon\|M\|\|y\|` (rounding amplified by the
    monodromy) although its initial state is determined to tol.  Failure raises
    :class:`ShootingError` (a :class:`~perturb.errors.PerturbError`) with the residual reached; a
    NaN orbit is never returned.

States of any dimension
    Forced orbits (:func:`periodic_orbit`, :func:`multiple_shooting`) take a flow of ``n``
    states, e.g. :class:`~perturb.simulate.flows.affine_exact.AffineExactFlow` of a system of
    several coordinates: the state size is the flow's declared ``n_states`` (or its
    ``affine_system.n``), else 2.  ``n = 2`` states are ``(x, v)`` and take exactly the SDOF
    path below; for ``n != 2`` the summary numbers describe the first state (``x1``), the
    multipliers are ``numpy.linalg.eigvals`` of the monodromy, and
    :meth:`PeriodicOrbit.max_abs` gives ``max |.|`` of every state or of any combination.
    Limit cycles of autonomous systems (:func:`limit_cycle`, :func:`multiple_shooting`) take
    ``n`` states too, the phase condition on the velocity of the first coordinate (or
    ``phase_state``).

Orbit data
    Multipliers are the eigenvalues of the monodromy.  Amplitude (max :math:`|x|`), mean and
    first-harmonic amplitude come from ``N_STATS = 1024`` equally spaced samples per forcing
    period (per orbit period when autonomous; the exact dense output for
    :class:`ExactPWLFlow`) by FFT; the extrema of :math:`x` are refined by solving
    :math:`v(t) = 0` (safeguarded Newton with :math:`\dot v = a`) in the bracketing sample
    interval, so the amplitude is exact to the flow's accuracy rather than to the sampling.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.sparse as sps
from numpy.typing import ArrayLike

from perturb.errors import ParameterError, PerturbError
from perturb.numeric.roots import NewtonOptions, NewtonResult, damped_newton
from perturb.simulate.flows.base import Flow, as_flow

__all__ = [
    "PeriodicOrbit",
    "ShootingError",
    "classify_multipliers",
    "is_autonomous",
    "monodromy_multipliers",
    "periodic_orbit",
    "limit_cycle",
    "state_dimension",
    "multiple_shooting",
]

#: samples per forcing period (per orbit period when autonomous) for the mean and the first
#: harmonic.  Uniform sampling of a periodic x(t) is spectrally accurate for smooth systems; for
#: a continuous PWL force the third derivative of x jumps and the aliasing error decays like
#: n^-5: about 3e-12 relative at 1024 (1e-10 at 512) on the nsd orbits; a force jump (x''
#: jumps) gives n^-3.
N_STATS = 1024
#: default distance from the unit circle below which a multiplier marks a bifurcation
UNIT_TOL = 1e-6
#: a Newton step is cut to this multiple of max(1, |z|)
_MAX_STEP = 10.0
#: smallest line-search step fraction (a power of 2: the number of halvings)
_MIN_ALPHA = 2.0**-12


class ShootingError(PerturbError):
    """A periodic-orbit solver did not converge.

    Attributes
    ----------
    residual : float
        ``max |r|`` at the last accepted iterate.
    iterations : int
        Newton steps taken.
    z : numpy.ndarray
        The last accepted iterate (state(s), and the period for autonomous systems).
    """

    def __init__(self, message: str, residual: float, iterations: int, z: np.ndarray) -> None:
        super().__init__(message)
        self.residual = float(residual)
        self.iterations = int(iterations)
        self.z = np.array(z, dtype=float)


# ---------------------------------------------------------------------------------------------
# the orbit object
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class PeriodicOrbit:
    r"""A periodic orbit with its Floquet multipliers and summary numbers.

    Attributes
    ----------
    y0 : ndarray, shape (n,)
        The state at ``t0``: ``(x, v)`` for ``n = 2``, the flow's state order otherwise.
    t0 : float
        Start time (the phase of the forcing; irrelevant for autonomous systems).
    period : float
        The orbit's period: ``m`` forcing periods, or the limit-cycle period.
    m : int
        Number of forcing periods (1 for autonomous orbits).
    forcing_period : float or None
        ``None`` for autonomous systems.
    autonomous : bool
    monodromy : ndarray, shape (n, n)
        :math:`\partial y(t_0 + P)/\partial y(t_0)`.
    multipliers : ndarray of complex, shape (n,)
        Eigenvalues of the monodromy, by decreasing modulus (for autonomous systems one of them
        is the trivial multiplier 1).
    stability : str
        ``'stable'``, ``'unstable'``, or, when a non-trivial multiplier lies within
        ``unit_tol`` of the unit circle, ``'fold'`` (at +1), ``'period-doubling'`` (at -1) or
        ``'neimark-sacker'`` (complex pair).  A conservative orbit (both multipliers 1: a member
        of a family, not isolated) is reported as ``'fold'``.
    max_multiplier : float
        :math:`\max|\mu|` over the non-trivial multipliers.
    amplitude : float
        :math:`\max_t |x(t)|` over the period (``x`` the first state).
    first_harmonic_amplitude : float
        Amplitude of the component of :math:`x` at the forcing frequency (harmonic ``m`` of the
        orbit period), or at the orbit's own fundamental for autonomous orbits.
    mean : float
        Mean of :math:`x` over the period.
    residual : float
        Final max-norm of the solver's residual.
    iterations : int
        Newton steps.
    method : str
        ``'single shooting'``, ``'multiple shooting'``, ``'collocation'``.
    nodes : ndarray or None
        Multiple-shooting nodes ``(N, n)`` or collocation values ``(N, 2)``.

    Notes
    -----
    :meth:`sample` evaluates the orbit itself: the exact dense output (``ExactPWLFlow``), the
    flow from the node of each sub-interval (other flows; one node for single shooting), or the
    trigonometric interpolant of the grid values (collocation).  The summary numbers come from
    the same samples (see the module docstring), so they describe the returned orbit.
    """

    y0: np.ndarray
    t0: float
    period: float
    m: int
    forcing_period: float | None
    autonomous: bool
    monodromy: np.ndarray
    multipliers: np.ndarray
    stability: str
    max_multiplier: float
    amplitude: float
    first_harmonic_amplitude: float
    mean: float
    residual: float
    iterations: int
    method: str
    nodes: np.ndarray | None = None
    _dense: Any = field(default=None, repr=False)

    @property
    def nontrivial_multipliers(self) -> np.ndarray:
        """The multipliers without the trivial 1 of an autonomous orbit."""
        if not self.autonomous:
            return self.multipliers
        k = int(np.argmin(np.abs(self.multipliers - 1.0)))
        return np.delete(self.multipliers, k)

    @property
    def is_stable(self) -> bool:
        return self.stability == "stable"

    def sample(self, n: int = 256) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``n`` equally spaced samples over one orbit period: ``(t, x, v)``,
        ``t = t0 + period * j / n`` for ``j = 0 .. n-1`` (two-state orbits; see
        :meth:`sample_states` for ``n`` states)."""
        if self.y0.size != 2:
            raise ParameterError(
                f"sample: the orbit has {self.y0.size} states, not (x, v): use sample_states"
            )
        t, X = self.sample_states(n)
        return t, X[0].copy(), X[1].copy()

    def sample_states(self, n: int = 256) -> tuple[np.ndarray, np.ndarray]:
        """``n`` equally spaced samples of every state over one orbit period: ``(t, Y)``,
        ``t = t0 + period * j / n`` for ``j = 0 .. n-1``, ``Y`` of shape ``(states, n)``."""
        if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 1:
            raise ParameterError(f"n = {n!r}: expected a positive integer")
        t = self.t0 + self.period * np.arange(int(n)) / int(n)
        return t, np.asarray(self._dense(t), dtype=float)

    def max_abs(self, output: ArrayLike | None = None) -> np.ndarray | float:
        r"""``max_t |c . y(t)|`` over the period, the extrema refined on the orbit itself.

        Parameters
        ----------
        output : array_like, shape (n,), optional
            The combination ``c`` (e.g. ``System.output("x1 - x2")``); default: every state,
            one maximum each.

        Returns
        -------
        float, or ndarray of shape (n,) without ``output``.

        Notes
        -----
        ``c . y`` is sampled at ``N_STATS * m`` points; each extremum is then located as the
        root of :math:`c\cdot f(t, y(t))` (the rate of the combination, ``f`` the vector
        field) in its bracketing sample interval by a safeguarded secant/bisection on the
        dense orbit, so the value is exact to the flow's accuracy, not to the sampling.
        """
        n = self.y0.size
        if output is None:
            return np.array([self.max_abs(np.eye(n)[i]) for i in range(n)])
        try:
            c = np.array(output, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            raise ParameterError(f"output = {output!r}: expected {n} numbers") from None
        if c.size != n or not np.all(np.isfinite(c)):
            raise ParameterError(f"output = {c.tolist()!r}: expected {n} finite numbers")
        harmonic = 1 if self.autonomous else self.m
        return _combination_extreme(self._dense, self.t0, self.period, harmonic, c)

    def to_dict(self) -> dict[str, Any]:
        """Plain-Python summary (JSON-serialisable)."""
        return {
            "y0": [float(v) for v in self.y0],
            "t0": self.t0,
            "period": self.period,
            "m": self.m,
            "forcing_period": self.forcing_period,
            "autonomous": self.autonomous,
            "multipliers": [[float(z.real), float(z.imag)] for z in self.multipliers],
            "stability": self.stability,
            "max_multiplier": self.max_multiplier,
            "amplitude": self.amplitude,
            "first_harmonic_amplitude": self.first_harmonic_amplitude,
            "mean": self.mean,
            "residual": self.residual,
            "iterations": self.iterations,
            "method": self.method,
        }

    @classmethod
    def from_solution(
        cls,
        *,
        dense: Any,
        y0: np.ndarray,
        t0: float,
        P: float,
        m: int,
        forcing_period: float | None,
        monodromy: np.ndarray,
        residual: float,
        iterations: int,
        method: str,
        unit_tol: float,
        nodes: np.ndarray | None = None,
        flow: Any = None,
    ) -> PeriodicOrbit:
        """The orbit a solver found, with its derived data: the one constructor the solvers of
        this package (single and multiple shooting, collocation) share.

        The keywords are the solver's raw results; the multipliers (from ``monodromy``, with the
        flow's exact sensitivity determinant when ``flow`` is given: see
        :func:`monodromy_multipliers`), the stability label (:func:`classify_multipliers` with
        ``unit_tol``) and the summary numbers (amplitude, first harmonic, mean: sampled from
        ``dense``, see the module docstring) are computed here, and the arrays are made
        read-only.

        Parameters
        ----------
        dense : callable
            ``dense(t) -> (states, len(t))`` states at the times ``t`` (what :meth:`sample`
            evaluates).
        y0, t0, P, m, forcing_period, monodromy, residual, iterations, method, nodes
            As the attributes ``y0``, ``t0``, ``period``, ``m``, ``forcing_period``,
            ``monodromy``, ``residual``, ``iterations``, ``method``, ``nodes`` (``forcing_period``
            None: autonomous).
        unit_tol : float
            Distance from the unit circle marking a bifurcation.
        flow : Flow, optional
            The flow, for the exact determinant of the monodromy.

        Raises
        ------
        PerturbError
            Non-finite orbit data (a NaN orbit is never returned).
        """
        autonomous = forcing_period is None
        determinant = None if flow is None else flow.sensitivity_determinant(t0, t0 + P)
        mu = monodromy_multipliers(monodromy, None if determinant is None else float(determinant))
        stability, max_mu = classify_multipliers(mu, autonomous=autonomous, unit_tol=unit_tol)
        amp, first, mean = _statistics(dense, t0, P, 1 if autonomous else m)
        values = [*y0, P, *monodromy.ravel(), amp, first, mean, residual]
        if not np.all(np.isfinite(values)) or not np.all(np.isfinite(mu)):
            raise PerturbError(
                f"{method}: non-finite orbit data (y0 = {y0.tolist()}, period = {P})"
            )
        for arr in (y0, monodromy, mu):
            arr.setflags(write=False)
        if nodes is not None:
            nodes = np.array(nodes, dtype=float)
            nodes.setflags(write=False)
        return cls(
            y0=y0,
            t0=float(t0),
            period=float(P),
            m=int(m),
            forcing_period=None if forcing_period is None else float(forcing_period),
            autonomous=autonomous,
            monodromy=monodromy,
            multipliers=mu,
            stability=stability,
            max_multiplier=max_mu,
            amplitude=amp,
            first_harmonic_amplitude=first,
            mean=mean,
            residual=float(residual),
            iterations=int(iterations),
            method=method,
            nodes=nodes,
            _dense=dense,
        )

    def __str__(self) -> str:
        kind = "autonomous" if self.autonomous else f"forced, m = {self.m}"
        mults = ", ".join(_fmt_complex(z) for z in self.multipliers)
        lines = [
            f"PeriodicOrbit ({self.method}, {kind})",
            f"  period       {self.period:.15g}"
            + (
                ""
                if self.forcing_period is None
                else f"  (= {self.m} x forcing period {self.forcing_period:.15g})"
            ),
            (
                f"  y0           x = {self.y0[0]:.15g}, v = {self.y0[1]:.15g} at t0 = {self.t0:g}"
                if self.y0.size == 2
                else f"  y0           {', '.join(f'{v:.15g}' for v in self.y0)} at t0 = {self.t0:g}"
            ),
            f"  amplitude    {self.amplitude:.15g}   (max |x|)",
            f"  1st harmonic {self.first_harmonic_amplitude:.15g}   mean {self.mean:.6g}",
            f"  multipliers  {mults}",
            f"  stability    {self.stability}   (max |mu| = {self.max_multiplier:.6g})",
            f"  residual     {self.residual:.3g} after {self.iterations} Newton steps",
        ]
        return "\n".join(lines)


def _fmt_complex(z: complex) -> str:
    if z.imag == 0.0:
        return f"{z.real:.10g}"
    return f"{z.real:.10g}{z.imag:+.10g}j"


def classify_multipliers(
    multipliers: ArrayLike, *, autonomous: bool = False, unit_tol: float = UNIT_TOL
) -> tuple[str, float]:
    """Stability label and ``max |mu|`` (non-trivial multipliers) of a periodic orbit.

    For autonomous systems the multiplier closest to 1 is the trivial one (the orbit's own
    direction) and is left out.  A non-trivial multiplier within ``unit_tol`` of the unit circle
    names the bifurcation: ``'fold'`` near +1, ``'period-doubling'`` near -1,
    ``'neimark-sacker'`` elsewhere (a complex pair on or outside the circle; a pair strictly
    inside it is ``'stable'``); otherwise ``'stable'`` if all are inside the circle and
    ``'unstable'`` if not.
    """
    mu = np.asarray(multipliers, dtype=complex).reshape(-1)
    if autonomous and mu.size:
        mu = np.delete(mu, int(np.argmin(np.abs(mu - 1.0))))
    if mu.size == 0:
        return "stable", 0.0
    mods = np.abs(mu)
    max_mu = float(mods.max())
    on = mu[np.abs(mods - 1.0) <= unit_tol]
    if on.size:
        if np.any(np.abs(on - 1.0) <= unit_tol):
            return "fold", max_mu
        if np.any(np.abs(on + 1.0) <= unit_tol):
            return "period-doubling", max_mu
        if max_mu < 1.0 - 1e-12:
            # a complex pair strictly inside the circle is stable: in a planar forced system
            # with damping mu its modulus is exp(-mu P/2) (det M = exp(-mu P)), so a lightly
            # damped orbit sits within unit_tol of the circle without being near a bifurcation
            return "stable", max_mu
        return "neimark-sacker", max_mu
    return ("stable" if max_mu < 1.0 else "unstable"), max_mu


# ---------------------------------------------------------------------------------------------
# dense output and orbit statistics
# ---------------------------------------------------------------------------------------------
class _FlowDense:
    """The orbit on ``[times[0], times[-1]]`` from nodes ``y_i`` at ``times[i]``, one flow
    segment each (exact dense output for :class:`ExactPWLFlow`)."""

    def __init__(self, flow: Flow, nodes: np.ndarray, times: np.ndarray) -> None:
        self.flow = flow
        nodes = np.array(nodes, dtype=float)
        self.nodes = nodes.reshape(-1, nodes.shape[-1] if nodes.ndim else 2)
        self.times = np.array(times, dtype=float)
        self.exact = flow.exact_dense_output
        self.trajs = (
            [
                flow.trajectory(self.nodes[i], self.times[i], self.times[i + 1])  # type: ignore[attr-defined]
                for i in range(len(self.nodes))
            ]
            if self.exact
            else None
        )

    def __call__(self, t: ArrayLike) -> np.ndarray:
        t = np.asarray(t, dtype=float).reshape(-1)
        nseg = len(self.nodes)
        idx = np.clip(np.searchsorted(self.times, t, side="right") - 1, 0, nseg - 1)
        out = np.empty((self.nodes.shape[1], t.size))
        for i in np.unique(idx):
            sel = np.flatnonzero(idx == i)
            a, b = self.times[i], self.times[i + 1]
            ts = np.clip(t[sel], a, b)
            if self.trajs is not None:
                out[:, sel] = self.trajs[i](ts)
                continue
            order = np.argsort(ts, kind="stable")
            res = self.flow(self.nodes[i], a, b, t_eval=ts[order])
            out[:, sel[order]] = np.asarray(res.ys).T
        return out

    def local(self, y_a: np.ndarray, t_a: float, t: float) -> np.ndarray:
        """State at ``t >= t_a`` given the state ``y_a`` at ``t_a`` (a short flow call)."""
        if self.trajs is not None:
            i = min(max(bisect.bisect_right(self.times, t) - 1, 0), len(self.trajs) - 1)
            return self.trajs[i](min(max(t, self.times[i]), self.times[i + 1]))
        if t <= t_a:
            return y_a
        return self.flow(y_a, t_a, t).y

    def field(self, t: float, y: np.ndarray) -> np.ndarray:
        return np.asarray(self.flow.vector_field(t, y), dtype=float)


def _hermite_root(va: float, vb: float, ma: float, mb: float) -> float:
    """Root in [0, 1] of the cubic Hermite interpolant of values ``va > 0 >= vb`` and slopes
    ``ma``, ``mb`` (per unit interval): Newton from the regula-falsi point, kept in [0, 1]."""
    s = va / (va - vb)
    for _ in range(8):
        s2, s3 = s * s, s * s * s
        val = (2 * s3 - 3 * s2 + 1) * va + (s3 - 2 * s2 + s) * ma + (-2 * s3 + 3 * s2) * vb
        val += (s3 - s2) * mb
        der = (6 * s2 - 6 * s) * (va - vb) + (3 * s2 - 4 * s + 1) * ma + (3 * s2 - 2 * s) * mb
        if der == 0.0 or not math.isfinite(val / der):
            break
        s = min(1.0, max(0.0, s - val / der))
    return s


def _refine_extremum(dense: Any, t: np.ndarray, X: np.ndarray, j: int, sign: int) -> float:
    """``x`` at the extremum (max for sign=+1, min for -1) near sample ``j``.

    The root of ``v`` in the bracketing sample interval starts from the root of the cubic
    Hermite interpolant of ``v`` (values and ``v' = a`` at both ends: error ``O(h^4)``) and is
    polished by Newton's method with the exact derivative ``a`` (the vector field), safeguarded
    by bisection so it never leaves the bracket.  Once the Newton correction ``d`` is below
    ``1e-8`` the last step is taken analytically, ``x(t + d) = x(t) + v d / 2 + O(d^3)`` (with
    ``d = -v/a``), so one or two dense evaluations suffice.  Returns the sample value when there
    is no sign change (a constant orbit)."""
    n = t.size - 1  # t[n] = t0 + P closes the period
    xj = float(X[0, j])
    sv = sign * X[1, j]
    if sv > 0.0:
        a, b = j, j + 1
    elif sv < 0.0:
        a, b = (j - 1, j) if j > 0 else (n - 1, n)
    else:
        return xj
    ya = X[:, a].copy()
    lo, hi = float(t[a]), float(t[b])
    va, vb = sign * X[1, a], sign * X[1, b]
    if not (va > 0.0 >= vb):
        return xj
    ta, h = lo, hi - lo
    ma = sign * float(dense.field(lo, X[:, a])[1]) * h
    mb = sign * float(dense.field(hi, X[:, b])[1]) * h
    tt = lo + h * _hermite_root(va, vb, ma, mb)
    eps = float(np.finfo(float).eps)
    xr = xj
    for _ in range(30):
        y = dense.local(ya, ta, tt)
        xr = float(y[0])
        s = sign * float(y[1])
        if s == 0.0:
            break
        if s > 0.0:
            lo = tt
        else:
            hi = tt
        acc = sign * float(dense.field(tt, y)[1])
        tn = tt - s / acc if acc != 0.0 else 0.5 * (lo + hi)
        if lo < tn < hi and abs(tn - tt) <= 1e-8 * max(1.0, abs(tt)):
            xr += 0.5 * float(y[1]) * (tn - tt)
            break
        if not lo < tn < hi:
            tn = 0.5 * (lo + hi)
        tt = tn
        if hi - lo <= 4.0 * eps * max(1.0, abs(tt)):
            xr = float(dense.local(ya, ta, tt)[0])
            break
    return xr if sign * xr >= sign * xj else xj


def _statistics(dense: Any, t0: float, P: float, harmonic: int) -> tuple[float, float, float]:
    """``(amplitude, first_harmonic_amplitude, mean)`` of ``x`` over ``[t0, t0 + P]``
    (``harmonic = m``: ``m * N_STATS`` samples)."""
    n = N_STATS * harmonic
    t = t0 + P * np.arange(n + 1) / n
    t[-1] = t0 + P
    X = dense(t)
    x = X[0, :n]
    c = np.fft.rfft(x) / n
    mean = float(c[0].real)
    first = float(2.0 * abs(c[harmonic])) if harmonic < c.size else 0.0
    if X.shape[0] != 2:  # n states: the first one, extrema on the roots of its rate
        e0 = np.zeros(X.shape[0])
        e0[0] = 1.0
        return _combination_extreme(dense, t0, P, harmonic, e0, (t, X)), first, mean
    xmax = _refine_extremum(dense, t, X, int(np.argmax(x)), 1)
    xmin = _refine_extremum(dense, t, X, int(np.argmin(x)), -1)
    return max(abs(xmax), abs(xmin)), first, mean


def _combination_extreme(
    dense: Any,
    t0: float,
    P: float,
    harmonic: int,
    c: np.ndarray,
    samples: tuple[np.ndarray, np.ndarray] | None = None,
) -> float:
    """``max |c . y(t)|`` over ``[t0, t0 + P]`` for a state of any size: ``N_STATS * harmonic``
    samples, then the maximum and the minimum each refined as the root of the rate
    ``c . f(t, y(t))`` in the bracketing sample interval (:func:`scipy.optimize.brentq` on the
    dense orbit, bounded); the sample value when the rate does not change sign there."""
    if samples is None:
        n = N_STATS * harmonic
        t = t0 + P * np.arange(n + 1) / n
        t[-1] = t0 + P
        X = dense(t)
    else:
        t, X = samples
    x = c @ X
    n = t.size - 1
    best = 0.0
    for sign, j in ((1, int(np.argmax(x[:n]))), (-1, int(np.argmin(x[:n])))):
        best = max(best, abs(_refine_combination(dense, t, X, c, j, sign, n)))
    return best


def _refine_combination(dense, t, X, c, j, sign, n) -> float:
    from scipy.optimize import brentq

    xj = float(c @ X[:, j])

    def rate(k: int) -> float:
        return sign * float(c @ dense.field(float(t[k]), X[:, k]))

    rj = rate(j)
    if rj > 0.0:
        a, b = j, j + 1
    elif rj < 0.0:
        a, b = (j - 1, j) if j > 0 else (n - 1, n)
    else:
        return xj
    ra, rb = (rj, rate(b)) if a == j else (rate(a), rj)
    if not (ra > 0.0 >= rb):
        return xj
    ya, ta = X[:, a].copy(), float(t[a])

    def g(tt: float) -> float:
        return sign * float(c @ dense.field(tt, dense.local(ya, ta, tt)))

    try:
        ts = brentq(g, ta, float(t[b]), xtol=1e-15 * max(1.0, abs(ta)), maxiter=100)
    except (ValueError, RuntimeError):
        return xj
    xr = float(c @ dense.local(ya, ta, ts))
    return xr if sign * xr >= sign * xj else xj


def monodromy_multipliers(M: np.ndarray, det: float | None = None) -> np.ndarray:
    r"""Eigenvalues of a monodromy by decreasing modulus.

    An ``n x n`` matrix with ``n != 2`` takes :func:`numpy.linalg.eigvals` (``det`` unused).
    For 2x2:

    With the exact determinant (Liouville: :math:`\det M = e^{\oint \operatorname{tr} J}`,
    e.g. :math:`e^{-\mu P}` for every PWL orbit, saltations having determinant 1) a real pair is
    computed as :math:`\mu_1 = (\operatorname{tr} + \operatorname{sign}(\operatorname{tr})
    \sqrt{\operatorname{tr}^2 - 4\det})/2`, :math:`\mu_2 = \det/\mu_1`: the small multiplier
    of a strongly unstable orbit keeps full relative accuracy, whereas ``eigvals`` loses it to
    the rounding of the large entries (absolute error :math:`\sim \epsilon \|M\|`).
    """
    if np.shape(M) != (2, 2) or det is None or not math.isfinite(det):
        mu = np.linalg.eigvals(M).astype(complex)
    else:
        half = 0.5 * float(M[0, 0] + M[1, 1])
        # (half/s)**2 - det/s**2 with s >= |half|, sqrt|det|: tr**2 itself overflows once the
        # multiplier passes 1e154, which a saddle orbit at low forcing frequency does
        s = max(abs(half), math.sqrt(abs(det)))
        q = (half / s) ** 2 - (det / s) / s if s > 0.0 else 0.0
        if q >= 0.0:
            l1 = half + math.copysign(s * math.sqrt(q), half)
            l2 = det / l1 if l1 != 0.0 else 0.0
            mu = np.array([l1, l2], dtype=complex)
        else:
            im = s * math.sqrt(-q)
            mu = np.array([complex(half, im), complex(half, -im)])
    return mu[np.argsort(-np.abs(mu), kind="stable")]


# ---------------------------------------------------------------------------------------------
# input checks
# ---------------------------------------------------------------------------------------------
def check_flow(flow: Any) -> Flow:
    """``flow`` as a :class:`~perturb.simulate.flows.base.Flow` (its declared capabilities);
    ParameterError when it is not callable with a ``vector_field`` method."""
    return as_flow(flow)


def is_autonomous(flow: Any) -> bool:
    """True for a flow without forcing (its declared ``autonomous``)."""
    return as_flow(flow).autonomous


def state_dimension(flow: Any) -> int:
    """Number of states of ``flow``: its declared ``n_states``, else the ``n`` of its
    ``affine_system`` (:class:`~perturb.simulate.flows.affine_exact.AffineExactFlow`), else 2
    (the ``(x, v)`` of an oscillator)."""
    n = getattr(flow, "n_states", None)
    if n is None:
        affine = getattr(flow, "affine_system", None)
        n = getattr(affine, "n", None)
    return 2 if n is None else int(n)


def _state(value: ArrayLike, name: str, n: int = 2) -> np.ndarray:
    what = "two finite numbers (x, v)" if n == 2 else f"{n} finite numbers (the flow's states)"
    try:
        y = np.array(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ParameterError(f"{name} = {value!r}: expected {what}") from None
    if y.size != n or not np.all(np.isfinite(y)):
        raise ParameterError(f"{name} = {y.tolist()!r}: expected {what}")
    return y


def check_positive(value: Any, name: str) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise ParameterError(f"{name} = {value!r}: expected a positive finite number") from None
    if not (math.isfinite(out) and out > 0.0):
        raise ParameterError(f"{name} = {value!r}: expected a positive finite number")
    return out


def check_count(value: Any, name: str, minimum: int = 1) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < minimum:
        raise ParameterError(f"{name} = {value!r}: expected an integer >= {minimum}")
    return int(value)


def check_finite(value: Any, name: str) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise ParameterError(f"{name} = {value!r}: expected a finite number") from None
    if not math.isfinite(out):
        raise ParameterError(f"{name} = {value!r}: expected a finite number")
    return out


def resolve_forcing_period(flow: Flow, period: float | None, who: str) -> float:
    # a fixed-period problem on an autonomous flow is singular (the trivial multiplier 1)
    if is_autonomous(flow):
        raise ParameterError(
            f"{who}: the flow {flow!r} has no forcing (autonomous system): its period is an "
            "unknown; use limit_cycle (or period_guess= with multiple_shooting / collocation)"
        )
    if period is not None:
        return check_positive(period, "period")
    T = flow.period
    if T is None:
        raise ParameterError(
            f"{who}: the flow {flow!r} has no common forcing period (incommensurate "
            "frequencies?): pass period= explicitly"
        )
    return check_positive(T, "flow.period")


# ---------------------------------------------------------------------------------------------
# safeguarded Newton
# ---------------------------------------------------------------------------------------------
Evaluator = Callable[[np.ndarray], tuple[np.ndarray, Any, Any]]


def shooting_newton(
    evaluate: Evaluator,
    z0: np.ndarray,
    *,
    tol: float,
    max_iter: int,
    scale: Callable[[np.ndarray], float],
    what: str,
    admissible: Callable[[np.ndarray], bool] | None = None,
) -> NewtonResult:
    """The safeguarded Newton of the module docstring on ``evaluate(z) -> (r, J, data)``:
    :func:`perturb.numeric.roots.damped_newton` with the shooting solvers' rules (step cap
    ``_MAX_STEP``, halvings down to ``_MIN_ALPHA``, the residual-floor test on the correction),
    shared by single and multiple shooting and collocation.

    Raises
    ------
    ShootingError
        The flow failed or gave a non-finite residual at ``z0``, a singular Newton system, no
        decrease along the Newton direction, or no convergence in ``max_iter`` steps.
    """
    options = NewtonOptions(
        tol=tol,
        max_iter=max_iter,
        scale=scale,
        # the correction is negligible although the residual is above tol: the residual floor
        # of a strongly unstable orbit is ~ eps |M| |y| (rounding amplified by the monodromy),
        # while z itself is determined to tol
        step_tol=tol,
        step_residual_tol=math.sqrt(tol),
        max_step=_MAX_STEP,
        max_halvings=round(-math.log2(_MIN_ALPHA)),
    )
    out = damped_newton(
        evaluate,
        z0,
        options=options,
        admissible=admissible,
        catch=(PerturbError,),  # a trial where the flow fails is a rejected step
    )
    if out.converged:
        return out
    z, rn, it = out.z, out.rnorm, out.iterations
    if out.status == "initial_error":
        raise ShootingError(
            f"{what}: the flow failed at the initial guess {z0.tolist()}: {out.error}",
            math.inf,
            0,
            z0,
        ) from out.error
    if out.status == "initial_nonfinite":
        raise ShootingError(
            f"{what}: non-finite residual at the initial guess {z0.tolist()}", math.inf, 0, z0
        )
    if out.status == "singular":
        raise ShootingError(
            f"{what}: singular Newton system at iteration {it} (residual {rn:.3g})", rn, it, z
        )
    if out.status == "no_decrease":
        raise ShootingError(
            f"{what}: no decrease of the residual along the Newton direction at "
            f"iteration {it + 1} (residual {rn:.3g}, tol {tol:g} x {scale(z):.3g}); "
            "the guess is too far from a periodic orbit, the orbit is degenerate, or "
            "the flow is not accurate enough for this tol",
            rn,
            it,
            z,
        )
    raise ShootingError(
        f"{what} did not converge in {max_iter} iterations: residual {rn:.3g} > tol {tol:g} x "
        f"{scale(z):.3g}",
        rn,
        max_iter,
        z,
    )


def _state_scale(z: np.ndarray) -> float:
    return max(1.0, float(np.max(np.abs(z))))


# ---------------------------------------------------------------------------------------------
# single shooting
# ---------------------------------------------------------------------------------------------
def periodic_orbit(
    flow: Flow,
    y_guess: ArrayLike,
    *,
    period: float | None = None,
    m: int = 1,
    t0: float = 0.0,
    tol: float = 1e-12,
    max_iter: int = 50,
    unit_tol: float = UNIT_TOL,
) -> PeriodicOrbit:
    r"""Period-``m`` orbit of a forced system by single shooting.

    Solves :math:`\varphi_{t_0\to t_0+mT}(y_0) = y_0` by safeguarded Newton with the Jacobian
    :math:`M - I` from the flow's sensitivity (exact, saltation included, for
    :class:`~perturb.simulate.flows.exact.ExactPWLFlow`).

    Parameters
    ----------
    flow
        A forced :class:`~perturb.simulate.flows.base.Flow` of any number of states
        (:func:`state_dimension`).
    y_guess
        Initial state at ``t0``: ``(x, v)``, or the flow's ``n`` states.
    period
        Forcing period :math:`T` (default ``flow.period``).
    m
        Periods of the forcing per orbit period.
    t0
        Phase of the Poincaré section.
    tol
        :math:`\|\varphi(y_0) - y_0\|_\infty \le \text{tol}\max(1, \|y_0\|_\infty)`.
    max_iter
        Newton steps.
    unit_tol
        Distance from the unit circle that marks a bifurcation in :attr:`PeriodicOrbit.stability`.

    Raises
    ------
    ParameterError
        Bad arguments, or a flow without forcing period.
    ShootingError
        No convergence (the message carries the residual reached).

    Examples
    --------
    >>> from perturb.model.builtins import builtin_model
    >>> from perturb.simulate.flows.exact import ExactPWLFlow
    >>> flow = ExactPWLFlow(builtin_model("nsd", k=-2, mu=0.05, F=2, Omega=0.6))
    >>> orb = periodic_orbit(flow, [-3.3, 0.5])
    >>> orb.stability
    'stable'
    """
    flow = check_flow(flow)
    y = _state(y_guess, "y_guess", state_dimension(flow))
    m = check_count(m, "m")
    t0 = check_finite(t0, "t0")
    tol = check_positive(tol, "tol")
    max_iter = check_count(max_iter, "max_iter", 0)
    T = resolve_forcing_period(flow, period, "periodic_orbit")
    P = m * T
    eye = np.eye(y.size)

    def evaluate(yy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        res = flow(yy, t0, t0 + P, sensitivity=True)
        M = np.asarray(res.sensitivity, dtype=float)
        return res.y - yy, M - eye, M

    out = shooting_newton(
        evaluate,
        y,
        tol=tol,
        max_iter=max_iter,
        scale=_state_scale,
        what=f"single shooting (period {m} x {T:.6g})",
    )
    y0 = out.z.copy()
    dense = _FlowDense(flow, y0[None, :], np.array([t0, t0 + P]))
    return PeriodicOrbit.from_solution(
        dense=dense,
        y0=y0,
        t0=t0,
        P=P,
        m=m,
        forcing_period=T,
        monodromy=np.array(out.data, dtype=float),
        residual=out.rnorm,
        iterations=out.iterations,
        method="single shooting",
        unit_tol=unit_tol,
        flow=flow,
    )


def _check_autonomous(flow: Any, who: str) -> None:
    if not is_autonomous(flow):
        raise ParameterError(
            f"{who}: the flow {flow!r} is forced (period {flow.period}): "
            "limit cycles of autonomous systems only; use periodic_orbit for forced orbits"
        )


def reject_equilibrium(flow: Flow, y0: np.ndarray, P: float, what: str, rn: float, it: int):
    f = np.asarray(flow.vector_field(0.0, y0), dtype=float)
    if float(np.max(np.abs(f))) <= 1e-8 * _state_scale(y0):
        raise ShootingError(
            f"{what} converged to an equilibrium y = {y0.tolist()} (vector field "
            f"{f.tolist()}), not a limit cycle: start from a guess on the cycle",
            rn,
            it,
            np.append(y0, P),
        )


#: Largest growth of the state, relative to the guess, that limit-cycle Newton may take.
_RUNAWAY = 100.0


def _settled_start(
    flow: Flow, y: np.ndarray, T0: float, k: int = 1, value: float = 0.0
) -> np.ndarray | None:
    """``(y*, P)`` of the attractor reached from ``y``: 50 guessed periods of transient, then
    two successive crossings of state ``k`` from + to - (for ``(x, v)``, ``k = 1``: maxima of
    ``x``; through ``value`` when given), located by linear interpolation on a 1/64-period
    grid, give the state (state ``k`` set to ``value``) and the period; ``None`` when the
    transient diverges, stops at an equilibrium, or shows no two crossings in 16 periods."""
    try:
        z = np.asarray(flow(y, 0.0, 50.0 * T0).y, dtype=float)
        h = T0 / 64.0
        t, crossings = 50.0 * T0, []
        for _ in range(16 * 64):
            z1 = np.asarray(flow(z, t, t + h).y, dtype=float)
            if not np.all(np.isfinite(z1)):
                return None
            if z[k] - value > 0.0 >= z1[k] - value:
                f = (z[k] - value) / ((z[k] - value) - (z1[k] - value))
                crossings.append((t + f * h, z + f * (z1 - z)))
                if len(crossings) == 2:
                    break
            z, t = z1, t + h
    except (ArithmeticError, ValueError, RuntimeError, PerturbError):
        return None
    if len(crossings) < 2:
        return None
    (t1, _), (t2, y2) = crossings
    if not (t2 - t1 > 0.0 and np.all(np.isfinite(y2))):
        return None
    y2 = np.array(y2, dtype=float)
    y2[k] = value
    return np.append(y2, t2 - t1)


def _phase_index(flow: Any, n: int, phase_state: int | None) -> int:
    """The state held at zero by the phase condition: ``phase_state``, else ``v`` of ``(x, v)``,
    else the velocity of the first coordinate of the flow's system (``system_model``)."""
    if phase_state is not None:
        if isinstance(phase_state, bool) or not isinstance(phase_state, int | np.integer):
            raise ParameterError(f"phase_state = {phase_state!r}: expected a state index")
        if not 0 <= phase_state < n:
            raise ParameterError(
                f"phase_state = {phase_state!r}: expected a state index in 0 .. {n - 1}"
            )
        return int(phase_state)
    if n == 2:
        return 1
    coords = getattr(getattr(flow, "system_model", None), "coordinates", None)
    if coords:
        return len(coords)
    raise ParameterError(
        f"limit_cycle: the flow {flow!r} has {n} states and no declared coordinates: pass "
        "phase_state= (the index of a state that vanishes once per cycle, e.g. a velocity)"
    )


def limit_cycle(
    flow: Flow,
    y_guess: ArrayLike,
    period_guess: float,
    *,
    phase: str = "velocity",
    phase_state: int | None = None,
    phase_value: float = 0.0,
    drift: ArrayLike | None = None,
    tol: float = 1e-12,
    max_iter: int = 50,
    unit_tol: float = UNIT_TOL,
) -> PeriodicOrbit:
    r"""Periodic orbit of an autonomous system, with its unknown period.

    Parameters
    ----------
    flow
        An autonomous flow (``flow.period is None``) of any number of states
        (:func:`state_dimension`): an ODE flow of a smooth system, the event-driven flow of a
        piecewise-smooth one (stick-slip).
    y_guess, period_guess
        Initial state and period.
    phase
        ``"velocity"`` (default): unknowns :math:`(x_0, v_0, T)` with the phase condition
        :math:`v_0 = \dot x(0) = 0`, bordered Newton system (module docstring); the returned
        orbit starts at an extremum of :math:`x`.
        ``"anchor"``: :math:`y_0` = ``y_guess`` is kept fixed and only :math:`T` is solved
        (Gauss–Newton on the two periodicity equations).  This is the method for conservative
        systems, whose orbits come in families (fix :math:`y_0 = (A, 0)` to pick the orbit of
        turning point :math:`A`); for an isolated limit cycle it converges only if ``y_guess``
        lies on it.
    phase_state
        With ``n != 2`` states, the index of the state held at zero by the velocity phase
        condition (default: the velocity of the first coordinate of the flow's
        ``system_model``, e.g. ``x1'``); for ``(x, v)`` it is ``v`` (index 1).
    phase_value
        The value that state is held at (default 0: an extremum of the coordinate). A state
        that stays at 0 over an interval (a velocity while a contact sticks) needs another
        value, one it passes through transversally.
    drift
        A direction ``d`` along which the vector field is invariant (``f(y + s d) = f(y)``:
        the angles of a rotating machine, ``d = (1, 1, 0, 0)`` for the drill string), making
        the orbit periodic up to a shift: :math:`\varphi_T(y_0) = y_0 + \delta d` with an
        unknown :math:`\delta` (one more unknown, and the gauge :math:`d\cdot y_0 =
        d\cdot y_{guess}`). The returned monodromy is then taken modulo the drift
        (:math:`M (I - d d^T/d^T d)`: the drift's trivial multiplier 1 becomes 0), so that the
        multipliers classify the orbit; the shift per period is the flow over one period
        minus ``y0``, along ``d``.
    tol, max_iter, unit_tol
        As in :func:`periodic_orbit`.

    Raises
    ------
    ParameterError
        Bad arguments or a forced flow.
    ShootingError
        No convergence, or convergence to an equilibrium, also after the fallback: when Newton
        from the guess fails (``phase = "velocity"``), the guess is simulated for 50 guessed
        periods and Newton restarts from the maximum of ``x`` and the period measured on the
        settled transient (stable cycles only: an unstable one repels the transient).
    """
    flow = check_flow(flow)
    _check_autonomous(flow, "limit_cycle")
    n = state_dimension(flow)
    y = _state(y_guess, "y_guess", n)
    k = _phase_index(flow, n, phase_state)
    T0 = check_positive(period_guess, "period_guess")
    tol = check_positive(tol, "tol")
    max_iter = check_count(max_iter, "max_iter", 0)
    if phase not in ("velocity", "anchor"):
        raise ParameterError(f"phase = {phase!r}: expected 'velocity' or 'anchor'")
    value = check_finite(phase_value, "phase_value")
    d_vec = None
    if drift is not None:
        d_vec = _state(drift, "drift", n)
        if not np.any(d_vec) or phase != "velocity":
            raise ParameterError(
                f"drift = {d_vec.tolist()!r}: expected a nonzero direction, with phase = 'velocity'"
            )
    eye = np.eye(n)
    what = f"limit cycle shooting (phase = {phase!r})"

    if d_vec is not None:
        gauge = float(d_vec @ y)

        def evaluate(z: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            yy, T, delta = z[:n], z[n], z[n + 1]
            res = flow(yy, 0.0, T, sensitivity=True)
            M = np.asarray(res.sensitivity, dtype=float)
            f = np.asarray(flow.vector_field(T, res.y), dtype=float)
            J = np.zeros((n + 2, n + 2))
            J[:n, :n] = M - eye
            J[:n, n] = f
            J[:n, n + 1] = -d_vec
            J[n, k] = 1.0
            J[n + 1, :n] = d_vec
            r = np.concatenate(
                [res.y - yy - delta * d_vec, [yy[k] - value, float(d_vec @ yy) - gauge]]
            )
            return r, J, M

        z0 = np.concatenate([y, [T0, 0.0]])
    elif phase == "velocity":

        def evaluate(z: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            yy, T = z[:n], z[n]
            res = flow(yy, 0.0, T, sensitivity=True)
            M = np.asarray(res.sensitivity, dtype=float)
            f = np.asarray(flow.vector_field(T, res.y), dtype=float)
            J = np.zeros((n + 1, n + 1))
            J[:n, :n] = M - eye
            J[:n, n] = f
            J[n, k] = 1.0
            return np.append(res.y - yy, yy[k] - value), J, M

        z0 = np.append(y, T0)
    else:
        y_fix = y.copy()

        def evaluate(z: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            res = flow(y_fix, 0.0, z[0], sensitivity=True)
            f = np.asarray(flow.vector_field(z[0], res.y), dtype=float)
            return res.y - y_fix, f[:, None], np.asarray(res.sensitivity, dtype=float)

        z0 = np.array([T0])

    i_period = n if phase == "velocity" else 0

    def solve(z_start: np.ndarray) -> tuple[Any, np.ndarray, float]:
        out = shooting_newton(
            evaluate,
            z_start,
            tol=tol,
            max_iter=max_iter,
            # the residual is a state difference: scale by the state, not the period
            scale=lambda z: _state_scale(z[:n] if phase == "velocity" else y),
            what=what,
            # a positive period, and no run-away: from a poor guess on a relaxation cycle the
            # iterates can double |x| while the period shrinks, each step stiffer than the last
            admissible=lambda z: (
                bool(z[i_period] > 0.0)
                and (phase != "velocity" or _state_scale(z[:n]) <= _RUNAWAY * _state_scale(y))
            ),
        )
        y0 = out.z[:n].copy() if phase == "velocity" else y.copy()
        P = float(out.z[i_period])
        reject_equilibrium(flow, y0, P, what, out.rnorm, out.iterations)
        return out, y0, P

    try:
        out, y0, P = solve(z0)
    except ShootingError as first:
        # Newton's basin shrinks as a cycle turns into a relaxation oscillation (van der Pol
        # at eps >~ 3 from the harmonic guess (2, 0), 2 pi runs into the equilibrium).  A
        # stable cycle attracts the guess, so settle on it by simulation and start again from
        # the measured maximum and period; an unstable cycle or a divergent transient leaves
        # the first error standing.
        if phase != "velocity":
            raise
        start = _settled_start(flow, y, T0, k, value)
        if start is None:
            raise first from None
        if d_vec is not None:  # the settled state, shifted back to the gauge, no drift yet
            start[:n] += d_vec * (gauge - float(d_vec @ start[:n])) / float(d_vec @ d_vec)
            start = np.append(start, 0.0)
        try:
            out, y0, P = solve(start)
        except ShootingError:
            raise first from None
    dense = _FlowDense(flow, y0[None, :], np.array([0.0, P]))
    monodromy = np.array(out.data, dtype=float)
    if d_vec is not None:  # modulo the drift: its trivial multiplier 1 -> 0
        monodromy = monodromy @ (eye - np.outer(d_vec, d_vec) / float(d_vec @ d_vec))
    return PeriodicOrbit.from_solution(
        dense=dense,
        y0=y0,
        t0=0.0,
        P=P,
        m=1,
        forcing_period=None,
        monodromy=monodromy,
        residual=out.rnorm,
        iterations=out.iterations,
        method="single shooting",
        unit_tol=unit_tol,
        flow=flow,
    )


# ---------------------------------------------------------------------------------------------
# multiple shooting
# ---------------------------------------------------------------------------------------------
def multiple_shooting(
    flow: Flow,
    guesses: ArrayLike,
    *,
    period: float | None = None,
    period_guess: float | None = None,
    m: int = 1,
    t0: float = 0.0,
    phase_state: int | None = None,
    tol: float = 1e-12,
    max_iter: int = 50,
    unit_tol: float = UNIT_TOL,
) -> PeriodicOrbit:
    r"""Periodic orbit by multiple shooting on ``N`` equal sub-intervals.

    Parameters
    ----------
    flow
        Forced or autonomous flow.
    guesses : array_like, shape (N, n)
        Guesses of the states (``n`` = :func:`state_dimension` of the flow) at
        :math:`t_i = t_0 + iP/N`, ``i = 0 .. N-1``.
    period
        Forcing period (default ``flow.period``); forced systems only.
    period_guess
        Initial period for autonomous systems (required there, rejected for forced ones).
    m, t0, tol, max_iter, unit_tol
        As in :func:`periodic_orbit` (``m`` and ``t0`` are for forced systems).
    phase_state
        Autonomous systems: the state held at zero at the first node, as in
        :func:`limit_cycle` (default ``v`` of ``(x, v)``, else the velocity of the first
        coordinate of the flow's ``system_model``).

    Notes
    -----
    Autonomous systems use the phase condition :math:`v_0 = 0`, as :func:`limit_cycle`.  The
    Newton system (block bidiagonal with the cyclic block, bordered for autonomous systems) is
    sparse and solved by SuperLU.  The convergence test is on the max-norm of all ``2N``
    continuity residuals.

    Raises
    ------
    ParameterError, ShootingError
        As in :func:`periodic_orbit`.
    """
    flow = check_flow(flow)
    d = state_dimension(flow)
    try:
        Y = np.array(guesses, dtype=float)
    except (TypeError, ValueError):
        raise ParameterError(f"guesses = {guesses!r}: expected an (N, {d}) array") from None
    if Y.ndim != 2 or Y.shape[1] != d or Y.shape[0] < 1:
        raise ParameterError(f"guesses has shape {Y.shape}: expected (N, {d}) with N >= 1")
    if not np.all(np.isfinite(Y)):
        raise ParameterError(f"guesses = {Y.tolist()!r}: expected finite values")
    N = Y.shape[0]
    tol = check_positive(tol, "tol")
    max_iter = check_count(max_iter, "max_iter", 0)
    auto = is_autonomous(flow)
    k = _phase_index(flow, d, phase_state) if auto else 0
    if auto and period is not None:
        raise ParameterError(
            f"period = {period!r} given for an autonomous flow: its period is an unknown; "
            "pass period_guess="
        )
    if auto:
        if period_guess is None:
            raise ParameterError(
                "multiple_shooting: autonomous flow: expected period_guess for the unknown period"
            )
        T0 = check_positive(period_guess, "period_guess")
        m = 1
        t0 = 0.0
        T_forcing = None
    else:
        if period_guess is not None:
            raise ParameterError(
                f"period_guess = {period_guess!r} given for a forced flow: the period is "
                "m x the forcing period; pass period= to override the forcing period"
            )
        m = check_count(m, "m")
        t0 = check_finite(t0, "t0")
        T_forcing = resolve_forcing_period(flow, period, "multiple_shooting")
        T0 = m * T_forcing
    n = d * N
    # static sparsity: -I blocks on the cyclic super-diagonal
    rows_c = np.arange(n)
    cols_c = (np.arange(n) + d) % n

    def evaluate(z: np.ndarray) -> tuple[np.ndarray, Any, list[np.ndarray]]:
        P = z[-1] if auto else T0
        nodes = z[:n].reshape(N, d)
        h = P / N
        r = np.empty(n + (1 if auto else 0))
        blocks = []
        fcol = np.empty(n) if auto else None
        for i in range(N):
            a = t0 + i * h
            res = flow(nodes[i], a, a + h, sensitivity=True)
            Mi = np.asarray(res.sensitivity, dtype=float)
            blocks.append(Mi)
            r[d * i : d * i + d] = res.y - nodes[(i + 1) % N]
            if auto:
                fcol[d * i : d * i + d] = np.asarray(flow.vector_field(a + h, res.y)) / N
        diag = sps.block_diag(blocks, format="coo")
        rows = [diag.row, rows_c]
        cols = [diag.col, cols_c]
        vals = [diag.data, -np.ones(n)]
        size = n
        if auto:
            r[n] = nodes[0, k]
            rows += [np.arange(n), np.array([n])]
            cols += [np.full(n, n), np.array([k])]
            vals += [fcol, np.array([1.0])]
            size = n + 1
        J = sps.csc_matrix(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
            shape=(size, size),
        )
        return r, J, blocks

    z0 = np.append(Y.ravel(), T0) if auto else Y.ravel().copy()
    what = f"multiple shooting ({N} nodes)"
    out = shooting_newton(
        evaluate,
        z0,
        tol=tol,
        max_iter=max_iter,
        scale=lambda z: _state_scale(z[:n]),
        what=what,
        admissible=(lambda z: bool(z[-1] > 0.0)) if auto else None,
    )
    nodes = out.z[:n].reshape(N, d).copy()
    P = float(out.z[-1]) if auto else T0
    if auto:
        reject_equilibrium(flow, nodes[0], P, what, out.rnorm, out.iterations)
    M = np.eye(d)
    for Mi in out.data:
        M = Mi @ M
    times = t0 + P * np.arange(N + 1) / N
    times[-1] = t0 + P
    dense = _FlowDense(flow, nodes, times)
    return PeriodicOrbit.from_solution(
        dense=dense,
        y0=nodes[0].copy(),
        t0=t0,
        P=P,
        m=m,
        forcing_period=T_forcing,
        monodromy=M,
        residual=out.rnorm,
        iterations=out.iterations,
        method="multiple shooting",
        unit_tol=unit_tol,
        nodes=nodes,
        flow=flow,
    )
