"""The closed-form steady state of one linear segment (:mod:`perturb.model.segments`).

Independent oracles: SciPy's ``solve_ivp`` on the linear segment ODE written here, either run
to steady state (a damped, stable segment) or used to build the periodic solution of the
linear system by one-period shooting, ``y0 = (I - M)^{-1} y_p(T)`` with ``M`` and ``y_p``
integrated numerically (any segment, saddle or centre included); and an orbit reported
inside its segment must be a periodic orbit of the whole piecewise-linear system (checked by
integrating the PWL right-hand side written here).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from perturb.model.segments import SegmentSteadyState, segment_steady_states

TOL = dict(method="DOP853", rtol=1e-12, atol=1e-13)


def _linear_rhs(s: float, o: float, mu: float, loads, c: float):
    """``x'' + mu x' + s x + o = c + sum F cos(w t + p)`` as a first-order system."""

    def rhs(t, y):
        f = c + sum(F * math.cos(w * t + p) for F, w, p in loads)
        return [y[1], f - mu * y[1] - s * y[0] - o]

    return rhs


def _periodic_state(s, o, mu, loads, c, T, t0=0.0):
    """State at ``t0`` of the T-periodic solution of the linear ODE, by one-period shooting:
    ``y(t0 + T) = M y0 + y_p(t0 + T)`` (``y_p`` from rest at ``t0``), periodic when
    ``(I - M) y0 = y_p(t0 + T)``."""
    rhs = _linear_rhs(s, o, mu, loads, c)
    hom = _linear_rhs(s, 0.0, mu, [], 0.0)
    M = np.column_stack(
        [solve_ivp(hom, (0.0, T), e, **TOL).y[:, -1] for e in ([1.0, 0.0], [0.0, 1.0])]
    )
    yp = solve_ivp(rhs, (t0, t0 + T), [0.0, 0.0], **TOL).y[:, -1]
    return np.linalg.solve(np.eye(2) - M, yp)


@pytest.mark.parametrize(
    "s, o, mu, load, c",
    [
        (1.0, 0.3, 0.5, (2.0, 1.3, 0.0), 0.0),
        (4.0, -1.0, 0.8, (0.7, 0.9, 1.1), 0.4),
        (0.5, 0.0, 1.0, (1.5, 2.2, -2.0), -0.3),
    ],
)
def test_stable_segment_matches_long_integration(s, o, mu, load, c):
    """A damped, stable segment forgets its start: integrating long enough from rest reaches
    the steady state (transient ``e^{-mu t/2}`` below 1e-12 of the start)."""
    (st,) = segment_steady_states([], [s], [o], mu, [load], c)
    w = load[1]
    T = 2 * math.pi / w
    n = math.ceil(2 * math.log(1e13) / mu / T)
    t_end = n * T
    t_eval = t_end - T + np.linspace(0.0, T, 9)
    sol = solve_ivp(
        _linear_rhs(s, o, mu, [load], c), (0.0, t_end), [0.0, 0.0], t_eval=t_eval, **TOL
    )
    x, v = st.states(t_eval)
    assert np.max(np.abs(x - sol.y[0])) < 1e-9
    assert np.max(np.abs(v - sol.y[1])) < 1e-9
    # the amplitude's convention: x = x_c + Re(Z e^{i w t}) = x_c + Re Z cos - Im Z sin
    Z = st.amplitude
    xa = st.centre + Z.real * np.cos(w * t_eval) - Z.imag * np.sin(w * t_eval)
    assert np.max(np.abs(xa - sol.y[0])) < 1e-9
    assert st.half_range == pytest.approx(abs(Z), rel=1e-14)


@pytest.mark.parametrize(
    "s, mu, loads",
    [
        (-2.0, 0.05, [(2.0, 0.6, 0.0)]),  # saddle (negative stiffness)
        (1.0, 0.0, [(0.5, 1.7, 0.4)]),  # undamped centre off resonance
        (-0.5, 0.1, [(1.0, 1.0, 0.2), (0.3, 3.0, -1.0)]),  # two commensurate loads
    ],
)
def test_any_segment_matches_periodic_shooting(s, mu, loads):
    """Saddle and centre segments too: the periodic solution of the linear ODE, found by
    one-period shooting on solve_ivp, is the closed form's."""
    o, c = 0.25, -0.1
    (st,) = segment_steady_states([], [s], [o], mu, loads, c)
    T = 2 * math.pi / min(w for _, w, _ in loads)
    # one-period shooting from several start times: a saddle amplifies integration errors by
    # its multiplier (~1e6 here) over a period, so the orbit is not integrated across it
    for t0 in (0.0, 0.3 * T, 0.77 * T):
        y0 = _periodic_state(s, o, mu, loads, c, T, t0)
        x, v = st.states([t0])
        assert abs(x[0] - y0[0]) < 1e-9 and abs(v[0] - y0[1]) < 1e-9


