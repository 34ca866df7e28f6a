"""The shooting problem of the exact frequency response: a continuation point in
shooting coordinates (``Pt``), one propagated iterate (``Eval``), the node count from the
Floquet growth, and the evaluation of the flow family (``Engine``: residual, Jacobian,
parameter derivative, orbit statistics and signatures; the quintic Hermite extremum of x).

Part of :mod:`perturb.simulate.exact_response` (the method is described there).
"""

from __future__ import annotations

import bisect
import cmath
import math
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.integrate import solve_ivp

from perturb.errors import ParameterError, PerturbError
from perturb.simulate.exact_response.base import (
    MAX_MULTIPLIER,
    MAX_NODES,
    NODE_GROWTH,
    SIG_PHASES,
    STAT_SAMPLES,
)
from perturb.simulate.flows.base import ODEFlow
from perturb.simulate.flows.factory import FlowFamily
from perturb.simulate.flows.piecewise_exact import sample_trajectories
from perturb.simulate.flows.scan_kernel import compiled_kernel
from perturb.simulate.flows.scan_kernel import disable as disable_kernel
from perturb.simulate.flows.system import frequency_symbol
from perturb.simulate.orbits.shooting import (
    monodromy_multipliers,
)


# =============================================================================================
# internal point record and evaluation
# =============================================================================================
class Pt:
    """A converged point while tracing (mutable; frozen into ContinuationPoint at the end)."""

    __slots__ = (
        "p",
        "Z",
        "J",
        "mult",
        "stats",
        "sig",
        "switches",
        "mode",
        "seg",
        "tangent",
        "singular",
        "grazing",
        "source",
        "blocks",
        "fold",
        "extra",
        "_zmax",
    )

    def __init__(self, p: float, Z: np.ndarray, n: int = 2) -> None:
        self.p = float(p)
        # n states per node: (x, v) of an oscillator, the state of a System
        self.Z = np.array(Z, dtype=float).reshape(-1, n)
        # max |Z| for R, asked for by every proximity test (Z is never changed in place)
        self._zmax = float(np.max(np.abs(self.Z)))
        self.J: np.ndarray | None = None  # [G_z | G_p], unscaled, at (or next to) the point
        self.mult = np.zeros(n, dtype=complex)
        self.stats = (0.0, 0.0, 0.0)  # amplitude, first harmonic, mean (of the output)
        self.sig = np.zeros(n * SIG_PHASES)  # states at SIG_PHASES phases per forcing period
        # systems: (max |q_k|, mean q_k) of every coordinate, arrays; None for an oscillator
        self.extra: tuple[np.ndarray, np.ndarray] | None = None
        self.switches = -1
        self.mode = "shoot"  # or "closed"
        self.seg = -1
        self.tangent: np.ndarray | None = None  # unit tangent in scaled (Z, p), oriented
        self.singular = False
        self.grazing = False
        self.source = "shooting"
        self.blocks: list[np.ndarray] | None = None  # node sensitivities (branch switching)
        self.fold = False  # a refined fold (dp/ds = 0), inserted between two sampled points

    @property
    def N(self) -> int:
        return self.Z.shape[0]

    @property
    def y0(self) -> np.ndarray:
        return self.Z[0]

    @property
    def R(self) -> float:
        return max(1.0, self._zmax, self.stats[0])

    @property
    def max_mult(self) -> float:
        return float(min(MAX_MULTIPLIER, np.max(np.abs(self.mult))))

    def D(self, Sp: float) -> np.ndarray:
        """Scales of (Z, p): a unit step is the orbit size (shared by the N nodes) or the
        window."""
        out = np.full(self.Z.size + 1, self.R * math.sqrt(self.N))
        out[-1] = Sp
        return out

    def u(self) -> np.ndarray:
        return np.append(self.Z.ravel(), self.p)

    def tangent3(self) -> np.ndarray:
        """The tangent's components on ``(y0, p)`` (the first node and the parameter),
        normalised: ``(x0, v0, p)`` for an oscillator."""
        t = self.tangent
        n = self.Z.shape[1]
        if t is None:
            return np.zeros(n + 1)
        v = np.array([t[0], t[1], t[-1]]) if n == 2 else np.append(t[:n], t[-1])
        n = np.linalg.norm(v)
        return v / n if n > 0 else v

    def keys(self, m: int) -> list[np.ndarray]:
        """The key of every representation of a period-``m`` orbit: its initial state taken
        after 0, 1, .., m-1 forcing periods (the signature shifted by whole periods)."""
        if m == 1:
            return [self.key()]
        phases = self.sig.reshape(-1, self.Z.shape[1])
        tail = np.concatenate((self.stats, (self.p, self.R)))
        return [
            np.concatenate((np.roll(phases, -j * SIG_PHASES, axis=0).ravel(), tail))
            for j in range(m)
        ]

    def key(self) -> np.ndarray:
        """``(signature, amplitude, first harmonic, mean, p, R)``: what proximity tests
        compare.  The state at several phases and the orbit's extremes separate orbits that a
        strongly unstable flow maps from nearly equal initial states (their ``y0`` can be
        0.5 % apart while the orbits differ by O(1)), and quasi-static orbits at low
        frequency that agree at most phases and differ in a short excursion."""
        return np.concatenate((self.sig, self.stats, (self.p, self.R)))


@dataclass
class Eval:
    r: np.ndarray
    Gz: np.ndarray
    Gp: np.ndarray | None
    M: np.ndarray
    switches: int
    blocks: list[np.ndarray]
    trajs: list[Any] | None
    eig: np.ndarray | None = None

    def eigenvalues(self) -> np.ndarray:
        """``numpy.linalg.eigvals`` of the monodromy, once: the corrector's acceptance test
        (:meth:`node_growth`) and the accepted point's multipliers (:meth:`Engine.finish`)
        both need them."""
        if self.eig is None:
            self.eig = np.linalg.eigvals(self.M)
        return self.eig

    def node_growth(self, N: int) -> float:
        """:func:`node_growth` of the monodromy."""
        return node_growth(self.M, N, self.eigenvalues if self.M.shape[0] != 2 else None)


