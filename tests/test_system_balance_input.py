"""Bad input to the harmonic balance of systems (perturb.numeric.system_balance), issue 16:
harmonics that cannot represent the requested subharmonic, an element on a combination that
is identically zero, an output that is not a coordinate -- each a PerturbError naming the
value and what was expected, raised before any solving. Beside each refusal, the accepted
neighbour (so the check is not refusing everything)."""

from __future__ import annotations

import numpy as np
import pytest

from perturb.errors import ModelError, ParameterError, PerturbError
from perturb.model.system import System, gap, polynomial
from perturb.model.system_builtins import builtin_system
from perturb.numeric.system_balance import (
    SystemBalance,
    system_balance_branch,
    system_balance_orbit,
    system_balance_response,
    system_balance_solutions_at,
)


def _pair(on: str, element=gap, params=None) -> System:
    """Two unit masses, one element on ``on`` (forcing on the first)."""
    el = element(on, 0.2, 4.0) if element is gap else element(on, [0, 0, 0, 1.0])
    return System.from_matrices(
        np.eye(2).tolist(),
        (0.05 * np.eye(2)).tolist(),
        [[1.5, -0.5], [-0.5, 1.0]],
        elements=[el],
        forcing=["0.05*cos(Omega*t)", "0"],
        coordinates=["x1", "x2"],
        params={"Omega": 1.1, **(params or {})},
        name="pair",
    )


# ------------------------------------------------------------------ subharmonics ----------
@pytest.mark.parametrize(("H", "m", "harmonic"), [(1, 2, "2"), (3, 4, "4"), (2, 3, "3")])
def test_harmonics_that_cannot_hold_the_subharmonic(H, m, harmonic):
    """The forcing at Omega is harmonic m of the response frequency Omega/m: H < m cannot
    represent it."""
    system = builtin_system("nsd2")
    with pytest.raises(ModelError) as info:
        SystemBalance(system, H, m=m)
    msg = str(info.value)
    assert f"harmonic {harmonic} of the response frequency Omega/{m}" in msg
    assert f"1..{H}" in msg and "harmonics=" in msg
    # the same through the front functions, before any solving
    with pytest.raises(ModelError, match=f"Omega/{m}"):
        system_balance_orbit(system, 1.0, harmonics=H, m=m)
    with pytest.raises(ModelError, match=f"Omega/{m}"):
        system_balance_response(system, (1.0, 2.0), harmonics=H, m=m)
    # enough harmonics: accepted
    assert SystemBalance(system, m, m=m).H == m


def test_forcing_rate_that_no_whole_harmonic_matches():
    """A forcing at 1.5 Omega is harmonic 1.5 of Omega (m = 1): refused; with m = 2 it is
    harmonic 3 of Omega/2 and accepted."""
    system = System.parse(
        ["x1'' + 0.1*x1' + x1 + (x1 - 1)*Heaviside(x1 - 1) = cos(1.5*Omega*t)"],
        {"Omega": 1.0},
    )
    with pytest.raises(ModelError, match=r"harmonic 1\.5 of the response frequency Omega/1"):
        SystemBalance(system, 5)
    assert SystemBalance(system, 5, m=2).m == 2


@pytest.mark.parametrize("m", [0, -1, 2.5, True, "2"])
def test_bad_m(m):
    with pytest.raises(ParameterError, match=f"m = {m!r}"):
        SystemBalance(builtin_system("nsd2"), 5, m=m)


# ------------------------------------------------------------------ zero combinations -----
@pytest.mark.parametrize(("on", "element"), [("x1 - x1", gap), ("0*x1", polynomial)])
def test_element_on_an_identically_zero_combination(on, element):
    with pytest.raises(ModelError) as info:
        SystemBalance(_pair(on, element), 3)
    msg = str(info.value)
    assert repr(on) in msg and "identically zero" in msg
    # a nonzero combination is accepted
    assert SystemBalance(_pair("x1 - x2", element), 3).n_unknowns == 14


def test_element_whose_combination_vanishes_for_the_parameter_values():
    """(a x1 - 1) H(a x1 - 1) with a = 0: the switching function is the constant -1."""
    zero = System.parse(
        ["x1'' + 0.1*x1' + x1 + (a*x1 - 1)*Heaviside(a*x1 - 1) = cos(Omega*t)"],
        {"a": 0.0, "Omega": 1.0},
    )
    with pytest.raises(ModelError, match="never changes sign") as info:
        SystemBalance(zero, 3)
    assert "nonsmooth(x1)" in str(info.value)
    assert SystemBalance(zero.with_params(a=1.0), 3).neq == 1


