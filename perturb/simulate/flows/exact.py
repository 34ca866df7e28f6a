r"""The exact piecewise-analytic propagator as a :class:`~perturb.simulate.flows.base.Flow`.

:class:`ExactPWLFlow` wraps :func:`~perturb.simulate.flows.piecewise_exact.propagate` so that
shooting,
Floquet analysis and continuation can run on it exactly like on :class:`ODEFlow`.

Sensitivity
-----------
Inside segment :math:`i` the variational equation is linear with constant coefficients,
:math:`\dot{\delta y} = A_i\,\delta y`, :math:`A_i = \begin{pmatrix}0 & 1\\ -s_i & -\mu
\end{pmatrix}` (the forcing does not enter), so a piece of duration :math:`h` contributes the
exact matrix exponential :math:`e^{A_i h}` (the propagator's closed form).  Where the
orbit crosses a breakpoint :math:`x = d` transversally (:math:`v \ne 0`) from segment :math:`i`
into segment :math:`j`, the perturbed orbit crosses at a slightly different time, and the
sensitivity picks up the saltation matrix

.. math::

    S = I + \frac{(f^+ - f^-)\,n^T}{n^T f^-},\qquad n = (1, 0)^T,\quad
    f^\mp = \bigl(v,\ a_{i,j}\bigr),\quad
    a_{i,j} = c + \text{load}(t) - \mu v - (s_{i,j} d + o_{i,j}),

i.e. :math:`S = \begin{pmatrix}1 & 0\\ (a_j - a_i)/v & 1\end{pmatrix}` with
:math:`a_j - a_i = (s_i - s_j)d + (o_i - o_j)`, minus the jump of the force.  For a continuous
force :math:`S = I` exactly.  Tangencies (the orbit touches a breakpoint and turns back) are not
switches: the segment and its field are unchanged, so they contribute nothing.  The monodromy is

.. math::

    \frac{\partial y(t_1)}{\partial y(t_0)} = e^{A_{i_n} h_n} S_{n-1} e^{A_{i_{n-1}} h_{n-1}}
    \cdots S_1 e^{A_{i_1} h_1},

exact up to rounding and the (full double precision) switching times.
"""

from __future__ import annotations

import math
from fractions import Fraction

import numpy as np
from numpy.typing import ArrayLike

from perturb.errors import ParameterError, PerturbError
from perturb.model.oscillator import Oscillator
from perturb.simulate.flows.base import Flow, FlowResult
from perturb.simulate.flows.piecewise_exact import PWLSystem, Trajectory, propagate
from perturb.simulate.flows.system import to_pwl_system

__all__ = ["ExactPWLFlow", "common_period"]


def common_period(frequencies: ArrayLike, *, max_denominator: int = 64) -> float | None:
    r"""The common period :math:`2\pi/\omega_0` of harmonics :math:`\omega_j = n_j\omega_0`.

    The ratios :math:`\omega_j/\omega_1` are matched by fractions with denominators up to
    ``max_denominator`` (to a relative :math:`10^{-12}`); ``None`` when there is no forcing or
    the frequencies are incommensurate at that resolution (quasi-periodic forcing).
    """
    w = [abs(float(f)) for f in np.asarray(frequencies, float).reshape(-1)]
    w = [f for f in w if f > 0.0]
    if not w:
        return None
    ref = w[0]
    den = 1
    for f in w[1:]:
        r = Fraction(f / ref).limit_denominator(max_denominator)
        if abs(float(r) * ref - f) > 1e-12 * f:
            return None
        den = math.lcm(den, r.denominator)
    # omega_0 = ref / den divides every omega_j; the period is 2 pi / omega_0
    return 2.0 * math.pi * den / ref


