"""Safe text serialisation of derivations, the derivation cache and `perturb derive`."""

from __future__ import annotations

import json

import pytest
import sympy as sp

from perturb import PerturbError, builtin_model
from perturb.apps.cli import main
from perturb.io.cache import cached_derivation, derivation_key
from perturb.io.serialize import (
    approximation_from_dict,
    approximation_to_dict,
    expr_from_text,
    expr_to_text,
)
from perturb.methods import METHODS
from perturb.methods.harmonic_balance import single_harmonic_balance


@pytest.mark.parametrize("model", ["nsd", "duffing", "saturation"])
def test_round_trip_is_exact(model):
    approx = single_harmonic_balance(builtin_model(model))
    text = json.dumps(approximation_to_dict(approx))
    back = approximation_from_dict(json.loads(text), approx.oscillator)
    assert back.residuals == approx.residuals
    assert back.frequency_polynomial == approx.frequency_polynomial
    assert back.slow_flow == approx.slow_flow
    assert back.steps == approx.steps
    assert back.waveform == approx.waveform


def test_expressions_with_constants_and_applied_functions():
    x = sp.Symbol("x", real=True)
    for e in (
        sp.pi * x + sp.E,
        sp.Function("a_1")(x) ** 2,
        sp.Piecewise((x, x > 0), (0, True)),
        sp.Heaviside(x - 1) * sp.Rational(3, 7),
        sp.oo,
        sp.Float("0.1", 30),
    ):
        assert expr_from_text(expr_to_text(e)) == e


@pytest.mark.parametrize(
    "text",
    [
        '__import__("os").system("id")',
        'Symbol("x").__class__',
        'eval("1")',
        "(lambda: 1)()",
        'Symbol(**{"a": 1})',
        'Symbol("x", real=[1])',
        "os",
        'Symbol("x")(1)',
        "Add(*[1])",
        "not valid (",
    ],
)
def test_hostile_or_broken_text_is_refused(text, tmp_path):
    with pytest.raises(PerturbError):
        expr_from_text(text)


def test_cache_hit_corruption_and_tampering(tmp_path, monkeypatch):
    monkeypatch.setenv("PERTURB_CACHE_DIR", str(tmp_path))
    osc = builtin_model("nsd")
    calls = []

    def method(o):
        calls.append(1)
        return single_harmonic_balance(o)

    first = cached_derivation("hb1", method, osc)
    second = cached_derivation("hb1", method, osc)
    assert len(calls) == 1 and second.residuals == first.residuals
    (entry,) = tmp_path.glob("*.json")
    # corruption: recomputed, not trusted
    entry.write_text("{ not json")
    third = cached_derivation("hb1", method, osc)
    assert len(calls) == 2 and third.residuals == first.residuals
    # tampering with code in an expression: refused, recomputed, never executed
    data = json.loads(entry.read_text())
    marker = tmp_path / "pwned"
    data["waveform"] = f'__import__("os").system("touch {marker}")'
    entry.write_text(json.dumps(data))
    fourth = cached_derivation("hb1", method, osc)
    assert len(calls) == 3 and fourth.waveform == first.waveform and not marker.exists()
    # different parameters, different key
    other = osc.with_params(k=-3.0)
    assert derivation_key("hb1", method, other, {}) != derivation_key("hb1", method, osc, {})


def test_derive_command_writes_latex_and_json(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("PERTURB_CACHE_DIR", str(tmp_path / "cache"))
    tex, js = tmp_path / "d.tex", tmp_path / "d.json"
    assert main(["derive", "hb1", "nsd", "--latex", str(tex), "--json", str(js)]) == 0
    assert "\\begin{document}" in tex.read_text()
    data = json.loads(js.read_text())
    assert data["method"] == "hb1" and data["oscillator"]["name"] == "nsd"
    assert main(["derive", "hb1", "nsd", "--order", "2"]) == 2
    # refused by the method registry, naming the option and the method
    assert "--order = 2: method 'hb1' takes no order" in capsys.readouterr().err
    assert main(["derive", "nope", "nsd"]) == 2


def test_json_round_trip_keeps_sympy_options(tmp_path, monkeypatch):
    # modified L-P stores omega0 as a SymPy number; `perturb derive mlp nsd --json` used to
    # crash on it.  The file must read back to the same options and expressions.
    monkeypatch.setenv("PERTURB_CACHE_DIR", str(tmp_path / "cache"))
    js = tmp_path / "mlp.json"
    assert main(["derive", "mlp", "nsd", "--order", "1", "--json", str(js)]) == 0
    data = json.loads(js.read_text())
    osc = builtin_model("nsd")
    back = approximation_from_dict(data, osc)
    assert back.options["omega0"] == sp.Integer(1)
    assert isinstance(back.options["omega0"], sp.Basic)
    assert back.options["order"] == 1
    from perturb.methods import modified_lindstedt

    fresh = modified_lindstedt(osc, 1)
    assert back.frequency_polynomial == fresh.frequency_polynomial
    assert dict(back.options) == dict(fresh.options)


def test_notes_are_saved_and_cached_with_the_approximation(tmp_path, monkeypatch):
    """An approximation whose method wrote notes (a zero-mean ansatz on a force with an even
    polynomial part) reads back equal, notes included, from JSON and from the cache: a cache
    hit does not recompute it."""
    from perturb.io.serialize import loads

    monkeypatch.setenv("PERTURB_CACHE_DIR", str(tmp_path))
    osc = builtin_model("quadratic_cubic")
    calls = []

    def method(o):
        calls.append(1)
        return METHODS["kb"](o)

    fresh = cached_derivation("kb", method, osc)
    assert fresh.notes and "even polynomial part" in fresh.notes[0]
    hit = cached_derivation("kb", method, osc)
    assert len(calls) == 1 and hit == fresh and hit.notes == fresh.notes
    data = approximation_to_dict(fresh)
    assert approximation_from_dict(data, osc).notes == fresh.notes
    assert loads(json.dumps(data), osc) == fresh
    # an approximation without notes is written as before: no 'notes' field at all
    assert "notes" not in approximation_to_dict(METHODS["kb"](builtin_model("nsd")))


def test_editing_a_shared_engine_changes_the_cache_key(monkeypatch):
    """modified L-P calls the series engine of perturb.methods.series: an edit there (seen
    here as a different source text) must orphan mlp's cache entries, while an edit of an
    unrelated module (the exact reference solvers) must not."""
    import inspect

    import perturb.io.cache as pc

    osc = builtin_model("nsd")
    fn = METHODS["mlp"]
    before = derivation_key("mlp", fn, osc, {})
    real = inspect.getsource

    def edited(name):
        def getsource(obj):
            text = real(obj)
            return text + "\n# edited\n" if getattr(obj, "__name__", "") == name else text

        return getsource

    monkeypatch.setattr(pc.inspect, "getsource", edited("perturb.methods.series"))
    assert derivation_key("mlp", fn, osc, {}) != before
    monkeypatch.setattr(pc.inspect, "getsource", edited("perturb.simulate.exact_response"))
    assert derivation_key("mlp", fn, osc, {}) == before
