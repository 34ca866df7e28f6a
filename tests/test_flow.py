"""Flows: the smooth reference and the parameter families, against independent builds."""

from __future__ import annotations

import numpy as np
import pytest

from perturb import ModelError, ParameterError, builtin_model
from perturb.simulate.flows.base import Flow, ODEFlow
from perturb.simulate.flows.exact import ExactPWLFlow
from perturb.simulate.flows.factory import FlowFamily


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


def test_declared_capabilities_of_the_concrete_flows():
    from perturb.simulate.flows.event_driven import EventFlow
    from perturb.simulate.flows.piecewise_exact import PWLSystem

    nsd = builtin_model("nsd", k=-2.0, mu=0.05, F=2.0, Omega=0.6)
    exact = ExactPWLFlow(nsd)
    assert isinstance(exact.system, PWLSystem) and exact.rhs is None and exact.surfaces == ()
    assert exact.exact_dense_output and exact.rtol == 0.0 and not exact.autonomous
    # Liouville: det = exp(-mu T), independently of the flow's own matrix
    assert exact.sensitivity_determinant(0.0, 2.0) == pytest.approx(np.exp(-0.05 * 2.0))
    ode = ODEFlow(builtin_model("duffing", mu=0.1, F=0.5, Omega=1.3))
    assert ode.system is None and callable(ode.rhs.fun) and not ode.exact_dense_output
    assert ode.sensitivity_determinant(0.0, 1.0) is None and ode.rtol == pytest.approx(1e-11)
    ev = EventFlow(builtin_model("nsd", k=-2.0, mu=0.05, F=0.0))
    assert len(ev.surfaces) >= 1 and ev.system is None and ev.rhs is None
    free = ExactPWLFlow(builtin_model("nsd", k=-2.0, mu=0.05, F=0.0))
    assert free.autonomous and free.period is None
    for f in (exact, ode, ev):
        assert isinstance(f, Flow)


def test_structural_flows_still_count_and_get_the_defaults():
    from perturb.simulate.flows.base import as_flow

    class Rotation:  # x' = v, v' = -x: no Flow base class, only the interface
        period = None

        def __call__(self, y0, t0, t1, *, sensitivity=False, t_eval=None):
            c, s = np.cos(t1 - t0), np.sin(t1 - t0)
            M = np.array([[c, s], [-s, c]])
            from perturb.simulate.flows.base import FlowResult

            return FlowResult(t0, t1, M @ np.asarray(y0, float), M if sensitivity else None)

        def vector_field(self, t, y):
            return np.array([y[1], -y[0]])

    rot = Rotation()
    assert isinstance(rot, Flow)
    flow = as_flow(rot)
    assert flow.autonomous and flow.system is None and flow.sensitivity_determinant(0, 1) is None
    np.testing.assert_allclose(flow([1.0, 0.0], 0.0, np.pi / 2).y, [0.0, -1.0], atol=1e-15)
    assert as_flow(ODEFlow(builtin_model("duffing", Omega=1.0))) is not None
    with pytest.raises(ParameterError, match="expected a Flow"):
        as_flow(object())
    assert not isinstance(object(), Flow)


def test_make_flow_is_the_one_choice():
    from perturb.simulate.flows.factory import make_flow

    nsd = builtin_model("nsd", k=-2.0, mu=0.05, F=2.0, Omega=0.6)
    assert isinstance(make_flow(nsd), ExactPWLFlow)
    assert isinstance(make_flow(nsd, method="ode"), ODEFlow)
    assert isinstance(make_flow(builtin_model("duffing")), ODEFlow)
    assert make_flow(nsd, 0.7).period == pytest.approx(2 * np.pi / 0.7, rel=1e-15)
    with pytest.raises(ModelError, match="not piecewise linear"):
        make_flow(builtin_model("duffing"), method="exact")
    with pytest.raises(ParameterError, match="method"):
        make_flow(nsd, method="rk4")
    with pytest.raises(ParameterError, match="rtol"):
        make_flow(nsd, rtol=2.0)


