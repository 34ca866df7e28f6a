"""Text serialisation of SymPy expressions and approximations, read back without ``eval``.

Expressions are written as SymPy's ``srepr`` (``Add(Symbol('x', real=True), Integer(1))``).
Reading it back with ``sympify``/``eval`` would execute whatever a tampered cache file
contains, so :func:`expr_from_text` parses the text with :mod:`ast` and rebuilds the tree by
calling only whitelisted SymPy constructors with literal arguments. Anything else — an
attribute access, an unknown name, a lambda, a subscript — is refused.
"""

from __future__ import annotations

import ast
import json
from collections.abc import Mapping
from types import MappingProxyType
from typing import Any

import sympy as sp

from .approximation import Approximation, Step
from .errors import PerturbError
from .fourier_symbols import DiracCoefficient, RampCoefficient, StepCoefficient
from .methods.lindstedt import _Continued

__all__ = ["expr_to_text", "expr_from_text", "approximation_to_dict", "approximation_from_dict"]

FORMAT_VERSION = 1

_CONSTRUCTORS: dict[str, Any] = {
    name: getattr(sp, name)
    for name in (
        "Add Mul Pow Symbol Dummy Integer Rational Float Function Derivative Tuple Eq Ne Lt Le "
        "Gt Ge StrictLessThan StrictGreaterThan LessThan GreaterThan Equality Unequality "
        "Piecewise And Or Not "
        "Heaviside DiracDelta Max Min Abs sign sin cos tan sinh cosh tanh asin acos atan atan2 "
        "exp log sqrt re im conjugate floor ceiling"
    ).split()
}
_CONSTRUCTORS.update(
    {
        "StepCoefficient": StepCoefficient,
        "RampCoefficient": RampCoefficient,
        "DiracCoefficient": DiracCoefficient,
        "Pi": lambda: sp.pi,
        "Exp1": lambda: sp.E,
        "ImaginaryUnit": lambda: sp.I,
        "Half": lambda: sp.S.Half,
        "One": lambda: sp.S.One,
        "NegativeOne": lambda: sp.S.NegativeOne,
        "Zero": lambda: sp.S.Zero,
        "Infinity": lambda: sp.oo,
        "NegativeInfinity": lambda: -sp.oo,
        "BooleanTrue": lambda: sp.true,
        "BooleanFalse": lambda: sp.false,
        "true": lambda: sp.true,
        "false": lambda: sp.false,
        "ExprCondPair": sp.functions.elementary.piecewise.ExprCondPair,
        "AppliedUndef": None,
        "Order": sp.Order,
        # the engines' "continued on the next line" rows of long derivation steps
        "_Continued": _Continued,
    }
)
# bare names srepr writes for singletons
_NAMES: dict[str, Any] = {
    "pi": sp.pi,
    "E": sp.E,
    "I": sp.I,
    "oo": sp.oo,
    "zoo": sp.zoo,
    "nan": sp.nan,
    "true": sp.true,
    "false": sp.false,
}
_MAX_TEXT = 5_000_000


def expr_to_text(expr: sp.Basic) -> str:
    """``srepr`` of ``expr`` (a plain-text, exact and complete description)."""
    return sp.srepr(expr)


def _literal(node: ast.AST) -> Any:
    if isinstance(node, ast.Constant) and isinstance(node.value, str | int | float | bool):
        return node.value
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
        value = _literal(node.operand)
        if isinstance(value, int | float):
            return -value
    raise PerturbError(f"unexpected literal {ast.dump(node)[:80]} in serialised expression")


def expr_from_text(text: str) -> sp.Basic:
    """Rebuild an expression written by :func:`expr_to_text` — without ``eval``.

    Applied undefined functions (``Function('a_1')(Symbol('A'))``) are supported.

    Raises
    ------
    PerturbError
        For text that is not a whitelisted constructor tree.
    """
    if not isinstance(text, str) or len(text) > _MAX_TEXT:
        raise PerturbError("serialised expression: expected a string of reasonable size")
    try:
        tree = ast.parse(text, mode="eval")
    except SyntaxError as exc:
        raise PerturbError(f"serialised expression is not valid: {exc.msg}") from None
    return _build(tree.body)


