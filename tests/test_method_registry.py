"""The method contract, checked for every method of the registry (perturb.methods.registry).

One parametrised set of checks instead of a copy per method:

- the registry is the one name table: ``METHODS`` (symbolic engines) is derived from it, every
  target resolves, and every option it lists is a keyword of the function that receives it;
- every symbolic derivation's LaTeX document compiles (pdflatex; skipped without it) and its
  JSON form reads back equal;
- the solutions a method returns satisfy its own equations: the derived residuals (the
  slow-flow / balance equations, evaluated independently of the tracer with SymPy's
  lambdify) vanish at every returned (Omega, amplitude) for some phase;
- an option a method does not take is an error naming it and what the method accepts;
- every method is reachable through ``frequency_response`` and ``perturb frc``, and
  ``frequencies=`` (``--omega w1,w2``) answers at exactly those frequencies.
"""

from __future__ import annotations

import csv
import inspect
import subprocess
import sys

import numpy as np
import pytest

import perturb
from perturb.errors import ParameterError
from perturb.methods.registry import (
    ALIASES,
    CAPABILITIES,
    KINDS,
    REGISTRY,
    MethodSpec,
    names,
    spec,
    symbolic_names,
)
from perturb.solve import derive, frequency_response

#: A model each symbolic method applies to (forced, centred orbits) and its options.
SYMBOLIC_CASES = {
    "hb1": ("nsd", {}),
    "shb": ("duffing", {}),
    "kb": ("duffing", {}),
    "vdp": ("duffing", {}),
    "ms": ("duffing", {}),
    "lp": ("quadratic_cubic", {}),  # free conservative oscillators only
    "mlp": ("duffing", {}),
}
#: Methods whose forced response is traced (lp answers free oscillations: a backbone).
TRACED = [m for m in SYMBOLIC_CASES if m != "lp"]
#: Second-order mLP: traced by residual continuation (not amplitude parametrisation).
EXTRA_TRACED = {"mlp2": ("mlp", "duffing", {"order": 2})}


def test_every_symbolic_method_has_a_contract_case():
    assert set(SYMBOLIC_CASES) == set(symbolic_names())


# ------------------------------------------------------------------------------------------
# the registry is the one name table
# ------------------------------------------------------------------------------------------
def test_methods_table_is_derived_from_the_registry():
    from perturb.methods import METHODS

    assert tuple(METHODS) == symbolic_names()
    for name, fn in METHODS.items():
        assert fn is REGISTRY[name].resolve()
    assert "hb" not in METHODS  # numeric harmonic balance is a solver, not an engine
    assert REGISTRY["hb"].kind == "numeric" and REGISTRY["shb"].kind == "symbolic"


@pytest.mark.parametrize("name", list(REGISTRY))
def test_spec_is_well_formed_and_its_options_reach_a_keyword(name):
    s = REGISTRY[name]
    assert isinstance(s, MethodSpec) and s.name == name and s.kind in KINDS
    assert set(s.capabilities) <= set(CAPABILITIES)
    fn = s.resolve()
    assert callable(fn)
    for alias in s.aliases:
        assert ALIASES[alias] == name and spec(alias) is s
    # every listed option is a keyword of the function that receives it (no option is
    # accepted by the registry and then dropped or refused by the solver)
    if s.kind == "symbolic":
        from perturb.numeric.amplitude import approximation_response
        from perturb.numeric.residual import residual_response

        engine = set(inspect.signature(fn).parameters)
        tracers = set(inspect.signature(approximation_response).parameters) | set(
            inspect.signature(residual_response).parameters
        )
        for key, opt in s.options.items():
            assert key in (engine if opt.stage == "derive" else tracers), key
    elif s.kind == "numeric":
        takes = set(inspect.signature(fn).parameters)
        if "knobs" in takes:  # keyword knobs are the fields of its options object
            import dataclasses

            from perturb.numeric.harmonic_balance import HarmonicBalanceOptions

            takes |= {f.name for f in dataclasses.fields(HarmonicBalanceOptions)}
        assert set(s.options) <= takes
    elif s.kind == "reference":
        from perturb.simulate.exact_response import exact_branches

        takes = set(inspect.signature(exact_branches).parameters)
        if "knobs" in takes:  # keyword knobs are the fields of its options object
            import dataclasses

            from perturb.simulate.exact_response import ExactResponseOptions

            takes |= {f.name for f in dataclasses.fields(ExactResponseOptions)}
        # the two approximation-seed options are taken by perturb.solve itself
        assert set(s.options) - {"approximation", "approximation_seeds"} <= takes
    else:
        takes = set(inspect.signature(fn).parameters)
        assert set(s.options) <= takes


