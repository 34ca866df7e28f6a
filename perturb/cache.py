"""On-disk cache of derivations, stored as text.

A derivation is keyed by the method, its options, the oscillator's equation (``srepr``) and
parameter values, perturb's version and a hash of the method's source file — so editing a
method invalidates its entries.

An entry is JSON: one table of expression nodes shared by every field (the derivation steps
repeat the same symbols and subexpressions thousands of times), each node a whitelisted
constructor name with references to earlier nodes, or a literal leaf (symbol, number,
constant). Reading it calls only those constructors, unevaluated, so a hit rebuilds exactly
the trees the method returned in milliseconds — parsing ``srepr`` text
(:mod:`perturb.serialize`) costs tenths of a second for a long derivation. Nothing in an entry
is evaluated as code: a tampered or corrupted entry is recomputed, never trusted and never
executed. An approximation whose rebuilt form would differ from it (an expression type the
table does not know) is not stored.

Location: ``$PERTURB_CACHE_DIR``, else ``$XDG_CACHE_HOME/perturb``, else
``~/.cache/perturb``; ``PERTURB_CACHE=0`` switches caching off.
"""

from __future__ import annotations

import hashlib
import inspect
import json
import os
import sys
import tempfile
from collections.abc import Callable, Mapping
from fractions import Fraction
from pathlib import Path
from types import MappingProxyType
from typing import Any

import sympy as sp
from sympy.core.function import AppliedUndef
from sympy.functions.elementary.piecewise import ExprCondPair
from sympy.printing.repr import mlib_to_str, repr_dps

from .approximation import Approximation, Step
from .fourier_symbols import DiracCoefficient, RampCoefficient, StepCoefficient
from .methods.lindstedt import _Continued  # the engines' continuation rows in derivation steps
from .model import Oscillator
from .serialize import FORMAT_VERSION

__all__ = ["cache_dir", "cached_derivation", "derivation_key"]

# Layout of an entry (bump to orphan older entries): 2 = node table, tagged options.
_ENTRY_VERSION = 2
_MAX_NODES = 2_000_000
_MAX_NAME = 200
_MAX_TEXT = 100_000


