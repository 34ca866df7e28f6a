"""Hostile derivation-cache entries and derivation files: nothing in them runs or is trusted.

The cache authenticates each entry with an HMAC under a per-user key and reads it, like the
``perturb derive --json`` codec, only through one closed vocabulary (perturb.io.serialize). Each
payload below would create a marker file if any part of it were executed — when read, or
later, when the approximation is compiled by ``lambdify``.
"""

from __future__ import annotations

import json
import os
import re
import stat
import warnings

import numpy as np
import pytest
import sympy as sp

import perturb.io.cache as pc
from perturb import builtin_model
from perturb.errors import ParseError, PerturbError
from perturb.io.serialize import (
    Vocabulary,
    approximation_from_dict,
    approximation_to_dict,
    expr_from_text,
    expr_to_text,
)
from perturb.methods import METHODS
from perturb.numeric.amplitude import approximation_response


@pytest.fixture
def cache(tmp_path, monkeypatch):
    """A private cache folder and key folder for one test."""
    monkeypatch.setenv("PERTURB_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    monkeypatch.delenv("PERTURB_CACHE_KEY", raising=False)
    monkeypatch.delenv("PERTURB_CACHE", raising=False)
    pc.reset_key_state()  # keys and warnings of earlier tests (other folders) are forgotten
    yield tmp_path / "cache"
    pc.reset_key_state()  # and this test's key is not left for the next


CALLS: list[str] = []


def hb1(osc, **options):
    CALLS.append("hb1")
    return METHODS["hb1"](osc, **options)


def _derive(osc=None):
    return pc.cached_derivation("hb1", hb1, osc or builtin_model("nsd"))


def _entry(cache_folder):
    (path,) = cache_folder.glob("*.json")
    data = json.loads(path.read_text())
    # the entry's node table: inside the authenticated wrapper (or, before it existed, at the top)
    table = data["entry"] if isinstance(data.get("entry"), dict) else data
    return path, data, table


def _peak(approx) -> float:
    resp = approximation_response(approx, (0.3, 1.8), points=300)
    return max(float(np.nanmax(b.amplitude)) for b in resp.branches)


# ------------------------------------------------------------------------------ the cache --
def test_entries_are_authenticated_and_reused(cache):
    CALLS.clear()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a good entry is read without a word
        first = _derive()
        second = _derive()
    assert len(CALLS) == 1 and second == first
    path, data, _ = _entry(cache)
    assert path.read_bytes().startswith(b'{"perturb-cache":3,"hmac":"')
    key = pc.cache_key_file()
    assert key.is_file() and not pc.is_inside(key, cache)
    if os.name == "posix":
        assert stat.S_IMODE(key.stat().st_mode) == 0o600
        assert stat.S_IMODE(key.parent.stat().st_mode) == 0o700


def _plant_symbol(table, marker):
    # lambdify prints a symbol it is not given as an argument verbatim: this name would run
    (node,) = [n for n in table["nodes"] if n[:2] == ["sym", "mu"]]
    node[1] = f"__import__('os').system('touch {marker}') * 0 + 0.05"


def _plant_function(table, marker):
    (node,) = [n for n in table["nodes"] if n[:2] == ["fn", "a_1"]]
    node[1] = f"__import__('os').system('touch {marker}')"


def _plant_constructor(table, marker):
    table["nodes"].append(["__import__", 0])


def _plant_float_text(table, marker):
    (node,) = [n for n in table["nodes"] if n[:2] == ["int", 2]]
    node[:] = ["float", f"__import__('os').system('touch {marker}')", 53]


PLANTS = [_plant_symbol, _plant_function, _plant_constructor, _plant_float_text]


@pytest.mark.parametrize("plant", PLANTS)
def test_planted_code_in_an_entry_never_runs(cache, tmp_path, plant):
    CALLS.clear()
    fresh = _derive()
    path, data, table = _entry(cache)
    marker = tmp_path / "pwned"
    plant(table, marker)
    path.write_text(json.dumps(data))
    with pytest.warns(pc.CacheWarning, match=re.escape(str(path))):
        again = _derive()
    assert len(CALLS) == 2, "the tampered entry was trusted"
    assert again == fresh
    _peak(again)  # compiled by lambdify: still nothing runs
    assert not marker.exists()
    # the entry was overwritten with a good one
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert _derive() == fresh and len(CALLS) == 2


@pytest.mark.parametrize("plant", PLANTS)
def test_planted_code_with_a_valid_hmac_is_refused_by_the_vocabulary(cache, tmp_path, plant):
    # as if the key had leaked: the closed vocabulary still refuses the entry
    CALLS.clear()
    fresh = _derive()
    path, data, table = _entry(cache)
    marker = tmp_path / "pwned"
    plant(table, marker)
    body = json.dumps(table, sort_keys=True, separators=(",", ":")).encode()
    sealed = pc.seal_entry(path.stem, body)
    assert sealed is not None
    path.write_bytes(sealed)
    with pytest.warns(pc.CacheWarning, match="content is invalid"):
        again = _derive()
    assert len(CALLS) == 2 and again == fresh
    _peak(again)
    assert not marker.exists()


def test_seal_entry_reproduces_the_written_file_and_binds_the_name(cache):
    # oracle: the file cached_derivation wrote; its body re-sealed under its own name is the
    # same bytes, under another name it fails authentication when read there
    fresh = _derive()
    path, _, table = _entry(cache)
    body = json.dumps(table, sort_keys=True, separators=(",", ":")).encode()
    assert pc.seal_entry(path.stem, body) == path.read_bytes()
    other = pc.seal_entry(path.stem[::-1], body)
    assert other is not None and other != path.read_bytes()
    path.write_bytes(other)
    with pytest.warns(pc.CacheWarning, match="failed authentication"):
        assert _derive() == fresh


def test_seal_entry_without_a_trustworthy_key_gives_none(cache, monkeypatch):
    monkeypatch.setenv("PERTURB_CACHE_KEY", "short")
    assert pc.seal_entry("name", b"{}") is None


def test_is_inside_resolves_links(tmp_path):
    outer, inner = tmp_path / "outer", tmp_path / "outer" / "inner"
    inner.mkdir(parents=True)
    assert pc.is_inside(inner, outer) and pc.is_inside(outer, outer)
    assert not pc.is_inside(outer, inner) and not pc.is_inside(tmp_path / "outer2", outer)
    if os.name == "posix":
        link = tmp_path / "link"
        link.symlink_to(inner)
        assert pc.is_inside(link / "key", outer)


def test_an_edited_number_is_detected_and_the_answer_is_right(cache):
    CALLS.clear()
    fresh = _derive()
    peak = _peak(fresh)
    path, data, table = _entry(cache)
    edited = [n for n in table["nodes"] if n[:2] == ["int", 2]]
    assert edited
    edited[0][1] = 3
    path.write_text(json.dumps(data, separators=(",", ":")))
    with pytest.warns(pc.CacheWarning, match="failed authentication"):
        again = _derive()
    assert len(CALLS) == 2
    assert again == fresh and _peak(again) == peak


def test_an_edited_number_with_the_layout_kept_byte_for_byte_is_detected(cache):
    # the same edit, without re-serialising: only the HMAC can tell
    CALLS.clear()
    fresh = _derive()
    path, _, _ = _entry(cache)
    raw = path.read_bytes()
    assert b'["int",2]' in raw
    path.write_bytes(raw.replace(b'["int",2]', b'["int",3]', 1))
    with pytest.warns(pc.CacheWarning, match="failed authentication"):
        again = _derive()
    assert len(CALLS) == 2 and again == fresh


def test_an_entry_moved_to_another_key_is_rejected(cache):
    CALLS.clear()
    _derive()
    (src,) = cache.glob("*.json")
    other = builtin_model("nsd", k=-3.0)
    fresh_other = METHODS["hb1"](other)
    name = pc.derivation_key("hb1", hb1, other, {})
    (cache / f"{name}.json").write_bytes(src.read_bytes())
    with pytest.warns(pc.CacheWarning, match="failed authentication"):
        got = _derive(other)
    assert got == fresh_other and len(CALLS) == 2


@pytest.mark.parametrize(
    "content",
    [b"", b"{ not json", b'{"entry": 3}', b"\x00" * 100, b'{"perturb-cache":2,"hmac":"x"}'],
)
def test_corrupted_entries_are_recomputed_with_a_warning(cache, content):
    CALLS.clear()
    fresh = _derive()
    path, _, _ = _entry(cache)
    path.write_bytes(content)
    with pytest.warns(pc.CacheWarning, match=re.escape(str(path))):
        assert _derive() == fresh
    assert len(CALLS) == 2


def test_an_entry_written_with_another_key_is_not_trusted(cache, monkeypatch):
    CALLS.clear()
    monkeypatch.setenv("PERTURB_CACHE_KEY", "first secret, long enough")
    fresh = _derive()
    assert not pc.cache_key_file().exists()  # the variable replaces the key file
    monkeypatch.setenv("PERTURB_CACHE_KEY", "second secret, long enough")
    with pytest.warns(pc.CacheWarning, match="failed authentication"):
        assert _derive() == fresh
    assert len(CALLS) == 2


def test_a_key_others_can_read_is_refused(cache):
    CALLS.clear()
    _derive()
    key = pc.cache_key_file()
    if os.name != "posix":
        pytest.skip("POSIX permissions")
    key.chmod(0o644)
    pc.reset_key_state()  # read the key file again: its mode changed
    with pytest.warns(pc.CacheWarning, match="accessible to other users"):
        _derive()
    assert len(CALLS) == 2  # the cache is not used: not read ...
    entries = sorted(cache.glob("*.json"))
    _derive()
    assert len(CALLS) == 3 and sorted(cache.glob("*.json")) == entries  # ... nor written


def test_a_key_inside_the_cache_folder_is_refused(cache, monkeypatch):
    CALLS.clear()
    monkeypatch.setenv("XDG_CONFIG_HOME", str(cache))
    with pytest.warns(pc.CacheWarning, match="inside the cache folder"):
        _derive()
    _derive()
    assert len(CALLS) == 2 and not list(cache.glob("**/cache-key"))


def test_a_short_environment_key_is_refused(cache, monkeypatch):
    monkeypatch.setenv("PERTURB_CACHE_KEY", "short")
    with pytest.warns(pc.CacheWarning, match="shorter than 16"):
        _derive()


# ---------------------------------------------------------------- derive --json files --
def _payload(marker) -> str:
    return f"__import__('os').system('touch {marker}')"


HOSTILE_EXPRESSIONS = [
    # SymPy would sympify (eval) a string argument of these constructors
    "_Continued({p!r})",
    "Tuple({p!r})",
    "sin({p!r})",
    "Order({p!r})",
    "Add({p!r}, Integer(1))",
    # lambdify would compile these names into code
    "Symbol({p!r}, real=True)",
    "Function({p!r})(Symbol('A', positive=True))",
    "Dummy({p!r}, dummy_index=1)",
    # not SymPy constructors at all
    "{p}",
    "__import__('os').system('true')",
    "Symbol('x').__class__",
    "Function('a_1').__call__(Symbol('A'))",
    "Float({p!r}, precision=53)",
    "Integer({p!r})",
    "Symbol('x', real={p!r})",
    "Symbol('x', **{{'real': True}})",
    "Add(*[Integer(1)])",
    "(lambda: 1)()",
]


@pytest.mark.parametrize("template", HOSTILE_EXPRESSIONS)
@pytest.mark.parametrize("field", ["frequency_polynomial", "waveform", "steps", "options"])
def test_planted_code_in_a_derivation_file_never_runs(tmp_path, template, field):
    osc = builtin_model("nsd")
    data = json.loads(json.dumps(approximation_to_dict(METHODS["hb1"](osc))))
    marker = tmp_path / "pwned"
    text = template.format(p=_payload(marker))
    if field == "frequency_polynomial":
        data[field][0] = text
    elif field == "waveform":
        data[field] = text
    elif field == "steps":
        data["steps"][0]["math"].append(text)
    else:
        data["options"]["planted"] = {"__sympy__": text}
    path = tmp_path / "d.json"
    path.write_text(json.dumps(data))
    with pytest.raises(ParseError) as err:
        approximation_from_dict(json.loads(path.read_text()), osc, str(path))
    assert str(path) in str(err.value)
    assert not marker.exists()


@pytest.mark.parametrize(
    "text, fragment",
    [
        ("Symbol('zeta', real=True)", "'zeta' is neither a name of the model"),
        ("Function('exit')(Symbol('A'))", "'exit' is not one of the derivation engines"),
        ("Float('nan', precision=53)", "not a finite decimal number"),
        ("Float('1e99999', precision=53)", "not a finite decimal number"),
        (f"Float('0.5', precision={10**9})", "precision"),
        (f"Integer({2**5000})", "at most 4096 bits"),
        ("Rational(1, 0)", "positive denominator"),
        (f"Pow(Integer(10), Integer({10**100}))", "is not allowed"),
        ("Symbol('A', positive=True, evil=True)", "assumptions"),
        ("ImmutableDenseMatrix([[Integer(1)], [Integer(1), Integer(2)]])", "rows of equal"),
        ("Add(" * 500 + "Integer(1)" + ")" * 500, "nested"),
    ],
)
def test_out_of_vocabulary_expressions_are_refused_by_name(text, fragment):
    vocab = Vocabulary.for_oscillator(builtin_model("nsd"), "d.json")
    with pytest.raises(ParseError, match=re.escape(fragment)):
        expr_from_text(text, vocab)


@pytest.mark.parametrize(
    "edit, fragment",
    [
        (lambda d: d.pop("fourier"), "'fourier' is missing"),
        (lambda d: d.update(format=99), "format 99"),
        (lambda d: d["options"].update(bad=float("nan")), "finite"),
        (lambda d: d.update(steps="x"), "expected a list"),
        (lambda d: d["steps"].append({"math": []}), "'title' and 'math'"),
        (lambda d: d.update(method=["hb1"]), "method"),
    ],
)
def test_malformed_derivation_files_are_clear_errors(edit, fragment):
    osc = builtin_model("nsd")
    data = json.loads(json.dumps(approximation_to_dict(METHODS["hb1"](osc))))
    edit(data)
    with pytest.raises(ParseError, match=re.escape(fragment)):
        approximation_from_dict(data, osc, "d.json")
    with pytest.raises(ParseError):
        approximation_from_dict([], osc)


def test_a_derivation_file_of_another_model_is_refused():
    # symbols of another model (the dead zone's d) are outside this model's vocabulary
    deadzone = builtin_model("deadzone")
    data = json.loads(json.dumps(approximation_to_dict(METHODS["hb1"](deadzone))))
    with pytest.raises(ParseError, match="'d' is neither a name of the model"):
        approximation_from_dict(data, builtin_model("nsd"))


def test_format_1_files_still_read():
    # files written before the exact (stored-order) srepr: read back evaluated
    osc = builtin_model("duffing")
    approx = METHODS["hb1"](osc)
    data = json.loads(json.dumps(approximation_to_dict(approx)))
    old = {k: v for k, v in data.items()}
    old["format"] = 1
    for key in ("residuals", "frequency_polynomial", "slow_flow"):
        old[key] = [sp.srepr(e) for e in getattr(approx, key)]
    back = approximation_from_dict(old, osc)
    assert back.frequency_polynomial == approx.frequency_polynomial
    assert back.residuals == approx.residuals


def test_plain_expression_text_without_a_model():
    x = sp.Symbol("x", real=True)
    e = sp.Mul(-2, x) + sp.Heaviside(x - 1) + sp.Function("a_1")(x)
    assert expr_from_text(expr_to_text(e)) == e
    with pytest.raises(PerturbError):
        expr_from_text("Symbol('a b')")


# ------------------------------------------------------- every engine reads back exactly --
ENGINE_CASES = [
    ("nsd", "hb1", {}),
    ("nsd", "shb", {"harmonics": (1,), "bias": True}),
    ("duffing", "shb", {"harmonics": (1, 3)}),
    ("duffing", "shb", {"harmonics": ("1/3", 1)}),
    ("nsd", "kb", {}),
    ("vanderpol", "vdp", {}),
    ("nsd", "ms", {"order": 1}),
    ("mathieu", "ms", {"order": 2}),
    ("duffing", "ms", {"order": 1, "resonance": "superharmonic"}),
    ("quadratic_cubic", "lp", {"order": 3}),
    ("nsd", "mlp", {"order": 2}),
    ("saturation", "mlp", {"order": 1}),
]


@pytest.mark.parametrize("model, method, options", ENGINE_CASES)
def test_every_engine_is_cached_and_read_back_exactly(cache, model, method, options):
    """The vocabulary covers what the engines produce: an entry outside it would silently
    not be cached, and a ``derive --json`` file would not read back."""
    oscs = [builtin_model(model)]
    if "mu" in oscs[0].params:  # a parameter left symbolic, as sweeps derive
        oscs.append(oscs[0].with_params({"mu": None}))
    calls = []

    def fn(o, **kw):
        calls.append(1)
        return METHODS[method](o, **kw)

    for osc in oscs:
        calls.clear()
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            first = pc.cached_derivation(method, fn, osc, **options)
            second = pc.cached_derivation(method, fn, osc, **options)
        assert len(calls) == 1 and second == first
        data = json.loads(json.dumps(approximation_to_dict(first)))
        assert approximation_from_dict(data, osc) == first


def test_derive_json_file_reads_back_through_load(tmp_path, cache):
    from perturb.apps.cli import main
    from perturb.io.serialize import load, loads

    path = tmp_path / "ms.json"
    assert main(["derive", "ms", "nsd", "--json", str(path)]) == 0
    osc = builtin_model("nsd")
    assert load(path, osc) == METHODS["ms"](osc)  # its Jacobian matrix included
    for text in ("{ not json", '{"format": NaN}', "[]"):
        with pytest.raises(ParseError, match="d.json"):
            loads(text, osc, "d.json")
    with pytest.raises(ParseError, match="cannot read"):
        load(tmp_path / "missing.json", osc)
    marker = tmp_path / "pwned"
    data = json.loads(path.read_text())
    data["steps"][0]["math"] = [f"_Continued({_payload(marker)!r})"]
    path.write_text(json.dumps(data))
    with pytest.raises(ParseError, match=re.escape(str(path))):
        load(path, osc)
    assert not marker.exists()


@pytest.mark.parametrize(
    "name", ["a" + "1" * 26 + "!", "a" + "_" * 62 + "!", "a" + "1_" * 20 + "!"]
)
def test_symbol_names_are_checked_in_linear_time(name):
    # a backtracking pattern took ~3 s on the first (and doubled with each further digit)
    import time

    vocab = Vocabulary.for_oscillator(builtin_model("nsd"))
    t0 = time.perf_counter()
    try:
        vocab.symbol_name(name)
    except ParseError:
        pass
    assert time.perf_counter() - t0 < 0.5


def test_no_home_folder_means_no_cache_not_a_key_in_the_working_folder(cache, monkeypatch):
    CALLS.clear()
    monkeypatch.setenv("XDG_CONFIG_HOME", "relative/config")
    with pytest.warns(pc.CacheWarning, match="no home folder"):
        _derive()
    _derive()
    assert len(CALLS) == 2 and not os.path.exists("relative")