@pytest.mark.parametrize(
    "argv", [None, ["--version"], ["--help"], ["models"], ["frc", "--help"], ["derive", "--help"]]
)
def test_start_up_loads_no_sympy_scipy_integrate_or_matplotlib(argv):
    """The issue's start-up gate, in a fresh process: the registry, the checks, the
    dispatcher and the command line (``None``: only imported) load none of SymPy, SciPy's
    integrators or matplotlib."""
    run = "" if argv is None else f"    main({argv!r})\n"
    code = (
        "import sys\n"
        "import perturb.methods.registry, perturb.checks, perturb.solve, perturb.methods\n"
        "from perturb.apps.cli import main\n"
        "try:\n" + (run or "    pass\n") + "except SystemExit:\n    pass\n"
        "bad = sorted(m for m in sys.modules if m.split('.')[0] in ('sympy', 'matplotlib') "
        "or m.startswith('scipy.integrate'))\n"
        "print('HEAVY', bad, file=sys.stderr)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True
    )
    assert "HEAVY []" in out.stderr.splitlines()[-1]


# ------------------------------------------------------------------------------------------
# derivations: LaTeX compiles, JSON reads back
# ------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def derived():
    cache: dict = {}

    def get(name):
        if name not in cache:
            model, options = SYMBOLIC_CASES[name]
            osc = perturb.builtin_model(model)
            cache[name] = (osc, derive(osc, name, **options))
        return cache[name]

    return get


@pytest.mark.parametrize("name", list(SYMBOLIC_CASES))
def test_derivation_latex_compiles(name, derived, tmp_path, compile_tex):
    from perturb.report.latex import latex_document

    assert "latex" in REGISTRY[name].capabilities
    _, approx = derived(name)
    tex = tmp_path / f"{name}.tex"
    latex_document(approx, tex)
    compile_tex(tex, timeout=120)


@pytest.mark.parametrize("name", list(SYMBOLIC_CASES))
def test_derivation_json_round_trip(name, derived):
    from perturb.io.serialize import dumps, loads

    osc, approx = derived(name)
    text = dumps(approx)
    back = loads(text, osc)
    assert back == approx
    assert dumps(back) == text


# ------------------------------------------------------------------------------------------
# the returned solutions satisfy the method's own equations
# ------------------------------------------------------------------------------------------
def _residual_at(approx, osc, omega: float, amplitude: float) -> float:
    """``min over the phase`` of the largest derived residual at ``(omega, amplitude)``.

    Polar unknowns ``(A, phase)`` take ``A = amplitude``; Cartesian ones ``(p, q)`` take
    ``p = amplitude cos(theta)``, ``q = amplitude sin(theta)``. The minimum over the phase is
    found on a 720-point grid and polished by ``scipy.optimize.least_squares``."""
    import sympy as sp
    from scipy.optimize import least_squares

    values = {s: v for s, v in osc.substitutions().items() if s != approx.frequency}
    res = [sp.sympify(r).xreplace(values) for r in approx.residuals]
    u = approx.unknowns
    assert len(u) == 2 and len(res) == 2
    from perturb.fourier.symbols import NUMERIC_IMPLEMENTATIONS  # the Fourier functions

    f = sp.lambdify((*u, approx.frequency), res, modules=[NUMERIC_IMPLEMENTATIONS, "numpy"])
    polar = approx.amplitude is not None
    ia = u.index(approx.amplitude) if polar else 0

    def r(theta):
        theta = np.asarray(theta, dtype=float)
        if polar:
            args = [amplitude, theta] if ia == 0 else [theta, amplitude]
        else:
            args = [amplitude * np.cos(theta), amplitude * np.sin(theta)]
        vals = f(*args, omega)
        return np.array([np.broadcast_to(np.asarray(v, float), theta.shape) for v in vals])

    grid = np.linspace(-np.pi, np.pi, 720, endpoint=False)
    best = grid[int(np.argmin(np.max(np.abs(r(grid)), axis=0)))]
    sol = least_squares(lambda t: r(np.atleast_1d(t)).ravel(), [best], xtol=1e-15, ftol=1e-15)
    return float(np.max(np.abs(r(np.atleast_1d(sol.x)))))


