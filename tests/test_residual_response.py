"""Residual-only approximations traced by seeding + continuation.

Oracles: the amplitude-parametrised curve of the same first-order approximation (roots of a
quadratic in Omega^2, a different route through the same equations) and exact periodic
orbits of the nsd oscillator from the exact propagator.
"""

from __future__ import annotations

import numpy as np
import pytest

from perturb.comparison import compare, relative_errors
from perturb.errors import ParameterError
from perturb.methods import modified_lindstedt
from perturb.model.builtins import builtin_model
from perturb.numeric.amplitude import solutions_at
from perturb.numeric.residual import residual_response
from perturb.solve import frequency_response, periodic_orbits

NSD = {"k": -0.5, "mu": 0.05, "F": 2.0}


@pytest.fixture(scope="module")
def mlp1():
    return modified_lindstedt(builtin_model("nsd", **NSD), 1)


def test_first_order_by_continuation_equals_amplitude_parametrisation(mlp1):
    window = (0.5, 1.2)
    cont = residual_response(mlp1, window, seed_frequencies=3)
    assert len(cont.branches) == 1
    rows = cont.rows()
    w = np.array([r["omega"] for r in rows])
    inside = w[(w > window[0]) & (w < window[1])]
    # the same equations solved by bisection on the quadratic in Omega^2 at exactly these
    # frequencies: an independent route to every root
    quad = solutions_at(mlp1, inside)
    err = relative_errors(cont, quad, quantity="first_harmonic_amplitude")
    finite = np.isfinite(err)
    assert finite.sum() >= inside.size
    assert np.max(err[finite]) < 1e-8
    # stability labels of the two routes agree (both Hill, one harmonic)
    assert compare(cont, quad, quantity="first_harmonic_amplitude").stability_disagreements == ()


def test_second_order_is_closer_to_the_exact_orbit_at_omega_0_6():
    osc = builtin_model("nsd", **NSD)
    exact = max(o.amplitude for o in periodic_orbits(osc, 0.6) if o.is_stable)
    errs = {}
    for order in (1, 2):
        resp = frequency_response(osc, "mlp", (0.55, 0.65), order=order)
        rows = resp.rows()
        w = np.array([r["omega"] for r in rows])
        a = np.array([r["amplitude"] for r in rows])
        near = np.argsort(np.abs(w - 0.6))[:2]
        amp = np.interp(0.6, w[near][np.argsort(w[near])], a[near][np.argsort(w[near])])
        errs[order] = abs(amp / exact - 1)
    # measured: 7.4e-3 (order 1), 1.3e-3 (order 2)
    assert errs[2] < 0.5 * errs[1]
    assert errs[1] < 2e-2


def test_bad_input(mlp1):
    with pytest.raises(ParameterError, match="omega_range"):
        residual_response(mlp1, (2.0, 1.0))
    with pytest.raises(ParameterError, match="seed_phases"):
        residual_response(mlp1, (0.5, 1.0), seed_phases=0)
    with pytest.raises(ParameterError, match="stability"):
        residual_response(mlp1, (0.5, 1.0), stability="magic")


def test_cartesian_averaging_is_traced_in_polar_unknowns():
    # van der Pol's averaging has unknowns (p, q) and no amplitude symbol; traced in
    # A = |(p, q)| it must give the Krylov-Bogoliubov curve (the same first-order equations
    # in polar form), which the amplitude parametrisation solves at the same frequencies
    from perturb.methods import krylov_bogoliubov, van_der_pol_averaging

    osc = builtin_model("nsd", **NSD)
    window = (0.5, 1.2)
    cont = residual_response(van_der_pol_averaging(osc), window, seed_frequencies=3)
    w = np.array([r["omega"] for r in cont.rows()])
    inside = w[(w > window[0]) & (w < window[1])]
    quad = solutions_at(krylov_bogoliubov(osc), inside)
    err = relative_errors(cont, quad, quantity="first_harmonic_amplitude")
    assert np.isfinite(err).sum() >= inside.size
    assert np.nanmax(err) < 1e-8


def test_second_order_low_frequency_artefacts_are_left_out():
    # below Omega ~ 0.26 a small divisor of the second-order mLP correction vanishes and its
    # waveform grows without bound (max|x| ~ 5e5); the exact orbits there stay small
    osc = builtin_model("nsd", **NSD)
    exact = max(o.amplitude for o in periodic_orbits(osc, 0.25))
    approx = modified_lindstedt(osc, 2)
    kept = residual_response(approx, (0.2, 0.4), seed_frequencies=2)
    assert kept.branches and any("left out" in n for n in kept.notes)
    assert max(b.amplitude.max() for b in kept.branches) < 3 * exact
    for b in kept.branches:
        assert np.all(b.amplitude <= 2 * b.first_harmonic_amplitude)
    every = residual_response(approx, (0.2, 0.4), seed_frequencies=2, max_correction=np.inf)
    assert max(b.amplitude.max() for b in every.branches) > 10 * exact


def test_bad_refinement_options(mlp1):
    with pytest.raises(ParameterError, match="refine"):
        residual_response(mlp1, (0.5, 1.0), refine=0)
    with pytest.raises(ParameterError, match="max_correction"):
        residual_response(mlp1, (0.5, 1.0), max_correction=0.0)