# ------------------------------------------------------------------------------------------
# make_flow for systems of several coordinates (issue 15)
# ------------------------------------------------------------------------------------------
def test_make_flow_dispatches_systems():
    from perturb.model.system_builtins import builtin_system
    from perturb.simulate.flows.affine_exact import AffineExactFlow
    from perturb.simulate.flows.factory import SystemODEFlow, make_flow
    from perturb.simulate.flows.system_events import SystemEventFlow
    from perturb.simulate.flows.system_lcp import SystemLCPFlow

    nsd2 = builtin_system("nsd2", Omega=1.2)
    exact = make_flow(nsd2)
    assert isinstance(exact, AffineExactFlow) and exact.period == pytest.approx(2 * np.pi / 1.2)
    assert isinstance(make_flow(nsd2.piecewise_affine()), AffineExactFlow)
    assert make_flow(nsd2, 0.7).period == pytest.approx(2 * np.pi / 0.7)
    ode = make_flow(nsd2, method="ode", rtol=1e-12, atol=1e-12)
    assert isinstance(ode, SystemODEFlow) and ode.n_states == 4
    assert ode.period == pytest.approx(exact.period, rel=1e-15)
    y0 = np.array([0.3, -0.2, 0.1, 0.0])
    T = exact.period
    # no switch reached from this state in one period: the two agree to the ODE tolerance
    np.testing.assert_allclose(ode(y0, 0.0, T).y, exact(y0, 0.0, T).y, atol=1e-9)
    a = ode(y0, 0.0, T, sensitivity=True).sensitivity
    b = exact(y0, 0.0, T, sensitivity=True).sensitivity
    np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-7)
    # not piecewise linear: the ODE flow of System.field (autonomous belt); a friction
    # contact gets the event-driven flow by default, method="ode" steps over the sticking
    belt = make_flow(builtin_system("belt"), method="ode")  # Stribeck exp(-|v|): not PWL
    assert isinstance(belt, SystemODEFlow) and belt.autonomous and belt.period is None
    # x'' = -x - (mu_k + (mu_s - mu_k) exp(-|x' - v_b| / v_s)) sign(x' - v_b), x = x' = 1
    assert belt.vector_field(0.0, [1.0, 1.0]) == pytest.approx(
        [1.0, -1.0 - (0.25 + 0.15 * np.exp(-0.8 / 0.5))], rel=1e-14
    )
    h = 1e-6
    fd = (belt.vector_field(0.0, [1.0, 1.0 + h]) - belt.vector_field(0.0, [1.0, 1.0 - h])) / 2 / h
    np.testing.assert_allclose(belt.jacobian(0.0, [1.0, 1.0])[:, 1], fd, rtol=1e-8)
    # friction contacts and stops switch modes (sticking, impacts, resting): by default the
    # event-driven flow, which locates those events; with the modes fixed, the exact flow
    coulomb = builtin_system("belt", mu_s=0.25, mu_k=0.25)  # sign(): PWL
    assert isinstance(make_flow(coulomb), SystemEventFlow)
    assert isinstance(make_flow(coulomb, active={"friction(x')": None}), AffineExactFlow)
    assert isinstance(make_flow(coulomb, method="exact"), AffineExactFlow)
    with pytest.raises(ModelError, match="not piecewise linear"):
        make_flow(builtin_system("belt"), method="exact")
    assert isinstance(make_flow(builtin_system("mount")), SystemEventFlow)
    with pytest.raises(ModelError, match="decoupler"):
        make_flow(builtin_system("mount"), method="exact")
    assert isinstance(make_flow(builtin_system("mount"), active={"decoupler": -1}), AffineExactFlow)
    assert isinstance(make_flow(builtin_system("mount"), method="lcp", h=1e-4), SystemLCPFlow)
    with pytest.raises(ParameterError, match="h = None"):
        make_flow(builtin_system("mount"), method="lcp")
    with pytest.raises(ParameterError, match="h = 0.1"):
        make_flow(builtin_system("mount"), h=0.1)
    with pytest.raises(ParameterError, match="method = 'rk4'"):
        make_flow(builtin_system("mount"), method="rk4")
    with pytest.raises(ParameterError, match="Omega"):
        make_flow(nsd2.piecewise_affine(), 1.0)
    with pytest.raises(ParameterError, match="active"):
        make_flow(builtin_model("nsd", k=-2.0, mu=0.05, F=2.0, Omega=0.6), active={"a": None})
    with pytest.raises(ParameterError, match="expected an Oscillator, a System"):
        make_flow("nsd2")