def _traced_cases():
    for name in TRACED:
        model, options = SYMBOLIC_CASES[name]
        yield pytest.param(name, model, options, id=name)
    for label, (name, model, options) in EXTRA_TRACED.items():
        yield pytest.param(name, model, options, id=label)


@pytest.mark.parametrize(("name", "model", "options"), list(_traced_cases()))
def test_residuals_vanish_on_the_returned_solutions(name, model, options):
    """At every returned point, curve and listed frequencies alike, some phase makes the
    derived equations vanish; 2 % off in amplitude they do not (the check can fail)."""
    osc = perturb.builtin_model(model)
    approx = derive(osc, name, **options)
    scale = float(max(abs(float(v)) for v in osc.substitutions().values()))
    curve = frequency_response(osc, name, (0.5, 1.8), **options)
    listed = frequency_response(osc, name, frequencies=[0.7, 1.1, 1.5], **options)
    checked = 0
    for resp in (curve, listed):
        assert resp.branches
        for b in resp.branches:
            idx = np.unique(np.linspace(0, len(b) - 1, min(len(b), 12)).astype(int))
            for i in idx:
                w, a = float(b.omega[i]), float(b.first_harmonic_amplitude[i])
                assert _residual_at(approx, osc, w, a) <= 1e-7 * scale * max(1.0, a**3)
                checked += 1
    b = listed.branches[0]
    w, a = float(b.omega[0]), float(b.first_harmonic_amplitude[0])
    assert _residual_at(approx, osc, w, 1.02 * a) > 1e-4 * scale * a
    assert checked >= 6


# ------------------------------------------------------------------------------------------
# options are validated
# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", list(REGISTRY))
def test_an_option_the_method_does_not_take_is_named(name):
    osc = perturb.builtin_model("duffing")
    accepted = ", ".join(REGISTRY[name].options)
    with pytest.raises(ParameterError) as err:
        frequency_response(osc, name, (0.5, 1.5), no_such_option=1)
    msg = str(err.value)
    assert "no_such_option" in msg and f"method {name!r}" in msg
    assert accepted in msg


@pytest.mark.parametrize("name", list(REGISTRY))
def test_limits_are_checked_before_any_work(name):
    s = REGISTRY[name]
    osc = perturb.builtin_model("duffing")
    if "order" in s.options:
        with pytest.raises(ParameterError, match="at most"):
            frequency_response(osc, name, order=10**6)
    if "harmonics" in s.options and s.kind != "symbolic":
        with pytest.raises(ParameterError, match="at most"):
            frequency_response(osc, name, harmonics=10**6)
    if "points" in s.options:
        with pytest.raises(ParameterError, match="at least 2"):
            frequency_response(osc, name, points=1)
    if "order" not in s.options:
        with pytest.raises(ParameterError, match="takes no order"):
            frequency_response(osc, name, order=2)


def test_hb_means_numeric_harmonic_balance_and_shb_the_symbolic_engine():
    osc = perturb.builtin_model("duffing")
    numeric = frequency_response(osc, "hb", frequencies=[0.9], harmonics=3)
    assert numeric.method.startswith("numeric HB H=3")
    symbolic = frequency_response(osc, "shb", frequencies=[0.9])
    assert symbolic.method.startswith("hb(")  # the engine's own label
    with pytest.raises(ParameterError, match="not a derivation"):
        derive(osc, "hb")
    # a harmonic set is traced in all its unknowns (checked against numeric HB in
    # tests/test_shb_response.py)
    assert frequency_response(osc, "shb", frequencies=[0.9], harmonics=(1, 3)).branches