def _build(node: ast.AST, depth: int = 0) -> Any:
    if depth > 2000:
        raise PerturbError("serialised expression nested too deeply")
    # Function('f')(x): a Call whose func is itself a Call
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Call):
        func = _build(node.func, depth + 1)
        args = [_build(a, depth + 1) for a in node.args]
        if not isinstance(func, sp.core.function.UndefinedFunction):
            raise PerturbError("serialised expression applies something that is not a function")
        return func(*args)
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name):
        # rebuild children through this function so nested applied functions work
        name = node.func.id
        if name not in _CONSTRUCTORS or _CONSTRUCTORS[name] is None:
            raise PerturbError(f"serialised expression uses {name!r}, which is not allowed")
        args = [_build(a, depth + 1) for a in node.args]
        if any(kw.arg is None for kw in node.keywords):
            raise PerturbError("serialised expression uses ** arguments")
        kwargs = {kw.arg: _literal(kw.value) for kw in node.keywords}
        if name == "Function":
            return sp.Function(*args, **kwargs)
        return _CONSTRUCTORS[name](*args, **kwargs)
    if isinstance(node, ast.Tuple):
        return tuple(_build(e, depth + 1) for e in node.elts)
    if isinstance(node, ast.Name):
        if node.id in _NAMES:
            return _NAMES[node.id]
        raise PerturbError(f"serialised expression uses the name {node.id!r}, which is not allowed")
    return _literal(node)


_SYMPY_TAG = "__sympy__"


def _maybe(expr: Any) -> str | None:
    return None if expr is None else expr_to_text(expr)


def _exprs(items: Any) -> list[str] | None:
    return None if items is None else [expr_to_text(e) for e in items]


def _option_to_json(value: Any) -> Any:
    # Options may hold SymPy numbers or symbols (``omega0 = 1`` is a SymPy One); JSON gets them
    # as tagged srepr text so they come back as the same objects, not as floats or strings.
    if isinstance(value, sp.Basic):
        return {_SYMPY_TAG: expr_to_text(value)}
    if isinstance(value, list | tuple):
        return [_option_to_json(v) for v in value]
    if isinstance(value, Mapping):
        return {str(k): _option_to_json(v) for k, v in value.items()}
    return value


def _option_from_json(value: Any) -> Any:
    if isinstance(value, Mapping):
        if set(value) == {_SYMPY_TAG}:
            return expr_from_text(value[_SYMPY_TAG])
        return {k: _option_from_json(v) for k, v in value.items()}
    if isinstance(value, list):
        return tuple(_option_from_json(v) for v in value)
    return value


def approximation_to_dict(approx: Approximation) -> dict[str, Any]:
    """A JSON-ready description of ``approx`` (expressions as srepr text)."""
    osc = approx.oscillator
    return {
        "format": FORMAT_VERSION,
        "oscillator": {
            "equation": osc.source or str(osc),
            "name": osc.name,
            "params": dict(osc.params),
        },
        "method": approx.method,
        "options": {k: _option_to_json(v) for k, v in approx.options.items()},
        "unknowns": _exprs(approx.unknowns),
        "residuals": _exprs(approx.residuals),
        "waveform": expr_to_text(approx.waveform),
        "tau": expr_to_text(approx.tau),
        "frequency": expr_to_text(approx.frequency),
        "slow_flow": _exprs(approx.slow_flow),
        "amplitude": _maybe(approx.amplitude),
        "frequency_polynomial": _exprs(approx.frequency_polynomial),
        "phase_from": _exprs(approx.phase_from),
        "backbone": _maybe(approx.backbone),
        "fourier": {k: expr_to_text(v) for k, v in approx.fourier.items()},
        "steps": [
            {"title": s.title, "text": s.text, "math": [expr_to_text(m) for m in s.math]}
            for s in approx.steps
        ],
    }


def approximation_from_dict(data: Mapping[str, Any], oscillator) -> Approximation:
    """Rebuild an :class:`Approximation` for ``oscillator`` from :func:`approximation_to_dict`.

    Raises
    ------
    PerturbError
        For a description of another format version or with disallowed content.
    """
    if data.get("format") != FORMAT_VERSION:
        raise PerturbError(f"serialised approximation has format {data.get('format')!r}")

    def many(key: str):
        v = data.get(key)
        return None if v is None else tuple(expr_from_text(t) for t in v)

    def one(key: str):
        v = data.get(key)
        return None if v is None else expr_from_text(v)

    return Approximation(
        oscillator=oscillator,
        method=str(data["method"]),
        options=MappingProxyType(
            {k: _option_from_json(v) for k, v in data.get("options", {}).items()}
        ),
        unknowns=many("unknowns") or (),
        residuals=many("residuals") or (),
        waveform=one("waveform"),
        tau=one("tau"),
        frequency=one("frequency"),
        slow_flow=many("slow_flow"),
        amplitude=one("amplitude"),
        frequency_polynomial=many("frequency_polynomial"),
        phase_from=many("phase_from"),
        backbone=one("backbone"),
        fourier=MappingProxyType({k: expr_from_text(v) for k, v in data["fourier"].items()}),
        steps=tuple(
            Step(s["title"], tuple(expr_from_text(m) for m in s["math"]), s.get("text", ""))
            for s in data["steps"]
        ),
    )


def dumps(approx: Approximation) -> str:
    """JSON text of an approximation."""
    return json.dumps(approximation_to_dict(approx), indent=1, sort_keys=True)
