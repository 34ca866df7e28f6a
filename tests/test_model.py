"""The Oscillator: parsing into parts, forcing, parameters, builtin models."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import sympy as sp

from perturb import BUILTIN_MODELS, ModelError, Oscillator, ParameterError, builtin_model
from perturb.model.parsing import real_symbol

x, v, t = real_symbol("x"), real_symbol("x'"), real_symbol("t")
k, mu, F, W = (real_symbol(n) for n in ("k", "mu", "F", "Omega"))


def test_every_builtin_model_builds_and_round_trips_its_equation():
    for name, spec in BUILTIN_MODELS.items():
        osc = builtin_model(name)
        assert osc.name == name
        assert dict(osc.params) == dict(spec.defaults)
        # g is the sum of its parts
        parts = (
            osc.damping * osc.v
            + osc.linear_stiffness * osc.x
            + osc.polynomial
            + osc.nonsmooth
            + osc.smooth
            + osc.velocity
            + osc.parametric
        )
        assert sp.simplify(parts - osc.g) == 0, name
        assert name in str(osc)


def test_nsd_parts():
    osc = builtin_model("nsd")
    assert osc.damping == mu
    assert osc.linear_stiffness == k
    assert osc.polynomial == 0 and osc.smooth == 0 and osc.velocity == 0
    assert osc.nonsmooth.has(sp.Heaviside)
    assert osc.forcing.harmonics[0].amplitude == F
    assert osc.forcing.harmonics[0].frequency == W
    assert not osc.is_autonomous and osc.is_piecewise_linear


def test_parts_of_other_models():
    assert builtin_model("duffing").polynomial == real_symbol("alpha") * x**3
    vdp = builtin_model("vanderpol")
    assert vdp.is_autonomous and vdp.velocity != 0 and vdp.damping == -real_symbol("eps")
    math_ = builtin_model("mathieu")
    assert math_.parametric != 0 and math_.is_autonomous is False
    assert builtin_model("pendulum").smooth.has(sp.sin)
    for name in ("clearance", "deadzone", "saturation", "bilinear", "nsd"):
        assert builtin_model(name).is_piecewise_linear, name
    for name in ("duffing", "vanderpol", "mathieu", "pendulum", "quadratic_cubic"):
        assert not builtin_model(name).is_piecewise_linear, name


def test_nsd_canonical_form_matches_the_segments_derived_by_hand():
    # f(x) = kx for |x| < 1; x - (1 - k) for x > 1; x + (1 - k) for x < -1
    kval = -2.0
    pwl = builtin_model("nsd", k=kval).piecewise_linear()
    assert [float(d) for d in pwl.breakpoints] == [-1.0, 1.0]
    assert [float(s) for s in pwl.slopes] == [1.0, kval, 1.0]
    assert [float(c) for c in pwl.offsets] == [1 - kval, 0.0, -(1 - kval)]


def test_mass_is_divided_out_and_static_load_goes_to_the_forcing():
    osc = Oscillator.parse("m*(x'' + x) + c*x' + 3 = F*cos(W*t)")
    m, c = real_symbol("m"), real_symbol("c")
    assert sp.simplify(osc.damping - c / m) == 0
    assert osc.linear_stiffness == 1
    assert osc.forcing.constant == -3 / m


def test_from_sympy_matches_parse():
    xf = sp.Function("x")
    ts = sp.Symbol("t")
    kk, mm, ff, ww = sp.symbols("k mu F Omega")
    lhs = xf(ts).diff(ts, 2) + mm * xf(ts).diff(ts) + kk * xf(ts) + xf(ts) ** 3
    osc = Oscillator.from_sympy(sp.Eq(lhs, ff * sp.cos(ww * ts)), xf(ts), ts)
    ref = Oscillator.parse("x'' + mu*x' + k*x + x**3 = F*cos(Omega*t)")
    assert sp.simplify(osc.g - ref.g) == 0
    assert osc.forcing == ref.forcing
    assert osc.params.keys() == ref.params.keys()


def test_forcing_forms():
    osc = Oscillator.parse("x'' + x = A1*sin(W*t) + A2*cos(3*W*t + 1) + cos(W*t)**2")
    by_freq = {h.frequency: h for h in osc.forcing.harmonics}
    w = real_symbol("W")
    assert by_freq[w].phase == -sp.pi / 2
    assert by_freq[3 * w].phase == 1
    assert by_freq[2 * w].amplitude == sp.Rational(1, 2)
    assert osc.forcing.constant == sp.Rational(1, 2)
    assert sp.simplify(osc.forcing.base_frequency - w) == 0
    # the harmonics reproduce the written right-hand side
    written = (
        sp.sympify(0)
        + real_symbol("A1") * sp.sin(w * t)
        + real_symbol("A2") * sp.cos(3 * w * t + 1)
        + sp.cos(w * t) ** 2
    )
    rng = np.random.default_rng(0)
    for _ in range(5):
        vals = {s: rng.uniform(0.3, 2) for s in written.free_symbols}
        assert float(osc.forcing.expr(t).subs(vals)) == pytest.approx(float(written.subs(vals)))
    assert Oscillator.parse("x'' + x = cos(2*t) + cos(3*t)").forcing.base_frequency == 1


@pytest.mark.parametrize(
    "text, fragment",
    [
        ("x' + x = 0", "no second derivative"),
        ("x + 1 = 0", "no second derivative"),
        ("x'' + x**2*x'' = 0", "nonlinearly"),
        ("x*x'' + x = 0", "depends on the state"),
        ("x'' + x = t*cos(t)", "not periodic"),
        ("x'' + x = exp(-t)", "not periodic"),
        ("x'' + x = cos(t**2)", "not periodic"),
        ("x'' + x = cos(t) + cos(sqrt(2)*t)", "ratio sqrt(2)"),
        ("x'' + t*x = 0", "not periodic"),
    ],
)
def test_equations_that_are_not_oscillators(text, fragment):
    with pytest.raises(ModelError) as info:
        Oscillator.parse(text)
    assert fragment in str(info.value)


@pytest.mark.parametrize(
    "value", [math.nan, math.inf, -math.inf, "1.0", True, 1 + 2j, None.__class__]
)
def test_bad_parameter_values_are_refused(value):
    with pytest.raises(ParameterError) as info:
        builtin_model("nsd").with_params(mu=value)
    assert "'mu'" in str(info.value)


def test_parameters_unknown_free_and_required():
    osc = builtin_model("nsd")
    with pytest.raises(ParameterError, match="unknown parameter 'kk'"):
        osc.with_params(kk=1.0)
    free = osc.with_params(k=None)
    assert free.free_parameters == ("k",)
    with pytest.raises(ParameterError, match="needs values for k"):
        free.require_values()
    assert osc.require_values("k") == {"k": -2.0}
    with pytest.raises(ModelError, match="unknown model"):
        builtin_model("nope")


def test_oscillator_is_immutable_and_with_params_copies():
    osc = builtin_model("nsd")
    with pytest.raises(dataclasses.FrozenInstanceError):
        osc.g = x  # type: ignore[misc]
    with pytest.raises(TypeError):
        osc.params["k"] = 1.0  # type: ignore[index]
    other = osc.with_params(k=-3)
    assert osc.params["k"] == -2.0 and other.params["k"] == -3.0


def test_symbolic_clearance_gap_is_kept_symbolic_until_values_are_given():
    osc = builtin_model("clearance").with_params(d=None)
    pwl = osc.piecewise_linear()  # a single breakpoint needs no ordering
    assert pwl.breakpoints == (real_symbol("d"),)


def test_latex_and_str():
    osc = builtin_model("nsd")
    # Heaviside prints as H, never as SymPy's \theta (the crossing angle's name)
    assert "\\theta" not in osc._repr_latex_()
    assert "H\\left(x - 1\\right)" in osc._repr_latex_()
    assert "k=-2" in str(osc)


PWL_MODELS = ("nsd", "clearance", "deadzone", "saturation", "bilinear")


@pytest.mark.parametrize("name", PWL_MODELS)
def test_builtin_canonical_forms_round_trip(name):
    """Canonical form vs the builtin's own restoring force, at random points and parameters."""
    from hypothesis import given, settings
    from hypothesis import strategies as st

    spec = BUILTIN_MODELS[name]

    @settings(max_examples=40, deadline=None, database=None)
    @given(
        scale=st.lists(
            st.floats(0.2, 3.0), min_size=len(spec.defaults), max_size=len(spec.defaults)
        ),
        xs=st.lists(st.floats(-20, 20, allow_nan=False), min_size=5, max_size=5),
    )
    def check(scale, xs):
        # gaps/dead-zones must stay positive: scale every default by a positive factor
        values = {
            p: v * s if v != 0 else s
            for (p, v), s in zip(spec.defaults.items(), scale, strict=True)
        }
        osc = builtin_model(name, **values)
        pwl = osc.piecewise_linear().numeric()
        f = sp.lambdify(osc.x, osc.restoring_force.xreplace(osc.substitutions()), "sympy")
        for xv in xs:
            if np.min(np.abs(np.asarray(pwl.breakpoints) - xv), initial=np.inf) < 1e-9:
                continue
            exact = float(f(sp.Rational(xv)))
            assert float(pwl(xv)) == pytest.approx(exact, rel=1e-12, abs=1e-12)

    check()
