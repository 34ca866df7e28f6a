"""Correctness guards of the fast paths of :mod:`perturb.numeric.system_balance` (no timing:
the speed is measured in ``benchmarks/bench_system_balance.py``).

* The largest multiplier modulus of every point of a branch, from the stacked products of
  ``SystemBalance._max_multipliers``, against the eigenvalues of the public one-point
  ``SystemBalance.multipliers`` (its own monodromy loop) at the same points.
* The attractor stage's vectorised RK4 simulation (``_attractor_guesses``) against a scalar
  RK4 written here from the nsd2 equations (hand-written field, own Halton points), one
  trajectory at a time: the same settled orbits, projected on the same basis.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from perturb.model.system import System
from perturb.model.system_builtins import builtin_system
from perturb.numeric import system_balance as sbm
from perturb.numeric.system_balance import SystemBalance, system_balance_branch


@pytest.mark.parametrize("params", [{}, {"k": 0.3, "F": 0.6}])
def test_stacked_max_multipliers_equal_the_one_point_monodromy(params):
    system = builtin_system("nsd2").with_params(**params)
    sb = SystemBalance(system, 15)
    br = system_balance_branch(system, (0.5, 2.0), balance=sb, stability=True)
    Us, Ws = br.U.reshape(len(br), -1), br.Omega
    picks = range(0, len(br), 20)
    ref = np.array([np.abs(sb.multipliers(Us[p], float(Ws[p]))).max() for p in picks])
    got = np.asarray(br.max_multiplier)[list(picks)]
    assert len(ref) >= 20
    np.testing.assert_allclose(got, ref, rtol=1e-10, atol=0.0)
    # and the stacked path was the one taken (a continuous force, no defective field)
    w = np.array([sb._omega(float(W)) for W in Ws[:5]])
    given = [{} for _ in range(5)]
    U3 = Us[:5].reshape(5, sb.neq, sb.size)
    el = sb.elements[0]
    S = np.einsum("j,pjk->pk", el.alpha, U3)
    for p, pc in enumerate(sbm._crossings_batch(el.pwl, sb.basis, S)):
        given[p][0] = pc
    assert sb._max_multipliers_stacked(w, given) is not None


def _halton(count: int, dim: int) -> np.ndarray:
    primes = [2, 3, 5, 7][:dim]
    out = np.empty((count, dim))
    for d, p in enumerate(primes):
        for i in range(count):
            n, f, r = i + 1, 1.0 / p, 0.0
            while n:
                r += f * (n % p)
                n //= p
                f /= p
            out[i, d] = r
    return out


def _step(y, k, h):
    return tuple(a + h * d for a, d in zip(y, k, strict=True))


def test_attractor_simulation_equals_a_scalar_rk4_of_the_nsd2_equations():
    system = builtin_system("nsd2")
    par = system.params
    k, k2, m2 = float(par["k"]), float(par["k2"]), float(par["m2"])
    mu1, mu2, F = float(par["mu1"]), float(par["mu2"]), float(par["F"])
    slope = 1.0 - k  # the device beyond |x1| = 1: f(s) = (1 - k)(s -+ 1)

    def device(s):
        return slope * (s - 1.0) if s > 1.0 else (slope * (s + 1.0) if s < -1.0 else 0.0)

    def field(y, t, W):
        x1, x2, v1, v2 = y
        a1 = F * math.cos(W * t) - ((k + k2) * x1 - k2 * x2 + (mu1 + mu2) * v1 - mu2 * v2)
        a1 -= device(x1)
        a2 = (k2 * x1 - k2 * x2 + mu2 * v1 - mu2 * v2) / m2
        return (v1, v2, a1, a2)

    lo, hi = 1.3, 1.313
    sb = SystemBalance(system, 15)
    got = sbm._attractor_guesses(sb, (lo, hi))
    # the design: frequencies 2 % apart, the rest state and Halton states in a box of three
    # times the breakpoint, a step of _ATTRACTOR_STEP over the field's largest eigenvalue
    # modulus on a grid of ``per`` steps a period, 40 periods, the last period settled within 5 %
    count = max(1, math.floor(math.log(hi / lo) / math.log1p(sbm._ATTRACTOR_SPACING))) + 1
    Omegas = np.geomspace(lo, hi, count)
    lam = 0.0
    for sl in (0.0, slope):
        A = np.array(
            [
                [0, 0, 1, 0],
                [0, 0, 0, 1],
                [-(k + k2) - sl, k2, -(mu1 + mu2), mu2],
                [k2 / m2, -k2 / m2, mu2 / m2, -mu2 / m2],
            ]
        )
        lam = max(lam, float(np.abs(np.linalg.eigvals(A)).max()))
    # steps a period: the stiffest segment's time scale at the lowest frequency, at least
    # the minimum count and more than twice the highest harmonic (H = 15)
    per = max(sbm._ATTRACTOR_MIN_STEPS, 32, math.ceil(2 * math.pi / lo * lam / sbm._ATTRACTOR_STEP))
    states = sbm._ATTRACTOR_STATES
    box = np.vstack([np.zeros((1, 4)), (2.0 * _halton(states - 1, 4) - 1.0) * 3.0])
    b = sb.basis
    theta = 2 * math.pi / per * (np.arange(per) + 1)
    want = []
    for W in Omegas:
        h = 2 * math.pi / W / per
        mine = []
        for y0 in box:
            y = tuple(float(v) for v in y0)
            samples = []
            for i in range(per * sbm._ATTRACTOR_PERIODS):
                t = i * h
                k1 = field(y, t, W)
                k2_ = field(_step(y, k1, 0.5 * h), t + 0.5 * h, W)
                k3 = field(_step(y, k2_, 0.5 * h), t + 0.5 * h, W)
                k4 = field(_step(y, k3, h), t + h, W)
                y = tuple(
                    a + h / 6.0 * (p + 2 * q + 2 * r + s)
                    for a, p, q, r, s in zip(y, k1, k2_, k3, k4, strict=True)
                )
                if i >= per * (sbm._ATTRACTOR_PERIODS - 2):
                    samples.append(y[:2])
            x = np.array(samples)
            last, before = x[per:], x[:per]
            if not np.all(np.isfinite(last)):
                continue
            rng = max(1e-12, float(np.ptp(last, axis=0).max()))
            if float(np.abs(last - before).max()) > 0.05 * rng:
                continue
            U = np.zeros((2, b.size))
            U[:, 0] = last.mean(axis=0)
            U[:, b.a_index] = (2.0 / per) * (last.T @ np.cos(np.outer(theta, b.k)))
            U[:, b.b_index] = (2.0 / per) * (last.T @ np.sin(np.outer(theta, b.k)))
            scale = max(1e-12, float(np.abs(U).max()))
            if any(float(np.abs(U - V).max()) <= 1e-2 * scale for V in mine):
                continue
            mine.append(U)
            want.append((float(W), U.reshape(-1)))
    assert len(want) >= 2
    assert [w for w, _ in got] == pytest.approx([w for w, _ in want], rel=1e-14)
    for (_, g), (_, u) in zip(got, want, strict=True):
        np.testing.assert_allclose(g, u, rtol=0.0, atol=1e-8 * float(np.abs(u).max()))


# an impact pair with an asymmetric clearance and a second, stiffer stop on one side: its
# force has a constant term and a sloped middle segment (the pieces of the simulation's
# product that the symmetric builtins leave out)
_ASYM = "(r*(x1 - x2 - d)*Heaviside(x1 - x2 - d) + r2*(x1 - x2 + d2)*Heaviside(-x1 + x2 - d2)"
_ASYM += " + r3*(x1 - x2 - d3)*Heaviside(x1 - x2 - d3))"
_ASYM_PARAMS = {"mu": 0.05, "mu2": 0.01, "r": 20.0, "d": 0.5, "m2": 0.2, "F": 0.5, "Omega": 1.0}
_ASYM_PARAMS.update(r2=8.0, d2=0.3, r3=30.0, d3=0.9)

# contact springs with a force step f0 where they engage: a discontinuous PWL force (the
# simulation evaluates it by its table, not as pieces)
_JUMP = "(r*(x1 - x2 - d)*Heaviside(x1 - x2 - d) + r*(x1 - x2 + d)*Heaviside(-x1 + x2 - d)"
_JUMP += " + f0*Heaviside(x1 - x2 - d) - f0*Heaviside(-x1 + x2 - d))"
_JUMP_PARAMS = {"mu": 0.05, "mu2": 0.01, "r": 20.0, "d": 0.5, "m2": 0.2, "F": 0.5, "Omega": 1.0}
_JUMP_PARAMS.update(f0=0.3)


def _impact_pair(kind):
    if kind == "builtin":
        system = builtin_system("impact_pair")
        par = {name: float(v) for name, v in system.params.items()}
        r, d = par["r"], par["d"]

        def contact(s):
            return r * (s - d) if s > d else (r * (s + d) if s < -d else 0.0)

        return system, par, contact
    if kind == "jump":
        system = System.parse(
            (
                f"x1'' + mu*x1' + x1 + {_JUMP} = F*cos(Omega*t)",
                f"m2*x2'' + mu2*(x2' - x1') - {_JUMP} = 0",
            ),
            _JUMP_PARAMS,
            name="jump_pair",
        )
        par = dict(_JUMP_PARAMS)

        def contact(s):
            r, d, f0 = par["r"], par["d"], par["f0"]
            return r * (s - d) + f0 if s > d else (r * (s + d) - f0 if s < -d else 0.0)

        return system, par, contact
    system = System.parse(
        (
            f"x1'' + mu*x1' + x1 + {_ASYM} = F*cos(Omega*t)",
            f"m2*x2'' + mu2*(x2' - x1') - {_ASYM} = 0",
        ),
        _ASYM_PARAMS,
        name="asymmetric_pair",
    )
    par = dict(_ASYM_PARAMS)

    def contact(s):
        out = par["r"] * (s - par["d"]) if s > par["d"] else 0.0
        out += par["r3"] * (s - par["d3"]) if s > par["d3"] else 0.0
        out += par["r2"] * (s + par["d2"]) if s < -par["d2"] else 0.0
        return out

    return system, par, contact


@pytest.mark.parametrize("kind", ["builtin", "asymmetric", "jump"])
def test_attractor_run_equals_a_scalar_rk4_of_impact_pair_equations(kind):
    """The simulation itself on a system with a combination ``x1 - x2`` (not a coordinate),
    a mass matrix other than the identity and stiff contact springs (and, asymmetric, a
    force with a constant term and a sloped middle segment): ``_attractor_run`` over three
    periods against a scalar RK4 of the equations written here, from states that reach the
    contact (checked); jump, a discontinuous force."""
    system, par, contact = _impact_pair(kind)
    mu, mu2, m2, F = par["mu"], par["mu2"], par["m2"], par["F"]
    d = min(par["d"], par.get("d2", par["d"]))

    def field(y, t, W):
        x1, x2, v1, v2 = y
        c = contact(x1 - x2)
        a1 = F * math.cos(W * t) - mu * v1 - x1 - c
        a2 = (c - mu2 * (v2 - v1)) / m2
        return (v1, v2, a1, a2)

    sb = SystemBalance(system, 15)
    Omegas = np.array([0.8, 1.1])
    box = np.array([[0.0, 0.0, 0.0, 0.0], [1.2, -0.3, 0.5, -1.0], [-0.9, 0.4, -0.2, 2.0]])
    per, periods = 144, 3  # h lam ~ 0.6 at Omega = 0.8 (lam ~ 11: the contact mode)
    got = sbm._attractor_run(sb, Omegas, box, per, periods)
    assert got.shape == (2 * per, 2, len(Omegas) * len(box))
    impacts = 0
    for f, W in enumerate(Omegas):
        h = 2 * math.pi / W / per
        for j, y0 in enumerate(box):
            y = tuple(float(v) for v in y0)
            samples = []
            for i in range(per * periods):
                t = i * h
                k1 = field(y, t, W)
                k2 = field(_step(y, k1, 0.5 * h), t + 0.5 * h, W)
                k3 = field(_step(y, k2, 0.5 * h), t + 0.5 * h, W)
                k4 = field(_step(y, k3, h), t + h, W)
                y = tuple(
                    a + h / 6.0 * (p + 2 * q + 2 * s + e)
                    for a, p, q, s, e in zip(y, k1, k2, k3, k4, strict=True)
                )
                if i >= per * (periods - 2):
                    samples.append(y[:2])
            want = np.array(samples)
            impacts += int(np.any(np.abs(want[:, 0] - want[:, 1]) > d))
            np.testing.assert_allclose(
                got[:, :, f * len(box) + j], want, rtol=0.0, atol=1e-10 * np.abs(want).max()
            )
    assert impacts >= 4
