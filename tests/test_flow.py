"""Flows: the smooth reference and the parameter families, against independent builds."""

from __future__ import annotations

import numpy as np
import pytest

from perturb import ModelError, ParameterError, builtin_model
from perturb.simulate.flows.base import Flow, FlowFamily, ODEFlow
from perturb.simulate.flows.exact import ExactPWLFlow


def test_ode_flow_sensitivity_obeys_liouville_and_finite_differences():
    osc = builtin_model("duffing", mu=0.1, F=0.5, Omega=1.3)
    flow = ODEFlow(osc, rtol=1e-12, atol=1e-13)
    assert isinstance(flow, Flow)
    T = flow.period
    res = flow([0.7, -0.2], 0.0, T, sensitivity=True)
    # det of the state-transition matrix = exp(-mu T) for x'' + mu x' + f(x) = F(t)
    assert np.linalg.det(res.sensitivity) == pytest.approx(np.exp(-0.1 * T), rel=1e-9)
    h = 1e-6
    fd = np.column_stack(
        [
            (
                flow([0.7 + h * e[0], -0.2 + h * e[1]], 0.0, T).y
                - flow([0.7 - h * e[0], -0.2 - h * e[1]], 0.0, T).y
            )
            / (2 * h)
            for e in np.eye(2)
        ]
    )
    np.testing.assert_allclose(res.sensitivity, fd, rtol=1e-6, atol=1e-7)


@pytest.mark.parametrize("parameter, value", [(None, 0.83), ("k", -2.7), ("mu", 0.2)])
def test_exact_family_equals_a_flow_built_from_scratch(parameter, value):
    osc = builtin_model("nsd", k=-2.0, mu=0.05, F=2.0, Omega=0.6)
    family = FlowFamily(osc, parameter)
    assert family.exact
    name = parameter or "Omega"
    direct = ExactPWLFlow(osc.with_params({name: value}))
    fam = family.at(value)
    assert fam.period == pytest.approx(direct.period, rel=1e-15)
    a = fam([0.4, 0.3], 0.0, 3 * fam.period, sensitivity=True)
    b = direct([0.4, 0.3], 0.0, 3 * direct.period, sensitivity=True)
    np.testing.assert_allclose(a.y, b.y, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(a.sensitivity, b.sensitivity, rtol=1e-10, atol=1e-12)


def test_ode_family_equals_ode_flow():
    osc = builtin_model("duffing", mu=0.1, F=0.5)
    fam = FlowFamily(osc).at(1.7)
    direct = ODEFlow(osc, Omega=1.7)
    assert fam.period == pytest.approx(2 * np.pi / 1.7)
    np.testing.assert_allclose(
        fam([0.2, 0.1], 0, fam.period).y, direct([0.2, 0.1], 0, direct.period).y, rtol=1e-9
    )


def test_family_with_unorderable_breakpoints_falls_back_per_value():
    # the dead zone's breakpoints -d, d cannot be ordered while d is a free real symbol
    osc = builtin_model("deadzone")
    family = FlowFamily(osc, "d")
    a = family.at(0.7)([1.5, 0.0], 0.0, 5.0).y
    b = ExactPWLFlow(osc.with_params(d=0.7))([1.5, 0.0], 0.0, 5.0).y
    np.testing.assert_allclose(a, b, rtol=1e-12)


def test_family_errors():
    with pytest.raises(ParameterError, match="not in model"):
        FlowFamily(builtin_model("nsd"), "zeta")
    with pytest.raises(ModelError, match="no forcing-frequency"):
        FlowFamily(builtin_model("vanderpol"))
    with pytest.raises(ModelError, match="not piecewise linear"):
        FlowFamily(builtin_model("duffing"), exact=True)
    with pytest.raises(ParameterError, match="finite"):
        FlowFamily(builtin_model("nsd")).at(float("nan"))