class ExactPWLFlow(Flow):
    r"""Exact flow (and exact sensitivity) of a piecewise-linear oscillator.

    Parameters
    ----------
    osc_or_system
        An :class:`~perturb.model.oscillator.Oscillator` with a piecewise-linear force, linear
        damping and
        harmonic forcing (converted by :func:`~perturb.simulate.flows.system.to_pwl_system`), or a
        :class:`~perturb.simulate.flows.piecewise_exact.PWLSystem`.
    Omega
        Forcing-frequency override (oscillators only).

    Attributes
    ----------
    system : PWLSystem
    period : float or None
        Common period of the harmonic loads; ``None`` without forcing (autonomous) or for
        incommensurate frequencies.
    autonomous : bool
        True when the system has no harmonic load.

    Notes
    -----
    The last trajectory is memoised: a shooting method that evaluates the converged state and
    then asks for samples over the same interval (:meth:`trajectory`) propagates only once.

    Examples
    --------
    >>> from perturb.model.builtins import builtin_model
    >>> flow = ExactPWLFlow(builtin_model("nsd", k=-2, mu=0.05, F=2, Omega=0.6))
    >>> res = flow([0.5, 0.0], 0.0, flow.period, sensitivity=True)
    >>> res.sensitivity.shape
    (2, 2)
    """

    def __init__(self, osc_or_system: Oscillator | PWLSystem, Omega: float | None = None) -> None:
        if isinstance(osc_or_system, PWLSystem):
            if Omega is not None:
                raise ParameterError(
                    f"Omega = {Omega!r} given with a PWLSystem: expected the forcing inside the "
                    "system (Omega overrides an Oscillator's frequency parameter only)"
                )
            system = osc_or_system
            self.name = "pwl"
        elif isinstance(osc_or_system, Oscillator):
            system = to_pwl_system(osc_or_system, Omega)
            self.name = osc_or_system.name
        else:
            raise ParameterError(
                f"osc_or_system = {osc_or_system!r}: expected an Oscillator or a PWLSystem"
            )
        self.system: PWLSystem = system
        self.period: float | None = common_period([w for _, w, _ in system.forcing])
        self._continuous = system.continuous_at()
        self._memo: tuple[tuple[float, float, float, float], Trajectory] | None = None

    #: ``trajectory`` gives the exact dense output (declared capability, see Flow)
    exact_dense_output = True

    @property
    def autonomous(self) -> bool:
        """No forcing term (a forced flow with incommensurate frequencies has no period but
        is not autonomous)."""
        return not self.system.forcing

    def __repr__(self) -> str:
        return f"ExactPWLFlow({self.name}, period={self.period})"

    # -- Flow protocol -------------------------------------------------------------------------
    def vector_field(self, t: float, y: ArrayLike) -> np.ndarray:
        """``(v, c + load(t) - mu v - f(x))`` (right-continuous at a jump of ``f``)."""
        return self.system.rhs(t, y)

    def trajectory(self, y0: ArrayLike, t0: float, t1: float) -> Trajectory:
        """The exact trajectory on ``[t0, t1]`` (memoised for the last arguments)."""
        y = np.asarray(y0, dtype=float).reshape(-1)
        if y.size != 2 or not np.all(np.isfinite(y)):
            raise ParameterError(
                f"y0 = {np.asarray(y0).tolist()!r}: expected two finite numbers (x, v)"
            )
        key = (float(y[0]), float(y[1]), float(t0), float(t1))
        if self._memo is not None and self._memo[0] == key:
            return self._memo[1]
        traj = propagate(self.system, y, (t0, t1))
        self._memo = (key, traj)
        return traj

    def __call__(
        self,
        y0: ArrayLike,
        t0: float,
        t1: float,
        *,
        sensitivity: bool = False,
        t_eval: ArrayLike | None = None,
    ) -> FlowResult:
        """Propagate ``y0`` from ``t0`` to ``t1 > t0``; see
        :class:`~perturb.simulate.flows.base.Flow`.

        Raises
        ------
        ParameterError
            Non-finite ``y0``, ``t1 <= t0``, ``t_eval`` outside ``[t0, t1]``.
        PerturbError
            Sticking/sliding at a discontinuity (from the propagator), or ``sensitivity=True``
            when the orbit switches across a jump of the force with zero velocity (the
            saltation matrix is unbounded there).
        """
        if not (math.isfinite(t0) and math.isfinite(t1) and t1 > t0):
            raise ParameterError(f"(t0, t1) = ({t0!r}, {t1!r}): expected finite t1 > t0")
        traj = self.trajectory(y0, t0, t1)
        y_end = np.array([traj.x[-1], traj.v[-1]], dtype=float)
        sens = self._sensitivity(traj) if sensitivity else None
        t_out = ys = None
        if t_eval is not None:
            t_out = np.asarray(t_eval, dtype=float).reshape(-1)
            ys = traj(t_out).T.copy() if t_out.size else np.empty((0, 2))
        n_events = sum(1 for e in traj.events if not e.tangency)
        return FlowResult(
            t0=float(t0),
            t1=float(t1),
            y=y_end,
            sensitivity=sens,
            t=t_out,
            ys=ys,
            n_events=n_events,
        )

    # -- sensitivity ---------------------------------------------------------------------------
    def sensitivity_determinant(self, t0: float, t1: float) -> float:
        r"""Exact :math:`\det\,\partial y(t_1)/\partial y(t_0) = e^{-\mu (t_1 - t_0)}`.

        Every piece has :math:`\det e^{A_i h} = e^{\operatorname{tr}(A_i) h} = e^{-\mu h}` and
        every saltation matrix has determinant 1, whatever the orbit.  Shooting uses it to get
        the small Floquet multiplier of strongly unstable orbits to full relative accuracy.
        """
        return math.exp(-self.system.damping * (float(t1) - float(t0)))

    def _sensitivity(self, traj: Trajectory) -> np.ndarray:
        sys_ = self.system
        pieces = traj.pieces
        steps = traj.transition_matrices()
        # 2x2 products in scalar arithmetic: a period has a handful of pieces, for which
        # numpy's per-call overhead would dominate
        m00, m01, m10, m11 = steps[0]
        for k in range(1, len(pieces)):
            before, after = pieces[k - 1].segment, pieces[k].segment
            if before != after:
                # a switch (a "touch" that starts a new piece in the same segment is not)
                b = min(before, after)  # breakpoint index between adjacent segments
                if not self._continuous[b]:
                    d = float(sys_.breakpoints[b])
                    v = pieces[k].v0
                    if v == 0.0:
                        raise PerturbError(
                            f"the orbit crosses the discontinuity x = {d!r} at t = "
                            f"{pieces[k].t0!r} with zero velocity: the saltation matrix "
                            "(1/v) is unbounded and the flow is not differentiable there"
                        )
                    da = (sys_.slopes[before] - sys_.slopes[after]) * d + (
                        sys_.offsets[before] - sys_.offsets[after]
                    )
                    # S = [[1, 0], [da / v, 1]]
                    g = float(da) / v
                    m10, m11 = m10 + g * m00, m11 + g * m01
            e00, e01, e10, e11 = steps[k]
            m00, m01, m10, m11 = (
                e00 * m00 + e01 * m10,
                e00 * m01 + e01 * m11,
                e10 * m00 + e11 * m10,
                e10 * m01 + e11 * m11,
            )
        M = np.array([[m00, m01], [m10, m11]])
        if not np.all(np.isfinite(M)):
            raise PerturbError(
                f"the sensitivity over {traj.t_span!r} overflows (non-finite monodromy): "
                "shorten the interval"
            )
        return M
