"""The exact frequency response of ``impact_pair`` holds the asymmetric isolas that cross the
low window edge.

Four isolas of asymmetric orbits (each with its mirror image under
:math:`(x, t) \\to (-x, t + T/2)`), unstable saddles (a real multiplier 10 .. 150), have a
fold below Omega = 0.6 (~0.51 .. 0.54) and one inside the window (~0.7973, 0.7701, 0.7721,
0.7557, at a grazing): over (0.6, 1.4) or (0.6, 0.8) each is a branch that enters and leaves
the window through its low edge, next to the symmetric saddle there.  No closed-form seed, no
branch point and no stable orbit leads to them; which of them the sweeps' Newton starts and
the edge starts (multiples of the traced edge states) reached depended on rounding (at
91d519b with the kernels: two of the four over (0.6, 1.4), none with numpy; at c509f5d two
over (0.6, 0.8) with and without the kernels).  The attractor stage now also starts Newton
beside every unstable symmetric orbit at a window edge of an odd system
(``attractors.symmetric_edge_starts``).

The oracle is ``tests/impact_pair_oracle.py``, independent of perturb (DOP853 one contact
state at a time, Newton on the period map with a central-difference Jacobian): from a fixed
start near each isola's orbit at Omega = 0.7 it finds the orbit, shows it unstable, isolated
and asymmetric (its mirror image is another orbit), and the exact response must hold it and
its image (the exact orbit at 0.7 polished from the branch equals the oracle's), with the
compiled kernels and without.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from impact_pair_oracle import flow, monodromy, periodic_orbit

from perturb.model.system_builtins import builtin_system
from perturb.simulate.exact_response import exact_branches
from perturb.simulate.exact_response.results import polish_at
from perturb.simulate.flows import scan_kernel

WINDOW = (0.6, 0.8)
OMEGA = 0.7
#: (x1, x2, x1', x2') at t = 0 near one orbit of each isola at Omega = 0.7 (6 digits of a shot
#: orbit), by the isola's fold inside the window
STARTS = {
    "fold 0.7973": (1.310091, 1.690799, 0.128733, -0.000733),
    "fold 0.7701": (1.193106, 1.576542, -0.089337, 0.902927),
    "fold 0.7557": (1.201783, 1.424122, -0.091833, 0.838388),
    "fold 0.7721": (1.207581, 1.259961, -0.082787, 0.723883),
}


def _max_x1(W: float, y: np.ndarray) -> float:
    fl = flow(W, y, dense=True)
    T = 2.0 * math.pi / W
    xs = [
        sol(np.linspace(t0, t1, 2 + int(4000 * (t1 - t0) / T)))[0] for t0, t1, _, sol in fl.segments
    ]
    return float(np.max(np.abs(np.hstack(xs))))


@pytest.fixture(scope="module")
def oracle():
    """name -> (orbit y0, its mirror image's y0, monodromy, max |x1|) at OMEGA."""
    T = 2.0 * math.pi / OMEGA
    out = {}
    for name, start in STARTS.items():
        y = periodic_orbit(OMEGA, np.array(start))
        image = -flow(OMEGA, y, t1=T / 2).y  # -y(T/2): the mirror orbit's state at t = 0
        out[name] = (y, image, monodromy(OMEGA, y), _max_x1(OMEGA, y))
    return out


def test_the_oracle_orbits_are_asymmetric_isolated_saddles(oracle):
    ys = []
    for name, (y, image, J, _) in oracle.items():
        assert np.max(np.abs(np.linalg.eigvals(J))) > 5.0, name  # unstable (17 .. 34)
        # isolated: J - I far from singular
        assert np.linalg.svd(J - np.eye(4), compute_uv=False)[-1] > 0.05, name
        # asymmetric: the mirror image is another orbit (its period map returns it)
        assert np.max(np.abs(image - y)) > 0.1, name
        assert np.max(np.abs(flow(OMEGA, image).y - image)) < 1e-8, name
        ys += [y, image]
    # eight distinct orbits
    for i in range(len(ys)):
        for k in range(i):
            assert np.max(np.abs(ys[i] - ys[k])) > 0.02


def _held(res, y: np.ndarray, amp: float) -> tuple[bool, str]:
    """Whether a branch of ``res`` crosses OMEGA through the orbit ``y`` (the exact orbit
    polished there equals it; the branch's amplitude there, interpolated, is ``amp``) and
    reaches the low window edge."""
    near = []
    for br in res.branches:
        p = np.array([q.parameter for q in br.points])
        Y = np.array([q.y0 for q in br.points])
        a = np.array([q.amplitude for q in br.points])
        for j in np.flatnonzero((p[:-1] - OMEGA) * (p[1:] - OMEGA) <= 0):
            s = 0.5 if p[j + 1] == p[j] else (OMEGA - p[j]) / (p[j + 1] - p[j])
            yi = (1.0 - s) * Y[j] + s * Y[j + 1]
            near.append(float(np.max(np.abs(yi - y))))
            if near[-1] > 0.05:
                continue
            orbit = polish_at(br, int(j), OMEGA)
            if orbit is None or np.max(np.abs(orbit.y0 - y)) > 1e-7:
                continue
            ai = (1.0 - s) * a[j] + s * a[j + 1]
            ok = p.min() == WINDOW[0] and abs(ai - amp) < 2e-3 * amp
            return ok, f"reaches {p.min():.4f}, max|x1| {ai:.6f} (oracle {amp:.6f})"
    return False, f"nearest crossing {min(near, default=math.inf):.3g} away"


@pytest.mark.parametrize("compiled", ["1", "0"])
def test_the_exact_response_holds_every_edge_isola(oracle, monkeypatch, compiled):
    monkeypatch.setattr(scan_kernel, "_KERNEL", [])
    monkeypatch.setattr(scan_kernel, "_KERNELS", {})
    monkeypatch.setenv("PERTURB_COMPILED", compiled)
    if compiled == "1" and scan_kernel.compiled_scan() is None:
        pytest.skip("numba is not installed: no compiled kernels")
    res = exact_branches(builtin_system("impact_pair"), WINDOW, progress=False, workers=1)
    missing = []
    for name, (y, image, _, amp) in oracle.items():
        # (the mirror image -y(t + T/2) has the same max |x1|)
        for what, z in (("orbit", y), ("mirror image", image)):
            ok, why = _held(res, z, amp)
            if not ok:
                missing.append(f"{name} {what}: {why}")
    assert not missing, "; ".join(missing)