def cache_dir() -> Path:
    """The cache folder (created on first write)."""
    if os.environ.get("PERTURB_CACHE_DIR"):
        return Path(os.environ["PERTURB_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "perturb"


def _source_hash(fn: Callable[..., Any]) -> str:
    try:
        module = sys.modules[fn.__module__]
        text = inspect.getsource(module)
    except (KeyError, OSError, TypeError):
        text = repr(fn)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def derivation_key(method: str, fn: Callable[..., Any], osc: Oscillator, options: dict) -> str:
    """The cache key: a hash of everything the derivation depends on."""
    from . import __version__

    payload = {
        "format": FORMAT_VERSION,
        "entry": _ENTRY_VERSION,
        "version": __version__,
        "method": method,
        "source": _source_hash(fn),
        "options": {k: repr(v) for k, v in sorted(options.items())},
        "equation": sp.srepr(osc.equation),
        "params": {k: repr(v) for k, v in sorted(osc.params.items())},
    }
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()


# ------------------------------------------------------------------------ expression table --
def _unevaluated(cls: type) -> Callable[[list], sp.Basic]:
    return lambda args: cls(*args, evaluate=False)


def _as_given(cls: type) -> Callable[[list], sp.Basic]:
    return lambda args: cls(*args)


def _assoc(cls: type) -> Callable[[list], sp.Basic]:
    # what Add/Mul(*args, evaluate=False) builds, without the constructor's cache lookup and
    # re-sympifying — most of a warm hit's time, as most nodes are products
    return lambda args: cls._from_args(args)


# Node name -> (class, constructor from the rebuilt arguments). Every class here satisfies
# ``constructor(e.args) == e``: operators and functions unevaluated; Order evaluated, because
# its constructor normalises by expanding and never terminates unevaluated. The write path
# checks the round trip, so a class that breaks this only costs its entries.
_CLASSES: dict[str, tuple[type, Callable[[list], sp.Basic]]] = {
    cls.__name__: (cls, _unevaluated(cls))
    for cls in (
        sp.Pow,
        sp.Equality,
        sp.Unequality,
        sp.StrictLessThan,
        sp.StrictGreaterThan,
        sp.LessThan,
        sp.GreaterThan,
        sp.Piecewise,
        sp.And,
        sp.Or,
        sp.Not,
        sp.Max,
        sp.Min,
        sp.Heaviside,
        sp.DiracDelta,
        sp.Abs,
        sp.sign,
        sp.sin,
        sp.cos,
        sp.tan,
        sp.sinh,
        sp.cosh,
        sp.tanh,
        sp.asin,
        sp.acos,
        sp.atan,
        sp.atan2,
        sp.exp,
        sp.log,
        sp.re,
        sp.im,
        sp.conjugate,
        sp.floor,
        sp.ceiling,
        StepCoefficient,
        RampCoefficient,
        DiracCoefficient,
    )
}
_CLASSES.update({cls.__name__: (cls, _assoc(cls)) for cls in (sp.Add, sp.Mul)})
_CLASSES.update(
    {
        cls.__name__: (cls, _as_given(cls))
        for cls in (sp.Tuple, sp.Derivative, ExprCondPair, sp.Order, _Continued)
    }
)
_CONSTANTS: dict[str, sp.Basic] = {
    type(c).__name__: c
    for c in (sp.pi, sp.E, sp.I, sp.oo, -sp.oo, sp.zoo, sp.nan, sp.true, sp.false, sp.EulerGamma)
}


class _Unsupported(Exception):
    """An expression the table cannot rebuild exactly: the approximation is not stored."""


def _assumptions(d: Mapping[str, Any]) -> dict[str, bool]:
    if not all(isinstance(k, str) and isinstance(v, bool) for k, v in d.items()):
        raise _Unsupported(f"assumptions {d!r}")
    return dict(d)


class _Writer:
    def __init__(self) -> None:
        self.nodes: list[list] = []
        self.index: dict[tuple, int] = {}

    def ref(self, e: Any) -> int:
        if not isinstance(e, sp.Basic):
            raise _Unsupported(f"{type(e).__name__} {e!r} is not a SymPy expression")
        # a Float equals another of a different precision; the type keeps 1 apart from 1.0
        key = (type(e), e, e._prec) if isinstance(e, sp.Float) else (type(e), e)
        i = self.index.get(key)
        if i is None:
            node = self._node(e)
            self.nodes.append(node)
            i = self.index[key] = len(self.nodes) - 1
        return i

    def refs(self, items: Any) -> list[int] | None:
        return None if items is None else [self.ref(e) for e in items]

    def _node(self, e: sp.Basic) -> list:
        if type(e) is sp.Symbol:
            return ["sym", e.name, _assumptions(e._assumptions_orig)]
        if type(e) is sp.Dummy:
            return ["dummy", e.name, e.dummy_index, _assumptions(e._assumptions_orig)]
        if isinstance(e, sp.Integer):
            return ["int", int(e)]
        if isinstance(e, sp.Rational):
            return ["rat", int(e.p), int(e.q)]
        if isinstance(e, sp.Float):
            return ["float", mlib_to_str(e._mpf_, repr_dps(e._prec)), int(e._prec)]
        name = type(e).__name__
        if _CONSTANTS.get(name) is e:
            return ["const", name]
        if isinstance(e, AppliedUndef):
            f = type(e)
            return ["fn", f.__name__, _assumptions(f._kwargs), *(self.ref(a) for a in e.args)]
        if type(e) is sp.ImmutableDenseMatrix:
            return ["matrix", e.rows, e.cols, *(self.ref(a) for a in e)]
        if name not in _CLASSES or _CLASSES[name][0] is not type(e):
            raise _Unsupported(f"expression type {name}")
        return [name, *(self.ref(a) for a in e.args)]


def _literal(value: Any, kind: type, limit: int = _MAX_NAME) -> Any:
    if type(value) is not kind or (kind is str and len(value) > limit):
        raise ValueError(f"cache entry: unexpected {value!r}")
    return value


def _read_nodes(nodes: Any) -> list[sp.Basic]:
    if not isinstance(nodes, list) or len(nodes) > _MAX_NODES:
        raise ValueError("cache entry: no node table")
    built: list[sp.Basic] = []

    def refs(items: list) -> list[sp.Basic]:
        out = []
        for i in items:
            if type(i) is not int or not 0 <= i < len(built):
                raise ValueError(f"cache entry: bad reference {i!r}")
            out.append(built[i])
        return out

    for node in nodes:
        if not isinstance(node, list) or not node or type(node[0]) is not str:
            raise ValueError("cache entry: bad node")
        tag, rest = node[0], node[1:]
        if tag == "sym":
            name, kw = rest
            e = sp.Symbol(_literal(name, str), **_assumptions(_literal(kw, dict)))
        elif tag == "dummy":
            name, index, kw = rest
            e = sp.Dummy(
                _literal(name, str),
                dummy_index=_literal(index, int),
                **_assumptions(_literal(kw, dict)),
            )
        elif tag == "int":
            (value,) = rest
            e = sp.Integer(_literal(value, int))
        elif tag == "rat":
            p, q = rest
            e = sp.Rational(_literal(p, int), _literal(q, int))
        elif tag == "float":
            text, prec = rest
            e = sp.Float(_literal(text, str), precision=_literal(prec, int))
        elif tag == "const":
            (name,) = rest
            e = _CONSTANTS[_literal(name, str)]
        elif tag == "fn":
            name, kw, *args = rest
            f = sp.Function(_literal(name, str), **_assumptions(_literal(kw, dict)))
            e = f(*refs(args))
        elif tag == "matrix":
            rows, cols, *items = rest
            e = sp.ImmutableDenseMatrix(_literal(rows, int), _literal(cols, int), refs(items))
        elif tag in _CLASSES:
            e = _CLASSES[tag][1](refs(rest))
        else:
            raise ValueError(f"cache entry: constructor {tag!r} is not allowed")
        built.append(e)
    return built


# JSON has no SymPy values (L-P stores omega0 as a symbol) and no tuples (harmonic balance's
# harmonic set): tagged, so that a cached approximation's options equal a fresh one's.
def _encode_option(value: Any, table: _Writer) -> Any:
    if isinstance(value, sp.Basic):
        return {"expr": table.ref(value)}
    if isinstance(value, tuple):
        return {"tuple": [_encode_option(v, table) for v in value]}
    if isinstance(value, Fraction):
        return {"fraction": [value.numerator, value.denominator]}
    if isinstance(value, list):
        return [_encode_option(v, table) for v in value]
    if value is None or isinstance(value, bool | int | float | str):
        return value
    raise _Unsupported(f"option value {value!r}")


def _decode_option(value: Any, built: list[sp.Basic]) -> Any:
    if isinstance(value, dict) and len(value) == 1:
        ((tag, body),) = value.items()
        if tag == "expr":
            if type(body) is not int or not 0 <= body < len(built):
                raise ValueError(f"cache entry: bad reference {body!r}")
            return built[body]
        if tag == "tuple":
            return tuple(_decode_option(v, built) for v in body)
        if tag == "fraction":
            return Fraction(_literal(body[0], int), _literal(body[1], int))
    if isinstance(value, list):
        return [_decode_option(v, built) for v in value]
    if value is None or isinstance(value, bool | int | float | str):
        return value
    raise ValueError(f"cache entry: unexpected option {value!r}")


_SINGLE = ("waveform", "tau", "frequency", "amplitude", "backbone")
_SEVERAL = ("unknowns", "residuals", "slow_flow", "frequency_polynomial", "phase_from")


def _entry(approx: Approximation) -> dict[str, Any]:
    table = _Writer()
    fields: dict[str, Any] = {
        name: None if getattr(approx, name) is None else table.ref(getattr(approx, name))
        for name in _SINGLE
    }
    fields.update({name: table.refs(getattr(approx, name)) for name in _SEVERAL})
    return {
        "format": FORMAT_VERSION,
        "entry": _ENTRY_VERSION,
        "method": approx.method,
        "options": {k: _encode_option(v, table) for k, v in approx.options.items()},
        **fields,
        "fourier": {k: table.ref(v) for k, v in approx.fourier.items()},
        "steps": [[s.title, s.text, table.refs(s.math)] for s in approx.steps],
        "nodes": table.nodes,
    }


def _approximation(data: Mapping[str, Any], osc: Oscillator) -> Approximation:
    if data.get("entry") != _ENTRY_VERSION:
        raise ValueError("cache entry of another layout")
    built = _read_nodes(data["nodes"])

    def at(i: Any) -> sp.Basic:
        if type(i) is not int or not 0 <= i < len(built):
            raise ValueError(f"cache entry: bad reference {i!r}")
        return built[i]

    def one(i: Any) -> sp.Basic | None:
        return None if i is None else at(i)

    def several(items: Any) -> tuple[sp.Basic, ...] | None:
        return None if items is None else tuple(at(i) for i in items)

    return Approximation(
        oscillator=osc,
        method=_literal(data["method"], str),
        options=MappingProxyType(
            {_literal(k, str): _decode_option(v, built) for k, v in data["options"].items()}
        ),
        unknowns=several(data["unknowns"]) or (),
        residuals=several(data["residuals"]) or (),
        slow_flow=several(data["slow_flow"]),
        frequency_polynomial=several(data["frequency_polynomial"]),
        phase_from=several(data["phase_from"]),
        fourier=MappingProxyType({k: one(i) for k, i in data["fourier"].items()}),
        steps=tuple(
            Step(
                _literal(title, str, _MAX_TEXT),
                tuple(at(i) for i in math),
                _literal(text, str, _MAX_TEXT),
            )
            for title, text, math in data["steps"]
        ),
        **{name: one(data[name]) for name in _SINGLE},
    )


def cached_derivation(
    method: str,
    fn: Callable[..., Approximation],
    osc: Oscillator,
    *,
    use_cache: bool | None = None,
    **options: Any,
) -> Approximation:
    """``fn(osc, **options)``, from the cache when an intact entry exists.

    The result is identical either way (same expressions and steps); a cache that cannot be
    read or written only costs time.
    """
    if use_cache is None:
        use_cache = os.environ.get("PERTURB_CACHE", "1") != "0"
    if not use_cache:
        return fn(osc, **options)
    key = derivation_key(method, fn, osc, options)
    path = cache_dir() / f"{key}.json"
    if path.is_file():
        try:
            return _approximation(json.loads(path.read_text()), osc)
        except Exception:
            pass  # whatever a corrupted or tampered entry raises: recompute and overwrite
    approx = fn(osc, **options)
    try:
        text = json.dumps(_entry(approx), sort_keys=True, separators=(",", ":"))
        # store only what reads back as the very same approximation
        if _approximation(json.loads(text), osc) != approx:
            return approx
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile("w", dir=path.parent, delete=False, suffix=".tmp") as fh:
            fh.write(text)
        os.replace(fh.name, path)
    except (OSError, ValueError, RecursionError, _Unsupported):
        pass  # a read-only or full disk, or an expression the table lacks, costs only time
    return approx
