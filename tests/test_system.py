"""The n-coordinate model (perturb.model.system): parsing, matrices, elements, the
piecewise-affine data, the SDOF case and the builtin systems against independent right-hand
sides (hand-coded numpy, derivations/hydraulic_mount.py)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import sympy as sp

from perturb.errors import ModelError, ParameterError, PerturbError
from perturb.model.builtins import builtin_model
from perturb.model.parsing import real_symbol
from perturb.model.system import (
    System,
    coulomb,
    dead_zone,
    element,
    gap,
    polynomial,
    pwl_spring,
    saturation,
    step,
    stop,
)
from perturb.model.system_builtins import BUILTIN_SYSTEMS, builtin_system

RNG = np.random.default_rng(20261127)


def sym(*names):
    return [real_symbol(n) for n in names]


# ------------------------------------------------------------------------ linear part --
def test_linear_part_of_parsed_strings_equals_hand_written_matrices():
    s = System.parse(
        [
            "x1'' + c1*x1' + c2*(x1' - x2') + k1*x1 + k2*(x1 - x2) = F*cos(Omega*t)",
            "m2*x2'' + c2*(x2' - x1') + k2*(x2 - x1) + k3*(x2 - x3) = 0",
            "m3*(x3'' + 2*x2'') + k3*(x3 - x2) = 0",
        ]
    )
    c1, c2, k1, k2, k3, m2, m3, F, Om, t = sym(
        "c1", "c2", "k1", "k2", "k3", "m2", "m3", "F", "Omega", "t"
    )
    assert s.coordinates == ("x1", "x2", "x3") and s.first_order == ()
    assert s.state_names == ("x1", "x2", "x3", "x1'", "x2'", "x3'")
    assert s.M == sp.Matrix([[1, 0, 0], [0, m2, 0], [0, 2 * m3, m3]])
    assert s.C == sp.Matrix([[c1 + c2, -c2, 0], [-c2, c2, 0], [0, 0, 0]])
    assert s.K == sp.Matrix([[k1 + k2, -k2, 0], [-k2, k2 + k3, -k3], [0, -k3, k3]])
    assert s.F == sp.Matrix([F * sp.cos(Om * t), 0, 0])
    assert s.elements == ()
    assert set(s.free_parameters) == {"c1", "c2", "k1", "k2", "k3", "m2", "m3", "F", "Omega"}


def test_first_order_states_are_declared_by_a_single_prime():
    s = System.parse(["x'' + k*x + A*p = 0", "C1*p' = A*x' - q", "I*q' + R*q = p"])
    A, C1, I_, R, k = sym("A", "C1", "I", "R", "k")
    assert s.coordinates == ("x",) and s.first_order == ("p", "q")
    assert s.state_names == ("x", "x'", "p", "q")
    assert s.M == sp.Matrix([[1], [0], [0]])
    assert s.D == sp.Matrix([[0, 0], [C1, 0], [0, I_]])
    assert s.C == sp.Matrix([[0], [-A], [0]]) and s.K == sp.Matrix([[k], [0], [0]])
    assert s.E == sp.Matrix([[A, 0], [0, 1], [-1, R]])
    vals = {"A": 2.0, "C1": 0.5, "I": 3.0, "R": 0.7, "k": 1.3}
    y = RNG.normal(size=4)
    x, v, p, q = y
    want = [
        v,
        -vals["k"] * x - vals["A"] * p,
        (vals["A"] * v - q) / vals["C1"],
        (p - vals["R"] * q) / vals["I"],
    ]
    assert np.allclose(s.with_params(vals).field(0.0, y), want, rtol=1e-14, atol=1e-14)


def test_from_sympy_and_from_matrices_agree_with_parse():
    t = sp.Symbol("t")
    x1, x2 = sp.Function("x1")(t), sp.Function("x2")(t)
    k, c, F, Om = sp.symbols("k c F Omega")
    eqs = [
        sp.Eq(x1.diff(t, 2) + c * x1.diff(t) + 2 * x1 - x2, F * sp.cos(Om * t)),
        x2.diff(t, 2) + k * (x2 - x1) + x2,
    ]
    a = System.from_sympy(eqs, ["x1", "x2"])
    b = System.parse(["x1'' + c*x1' + 2*x1 - x2 = F*cos(Omega*t)", "x2'' + k*(x2 - x1) + x2 = 0"])
    m = System.from_matrices(
        [[1, 0], [0, 1]],
        [["c", 0], [0, 0]],
        [[2, -1], ["-k", "k + 1"]],
        forcing=["F*cos(Omega*t)", 0],
    )
    for other in (a, m):
        assert (other.M, other.C, other.K, other.F) == (b.M, b.C, b.K, b.F)


# ------------------------------------------------------------------ 2-DOF nsd structure --
def _nsd2_rhs(p):
    """Hand-coded right-hand side of the 2-DOF nsd structure (system_builtins docstring)."""

    def f(x):
        return p["k"] * x + (1 - p["k"]) * (
            (x - 1) * np.heaviside(x - 1, 0.5) + (x + 1) * np.heaviside(-x - 1, 0.5)
        )

    def rhs(t, y):
        x1, x2, v1, v2 = y
        a1 = (
            p["F"] * math.cos(p["Omega"] * t)
            - p["mu1"] * v1
            - p["mu2"] * (v1 - v2)
            - f(x1)
            - p["k2"] * (x1 - x2)
        )
        a2 = (-p["mu2"] * (v2 - v1) - p["k2"] * (x2 - x1)) / p["m2"]
        return np.array([v1, v2, a1, a2])

    return rhs


def test_nsd2_piecewise_affine_field_equals_hand_coded_rhs():
    for trial in range(3):
        p = dict(BUILTIN_SYSTEMS["nsd2"].defaults)
        if trial:
            p.update(
                k=RNG.uniform(-2, 0.5),
                mu1=RNG.uniform(0, 0.2),
                mu2=RNG.uniform(0, 0.2),
                k2=RNG.uniform(0.2, 3),
                m2=RNG.uniform(0.3, 3),
                F=RNG.uniform(0.1, 3),
                Omega=RNG.uniform(0.3, 3),
            )
        s = builtin_system("nsd2", **p)
        pa = s.piecewise_affine()
        assert pa.state_names == ("x1", "x2", "x1'", "x2'")
        assert [sf.offset for sf in pa.surfaces] == [-1.0, 1.0]
        assert sorted(pa.regions) == [(-1, -1), (1, -1), (1, 1)]  # (-1, +1) cannot occur
        assert pa.period == pytest.approx(2 * math.pi / p["Omega"], rel=1e-15)
        assert all(pa.continuous)
        want = _nsd2_rhs(p)
        for _ in range(200):
            y = RNG.uniform(-3, 3, size=4)
            t = RNG.uniform(0, 20)
            ref = want(t, y)
            scale = max(1.0, np.abs(ref).max())
            assert np.abs(pa.field(t, y) - ref).max() <= 1e-12 * scale
            assert np.abs(s.field(t, y) - ref).max() <= 1e-12 * scale


def test_nsd2_from_matrices_with_a_named_element_equals_the_parsed_model():
    p = dict(BUILTIN_SYSTEMS["nsd2"].defaults)
    m = System.from_matrices(
        [[1, 0], [0, "m2"]],
        [["mu1 + mu2", "-mu2"], ["-mu2", "mu2"]],
        [["k + k2", "-k2"], ["-k2", "k2"]],
        elements=[
            element(
                "x1", "(1 - k)*((s - 1)*Heaviside(s - 1) + (s + 1)*Heaviside(-s - 1))", name="nsd"
            )
        ],
        forcing=["F*cos(Omega*t)", 0],
        params=p,
    )
    assert m.element("nsd").distribution == (1, 0)
    a, b = m.piecewise_affine(), builtin_system("nsd2").piecewise_affine()
    assert sorted(a.regions) == sorted(b.regions)
    for key in a.regions:
        assert np.allclose(a.regions[key].A, b.regions[key].A, rtol=1e-15, atol=0)
        assert np.allclose(a.regions[key].b, b.regions[key].b, rtol=1e-15, atol=0)


def test_impact_pair_gap_factory_and_distribution():
    s = builtin_system("impact_pair")
    (e,) = s.elements
    assert e.kind == "nonsmooth" and e.distribution == (1, -1)
    p = dict(BUILTIN_SYSTEMS["impact_pair"].defaults)
    m = System.from_matrices(
        [[1, 0], [0, "m2"]],
        [["mu", 0], ["-mu2", "mu2"]],
        [[1, 0], [0, 0]],
        elements=[gap("x1 - x2", "d", "r")],
        forcing=["F*cos(Omega*t)", 0],
        params=p,
    )
    for _ in range(50):
        y, t = RNG.uniform(-2, 2, size=4), RNG.uniform(0, 10)
        assert np.allclose(m.field(t, y), s.field(t, y), rtol=1e-14, atol=1e-14)
        assert np.allclose(m.piecewise_affine().field(t, y), s.field(t, y), rtol=1e-13, atol=1e-13)


# --------------------------------------------------------------------------- SDOF case --
@pytest.mark.parametrize("name", ["nsd", "clearance", "deadzone", "saturation", "bilinear"])
def test_from_oscillator_reproduces_the_sdof_pwl_data(name):
    osc = builtin_model(name)
    s = System.from_oscillator(osc)
    assert s.coordinates == (osc.x.name,) and dict(s.params) == dict(osc.params)
    pa = s.piecewise_affine()
    pwl = osc.piecewise_linear().numeric()
    assert np.allclose([sf.offset for sf in pa.surfaces], pwl.breakpoints, rtol=1e-15, atol=0)
    for i in range(len(pwl.slopes)):
        # the i-th segment: every surface below it crossed
        key = tuple(1 if j < i else -1 for j in range(len(pwl.breakpoints)))
        reg = pa.regions[key]
        assert reg.A[1, 0] == pytest.approx(-pwl.slopes[i], rel=1e-14, abs=1e-14)
        assert reg.b[1] == pytest.approx(-pwl.offsets[i], rel=1e-14, abs=1e-14)
        assert reg.A[1, 1] == pytest.approx(-osc.params["mu"], rel=1e-15)
    assert pa.period == pytest.approx(2 * math.pi / osc.params["Omega"], rel=1e-15)
    (h,) = pa.inputs
    assert h.u[1] == pytest.approx(osc.params["F"], rel=1e-15)
    # the whole field against the oscillator's own equation
    x, v, t = osc.x, osc.v, osc.t
    g = sp.lambdify((x, v, t), (osc.forcing.expr(t) - osc.g).xreplace(osc.substitutions()))
    for _ in range(50):
        y, tt = RNG.uniform(-3, 3, size=2), RNG.uniform(0, 10)
        assert np.allclose(pa.field(tt, y), [y[1], g(y[0], y[1], tt)], rtol=1e-13, atol=1e-13)


# -------------------------------------------------------------------------- the mount --
def _script_rhs(m, X, *, floating):
    """The right-hand side of the derivation script's historical ``solve_ivp`` loop
    (``simulate_mount`` before it moved onto perturb's solvers), copied here as an
    independent oracle: states (V_i, q_i, V_d, q_d), in the mode it starts in (plate on the
    top stop, vacuum according to X) or, with ``floating``, after an "open" event."""
    knee = -m.p_vac * m.C1
    vac = m.A_r * X < knee
    dec = 0 if floating else -1

    def rhs(_t, y):
        dv1 = m.A_r * X - y[0] - y[2]
        p1 = -m.p_vac + (dv1 + m.p_vac * m.C1) / m.C1_vac if vac else dv1 / m.C1
        p2 = (y[0] + y[2]) / m.C2
        dq_i = (p1 - p2 - m.R_i * y[1]) / m.I_i
        if dec == 0:
            return [y[1], dq_i, y[3], (p1 - p2 - m.R_d * y[3]) / m.I_d]
        return [y[1], dq_i, 0.0, 0.0]

    return rhs


def test_mount_field_equals_the_derivation_script(derivation_module):
    hm = derivation_module("hydraulic_mount")
    m = hm.Mount()
    knee = -m.p_vac * m.C1
    perm = [0, 2, 1, 3]  # ours (V_i, V_d, V_i', V_d') -> script (V_i, q_i, V_d, q_d)
    worst = 0.0
    for X, vac in ((m.X_free, True), (-1.0e-3, False)):
        assert (m.A_r * X < knee) is vac  # the script starts in this vacuum mode
        s = builtin_system("mount", X=X)
        for floating in (False, True):
            rhs = _script_rhs(m, X, floating=floating)
            active = {"decoupler": None if floating else -1}
            pa = s.piecewise_affine(active)
            n_checked = 0
            for _ in range(400):
                V = RNG.uniform(-1, 1, size=2) * 5e-6
                q = RNG.uniform(-1, 1, size=2) * 1e-4
                if bool(m.A_r * X - V.sum() < knee) is not vac:
                    continue  # the script's mode fixes the vacuum; ours reads it off the state
                y = np.array([V[0], V[1], q[0], q[1]])
                ref = np.asarray(rhs(0.0, y[perm]), dtype=float)
                for got in (s.field(0.0, y, active), pa.field(0.0, y)):
                    err = np.abs(got[perm] - ref) / np.maximum(np.abs(ref), 1e-300)
                    err = np.where(ref == 0, np.abs(got[perm]), err)
                    worst = max(worst, float(err.max()))
                n_checked += 1
            assert n_checked > 50
    print(f"mount: worst relative deviation from the script {worst:.3g}")
    assert worst <= 1e-9, worst


def test_mount_linear_first_order_form_equals_integrate_full(derivation_module):
    """``mount_linear`` against the right-hand side of the script's historical
    ``integrate_full`` (copied here: the script now calls perturb's step response)."""
    m = derivation_module("hydraulic_mount").Mount()

    def rhs(_t, y):
        p1, p2, qi, qd = y
        return [
            -(qi + qd) / m.C1,
            (qi + qd) / m.C2,
            (p1 - p2 - m.R_i * qi) / m.I_i,
            (p1 - p2 - m.R_d * qd) / m.I_d,
        ]

    calls = [rhs]
    s = builtin_system("mount_linear", Xa=0.0)
    assert s.first_order == ("p1", "p2", "q_i", "q_d") and s.coordinates == ()
    pa = s.piecewise_affine()
    assert pa.period is None and pa.inputs == ()
    for _ in range(100):
        y = np.concatenate([RNG.uniform(-1, 1, 2) * 1e5, RNG.uniform(-1, 1, 2) * 1e-4])
        ref = np.array(calls[0](0.0, y))
        assert np.allclose(s.field(0.0, y), ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())
        assert np.allclose(pa.field(0.0, y), ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())


# ------------------------------------------------------------------- friction, stops --
def test_friction_elements_and_sticking():
    belt = builtin_system("belt")
    (e,) = belt.elements
    assert e.kind == "friction" and belt.state_names == ("x", "x'")
    with pytest.raises(ModelError, match=r"friction\(x'\).*not piecewise linear"):
        belt.piecewise_affine()
    coul = builtin_system("belt", mu_s=0.25)  # Coulomb: piecewise linear with a jump
    pa = coul.piecewise_affine()
    assert [sf.offset for sf in pa.surfaces] == [0.2] and pa.continuous == (False,)
    # stuck on the belt: the friction force holds x'' = 0
    assert np.allclose(belt.field(0.0, [0.3, 0.2], {e.name: 1}), [0.2, 0.0])
    assert builtin_system("drill_string").element("friction(phi_b')").kind == "friction"
    m = System.from_matrices([[1]], [[0]], [[1]], elements=[coulomb("x1'", 0.3, offset=0.1)])
    assert m.elements[0].kind == "friction"
    assert m.field(0, [0.0, 1.0])[1] == pytest.approx(-0.3)
    with pytest.raises(ModelError, match="stop"):
        builtin_system("mount").piecewise_affine()


def test_every_builtin_builds_prints_and_is_immutable():
    for name in BUILTIN_SYSTEMS:
        s = builtin_system(name)
        text = str(s)
        assert name in text and all(c in text for c in s.coordinates + s.first_order)
        assert s.n == len(s.state_names)
        with pytest.raises(dataclasses.FrozenInstanceError):
            s.name = "x"  # type: ignore[misc]
    with pytest.raises(ModelError, match="'nope'"):
        builtin_system("nope")


# ------------------------------------------------------------------------ bad input --
def _raises(exc, match, fn, *args, **kw):
    with pytest.raises(exc, match=match) as info:
        fn(*args, **kw)
    assert isinstance(info.value, PerturbError)
    return str(info.value)


def test_bad_input_each_a_clear_perturb_error():
    eye, zero = [[1, 0], [0, 1]], [[0, 0], [0, 0]]
    # singular mass matrix without a first-order declaration
    _raises(ModelError, r"singular.*first-order", System.from_matrices, [[1, 1], [1, 1]], zero, eye)
    _raises(
        ModelError, r"singular", System.parse, ["x1'' + x2'' + x1 = 0", "2*x1'' + 2*x2'' + x2 = 0"]
    )
    _raises(
        ModelError,
        r"singular for the parameter values",
        System.parse(["x1'' + x2'' + x1 = 0", "a*x1'' + x2'' + x2 = 0"], {"a": 1.0}).field,
        0.0,
        [0, 0, 0, 0],
    )
    # a nonlinear element on an unknown coordinate
    _raises(
        ModelError,
        r"x1 - x3.*unknown coordinate.*x3",
        System.from_matrices,
        eye,
        zero,
        eye,
        elements=[gap("x1 - x3", 0.1, 10)],
    )
    _raises(
        ModelError,
        r"Heaviside\(x3 - 1\).*switches on no coordinate",
        System.parse,
        ["x1'' + x1 + Heaviside(x3 - 1)*x3 = 0"],
    )
    # mismatched dimensions
    _raises(
        ModelError,
        r"K has shape \(3, 3\).*\(2, 2\)",
        System.from_matrices,
        eye,
        zero,
        [[1, 0, 0], [0, 1, 0], [0, 0, 1]],
    )
    _raises(
        ModelError,
        r"forcing has 3 entries: expected 2",
        System.from_matrices,
        eye,
        zero,
        eye,
        forcing=[0, 0, 0],
    )
    _raises(
        ModelError,
        r"3 equation\(s\) for 2 coordinate",
        System.parse,
        ["x1'' + x1 = 0", "x2'' + x2 = 0", "x1 + x2 = 0"],
    )
    _raises(
        ModelError,
        r"coordinates = \['x1', 'x2', 'x3'\]: 3 names for 2 rows",
        System.from_matrices,
        eye,
        zero,
        eye,
        coordinates=["x1", "x2", "x3"],
    )
    # a switching function that never changes sign
    _raises(
        ModelError,
        r"'x1 - x1'.*identically zero.*never changes sign",
        System.from_matrices,
        eye,
        zero,
        eye,
        elements=[gap("x1 - x1", 0.1, 10)],
    )
    # nonsmooth argument not affine; a term on two combinations
    _raises(
        ModelError, r"x1\*\*2 - 1.*not affine", System.parse, ["x1'' + Heaviside(x1**2 - 1) = 0"]
    )
    _raises(
        ModelError,
        r"two different combinations",
        System.parse,
        ["x1'' + Heaviside(x1 - 1)*Heaviside(x2 - 1) = 0", "x2'' = 0"],
    )
    # output not a coordinate or combination
    s = builtin_system("nsd2")
    assert np.array_equal(s.output("x1 - x2"), [1, -1, 0, 0])
    assert np.array_equal(s.output("x2'"), [0, 0, 0, 1])
    assert np.array_equal(s.output("k2*x2"), [0, 1, 0, 0])
    for bad, why in (
        ("x3", "unknown name"),
        ("x1*x2", "not linear"),
        ("x1 + 1", "constant"),
        ("x1 - x1", "identically zero"),
        ("Abs(x1)", "not linear"),
    ):
        msg = _raises(ModelError, why, s.output, bad)
        assert repr(bad) in msg and "x1 - x2" in msg
    # PWL data from a non-PWL system / free parameters / unknown parameter
    _raises(ModelError, r"friction\(phi_b'\)", builtin_system("drill_string").piecewise_affine)
    _raises(
        ParameterError, r"needs values for .*k", System.parse(["x'' + k*x = 0"]).piecewise_affine
    )
    _raises(ParameterError, r"unknown parameter 'zz'", builtin_system, "nsd2", zz=1.0)
    # the field at a state of the wrong length names it (was a matmul ValueError)
    _raises(ParameterError, r"y = \[0.0, 0.0, 0.0\]: expected 4 numbers",
            builtin_system("nsd2").field, 0.0, [0.0, 0.0, 0.0])  # fmt: skip
    _raises(ParameterError, r"'k'.*finite", builtin_system, "nsd2", k=float("nan"))
    # stops: bad restitution; active element that is no constraint
    _raises(ParameterError, r"restitution", stop, "x1", 0, 1, restitution=2.0)
    _raises(
        ModelError,
        r"active element .* expected a stop or a friction",
        s.field,
        0.0,
        [0, 0, 0, 0],
        {s.elements[0].name: 1},
    )


def test_parser_is_not_bypassed():
    # a string is read by the safe parser only: calls of unknown functions are refused
    from perturb.errors import ParseError

    _raises(
        ParseError,
        r"unknown function '__import__'|not allowed",
        System.parse,
        ["x'' + __import__('os') = 0"],
    )
    _raises(ParseError, "unknown function 'g'", System.parse, ["x'' + g(x) = 0"])
    _raises(ParseError, "reserved", System.parse, ["x'' + x__d1 = 0"])
    _raises(ParseError, "only first", System.parse, ["x''' + x = 0"])


# ---------------------------------------------------------------- element factories --
@pytest.mark.parametrize(
    ("name", "spec"),
    [
        ("deadzone", lambda: dead_zone("x", "d", "k2")),
        ("saturation", lambda: saturation("x", "d", "k2")),
        ("clearance", lambda: pwl_spring("x", ["d"], [0, "r"])),
    ],
)
def test_factories_reproduce_the_sdof_builtins(name, spec):
    osc = builtin_model(name)
    p = {k: v for k, v in osc.params.items() if k in ("mu", "d", "k2", "r", "F", "Omega")}
    k_lin = osc.params.get("k1", 1.0)
    m = System.from_matrices(
        [[1]],
        [["mu"]],
        [[k_lin]],
        elements=[spec()],
        forcing=["F*cos(Omega*t)"],
        coordinates=["x"],
        params=p,
    )
    ref = System.from_oscillator(osc)
    a, b = m.piecewise_affine(), ref.piecewise_affine()
    assert [sf.offset for sf in a.surfaces] == pytest.approx([sf.offset for sf in b.surfaces])
    for _ in range(50):
        y, t = RNG.uniform(-3, 3, size=2), RNG.uniform(0, 10)
        assert np.allclose(a.field(t, y), b.field(t, y), rtol=1e-13, atol=1e-13)
        assert np.allclose(m.field(t, y), ref.field(t, y), rtol=1e-13, atol=1e-13)


def test_steps_and_smooth_polynomial_elements():
    s = System.parse(
        [
            "x1'' + x1 + a*(x1 - x2)**3 + J*Heaviside(x1 - x2 - 1) = 0",
            "x2'' + x2 - a*(x1 - x2)**3 - J*Heaviside(x1 - x2 - 1) = 0",
        ],
        {"a": 0.7, "J": 0.3},
    )
    kinds = sorted((e.kind, e.distribution) for e in s.elements)
    assert kinds == [("nonsmooth", (1, -1)), ("smooth", (1, -1))]
    with pytest.raises(ModelError, match=r"smooth\(x1 - x2\).*not piecewise linear"):
        s.piecewise_affine()
    assert not s.is_piecewise_linear
    for _ in range(50):
        x1, x2, v1, v2 = y = RNG.uniform(-2, 2, size=4)
        f = 0.7 * (x1 - x2) ** 3 + 0.3 * (x1 - x2 >= 1)
        assert np.allclose(s.field(0.0, y), [v1, v2, -x1 - f, -x2 + f], rtol=1e-14, atol=1e-14)
    m = System.from_matrices(
        [[1, 0], [0, 1]],
        [[0, 0], [0, 0]],
        [[1, 0], [0, 1]],
        elements=[polynomial("x1 - x2", [0, 0, 0, 0.7]), step("x1 - x2", 1, 0.3)],
    )
    for _ in range(20):
        y = RNG.uniform(-2, 2, size=4)
        assert np.allclose(m.field(0.0, y), s.field(0.0, y), rtol=1e-14, atol=1e-14)
    jump = m.piecewise_affine  # the polynomial element is not PWL
    with pytest.raises(ModelError, match="polynomial"):
        jump()
    only_step = System.from_matrices([[1]], [[0.1]], [[1]], elements=[step("x1", 1, 0.3)])
    pa = only_step.piecewise_affine()
    assert pa.continuous == (False,) and pa.regions[(1,)].b[1] == pytest.approx(-0.3)


def test_constraints_and_numerically_zero_combinations():
    (c,) = builtin_system("mount").constraints()
    assert c.kind == "stop" and c.lower == 0.0 and c.upper == pytest.approx(1.5e-6)
    assert np.array_equal(c.normal, [0, 1, 0, 0]) and np.array_equal(c.distribution, [0, 1])
    (f,) = builtin_system("belt").constraints()
    assert f.kind == "friction" and np.array_equal(f.normal, [0, 1]) and math.isnan(f.lower)
    s = System.parse(["x'' + x + Heaviside(a*x - 1) = 0"], {"a": 0.0})
    _raises(ModelError, r"never changes sign", s.field, 0.0, [0, 0])