def node_growth(M: np.ndarray, N: int, eigenvalues: Any = None) -> float:
    """Growth of a perturbation over one of ``N`` node intervals, from the monodromy
    (``eigenvalues``: a function giving those of ``M``, when already known)."""
    if M.shape[0] != 2:
        # n states: the spectral radius itself
        try:
            mu = np.linalg.eigvals(M) if eigenvalues is None else eigenvalues()
            rho = float(np.max(np.abs(mu)))
        except np.linalg.LinAlgError:
            return NODE_GROWTH
        return max(1.0, rho) ** (1.0 / N) if math.isfinite(rho) else NODE_GROWTH
    tr = abs(float(M[0, 0] + M[1, 1]))
    det = abs(float(M[0, 0] * M[1, 1] - M[0, 1] * M[1, 0]))
    rho = 0.5 * (tr + math.sqrt(tr * tr + 4.0 * det))  # bounds the spectral radius
    return max(1.0, rho) ** (1.0 / N) if math.isfinite(rho) else NODE_GROWTH


def nodes_needed(max_mult: float, m: int) -> int:
    """Shooting nodes for an orbit: a growth of at most NODE_GROWTH per node, and a node at
    every forcing period."""
    k = 1
    if max_mult > NODE_GROWTH:
        k = int(math.ceil(math.log(min(max_mult, MAX_MULTIPLIER)) / math.log(NODE_GROWTH)))
    n = max(m, k)
    n = int(math.ceil(n / m) * m)
    return min(n, MAX_NODES * m)