# ------------------------------------------------------------------ outputs ---------------
@pytest.mark.parametrize(
    ("output", "expected"),
    [
        ("x3", r"output 'x3'.*unknown name\(s\) \['x3'\]"),
        ("t", r"output 't'.*unknown name"),
        ("x1 - x1", r"output 'x1 - x1'.*identically zero"),
        ("Omega", r"output 'Omega'.*constant term"),
        ("x1**2", r"output 'x1\*\*2'.*not linear"),
        ([0, 0, 0, 0], r"output vector \[0, 0, 0, 0\].*not all zero"),
        ([1.0, 0.0], r"output vector \[1.0, 0.0\]: expected 4 finite numbers"),
        (3, r"output vector 3"),
    ],
)
def test_output_that_is_not_a_coordinate(output, expected):
    system = builtin_system("nsd2")
    for call in (
        lambda: system_balance_branch(system, (1.0, 2.0), harmonics=3, output=output),
        lambda: system_balance_response(system, (1.0, 2.0), harmonics=3, output=output),
        lambda: system_balance_solutions_at(system, [1.0], harmonics=3, output=output),
    ):
        with pytest.raises(PerturbError, match=expected) as info:
            call()
        assert "expected" in str(info.value)


_TH = np.linspace(0, 2 * np.pi, 40001)
_K = np.arange(1, 4)


def _series(D):
    """Samples of D[0] + sum_k D[2k-1] cos k th + D[2k] sin k th over one period (40001
    samples: the sampled max is within 1e-8 of the true one for H = 3)."""
    return D[0] + D[1::2] @ np.cos(np.outer(_K, _TH)) + D[2::2] @ np.sin(np.outer(_K, _TH))


def test_outputs_that_are_accepted():
    """A coordinate, a velocity, a combination and a vector: the branch's output amplitude
    is that signal's max |.| (x1 - x2 checked against the two coordinates' series)."""
    system = builtin_system("nsd2")
    sb = SystemBalance(system, 3)
    for output in ("x2", "x1'", "x1 - x2", [1.0, -1.0, 0.0, 0.0]):
        sols = system_balance_solutions_at(
            system, [1.9], harmonics=3, output=output, balance=sb, stability=False
        )
        b = sols.branches[0]
        U1, U2 = b.U[0, 0], b.U[0, 1]  # [a0, a1, b1, ...] of x1 and x2 at theta = Omega t
        if output == "x2":
            vals = _series(U2)
        elif output == "x1'":
            # d/dt of a_k cos k th + b_k sin k th is Omega k (b_k cos - a_k sin)
            dU = np.zeros_like(U1)
            dU[1::2], dU[2::2] = 1.9 * _K * U1[2::2], -1.9 * _K * U1[1::2]
            vals = _series(dU)
        else:
            vals = _series(U1 - U2)
        assert b.output_amplitude[0] == pytest.approx(np.abs(vals).max(), rel=1e-6), output


@pytest.mark.parametrize(
    ("option", "match"),
    [
        ({"ds_max": -1.0}, r"ds_max = -1.0: expected 0 < ds_max"),
        ({"ds_max": float("nan")}, r"ds_max = nan: expected a finite"),
        ({"tol": "a"}, r"tol = 'a': expected a finite"),
        ({"tol": 2.0}, r"tol = 2.0: expected 0 < tol < 1"),
        ({"max_points": 0}, r"max_points = 0: expected an integer in 2\.\.1000000"),
        ({"max_points": "a"}, r"max_points = 'a'"),
        ({"max_branches": 0}, r"max_branches = 0: expected an integer in 1\.\.1000"),
        ({"stability": "no"}, r"stability = 'no': expected True or False"),
        ({"mirror": "no"}, r"mirror = 'no': expected True or False"),
        ({"branch_points": 1}, r"branch_points = 1: expected True or False"),
    ],
)
def test_bad_response_options_are_named(option, match):
    # before: a bad step or tolerance made every seed fail and was reported as 'no solution at
    # any of the seed frequencies' (blaming the model); text reached the continuation core
    with pytest.raises(ParameterError, match=match):
        system_balance_response(
            builtin_system("nsd2"), (0.5, 2.0), harmonics=3, attractors=False, **option
        )


def test_a_balance_of_another_system_is_refused():
    sb = SystemBalance(builtin_system("nsd2"), 3)
    with pytest.raises(ParameterError, match="built for another system than 'junk'"):
        system_balance_response("junk", (0.5, 2.0), balance=sb, attractors=False)
    with pytest.raises(ParameterError, match="built for another system"):
        system_balance_response(builtin_system("impact_pair"), (0.8, 1.2), balance=sb)


def test_compare_coordinates_of_what_is_no_response():
    from perturb.comparison import compare_coordinates

    with pytest.raises(ParameterError, match="response = 'a': expected a perturb Response"):
        compare_coordinates("a", 3)