def _nsd(k: float, mu: float, F: float, w: float):
    """Zou-Nagarajaiah negative-stiffness device: slope ``k`` in ``|x| < 1``, 1 outside,
    continuous (offsets ``1 - k``, 0, ``k - 1``)."""
    bps, sl, of = [-1.0, 1.0], [1.0, k, 1.0], [1.0 - k, 0.0, k - 1.0]

    def rhs(t, y):
        i = 0 if y[0] < -1.0 else (1 if y[0] < 1.0 else 2)
        return [y[1], F * math.cos(w * t) - mu * y[1] - sl[i] * y[0] - of[i]]

    return (bps, sl, of, mu, [(F, w, 0.0)]), rhs


def test_inside_orbit_is_an_orbit_of_the_pwl_system():
    """The saddle orbit of nsd's central segment (small forcing) stays inside ``|x| < 1``: it
    is periodic for the PWL right-hand side; the outer segments' centres lie at ``-+3`` with
    amplitude above 2, so they cross ``-+1`` and are not inside."""
    data, rhs = _nsd(-2.0, 0.05, 0.5, 0.6)
    left, mid, right = segment_steady_states(*data)
    assert mid.inside and mid.margin > 0
    assert (mid.lower, mid.upper) == (-1.0, 1.0)
    T = 2 * math.pi / 0.6
    # the saddle's unstable multiplier ~ e^{1.4 T} amplifies errors: integrate a tenth of the
    # period at a time from the closed-form states, which are on the orbit throughout
    t = np.linspace(0.0, T, 41)
    x, v = mid.states(t)
    assert np.all(np.abs(x) < 1.0)
    for i in range(len(t) - 1):
        y = solve_ivp(rhs, (t[i], t[i + 1]), [x[i], v[i]], **TOL).y[:, -1]
        assert abs(y[0] - x[i + 1]) < 1e-9 and abs(y[1] - v[i + 1]) < 1e-9
    assert left.centre == pytest.approx(-3.0) and right.centre == pytest.approx(3.0)
    # a large forcing pushes the central orbit out of its segment
    data, _ = _nsd(-2.0, 0.05, 5.0, 0.6)
    assert not segment_steady_states(*data)[1].inside


def test_inside_is_strict_and_edges():
    """``inside`` means strictly between the edges; the outer segments are unbounded."""
    (st,) = segment_steady_states([], [1.0], [0.0], 0.0, [(0.0, 2.0, 0.0)])
    assert st.inside and st.lower == -math.inf and st.upper == math.inf
    # zero forcing: the orbit is the centre point; a breakpoint exactly there is not inside
    sts = segment_steady_states([0.5], [2.0, 2.0], [-1.0, -1.0], 0.1, [(0.0, 1.0, 0.0)])
    assert sts[0].centre == 0.5 and not sts[0].inside and not sts[1].inside


def test_no_steady_state():
    """Zero slope and an undamped resonance have no unique steady state: None."""
    sts = segment_steady_states([0.0], [0.0, 4.0], [1.0, 0.0], 0.0, [(1.0, 2.0, 0.0)])
    assert sts == (None, None)
    assert isinstance(
        segment_steady_states([0.0], [0.0, 4.0], [1.0, 0.0], 0.1, [(1, 2, 0)])[1],
        SegmentSteadyState,
    )


def test_several_loads_and_bad_input():
    (st,) = segment_steady_states([], [1.0], [0.0], 0.2, [(1.0, 1.0, 0.0), (1.0, 2.0, 0.0)])
    with pytest.raises(ValueError, match="exactly one"):
        _ = st.amplitude
    assert len(st.amplitudes) == 2
    # the range bound holds on a fine sample
    x, _ = st.states(np.linspace(0.0, 2 * math.pi, 2001))
    assert st.xmin <= x.min() and x.max() <= st.xmax
    with pytest.raises(ValueError, match="expected"):
        segment_steady_states([0.0], [1.0], [0.0, 0.0], 0.1, [])