class Engine:
    """Flows, residuals, Jacobians and the work counter of one continuation problem."""

    def __init__(
        self,
        family: FlowFamily,
        m: int,
        t0: float,
        window: tuple[float, float],
        tol: float,
        output: np.ndarray | None = None,
    ) -> None:
        self.family = family
        self.m = int(m)
        self.t0 = float(t0)
        self.lo, self.hi = window
        self.Sp = self.hi - self.lo
        self.tol = tol
        self.periods = 0.0
        self.calls = 0
        self._flows: OrderedDict[float, Any] = OrderedDict()
        self.exact = bool(family.exact)
        # a System of n states (None: an oscillator, the (x, v) code paths below)
        self.model_system = getattr(family, "system", None)
        self.n = int(getattr(family, "n_states", 2))
        self.nd = self.model_system is not None
        if self.nd:
            # the forcing frequency must stay positive (other parameters may change sign)
            self.positive = family.parameter == "Omega" or family._scaled is not None
            name = self.model_system.name
            self._nd_setup(output)
        else:
            self.output = None  # an oscillator's statistics are those of x
            sym = frequency_symbol(family.oscillator)
            self.positive = sym is not None and sym.name == family.parameter
            name = family.oscillator.name
        probe = self.flow(0.5 * (self.lo + self.hi))
        if getattr(probe, "period", None) is None:
            raise ParameterError(
                f"the flow of {name!r} has no forcing period: continuation of "
                "forced orbits needs a periodic forcing"
            )
        self.system0 = getattr(probe, "system", None)
        if self.nd:
            self._continuous = False
            self._dw = None
            self.closed_form = False
            self.affine0 = getattr(probe, "affine_system", None)
            # the exact parameter rate needs fixed regions and frequencies proportional to p
            scaled = getattr(family, "_scaled", None)
            self._nd_rates = None if scaled is None or self.affine0 is None else scaled[1]
            self._modal: dict[tuple[int, ...], tuple[np.ndarray, ...] | None] = {}
            self._rate_cache: dict[tuple[Any, ...], tuple[Any, ...] | None] = {}
            self._rate_sources: dict[tuple[int, ...], tuple[list, float]] = {}
            return
        # own sensitivities from the trajectory pieces where saltation is the identity
        self._continuous = self.exact and bool(np.all(self.system0.continuous_at()))
        self._dw = self._frequency_rates() if self.exact else None
        self.closed_form = self.exact and self.m == 1 and bool(self.system0.forcing)

    # -- flows ---------------------------------------------------------------------------------
    def flow(self, p: float) -> Any:
        key = float(p)
        f = self._flows.get(key)
        if f is None:
            f = self.family.at(key)
            self._flows[key] = f
            if len(self._flows) > 24:
                self._flows.popitem(last=False)
        else:
            self._flows.move_to_end(key)
        return f

    def system(self, p: float) -> Any:
        return self.flow(p).system

    def period(self, p: float) -> float:
        return float(self.flow(p).period)

    def _frequency_rates(self) -> np.ndarray | None:
        """d omega_j / dp when p enters the PWL system only through the forcing frequencies,
        linearly and proportionally, and the force is continuous; else None (forward
        differences)."""
        try:
            vals = [self.lo, 0.5 * (self.lo + self.hi), self.hi]
            systems = [self.family.at(v).system for v in vals]
        except PerturbError:
            return None
        s0 = systems[1]
        if not np.all(s0.continuous_at()) or not s0.forcing:
            return None
        for s in systems:
            same = (
                np.array_equal(s.breakpoints, s0.breakpoints)
                and np.array_equal(s.slopes, s0.slopes)
                and np.array_equal(s.offsets, s0.offsets)
                and s.damping == s0.damping
                and s.static_force == s0.static_force
                and len(s.forcing) == len(s0.forcing)
                and all(
                    a[0] == b[0] and a[2] == b[2]
                    for a, b in zip(s.forcing, s0.forcing, strict=True)
                )
            )
            if not same:
                return None
        w = np.array([[f[1] for f in s.forcing] for s in systems])
        slope = (w[2] - w[0]) / (vals[2] - vals[0])
        # linear in p (so the rate is constant) and proportional (the period scales with it)
        mid = w[0] + slope * (vals[1] - vals[0])
        if not np.allclose(mid, w[1], rtol=1e-12, atol=0.0) or np.any(slope == 0.0):
            return None
        rel = slope / w[1]
        if not np.allclose(rel, rel[0], rtol=1e-10, atol=0.0):
            return None
        return slope

    # -- residual ------------------------------------------------------------------------------
    def node_times(self, P: float, N: int) -> np.ndarray:
        t = self.t0 + P * np.arange(N + 1) / N
        t[-1] = self.t0 + P
        return t

    def evaluate(self, Z: np.ndarray, p: float, gp: bool = True) -> Eval:
        """Residual, Jacobians, monodromy and switches of the multiple-shooting problem.

        For a continuous PWL force the node sensitivities are assembled here from the
        trajectory's pieces (products of the exact exponentials; saltation is the identity),
        together with the parameter rate, so the exponentials are computed once."""
        flow = self.flow(p)
        P = self.m * float(flow.period)
        N = Z.shape[0]
        n = self.n
        tn = self.node_times(P, N)
        r = np.empty(n * N)
        Gz = np.zeros((n * N, n * N))
        own = self._continuous
        Gp = np.empty(2 * N) if (gp and self._dw is not None) else None
        if gp and self.nd and self._nd_rates is not None:
            Gp = np.empty(n * N)
            dP = -P / p  # the period is inversely proportional to p
            pas = flow.affine_system
        M = np.eye(n)
        blocks = []
        trajs: list[Any] | None = [] if self.exact else None
        switches = 0
        if not self.nd:
            dP = -P * self._dw[0] / flow.system.forcing[0][1] if Gp is not None else 0.0
        self.periods += self.m
        self.calls += N
        system = flow.system if own else None
        for i in range(N):
            ta, tb = tn[i], tn[i + 1]
            if own:
                # the trajectory itself (its end state and switches), without the flow's
                # result object: a continuous force needs no saltation, and the sensitivity
                # comes from the pieces below
                traj = flow.trajectory(Z[i], ta, tb)
                trajs.append(traj)
                yb = np.array([traj.x[-1], traj.v[-1]], dtype=float)
                n_ev = sum(1 for e in traj.events if not e.tangency)
                Mi, zeta = self._pieces(flow, traj, tb, Gp is not None)
            else:
                res = flow(Z[i], ta, tb, sensitivity=True)
                if trajs is not None:
                    trajs.append(flow.trajectory(Z[i], ta, tb))  # memoised: no propagation
                yb, n_ev = res.y, res.n_events
                Mi, zeta = np.asarray(res.sensitivity, dtype=float), None
                if Gp is not None and self.nd:
                    zeta = self._nd_rate(pas, trajs[-1], float(tb), p)
            blocks.append(Mi)
            j = (i + 1) % N
            r[n * i : n * i + n] = yb - Z[j]
            Gz[n * i : n * i + n, n * i : n * i + n] += Mi
            for k in range(n):
                Gz[n * i + k, n * j + k] -= 1.0
            M = Mi @ M
            switches += int(n_ev)
            if Gp is not None:
                if zeta is None:
                    Gp = None
                elif self.nd:
                    fb = pas.field(float(tb), yb)
                    fa = pas.field(float(ta), Z[i])
                    Gp[n * i : n * i + n] = zeta + fb * ((i + 1) / N) * dP - Mi @ fa * (i / N) * dP
                else:
                    # the field at both ends (scalar: the same values as vector_field)
                    fb = np.array(system.field1(float(tb), float(yb[0]), float(yb[1])))
                    fa = np.array(system.field1(float(ta), float(Z[i, 0]), float(Z[i, 1])))
                    Gp[2 * i : 2 * i + 2] = zeta + fb * ((i + 1) / N) * dP - Mi @ fa * (i / N) * dP
        if not np.all(np.isfinite(M)):
            raise PerturbError("the monodromy overflows: the orbit is too unstable for its nodes")
        return Eval(r, Gz, Gp, M, switches if self.exact else -1, blocks, trajs)

    def gp_fd(self, Z: np.ndarray, p: float, r: np.ndarray) -> np.ndarray:
        """Forward difference of G in p (one propagation without sensitivity).  The step
        balances truncation against the flow's own error: ~sqrt(rtol) for an integrator,
        1e-7 (~sqrt(eps)) for the exact flow."""
        rtol = float(getattr(self.flow(p), "rtol", 0.0))
        h = max(1e-7, 3.0 * math.sqrt(rtol)) * max(1.0, abs(p))
        flow = self.flow(p + h)
        P = self.m * float(flow.period)
        N = Z.shape[0]
        n = self.n
        tn = self.node_times(P, N)
        rh = np.empty(n * N)
        for i in range(N):
            rh[n * i : n * i + n] = flow(Z[i], tn[i], tn[i + 1]).y - Z[(i + 1) % N]
        self.periods += self.m
        self.calls += N
        return (rh - r) / h

    @staticmethod
    def _samples(flow: Any, y: np.ndarray, a: float, b: float, t: np.ndarray) -> np.ndarray:
        """States at times ``t`` in [a, b]: one integration with dense output for an ODE flow
        (its ``t_eval`` would integrate twice), else the flow's own sampling."""
        rhs = getattr(flow, "rhs", None)
        if isinstance(flow, ODEFlow) and rhs is not None:
            sol = solve_ivp(
                rhs.fun,
                (a, b),
                y,
                method="DOP853",
                rtol=flow.rtol,
                atol=flow.atol,
                dense_output=True,
            )
            if sol.status == 0:
                return sol.sol(t)
        return np.asarray(flow(y, a, b, t_eval=t).ys).T

    def _pieces(
        self, flow: Any, traj: Any, tb: float, want_rate: bool
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """Sensitivity ``d y(tb) / d y(ta)`` (continuous force) and, on request, the exact
        parameter rate ``d phi / dp`` at fixed times (frequency parameter), from the
        trajectory's pieces; see the module docstring.  Scalar arithmetic throughout: a node
        interval has a handful of pieces, where array code is mostly call overhead."""
        sys_ = flow.system
        mu = float(sys_.damping)
        pieces = traj.pieces
        n = len(pieces)
        E = traj.transition_matrices()
        m00, m01, m10, m11 = E[0]
        for e00, e01, e10, e11 in E[1:]:
            m00, m01, m10, m11 = (
                e00 * m00 + e01 * m10,
                e00 * m01 + e01 * m11,
                e10 * m00 + e11 * m10,
                e10 * m01 + e11 * m11,
            )
        M = np.array([[m00, m01], [m10, m11]])
        if not want_rate:
            return M, None
        a = [q.t0 for q in pieces]
        b = a[1:] + [float(tb)]
        slopes = [float(sys_.slopes[q.segment]) for q in pieces]
        inc0 = [0.0] * n
        inc1 = [0.0] * n
        for (F, w, ph), dw in zip(sys_.forcing, self._dw, strict=True):
            if F == 0.0:
                continue
            cF = 1j * F * float(dw) * cmath.exp(1j * ph)
            ww = w * w
            for k in range(n):
                sk = slopes[k]
                det = complex(sk - ww, mu * w)
                if abs(det) < 1e-12 * (abs(sk) + ww):
                    return M, None  # undamped resonance in a segment: no particular solution
                c = cF / det
                # zeta_p(t) = Re[(R t - R^2) e2 c' e^{iwt}], R e2 = (1, iw)/det,
                # R^2 e2 = (2iw + mu, -s - w^2)/det^2  (c' = c det)
                ak, bk = a[k], b[k]
                ea, eb = cmath.exp(1j * w * ak), cmath.exp(1j * w * bk)
                q0 = (2j * w + mu) / det
                q1 = (-sk - ww) / det
                za0 = c * (ak - q0) * ea
                za1 = c * (1j * w * ak - q1) * ea
                zb0 = c * (bk - q0) * eb
                zb1 = c * (1j * w * bk - q1) * eb
                e00, e01, e10, e11 = E[k]
                inc0[k] += (zb0 - e00 * za0 - e01 * za1).real
                inc1[k] += (zb1 - e10 * za0 - e11 * za1).real
        z0 = z1 = 0.0
        for k in range(n):
            e00, e01, e10, e11 = E[k]
            z0, z1 = e00 * z0 + e01 * z1 + inc0[k], e10 * z0 + e11 * z1 + inc1[k]
        if not (math.isfinite(z0) and math.isfinite(z1)):
            return M, None
        return M, np.array([z0, z1])

    # -- orbit data ----------------------------------------------------------------------------
    def finish(self, pt: Pt, ev: Eval, Zev: np.ndarray, p_ev: float) -> None:
        """Multipliers, statistics, signature and switches of a converged point, from the
        evaluation at ``(Zev, p_ev)``, the last propagated iterate (its trajectories are
        reused: the statistics cost no propagation)."""
        flow = self.flow(p_ev)
        P = self.m * float(flow.period)
        if self.nd:
            # (monodromy_multipliers for n states: eigvals by decreasing modulus)
            mu = ev.eigenvalues().astype(complex)
            pt.mult = mu[np.argsort(-np.abs(mu), kind="stable")]
            pt.switches = ev.switches
            pt.stats, pt.extra, pt.sig = self.nd_statistics(flow, Zev, P, ev.trajs)
            pt.J = None
            pt.blocks = ev.blocks
            pt.source = "multiple shooting" if pt.N > 1 else "shooting"
            return
        det = flow.sensitivity_determinant(self.t0, self.t0 + P)  # None: not known exactly
        pt.mult = monodromy_multipliers(ev.M, det)
        pt.switches = ev.switches
        *stats, sig = self.statistics(flow, Zev, P, ev.trajs)
        pt.stats = tuple(stats)
        pt.sig = sig
        pt.J = None
        pt.blocks = ev.blocks
        pt.source = "multiple shooting" if pt.N > 1 else "shooting"

    def statistics(
        self, flow: Any, Z: np.ndarray, P: float, trajs: list[Any] | None = None
    ) -> tuple[float, float, float, np.ndarray]:
        """(max |x|, first-harmonic amplitude, mean, signature) over one orbit period.

        Mean and first harmonic by the FFT of ``STAT_SAMPLES`` samples per forcing period,
        the signature from every ``STAT_SAMPLES / SIG_PHASES``-th of them, the extrema of x
        refined between the samples."""
        m, N = self.m, Z.shape[0]
        n = STAT_SAMPLES * m
        t = self.t0 + P * np.arange(n + 1) / n
        node_t = self.node_times(P, N)
        idx = np.clip(np.searchsorted(node_t, t, side="right") - 1, 0, N - 1)
        if trajs is None and self.exact:
            trajs = [flow.trajectory(Z[i], node_t[i], node_t[i + 1]) for i in range(N)]
        if trajs is not None:
            # one vectorised evaluation per segment of the force over all node intervals
            X = sample_trajectories(trajs, np.clip(t, node_t[idx], node_t[idx + 1]), idx)
        else:
            X = np.empty((2, n + 1))
            for i in range(N):
                sel = idx == i
                if not np.any(sel):
                    continue
                a, b = node_t[i], node_t[i + 1]
                X[:, sel] = self._samples(flow, Z[i], a, b, np.clip(t[sel], a, b))
                self.periods += self.m / N
                self.calls += 1
        x = X[0, :n]
        c = np.fft.rfft(x) / n
        mean = float(c[0].real)
        first = float(2.0 * abs(c[m])) if m < c.size else 0.0
        sig = X[:, : n : STAT_SAMPLES // SIG_PHASES].T.ravel().copy()
        # extrema of x: the quintic Hermite interpolant of (x, v, a) on the sample interval
        # where v changes sign next to the extreme sample, O(h^6) (~1e-10 relative); the
        # stored orbit differs from the sampled one by up to STATS_TOL anyway
        best = [float(x.max()), float(x.min())]
        for which, sign in enumerate((1.0, -1.0)):
            j = int(np.argmax(sign * x))
            for a_i, b_i in (((j - 1) % n, j), (j, j + 1)):
                ta, tb = t[a_i], t[b_i]
                if not (sign * X[1, a_i] >= 0.0 >= sign * X[1, b_i] and tb > ta):
                    continue
                xr = self._reversal_extremum(flow, ta, tb, X[:, a_i], sign)
                if xr is None:
                    xr = self._hermite_extremum(flow, ta, tb, X[:, a_i], X[:, b_i], sign)
                if sign * xr > sign * best[which]:
                    best[which] = xr
        return max(abs(best[0]), abs(best[1])), first, mean, sig

    # -- systems of n states ----------------------------------------------------------------------
    def _region_modes(self, pas: Any, key: tuple[int, ...]) -> tuple[np.ndarray, ...] | None:
        """``(A, lambda, V, V^-1)`` of a region (fixed over the family), None when its
        eigenvectors are ill conditioned (the parameter rate then falls back to differences)."""
        if key in self._modal:
            return self._modal[key]
        A = np.asarray(pas.region(key).A, dtype=float)
        out = None
        try:
            lam, V = np.linalg.eig(A)
            if np.linalg.cond(V) < 1e8:
                out = (A, lam, V, np.linalg.inv(V))
        except np.linalg.LinAlgError:
            out = None
        self._modal[key] = out
        return out

    def _rate_terms(
        self, pas: Any, key: tuple[int, ...], omegas: tuple[float, ...]
    ) -> tuple[Any, ...] | None:
        """``(lambda, V, V^-1, ((omega_k, w1_k, w2_k), ...))`` of region ``key`` at the input
        frequencies ``omegas`` of ``pas`` (:meth:`_nd_rate`: ``w1 = V c / (i omega - lambda)``,
        ``w2 = V c / (i omega - lambda)^2``), None when the region is ill conditioned or
        resonant.

        Cached per (region, frequencies): a Newton iterate visits each region once or twice
        per node interval, at one frequency, so the sources are computed once per iterate
        and region instead of once per piece (same arithmetic as per piece)."""
        ck = (key, omegas)
        cache = self._rate_cache
        if ck in cache:
            return cache[ck]
        modes = self._region_modes(pas, key)
        out = None
        if modes is not None:
            _, lam, V, Vinv = modes
            # the modal sources V^-1 c_k do not depend on the frequencies: once per region
            src = self._rate_sources.get(key)
            if src is None:
                src = self._rate_sources[key] = (
                    [
                        Vinv @ (1j * rk * (h.u - 1j * h.v))
                        for h, rk in zip(pas.inputs, self._nd_rates, strict=True)
                    ],
                    float(np.max(np.abs(lam))),
                )
            forced = []
            for h, c in zip(pas.inputs, src[0], strict=True):
                w = h.omega
                den = 1j * w - lam
                if np.min(np.abs(den)) <= 1e-12 * max(1.0, w, src[1]):
                    forced = None  # undamped resonance in a region: no particular solution
                    break
                q = c / den
                forced.append((w, V @ q, V @ (q / den)))
            if forced is not None:
                out = (lam, V, Vinv, tuple(forced))
        if len(cache) >= 64:
            cache.clear()  # one continuation step needs a few entries
        cache[ck] = out
        return out

    def _nd_rate(self, pas: Any, traj: Any, tb: float, p: float) -> np.ndarray | None:
        r"""``d phi / dp`` at fixed times over one node interval of the exact affine flow, the
        parameter scaling the input frequencies (:math:`\omega_k = r_k p`): on each piece
        (region :math:`A`, :math:`[a, b]`) the rate obeys :math:`\zeta' = A\zeta +
        \operatorname{Re}\sum_k c_k t e^{i\omega_k t}`, :math:`c_k = i r_k (u_k - i v_k)`,
        with the particular solution :math:`\operatorname{Re}[(R t - R^2) c_k e^{i\omega_k
        t}]`, :math:`R = (i\omega_k I - A)^{-1}` (the oscillator's formula, module docstring),
        so a piece adds :math:`\zeta_p(b) - e^{A(b-a)}\zeta_p(a)`; a crossing of a
        discontinuous surface applies its saltation matrix.  None when a region is ill
        conditioned or resonant (forward differences instead)."""
        starts = traj.starts
        keys = traj.patterns
        cross = [e for e in traj.events if not e.tangency]
        if len(cross) != len(keys) - 1:
            return None
        n = self.n
        zeta = np.zeros(n)
        omegas = tuple(h.omega for h in pas.inputs)
        reuse = getattr(traj, "transition", None)
        for k, key in enumerate(keys):
            terms = self._rate_terms(pas, key, omegas)
            if terms is None:
                return None
            lam, V, Vinv, forced = terms
            a = float(starts[k])
            b = float(starts[k + 1]) if k + 1 < len(keys) else tb
            # the flow's sensitivity computed the same product from the same decomposition
            # of the same A (np.linalg.eig, inv): reused, else computed here
            E = reuse(k, b - a) if reuse is not None else None
            if E is None:
                E = ((V * np.exp(lam * (b - a))) @ Vinv).real
            if len(forced) == 1:
                # (one input, the common case: scalar phases, one product with E)
                w, w1, w2 = forced[0]
                za = ((w1 * a - w2) * cmath.exp(complex(0.0, w * a))).real
                zb = ((w1 * b - w2) * cmath.exp(complex(0.0, w * b))).real
                zeta = E @ (zeta - za) + zb
            else:
                inc = np.zeros(n)
                for w, w1, w2 in forced:
                    za = ((w1 * a - w2) * np.exp(1j * w * a)).real
                    zb = ((w1 * b - w2) * np.exp(1j * w * b)).real
                    inc += zb - E @ za
                zeta = E @ zeta + inc
            if k + 1 < len(keys):
                ev = cross[k]
                j = ev.surface
                if not pas.continuous[j]:
                    u = sum(
                        (
                            q.u * math.cos(q.omega * ev.time) + q.v * math.sin(q.omega * ev.time)
                            for q in pas.inputs
                        ),
                        np.zeros(n),
                    )
                    rb, ra = pas.region(ev.pattern_before), pas.region(ev.pattern_after)
                    fm = rb.A @ ev.y + rb.b + u
                    fp = ra.A @ ev.y + ra.b + u
                    cj = pas.surfaces[j].normal
                    rate = float(cj @ fm)
                    if rate == 0.0:
                        return None
                    zeta = zeta + (fp - fm) * float(cj @ zeta) / rate
        return zeta if np.all(np.isfinite(zeta)) else None

    def _nd_setup(self, output: np.ndarray | None) -> None:
        """The functionals whose statistics a point carries: the output ``c . y`` (default:
        the first coordinate) and every coordinate (second-order coordinates and first-order
        states; velocities are not coordinates)."""
        system = self.model_system
        n, n2 = self.n, len(system.coordinates)
        self.coordinate_names = (*system.coordinates, *system.first_order)
        self.coordinate_index = np.array([*range(n2), *range(2 * n2, n)], dtype=int)
        if output is None:
            c = np.zeros(n)
            c[0] = 1.0
        else:
            c = np.asarray(output, dtype=float).reshape(-1)
            if c.shape != (n,) or not np.all(np.isfinite(c)) or not np.any(c):
                raise ParameterError(
                    f"output = {np.asarray(output).tolist()!r}: expected {n} finite numbers, "
                    f"not all zero (a combination of {', '.join(system.state_names)})"
                )
        self.output = c
        rows = [c] + [np.eye(n)[k] for k in self.coordinate_index]
        # the output row again when it is a coordinate: computed once
        self._funcs = np.array(rows)
        same = [k for k in range(1, len(rows)) if np.array_equal(rows[k], c)]
        self._out_is = same[0] if same else None

    def _nd_field(self, flow: Any, t: np.ndarray, X: np.ndarray) -> np.ndarray:
        """The vector field at the samples ``(t_j, X[:, j])``: vectorised per region for the
        exact affine flow, one call per sample otherwise."""
        pas = getattr(flow, "affine_system", None)
        if pas is None:
            return np.array([flow.vector_field(float(tj), X[:, j]) for j, tj in enumerate(t)]).T
        F = np.empty_like(X)
        if pas.surfaces:
            C = np.array([q.normal for q in pas.surfaces])
            d = np.array([q.offset for q in pas.surfaces])
            signs = (C @ X - d[:, None]) >= 0.0  # s = 0 counts as +1, as pattern() does
            code = signs.T @ (1 << np.arange(len(d)))
        else:
            signs = np.zeros((0, X.shape[1]), dtype=bool)
            code = np.zeros(X.shape[1], dtype=int)
        for cval in np.unique(code):
            sel = code == cval
            j = int(np.flatnonzero(sel)[0])
            key = tuple(1 if sg else -1 for sg in signs[:, j])
            reg = pas.region(key)
            F[:, sel] = reg.A @ X[:, sel] + reg.b[:, None]
        for h in pas.inputs:
            F += np.outer(h.u, np.cos(h.omega * t)) + np.outer(h.v, np.sin(h.omega * t))
        return F

    def nd_statistics(
        self, flow: Any, Z: np.ndarray, P: float, trajs: list[Any] | None = None
    ) -> tuple[tuple[float, float, float], tuple[np.ndarray, np.ndarray], np.ndarray]:
        """Statistics of an orbit of a System over one orbit period: ``(max |c.y|, first
        harmonic of c.y, mean of c.y)`` for the output ``c``, ``(max |q_k|, mean q_k)`` of every
        coordinate, and the signature (every state at ``SIG_PHASES`` phases per period).

        ``STAT_SAMPLES`` samples per forcing period (exact dense output for the affine flow);
        each extremum is then located in its bracketing sample interval as the root of the
        derivative of the cubic Hermite interpolant of the values and rates (``c . f``, the
        vector field at the samples) and the state there evaluated on the orbit itself (the
        exact trajectory, or a short flow call), so the value is exact up to the square of the
        location error (~1e-11 relative); a few regula-falsi steps on the rate follow when
        that error estimate is larger (a switch inside the interval)."""
        m, N, n = self.m, Z.shape[0], self.n
        ns = STAT_SAMPLES * m
        t = self.t0 + P * np.arange(ns + 1) / ns
        node_t = self.node_times(P, N)
        if trajs is None and self.exact:
            trajs = [flow.trajectory(Z[i], node_t[i], node_t[i + 1]) for i in range(N)]
        got_c = self._compiled_statistics(trajs, t, node_t, ns, P) if N == 1 else None
        if got_c is not None:
            return got_c
        X = np.empty((n, ns + 1))
        # the exact affine flow: states and rates from the closed form of each piece (None:
        # a piece without one, then the field at the samples)
        F: np.ndarray | None = None
        rated = trajs is not None and all(hasattr(tr, "state_and_rate") for tr in trajs)
        got = None
        if rated and N == 1:
            # one node (the common case): every sample on the one trajectory, whose span
            # t0 .. t0 + P holds them all (P n / n = P exactly: n is a power of two)
            assert trajs is not None
            got = trajs[0].state_and_rate(np.clip(t, node_t[0], node_t[1]), trusted=True)
        if got is not None:
            X, F = got
            idx = np.zeros(ns + 1, dtype=int)
        else:
            idx = np.clip(np.searchsorted(node_t, t, side="right") - 1, 0, N - 1)
        if rated and got is None:
            F = np.empty((n, ns + 1))
        for i in range(N if got is None else 0):
            sel = idx == i
            if not np.any(sel):
                continue
            a, b = node_t[i], node_t[i + 1]
            ts = np.clip(t[sel], a, b)
            if trajs is not None:
                got_i = trajs[i].state_and_rate(ts) if F is not None else None
                if got_i is not None:
                    X[:, sel], F[:, sel] = got_i
                else:
                    F = None
                    X[:, sel] = trajs[i](ts)
            else:
                X[:, sel] = np.asarray(flow(Z[i], a, b, t_eval=ts).ys).T
                self.periods += self.m / N
                self.calls += 1
        if F is None:
            rated = False
            F = self._nd_field(flow, t, X)
        G = self._funcs @ X
        Gd = self._funcs @ F

        node_list = node_t.tolist()

        def state_at(j: int, tt: float) -> tuple[np.ndarray, np.ndarray]:
            # the orbit and its rate at tt in sample interval [t_j, t_j+1] (which may hold
            # a node)
            if trajs is not None:
                i = min(max(bisect.bisect_right(node_list, tt) - 1, 0), N - 1)
                ti = min(max(tt, node_list[i]), node_list[i + 1])
                got = trajs[i].state_and_rate1(float(ti)) if rated else None
                if got is not None:
                    return got
                y = np.asarray(trajs[i](ti), dtype=float)
            elif tt <= t[j]:
                y = X[:, j]
            else:
                self.calls += 1
                y = flow(X[:, j], float(t[j]), tt).y
            return y, np.asarray(flow.vector_field(tt, y), dtype=float)

        K = G.shape[0]
        amps = np.empty(K)
        means = G[:, :ns].mean(axis=1)
        h = P / ns
        for k in range(K):
            if k == 0 and self._out_is is not None:
                continue
            row = G[k, :ns]
            ext = [(1.0, int(np.argmax(row))), (-1.0, int(np.argmin(row)))]
            vals = [abs(float(row[j])) for _, j in ext]
            if vals[1] > vals[0]:
                ext.reverse()
                vals.reverse()
            best = 0.0
            for i, (sign, j) in enumerate(ext):
                if i == 1:
                    # the other extremum lies within one sample interval of its sample, so
                    # it moves from the sample by at most h max|rate| (bounded by twice the
                    # largest sampled rate, far above the O(h^2) error of that sample): when
                    # even then its size stays below the refined one, max |.| is known
                    slack = 2.0 * h * float(np.max(np.abs(Gd[k, :ns])))
                    if vals[1] + slack < best:
                        break
                v = _refine_nd(self._funcs[k], G[k], Gd[k], t, j, sign, ns, state_at, flow)
                best = max(best, abs(v))
            amps[k] = best
        if self._out_is is not None:
            amps[0] = amps[self._out_is]
        c = np.fft.rfft(G[0, :ns]) / ns
        first = float(2.0 * abs(c[m])) if m < c.size else 0.0
        # the same arithmetic as the coordinates' means (the output may be one of them)
        mean = float(means[self._out_is if self._out_is is not None else 0])
        sig = X[:, : ns : STAT_SAMPLES // SIG_PHASES].T.ravel().copy()
        return (float(amps[0]), first, mean), (amps[1:].copy(), means[1:].copy()), sig

    def _compiled_statistics(
        self, trajs: list[Any] | None, t: np.ndarray, node_t: np.ndarray, ns: int, P: float
    ) -> tuple[tuple[float, float, float], tuple[np.ndarray, np.ndarray], np.ndarray] | None:
        """:meth:`nd_statistics` of a one-node orbit of the exact affine flow by the compiled
        kernel (:mod:`.statistics_numba`, the same algorithm), or None where it does not
        apply (numba missing, a piece without a modal closed form)."""
        modal = getattr(trajs[0], "modal_pieces", None) if trajs else None
        if modal is None:
            return None
        where = "perturb.simulate.exact_response.statistics_numba"
        kernel = compiled_kernel(where, "orbit_statistics")
        if kernel is None:
            return None
        arrays = modal()
        if arrays is None:
            return None
        starts, Y, mu, D, scaled = arrays
        a, b = float(node_t[0]), float(node_t[1])
        out_is = -1 if self._out_is is None else self._out_is
        try:
            amps, means, first, X = kernel(
                starts, Y, mu, D, scaled, self._funcs, t, a, b, ns, P / ns, self.m, out_is,
            )  # fmt: skip
        except Exception as exc:  # a numba that cannot compile or run it: numpy from now on
            disable_kernel(where, "orbit_statistics", exc)
            return None
        mean = float(means[self._out_is if self._out_is is not None else 0])
        sig = X[:, : ns : STAT_SAMPLES // SIG_PHASES].T.ravel().copy()
        return (float(amps[0]), float(first), mean), (amps[1:].copy(), means[1:].copy()), sig

    @staticmethod
    def _reversal_extremum(
        flow: Any, ta: float, tb: float, ya: np.ndarray, sign: float
    ) -> float | None:
        """For an event-driven flow whose field switches at x' = 0 (friction ``sign(x')``):
        the extremum of x on ``[ta, tb]``, read at the velocity reversal the flow locates.
        The acceleration jumps there, so the Hermite interpolant of (x, v, a) would be
        accurate to O(h^2) only (~3e-6 relative at 128 samples per period).  None when the
        flow has no such surface or meets no reversal in the interval."""
        surfaces = getattr(flow, "surfaces", None)
        simulate = getattr(flow, "simulate", None)
        if not surfaces or simulate is None:
            return None
        rev = {j for j, q in enumerate(surfaces) if q.a == 0.0 and q.c == 0.0 and q.b != 0.0}
        if not rev:
            return None
        try:
            tr = simulate(ya, (ta, tb))
        except PerturbError:
            return None
        xs = [e.x for e in tr.events if e.surface in rev and e.kind != "graze"]
        if not xs:
            return None
        return max(xs) if sign > 0 else min(xs)

    @staticmethod
    def _hermite_extremum(
        flow: Any, ta: float, tb: float, ya: np.ndarray, yb: np.ndarray, sign: float
    ) -> float:
        """Extreme value of x on ``[ta, tb]`` from the quintic Hermite interpolant of
        (x, v, a) at the ends, O(h^6) accurate (~1e-10 relative at 128 samples per period; a
        switch inside the interval costs little accuracy because v, which multiplies the
        jump of the third derivative, vanishes at the extremum)."""
        h = tb - ta
        system = getattr(flow, "system", None)
        if system is not None:
            # the exact flow's scalar field (same arithmetic as its vector_field)
            aa = system.field1(float(ta), float(ya[0]), float(ya[1]))[1]
            ab = system.field1(float(tb), float(yb[0]), float(yb[1]))[1]
        else:
            aa = float(flow.vector_field(ta, ya)[1])
            ab = float(flow.vector_field(tb, yb)[1])
        _, xr = _hermite5_extremum(ya[0], ya[1] * h, aa * h * h, yb[0], yb[1] * h, ab * h * h, sign)
        return xr


def _hermite5_extremum(x0, d0, s0, x1, d1, s1, sign) -> tuple[float, float]:
    """(s, value) of the extremum on [0, 1] of the quintic with the given values, first and
    second derivatives at the ends (derivatives already scaled by h, h^2): safeguarded Newton
    on p'(s) = 0 (p' changes sign on the bracket by construction)."""
    c0, c1, c2 = x0, d0, 0.5 * s0
    r1 = x1 - c0 - c1 - c2
    r2 = d1 - c1 - 2 * c2
    r3 = s1 - 2 * c2
    # [[1, 1, 1], [3, 4, 5], [6, 12, 20]] (c3, c4, c5) = (r1, r2, r3), solved in closed form
    c3 = 10 * r1 - 4 * r2 + 0.5 * r3
    c4 = -15 * r1 + 7 * r2 - r3
    c5 = 6 * r1 - 3 * r2 + 0.5 * r3

    def val(s: float) -> float:
        return c0 + s * (c1 + s * (c2 + s * (c3 + s * (c4 + s * c5))))

    def der(s: float) -> float:
        return c1 + s * (2 * c2 + s * (3 * c3 + s * (4 * c4 + s * 5 * c5)))

    def der2(s: float) -> float:
        return 2 * c2 + s * (6 * c3 + s * (12 * c4 + s * 20 * c5))

    lo, hi = 0.0, 1.0
    g_lo = sign * der(lo)
    if g_lo <= 0.0 or sign * der(hi) >= 0.0:
        return (0.0, x0) if sign * x0 >= sign * x1 else (1.0, x1)
    s = 0.5
    for _ in range(30):
        g = sign * der(s)
        if g > 0.0:
            lo = s
        else:
            hi = s
        g2 = sign * der2(s)
        sn = s - g / g2 if g2 != 0.0 else 0.5 * (lo + hi)
        if not lo < sn < hi:
            sn = 0.5 * (lo + hi)
        if abs(sn - s) < 1e-14:
            s = sn
            break
        s = sn
    return s, val(s)


def _quadratic_root01(a: float, b: float, c: float) -> float:
    """The root in ``[0, 1]`` of ``a s^2 + b s + c`` with ``c > 0`` and ``a + b + c <= 0``
    (one sign change on the interval), by the cancellation-free formula, or NaN when rounding
    puts no root there."""
    if a == 0.0:
        return -c / b if b != 0.0 else math.nan
    disc = b * b - 4.0 * a * c
    if not disc >= 0.0:
        return math.nan
    q = -0.5 * (b + math.copysign(math.sqrt(disc), b))
    if q == 0.0:
        return math.nan
    # q(s) > 0 on [0, root): the smallest root in [0, 1] is the sign change
    best = math.nan
    for r in (q / a, c / q):
        if 0.0 <= r <= 1.0 and not best <= r:
            best = r
    return best


def _refine_nd(c, g, gd, t, j, sign, ns, state_at, flow, max_iter: int = 4) -> float:
    """``c . y`` at its extremum (max for ``sign`` +1, min for -1) next to sample ``j``.

    In the sample interval where the rate ``gd`` changes sign: the root of the derivative of
    the cubic Hermite interpolant of ``(g, gd)`` (error O(h^3) in time), the state evaluated
    there on the orbit; while the estimated value error ``|rate| * |step| / 2`` exceeds
    1e-13 of the value, regula falsi on the rate with the new point (at most ``max_iter``
    evaluations).  The sample value when the rate does not change sign (a kink)."""
    gj = float(g[j])
    rj = sign * float(gd[j])
    if rj > 0.0:
        a, b = j, j + 1
    elif rj < 0.0:
        a, b = (j - 1, j) if j > 0 else (ns - 1, ns)
    else:
        return gj
    ra, rb = sign * float(gd[a]), sign * float(gd[b])
    if not (ra > 0.0 >= rb):
        return gj
    ta, tb = float(t[a]), float(t[b])
    h = tb - ta
    ga, gb = sign * float(g[a]), sign * float(g[b])
    # derivative of the cubic Hermite interpolant (unit interval): q(s) = A s^2 + B s + C
    ma, mb = ra * h, rb * h
    qa = 6.0 * ga + 3.0 * ma - 6.0 * gb + 3.0 * mb
    qb = -6.0 * ga - 4.0 * ma + 6.0 * gb - 2.0 * mb
    qc = ma
    lo, hi = 0.0, 1.0
    # the root in [0, 1] of q (q(0) = ma > 0 >= mb = q(1)): closed form; the safeguarded
    # Newton-bisection below only when it fails (rounding)
    s = _quadratic_root01(qa, qb, qc)
    iters = 0 if 0.0 <= s <= 1.0 else 40
    if iters:
        s = ra / (ra - rb)
    for _ in range(iters):
        q = (qa * s + qb) * s + qc
        if q > 0.0:
            lo = s
        else:
            hi = s
        dq = 2.0 * qa * s + qb
        sn = s - q / dq if dq != 0.0 else 0.5 * (lo + hi)
        if not lo < sn < hi:
            sn = 0.5 * (lo + hi)
        if abs(sn - s) < 1e-15:
            s = sn
            break
        s = sn
    # the orbit itself at the estimate; regula falsi on the rate while the value may be off
    best = gj
    lo_t, hi_t, rlo, rhi = ta, tb, ra, rb
    tt = ta + s * h
    for _ in range(max_iter):
        y, f = state_at(a, tt)
        val = float(c @ y)
        if sign * val > sign * best:
            best = val
        rate = sign * float(c @ f)
        if rate > 0.0:
            lo_t, rlo = tt, rate
        else:
            hi_t, rhi = tt, rate
        # step to the rate's root ~ rate / g''; the value error is ~ rate * step / 2
        curv = (rlo - rhi) / max(hi_t - lo_t, 1e-300)
        step = abs(rate) / curv if curv > 0.0 else hi_t - lo_t
        if abs(rate) * step <= 1e-13 * max(1.0, abs(val)) or hi_t - lo_t <= 1e-14 * h:
            break
        tt = lo_t + (hi_t - lo_t) * rlo / (rlo - rhi) if rlo != rhi else 0.5 * (lo_t + hi_t)
    return best