def test_aliases_reach_the_same_method():
    osc = perturb.builtin_model("duffing")
    for alias, name in ALIASES.items():
        a = frequency_response(osc, alias, frequencies=[0.8])
        b = frequency_response(osc, name, frequencies=[0.8])
        assert a.method == b.method
        assert [list(x.amplitude) for x in a.branches] == [list(x.amplitude) for x in b.branches]


# ------------------------------------------------------------------------------------------
# every method: frequency_response(frequencies=) and perturb frc --omega w1,w2
# ------------------------------------------------------------------------------------------
LISTED = [0.7, 1.3]


def _cases_at():
    for name in names():
        if "frequencies" not in REGISTRY[name].capabilities:
            continue
        if name == "lp":
            continue  # a free oscillation (tested above: refused with a clear message)
        model, options = SYMBOLIC_CASES.get(name, ("duffing", {}))
        if name == "hb":
            options = {"harmonics": 5}
        marks = [pytest.mark.slow] if name in ("exact", "auto") else []
        yield pytest.param(name, model, options, marks=marks, id=name)
    yield pytest.param("mlp", "duffing", {"order": 2}, id="mlp2")


@pytest.mark.parametrize(("name", "model", "options"), list(_cases_at()))
def test_frequencies_answer_at_exactly_those_frequencies(name, model, options):
    osc = perturb.builtin_model(model)
    resp = frequency_response(osc, name, frequencies=LISTED, **options)
    got = sorted({float(w) for b in resp.branches for w in b.omega})
    assert got == LISTED  # bit for bit: polished at the requested frequency, not interpolated


@pytest.mark.parametrize(("name", "model", "options"), list(_cases_at()))
def test_perturb_frc_reaches_every_method_at_listed_frequencies(name, model, options, tmp_path):
    from perturb.apps.cli import main

    out = tmp_path / "frc.csv"
    argv = ["frc", model, "--method", name, "--omega", ",".join(map(str, LISTED))]
    argv += ["--out", str(out)]
    if "order" in options:
        argv += ["--order", str(options["order"])]
    if name == "hb":
        argv += ["--harmonics", str(options["harmonics"])]
    assert main(argv) == 0
    with out.open() as fh:
        rows = list(csv.DictReader(fh))
    assert rows and sorted({float(r["omega"]) for r in rows}) == LISTED


@pytest.mark.slow
def test_auto_checks_its_choice_at_the_listed_frequencies():
    """With frequencies=, auto's exact spot checks run at those frequencies (where the answer
    is given), and the chosen method answers there."""
    osc = perturb.builtin_model("duffing")
    resp = frequency_response(osc, "auto", frequencies=LISTED, rtol=1e-2)
    assert resp.notes[0].startswith("auto: chose")
    assert any("spot checks at Omega = 0.7, 1.3" in n for n in resp.notes)
    with pytest.raises(ParameterError, match="points"):
        frequency_response(osc, "auto", frequencies=LISTED, points=100)


def test_lp_answers_free_oscillations_and_says_so():
    osc = perturb.builtin_model("quadratic_cubic")
    assert REGISTRY["lp"].applies(osc)
    with pytest.raises(ParameterError, match="backbone"):
        frequency_response(osc, "lp", (0.5, 1.5))


def test_applies_follows_the_centring_of_the_orbit():
    clearance = perturb.builtin_model("clearance")  # one-sided: orbits off centre
    duffing = perturb.builtin_model("duffing")
    for name in ("hb1", "kb", "ms", "mlp"):
        assert REGISTRY[name].applies(duffing)
        assert not REGISTRY[name].applies(clearance)
    for name in ("hb", "exact", "shb"):
        assert REGISTRY[name].applies(clearance)
