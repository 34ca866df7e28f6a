"""Text serialisation of SymPy expressions and approximations, read back without ``eval``.

Expressions are written as SymPy's ``srepr`` (``Add(Symbol('x', real=True), Integer(1))``).
Reading it back with ``sympify``/``eval`` would execute whatever a tampered file contains, so
:func:`expr_from_text` parses the text with :mod:`ast` and rebuilds the tree itself, checking
every node against one **closed vocabulary** before anything is built — the same vocabulary
the derivation cache (:mod:`perturb.io.cache`) reads its entries with:

- constructors: the SymPy classes the engines produce (:data:`CLASSES`: operators,
  relations, the elementary and nonsmooth functions, perturb's Fourier-coefficient
  functions, the engines' display rows), called with already-built subexpressions only —
  never with a string or another literal, which SymPy would ``sympify``;
  the constants of :data:`CONSTANTS`;
- symbol names (``Symbol``, ``Dummy``): the names the model declares (its coordinate ``x``,
  ``x'``, ``x''``, time, parameters and the symbols of its equation) and the engines' own
  names (``A``, ``phi``, ``tau``, ``a_1``, ``S_{1,3}``, ``\\dot{a}`` ...: a fixed list of
  stems with numeric indices and the engines' clash suffixes ``_r`` and ``_``); without a
  model (:func:`expr_from_text` alone) any plain identifier stands for a model name;
  assumptions only SymPy's own assumption names with ``True``/``False``;
- undefined-function names: only the engines' own (``a_1``, ``g``, ``x_0`` ...,
  :data:`FUNCTIONS`);
- numbers as numbers: integers of at most :data:`MAX_INT_BITS` bits, rationals of such
  integers, floats as decimal text (no ``inf``/``nan``, decimal exponent within ±1000,
  precision at most :data:`MAX_INT_BITS` bits).

Anything else — an attribute access, an unknown name, a lambda, a subscript, a string where
an expression belongs, a symbol named with Python code — is refused with a
:class:`~perturb.errors.ParseError` naming it; nothing of a refused text is built, compiled
or executed. :func:`approximation_from_dict` reads a ``perturb derive --json`` file that way,
with the vocabulary of the oscillator it is given (:func:`load` reads the file itself).

The same vocabulary reads the second form, a **node table** (:class:`ExpressionTable`,
:func:`expressions_from_table`, :func:`approximation_to_table` /
:func:`approximation_from_table`): one table of nodes shared by every expression of an
approximation, each a whitelisted constructor name with references to earlier nodes or a
literal leaf. It rebuilds a long derivation in milliseconds where parsing srepr text takes
tenths of a second; the derivation cache (:mod:`perturb.io.cache`) stores its entries so and
adds only keys, authentication and files.
"""

from __future__ import annotations

import ast
import json
import math
import re
from collections.abc import Callable, Iterable, Mapping
from fractions import Fraction
from types import MappingProxyType
from typing import Any

import sympy as sp
from sympy.core.assumptions import _assume_defined
from sympy.core.function import AppliedUndef
from sympy.functions.elementary.piecewise import ExprCondPair
from sympy.printing.repr import mlib_to_str, repr_dps

from perturb.approximation import Approximation, Step
from perturb.errors import ParseError
from perturb.fourier.symbols import DiracCoefficient, RampCoefficient, StepCoefficient

__all__ = [
    "CLASSES",
    "CONSTANTS",
    "FUNCTIONS",
    "MAX_INT_BITS",
    "Vocabulary",
    "expr_to_text",
    "expr_from_text",
    "approximation_to_dict",
    "approximation_from_dict",
    "ExpressionTable",
    "MAX_TABLE_NODES",
    "UnsupportedExpression",
    "expressions_from_table",
    "approximation_to_table",
    "approximation_from_table",
    "dumps",
    "loads",
    "load",
]

#: Written by :func:`approximation_to_dict`: 2 = srepr in SymPy's stored argument order, read
#: back unevaluated (exactly the trees written); 1 (canonical print order, read back
#: evaluated) is still read.
FORMAT_VERSION = 2
_FORMATS = (1, 2)

#: Largest integer (numerator, denominator, dummy index) a serialised expression may hold.
MAX_INT_BITS = 4096
_MAX_TEXT = 5_000_000  # characters of one serialised expression
_MAX_NAME = 64  # characters of a symbol or function name
_MAX_STRING = 100_000  # characters of a step's title or text
_MAX_DEPTH = 400  # nesting of a serialised expression (the reader recurses)
_MAX_ITEMS = 1_000_000  # elements of a list in an approximation's description
_MAX_POWER = 10_000  # numerator and denominator of the exponent of a power of a number


# ------------------------------------------------------------------------------------------
# constructors
# ------------------------------------------------------------------------------------------
def _unevaluated(cls: type) -> Callable[[list], sp.Basic]:
    return lambda args: cls(*args, evaluate=False)


def _as_given(cls: type) -> Callable[[list], sp.Basic]:
    return lambda args: cls(*args)


def _assoc(cls: type) -> Callable[[list], sp.Basic]:
    # what Add/Mul(*args, evaluate=False) builds, without the constructor's cache lookup and
    # re-sympifying — most of a warm cache hit's time, as most nodes are products
    return lambda args: cls._from_args(args)


_RELATIONS = (
    sp.Equality,
    sp.Unequality,
    sp.StrictLessThan,
    sp.StrictGreaterThan,
    sp.LessThan,
    sp.GreaterThan,
)


class _Continued(sp.Expr):
    """A continuation row of a long equation in a derivation; prints as ``+ terms``.

    The engines no longer split equations (the writer, :mod:`perturb.report.latex`, does, and
    joins such rows back); kept here, with the underscore its saved form ``_Continued(...)``
    spells, so that derivations saved as JSON by earlier versions load."""

    def __new__(cls, expr: sp.Expr) -> _Continued:
        return sp.Expr.__new__(cls, sp.sympify(expr))

    def _latex(self, printer: Any, *args: Any) -> str:
        s = printer._print(self.args[0])
        return r"\qquad " + (s if s.lstrip().startswith("-") else "+ " + s)

    def _sympystr(self, printer: Any, *args: Any) -> str:
        s = printer._print(self.args[0])
        return "    " + (s if s.startswith("-") else "+ " + s)


#: Class name -> (class, constructor from the rebuilt arguments): every expression type the
#: engines produce. Each satisfies ``constructor(e.args) == e``: operators and functions
#: unevaluated; ``Order`` and the containers as given (``Order`` normalises by expanding and
#: never stays unevaluated). A constructor is only ever called with built SymPy objects.
CLASSES: Mapping[str, tuple[type, Callable[[list], sp.Basic]]] = MappingProxyType(
    {
        **{
            cls.__name__: (cls, _unevaluated(cls))
            for cls in (
                sp.Pow,
                *_RELATIONS,
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
        },
        **{cls.__name__: (cls, _assoc(cls)) for cls in (sp.Add, sp.Mul)},
        **{
            cls.__name__: (cls, _as_given(cls))
            for cls in (sp.Tuple, sp.Derivative, ExprCondPair, sp.Order, _Continued)
        },
    }
)


#: Class name -> the constant (SymPy singletons an expression may contain).
CONSTANTS: Mapping[str, sp.Basic] = MappingProxyType(
    {
        type(c).__name__: c
        for c in (
            sp.pi,
            sp.E,
            sp.I,
            sp.oo,
            -sp.oo,
            sp.zoo,
            sp.nan,
            sp.true,
            sp.false,
            sp.EulerGamma,
        )
    }
)
# the bare names srepr writes for those singletons (``-oo`` is ``-`` applied to ``oo``)
_BARE: Mapping[str, sp.Basic] = MappingProxyType(
    {
        "pi": sp.pi,
        "E": sp.E,
        "I": sp.I,
        "oo": sp.oo,
        "zoo": sp.zoo,
        "nan": sp.nan,
        "true": sp.true,
        "false": sp.false,
        "EulerGamma": sp.EulerGamma,
    }
)

#: Names of the undefined functions the engines apply (``a_1(A)``, ``g(x, x')``,
#: ``x_0(tau)`` ...); ``x_<n>`` and ``g_<n>`` for every order ``n``.
FUNCTIONS: frozenset[str] = frozenset(
    {"+", "B", "a_1", "c_eq", "g", "g_0", "g_c", "g_s", "ghat_1", "k_eq", "x"}
)
_FUNCTION_FAMILY = re.compile(r"[xg]_\d{1,4}")

# Stems of the engines' own symbol names (methods/*.py: the unknowns, phases, scales, their
# Dummy symbols and the display names of derivation steps), each followed by any number of
# indices: _<n>, <n>, _{<p>/<q>} (a fractional harmonic), _{<m>,<n>}, and the suffixes _r
# and _ that keep a name clear of the model's parameters.
_ENGINE_STEMS = frozenset(
    """A B Bb D Delta J Lambda NST Omega R S T U V W a alpha alphahat b beta c cc delta epsilon
    f g gamma nu omega p phi psi q sh sigma tau theta u v varepsilon w x y z""".split()
)
_DISPLAY = frozenset({r"\ldots", "...", "x_p"})
# possessive (no backtracking): "a" followed by 60 digits would otherwise take for ever
_INDEXED = re.compile(
    r"(?P<stem>[A-Za-z]++)(?P<tail>(?:_?\d{1,4}+|_\{\d{1,4}/\d{1,4}\}|_\{\d{1,4},\d{1,4}\}"
    r"|_r|_)*+)"
)
_DOT = re.compile(r"\\dot\{\\?(?P<stem>[A-Za-z]+)[A-Za-z0-9_{} ]*\}")
_IDENTIFIER = re.compile(r"[A-Za-z][A-Za-z0-9_]*'{0,2}")
_FLOAT_TEXT = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?(?P<exp>\d{1,4}))?")
_ASSUMPTIONS = frozenset(_assume_defined)


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


class Vocabulary:
    """The closed vocabulary a serialised expression is read with (module docstring).

    Parameters
    ----------
    names
        The symbol names the model declares; ``None``: any plain identifier (letters, digits
        and underscores, at most two trailing primes) stands for a model name.
    where
        What is being read, for error messages (``"cache entry ..."``, a file name).

    Every method raises :class:`~perturb.errors.ParseError` naming the refused value.
    """

    __slots__ = ("_names", "_ok", "where")

    def __init__(self, names: Iterable[str] | None = None, where: str = "serialised expression"):
        self._names = None if names is None else frozenset(names)
        self._ok: set[str] = set()
        self.where = where

    @classmethod
    def for_oscillator(cls, oscillator: Any, where: str = "serialised expression") -> Vocabulary:
        """The vocabulary of the engines' derivations of ``oscillator``."""
        x = oscillator.x.name
        names = {x, oscillator.v.name, oscillator.t.name, x + "'", x + "''", *oscillator.params}
        names.update(s.name for s in oscillator.equation.free_symbols if isinstance(s, sp.Symbol))
        return cls(names, where)

    def fail(self, what: str) -> ParseError:
        """The error for a refused ``what``."""
        return ParseError(f"{self.where}: {what}")

    # -- names ---------------------------------------------------------------------------------
    def _known_stem(self, stem: str) -> bool:
        return stem in _ENGINE_STEMS or self._names is None or stem in self._names

    def symbol_name(self, name: Any) -> str:
        """``name`` if it is a model's or an engine's symbol name."""
        if name in self._ok:
            return name
        if type(name) is not str or not 0 < len(name) <= _MAX_NAME:
            raise self.fail(f"symbol name {_short(name)} is not allowed")
        ok = name in _DISPLAY or (self._names is not None and name in self._names)
        if not ok and self._names is None:
            ok = _IDENTIFIER.fullmatch(name) is not None
        if not ok:
            m = _INDEXED.fullmatch(name) or _DOT.fullmatch(name)
            ok = m is not None and self._known_stem(m["stem"])
        if not ok:
            raise self.fail(
                f"symbol name {_short(name)} is neither a name of the model nor one of the "
                "derivation engines' names"
            )
        self._ok.add(name)
        return name

    def function_name(self, name: Any) -> str:
        """``name`` if it is one of the engines' undefined functions."""
        if type(name) is not str or not (
            name in FUNCTIONS or _FUNCTION_FAMILY.fullmatch(name) is not None
        ):
            raise self.fail(
                f"function name {_short(name)} is not one of the derivation engines' functions"
            )
        return name

    def assumptions(self, kw: Any) -> dict[str, bool]:
        """``kw`` if it maps SymPy assumption names to ``True``/``False``."""
        if not isinstance(kw, dict) or not all(
            k in _ASSUMPTIONS and type(v) is bool for k, v in kw.items()
        ):
            raise self.fail(f"assumptions {_short(kw)} are not allowed")
        return kw

    # -- numbers -------------------------------------------------------------------------------
    def integer_value(self, value: Any) -> int:
        """``value`` if it is an ``int`` (not a bool) of at most :data:`MAX_INT_BITS` bits."""
        if type(value) is not int or value.bit_length() > MAX_INT_BITS:
            raise self.fail(f"{_short(value)} is not an integer of at most {MAX_INT_BITS} bits")
        return value

    # -- leaves --------------------------------------------------------------------------------
    def symbol(self, name: Any, assumptions: Any) -> sp.Symbol:
        return sp.Symbol(self.symbol_name(name), **self.assumptions(assumptions))

    def dummy(self, name: Any, index: Any, assumptions: Any) -> sp.Dummy:
        return sp.Dummy(
            self.symbol_name(name),
            dummy_index=self.integer_value(index),
            **self.assumptions(assumptions),
        )

    def function(self, name: Any, assumptions: Any) -> sp.core.function.UndefinedFunction:
        return sp.Function(self.function_name(name), **self.assumptions(assumptions))

    def integer(self, value: Any) -> sp.Integer:
        return sp.Integer(self.integer_value(value))

    def rational(self, p: Any, q: Any) -> sp.Rational:
        if self.integer_value(q) <= 0:
            raise self.fail(f"rational {_short(p)}/{_short(q)}: expected a positive denominator")
        return sp.Rational(self.integer_value(p), q)

    def float(self, text: Any, precision: Any) -> sp.Float:
        """A finite float from decimal text and a precision in bits."""
        m = _FLOAT_TEXT.fullmatch(text) if type(text) is str and len(text) <= 1500 else None
        if m is None or (m["exp"] is not None and int(m["exp"]) > 1000):
            raise self.fail(f"{_short(text)} is not a finite decimal number")
        prec = self.integer_value(precision)
        if not 1 <= prec <= MAX_INT_BITS:
            raise self.fail(f"float precision {prec} is not in 1..{MAX_INT_BITS}")
        return sp.Float(text, precision=prec)

    def constant(self, name: Any) -> sp.Basic:
        if type(name) is not str or name not in CONSTANTS:
            raise self.fail(f"constant {_short(name)} is not allowed")
        return CONSTANTS[name]

    def matrix(self, rows: Any, cols: Any, items: list[sp.Basic]) -> sp.ImmutableDenseMatrix:
        r, c = self.integer_value(rows), self.integer_value(cols)
        if not (0 <= r and 0 <= c and r * c == len(items)):
            raise self.fail(f"a {r}x{c} matrix with {len(items)} elements")
        return sp.ImmutableDenseMatrix(r, c, items)

    def power(self, base: sp.Basic, exponent: sp.Basic) -> None:
        """Refuse a power of a number whose exponent is not a rational of at most 10 000 in
        numerator and denominator (``10**10**100`` would never finish evaluating)."""
        if base.is_Number and not (
            exponent.is_Rational and abs(exponent.p) <= _MAX_POWER and exponent.q <= _MAX_POWER
        ):
            raise self.fail(f"the power {_short(base)}**({_short(exponent)}) is not allowed")

    def node(self, name: Any, args: list[sp.Basic], evaluate: bool = False) -> sp.Basic:
        """``name(*args)`` for a class of :data:`CLASSES` (``args`` already built), as the
        class's table constructor builds it or, with ``evaluate``, evaluated (relations
        stay unevaluated: ``Eq(J, Matrix(...))`` would become ``False``)."""
        entry = CLASSES.get(name) if type(name) is str else None
        if entry is None:
            raise self.fail(f"constructor {_short(name)} is not allowed")
        if entry[0] is sp.Pow and len(args) == 2:
            self.power(*args)
        try:
            if not evaluate or entry[0] in _RELATIONS:
                return entry[1](args)
            return entry[0](*args)
        except (TypeError, ValueError, AttributeError, IndexError, RecursionError) as exc:
            raise self.fail(f"{name} of {len(args)} argument(s): {exc}") from None


# ------------------------------------------------------------------------------------------
# srepr text
# ------------------------------------------------------------------------------------------
def expr_to_text(expr: sp.Basic) -> str:
    """``srepr`` of ``expr`` (a plain-text, exact and complete description), arguments in the
    order SymPy stores them, so that :func:`expr_from_text` rebuilds the very same tree."""
    return sp.srepr(expr, order="none")


def _literal(node: ast.AST, vocab: Vocabulary) -> Any:
    if isinstance(node, ast.Constant) and type(node.value) in (str, int, float, bool):
        return node.value
    if (
        isinstance(node, ast.UnaryOp)
        and isinstance(node.op, ast.USub)
        and isinstance(node.operand, ast.Constant)
        and type(node.operand.value) is int
    ):
        return -node.operand.value
    raise vocab.fail(f"unexpected {ast.dump(node)[:80]}")


def expr_from_text(
    text: str, vocabulary: Vocabulary | None = None, *, evaluate: bool = False
) -> sp.Basic:
    """Rebuild an expression written by :func:`expr_to_text` — without ``eval``.

    Parameters
    ----------
    text
        ``srepr`` text.
    vocabulary
        The names allowed (:class:`Vocabulary`; default: the engines' names and any plain
        identifier as a model name).
    evaluate
        Build each node evaluated (text written in SymPy's default print order, e.g. by
        format 1 of :func:`approximation_to_dict`) instead of exactly as written.

    Returns
    -------
    sympy.Basic
        The expression, built from the whitelisted constructors.

    Raises
    ------
    ParseError
        For text that is not a tree of the closed vocabulary (module docstring), naming the
        first refused element.
    """
    vocab = vocabulary if vocabulary is not None else Vocabulary()
    if not isinstance(text, str) or len(text) > _MAX_TEXT:
        raise vocab.fail(f"expected srepr text of at most {_MAX_TEXT} characters")
    try:
        tree = ast.parse(text, mode="eval")
    except (SyntaxError, ValueError, MemoryError, RecursionError) as exc:
        raise vocab.fail(f"{_short(text)} is not valid: {getattr(exc, 'msg', exc)}") from None
    try:
        return _expr(tree.body, vocab, 0, evaluate)
    except RecursionError:
        raise vocab.fail("nested too deeply") from None


def _keywords(node: ast.Call, vocab: Vocabulary) -> dict[str, Any]:
    out = {}
    for kw in node.keywords:
        if kw.arg is None:
            raise vocab.fail("** arguments are not allowed")
        out[kw.arg] = _literal(kw.value, vocab)
    return out


def _positional(node: ast.Call, vocab: Vocabulary, n: int) -> list[Any]:
    if len(node.args) != n:
        raise vocab.fail(f"{ast.unparse(node.func)[:40]} takes {n} literal argument(s)")
    return [_literal(a, vocab) for a in node.args]


def _expr(node: ast.AST, vocab: Vocabulary, depth: int, evaluate: bool) -> sp.Basic:
    """The expression ``node`` describes; every constructor gets built SymPy objects only."""
    if depth > _MAX_DEPTH:
        raise vocab.fail(f"nested deeper than {_MAX_DEPTH} levels")
    if isinstance(node, ast.Name):
        if node.id in _BARE:
            return _BARE[node.id]
        raise vocab.fail(f"the name {node.id!r} is not allowed")
    if (
        isinstance(node, ast.UnaryOp)
        and isinstance(node.op, ast.USub)
        and isinstance(node.operand, ast.Name)
        and node.operand.id == "oo"
    ):
        return -sp.oo
    if not isinstance(node, ast.Call):
        raise vocab.fail(f"unexpected {ast.dump(node)[:80]} where an expression belongs")
    args_in = node.args
    if any(isinstance(a, ast.Starred) for a in args_in):
        raise vocab.fail("* arguments are not allowed")
    # Function('f')(x): an applied undefined function
    if isinstance(node.func, ast.Call):
        head = node.func
        if not (isinstance(head.func, ast.Name) and head.func.id == "Function") or node.keywords:
            raise vocab.fail("only Function('name') may be applied")
        (name,) = _positional(head, vocab, 1)
        f = vocab.function(name, _keywords(head, vocab))
        return f(*(_expr(a, vocab, depth + 1, evaluate) for a in args_in))
    if not isinstance(node.func, ast.Name):
        raise vocab.fail(f"unexpected call of {ast.dump(node.func)[:80]}")
    name = node.func.id
    kw = _keywords(node, vocab)
    if name == "Symbol":
        (sym,) = _positional(node, vocab, 1)
        return vocab.symbol(sym, kw)
    if name == "Dummy":
        (sym,) = _positional(node, vocab, 1)
        if "dummy_index" not in kw:
            raise vocab.fail(f"Dummy({_short(sym)}) without its dummy_index")
        index = kw.pop("dummy_index")
        return vocab.dummy(sym, index, kw)
    if name in ("Integer", "Rational", "Float"):
        values = _positional(node, vocab, {"Integer": 1, "Rational": 2, "Float": 1}[name])
        if name == "Float":
            if set(kw) != {"precision"}:
                raise vocab.fail(f"Float({_short(values[0])}) needs precision= and nothing else")
            return vocab.float(values[0], kw["precision"])
        if kw:
            raise vocab.fail(f"{name} takes no keyword arguments")
        return vocab.integer(*values) if name == "Integer" else vocab.rational(*values)
    if name == "ImmutableDenseMatrix":
        if len(args_in) != 1 or kw or not isinstance(args_in[0], ast.List):
            raise vocab.fail("ImmutableDenseMatrix takes one list of rows")
        rows = args_in[0].elts
        if not all(isinstance(r, ast.List) and len(r.elts) == len(rows[0].elts) for r in rows):
            raise vocab.fail("ImmutableDenseMatrix takes one list of rows of equal length")
        items = [_expr(e, vocab, depth + 1, evaluate) for r in rows for e in r.elts]
        return vocab.matrix(len(rows), len(rows[0].elts) if rows else 0, items)
    if kw:
        raise vocab.fail(f"{name} takes no keyword arguments")
    if name not in CLASSES:
        raise vocab.fail(f"constructor {name!r} is not allowed")
    args = [_expr(a, vocab, depth + 1, evaluate) for a in args_in]
    return vocab.node(name, args, evaluate=evaluate)


# ------------------------------------------------------------------------------------------
# approximations
# ------------------------------------------------------------------------------------------
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


def check_plain(value: Any, vocab: Vocabulary, what: str) -> Any:
    """``value`` if it is JSON data of bounded size: ``None``, a bool, an integer of at most
    :data:`MAX_INT_BITS` bits, a finite float, a string of at most 100 000 characters."""
    if value is None or type(value) is bool:
        return value
    if type(value) is int:
        return vocab.integer_value(value)
    if type(value) is float:
        if not math.isfinite(value):
            raise vocab.fail(f"{what} = {value!r}: expected a finite number")
        return value
    if type(value) is str:
        if len(value) > _MAX_STRING:
            raise vocab.fail(f"{what}: a text of {len(value)} characters")
        return value
    raise vocab.fail(f"{what} = {_short(value)} is not allowed")


def _option_from_json(value: Any, vocab: Vocabulary, evaluate: bool, depth: int = 0) -> Any:
    if depth > 20:
        raise vocab.fail("option nested too deeply")
    if isinstance(value, Mapping):
        if set(value) == {_SYMPY_TAG}:
            return expr_from_text(value[_SYMPY_TAG], vocab, evaluate=evaluate)
        return {
            _text(k, vocab, "option name", 200): _option_from_json(v, vocab, evaluate, depth + 1)
            for k, v in value.items()
        }
    if isinstance(value, list):
        return tuple(_option_from_json(v, vocab, evaluate, depth + 1) for v in _items(value, vocab))
    return check_plain(value, vocab, "option")


def _text(value: Any, vocab: Vocabulary, what: str, limit: int = _MAX_STRING) -> str:
    if type(value) is not str or len(value) > limit:
        raise vocab.fail(f"{what}: expected a text of at most {limit} characters")
    return value


def _items(value: Any, vocab: Vocabulary) -> list:
    if not isinstance(value, list) or len(value) > _MAX_ITEMS:
        raise vocab.fail(f"expected a list of at most {_MAX_ITEMS} items, got {_short(value)}")
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
        **({"notes": list(approx.notes)} if approx.notes else {}),
    }


def approximation_from_dict(
    data: Mapping[str, Any], oscillator: Any, source: str = "serialised approximation"
) -> Approximation:
    """Rebuild an :class:`Approximation` for ``oscillator`` from :func:`approximation_to_dict`.

    Every expression is read with the vocabulary of ``oscillator`` (its declared names and the
    engines' names, module docstring) before anything is built; nothing is evaluated.

    Parameters
    ----------
    data
        The description, e.g. ``json.load`` of a ``perturb derive --json`` file.
    oscillator
        The :class:`~perturb.model.oscillator.Oscillator` the derivation is of.
    source
        What ``data`` was read from (a file name), for error messages.

    Raises
    ------
    ParseError
        For a description of another format version, a missing or malformed field, or
        content outside the vocabulary — naming the field or value.
    """
    from perturb.model.oscillator import Oscillator

    if not isinstance(oscillator, Oscillator):
        raise ParseError(f"{source}: expected an Oscillator, got {type(oscillator).__name__}")
    vocab = Vocabulary.for_oscillator(oscillator, source)
    if not isinstance(data, Mapping):
        raise vocab.fail(f"expected a JSON object, got {type(data).__name__}")
    fmt = data.get("format")
    if type(fmt) is not int or fmt not in _FORMATS:
        raise vocab.fail(f"format {_short(fmt)}: expected one of {_FORMATS}")
    # format 1 printed srepr in canonical order (-2*x as Mul(-1, 2, x)): rebuilt evaluated
    evaluate = fmt == 1

    def expr(text: Any) -> sp.Basic:
        return expr_from_text(text, vocab, evaluate=evaluate)

    def field(key: str, required: bool = True) -> Any:
        if key not in data:
            if required:
                raise vocab.fail(f"the field {key!r} is missing")
            return None
        return data[key]

    def many(key: str) -> tuple[sp.Basic, ...] | None:
        v = field(key, required=False)
        return None if v is None else tuple(expr(t) for t in _items(v, vocab))

    def one(key: str, required: bool = False) -> sp.Basic | None:
        v = field(key, required)
        return None if v is None else expr(v)

    options = field("options", required=False) or {}
    fourier = field("fourier")
    steps = _items(field("steps"), vocab)
    if not isinstance(options, Mapping) or not isinstance(fourier, Mapping):
        raise vocab.fail("'options' and 'fourier' must be JSON objects")
    if not all(isinstance(s, Mapping) and "title" in s and "math" in s for s in steps):
        raise vocab.fail("every step must be an object with 'title' and 'math'")
    return Approximation(
        oscillator=oscillator,
        method=_text(field("method"), vocab, "method", 200),
        options=MappingProxyType(
            {
                _text(k, vocab, "option name", 200): _option_from_json(v, vocab, evaluate)
                for k, v in options.items()
            }
        ),
        unknowns=many("unknowns") or (),
        residuals=many("residuals") or (),
        waveform=one("waveform", required=True),
        tau=one("tau", required=True),
        frequency=one("frequency", required=True),
        slow_flow=many("slow_flow"),
        amplitude=one("amplitude"),
        frequency_polynomial=many("frequency_polynomial"),
        phase_from=many("phase_from"),
        backbone=one("backbone"),
        fourier=MappingProxyType(
            {_text(k, vocab, "label", 200): expr(v) for k, v in fourier.items()}
        ),
        steps=tuple(
            Step(
                _text(s["title"], vocab, "step title"),
                tuple(expr(m) for m in _items(s["math"], vocab)),
                _text(s.get("text", ""), vocab, "step text"),
            )
            for s in steps
        ),
        notes=tuple(
            _text(note, vocab, "note") for note in _items(field("notes", False) or [], vocab)
        ),
    )


# ------------------------------------------------------------------------------------------
# node tables (the derivation cache's entries, :mod:`perturb.io.cache`)
# ------------------------------------------------------------------------------------------
#: Largest node table :func:`expressions_from_table` reads.
MAX_TABLE_NODES = 2_000_000


class UnsupportedExpression(Exception):
    """An expression :class:`ExpressionTable` cannot write so that it reads back exactly
    (a type outside :data:`CLASSES`, non-boolean assumptions, an option value of no JSON
    form): the caller does not store it."""


def _assumptions_of(d: Mapping[str, Any]) -> dict[str, bool]:
    if not all(isinstance(k, str) and isinstance(v, bool) for k, v in d.items()):
        raise UnsupportedExpression(f"assumptions {d!r}")
    return dict(d)


class ExpressionTable:
    """A table of expression nodes shared by many expressions, for JSON.

    Each node is a list: a constructor name of :data:`CLASSES` followed by the indices of its
    arguments' nodes (earlier in the table), or a tagged leaf: ``["sym", name,
    assumptions]``, ``["dummy", name, index, assumptions]``, ``["int", n]``, ``["rat", p,
    q]``, ``["float", decimal text, precision]``, ``["const", name]``, ``["fn", name,
    assumptions, *args]`` (an applied undefined function), ``["matrix", rows, cols,
    *items]``. Equal subexpressions share one node: the derivation steps repeat the same
    symbols and subexpressions thousands of times. :func:`expressions_from_table` reads it
    back through a :class:`Vocabulary`.
    """

    def __init__(self) -> None:
        self.nodes: list[list] = []
        self.index: dict[tuple, int] = {}

    def ref(self, e: Any) -> int:
        """The index of ``e``'s node, written (with its arguments) if new.

        Raises
        ------
        UnsupportedExpression
            For anything the table cannot rebuild exactly.
        """
        if not isinstance(e, sp.Basic):
            raise UnsupportedExpression(f"{type(e).__name__} {e!r} is not a SymPy expression")
        # a Float equals another of a different precision; the type keeps 1 apart from 1.0
        key = (type(e), e, e._prec) if isinstance(e, sp.Float) else (type(e), e)
        i = self.index.get(key)
        if i is None:
            node = self._node(e)
            self.nodes.append(node)
            i = self.index[key] = len(self.nodes) - 1
        return i

    def refs(self, items: Any) -> list[int] | None:
        """The indices of ``items``' nodes; ``None`` for ``None``."""
        return None if items is None else [self.ref(e) for e in items]

    def _node(self, e: sp.Basic) -> list:
        if type(e) is sp.Symbol:
            return ["sym", e.name, _assumptions_of(e._assumptions_orig)]
        if type(e) is sp.Dummy:
            return ["dummy", e.name, e.dummy_index, _assumptions_of(e._assumptions_orig)]
        if isinstance(e, sp.Integer):
            return ["int", int(e)]
        if isinstance(e, sp.Rational):
            return ["rat", int(e.p), int(e.q)]
        if isinstance(e, sp.Float):
            return ["float", mlib_to_str(e._mpf_, repr_dps(e._prec)), int(e._prec)]
        name = type(e).__name__
        if CONSTANTS.get(name) is e:
            return ["const", name]
        if isinstance(e, AppliedUndef):
            f = type(e)
            return ["fn", f.__name__, _assumptions_of(f._kwargs), *(self.ref(a) for a in e.args)]
        if type(e) is sp.ImmutableDenseMatrix:
            return ["matrix", e.rows, e.cols, *(self.ref(a) for a in e)]
        if name not in CLASSES or CLASSES[name][0] is not type(e):
            raise UnsupportedExpression(f"expression type {name}")
        return [name, *(self.ref(a) for a in e.args)]


def expressions_from_table(nodes: Any, vocab: Vocabulary) -> list[sp.Basic]:
    """The expressions of a node table written by :class:`ExpressionTable`, in order.

    Each node is checked against ``vocab`` before it is built, and refers only to nodes
    before it; constructors get built SymPy objects only, unevaluated.

    Raises
    ------
    ValueError
        (:class:`~perturb.errors.ParseError` for content outside the vocabulary) naming the
        first refused node.
    """
    if not isinstance(nodes, list) or len(nodes) > MAX_TABLE_NODES:
        raise ValueError("no node table")
    built: list[sp.Basic] = []
    n_built = 0

    def refs(items: list) -> list[sp.Basic]:
        out = []
        for i in items:
            if type(i) is not int or not 0 <= i < n_built:
                raise ValueError(f"bad reference {str(i)[:40]!r}")
            out.append(built[i])
        return out

    for node in nodes:
        if type(node) is not list or not node or type(node[0]) is not str:
            raise ValueError(f"bad node {str(node)[:80]!r}")
        tag, rest = node[0], node[1:]
        if tag in CLASSES:  # most nodes: a whitelisted class of built arguments
            e = vocab.node(tag, refs(rest))
        elif tag == "sym":
            name, kw = rest
            e = vocab.symbol(name, kw)
        elif tag == "dummy":
            name, index, kw = rest
            e = vocab.dummy(name, index, kw)
        elif tag == "int":
            (value,) = rest
            e = vocab.integer(value)
        elif tag == "rat":
            p, q = rest
            e = vocab.rational(p, q)
        elif tag == "float":
            text, prec = rest
            e = vocab.float(text, prec)
        elif tag == "const":
            (name,) = rest
            e = vocab.constant(name)
        elif tag == "fn":
            name, kw, *args = rest
            e = vocab.function(name, kw)(*refs(args))
        elif tag == "matrix":
            rows, cols, *items = rest
            e = vocab.matrix(rows, cols, refs(items))
        else:
            raise ValueError(f"constructor {tag[:80]!r} is not allowed")
        built.append(e)
        n_built += 1
    return built


def _literal_of(value: Any, kind: type, limit: int = 200) -> Any:
    if type(value) is not kind or (kind is str and len(value) > limit):
        raise ValueError(f"unexpected {str(value)[:80]!r}")
    return value


# JSON has no SymPy values (L-P stores omega0 as a symbol) and no tuples (harmonic balance's
# harmonic set): tagged, so that a read-back approximation's options equal a fresh one's.
def _option_to_table(value: Any, table: ExpressionTable) -> Any:
    if isinstance(value, sp.Basic):
        return {"expr": table.ref(value)}
    if isinstance(value, tuple):
        return {"tuple": [_option_to_table(v, table) for v in value]}
    if isinstance(value, Fraction):
        return {"fraction": [value.numerator, value.denominator]}
    if isinstance(value, list):
        return [_option_to_table(v, table) for v in value]
    if value is None or isinstance(value, bool | int | float | str):
        return value
    raise UnsupportedExpression(f"option value {value!r}")


def _option_from_table(value: Any, built: list[sp.Basic], vocab: Vocabulary, depth: int = 0) -> Any:
    if depth > 20:
        raise ValueError("option nested too deeply")
    if isinstance(value, dict) and len(value) == 1:
        ((tag, body),) = value.items()
        if tag == "expr":
            if type(body) is not int or not 0 <= body < len(built):
                raise ValueError(f"bad reference {str(body)[:40]!r}")
            return built[body]
        if tag == "tuple":
            return tuple(
                _option_from_table(v, built, vocab, depth + 1) for v in _literal_of(body, list)
            )
        if tag == "fraction":
            p, q = _literal_of(body, list)
            if vocab.integer_value(q) <= 0:
                raise ValueError(f"fraction {p!r}/{q!r}")
            return Fraction(vocab.integer_value(p), q)
    if isinstance(value, list):
        return [_option_from_table(v, built, vocab, depth + 1) for v in value]
    return check_plain(value, vocab, "option")


_SINGLE = ("waveform", "tau", "frequency", "amplitude", "backbone")
_SEVERAL = ("unknowns", "residuals", "slow_flow", "frequency_polynomial", "phase_from")
_MAX_TABLE_TEXT = 100_000  # characters of a step's title or text in a table


def approximation_to_table(approx: Approximation) -> dict[str, Any]:
    """A JSON-ready description of ``approx`` whose expressions share one node table
    (:class:`ExpressionTable`): the derivation cache's entry body. Options are tagged so
    that they read back as the same values (SymPy objects, tuples, fractions).

    Raises
    ------
    UnsupportedExpression
        For an expression or option value the table cannot rebuild exactly.
    """
    table = ExpressionTable()
    fields: dict[str, Any] = {
        name: None if getattr(approx, name) is None else table.ref(getattr(approx, name))
        for name in _SINGLE
    }
    fields.update({name: table.refs(getattr(approx, name)) for name in _SEVERAL})
    out = {
        "format": FORMAT_VERSION,
        "method": approx.method,
        "options": {k: _option_to_table(v, table) for k, v in approx.options.items()},
        **fields,
        "fourier": {k: table.ref(v) for k, v in approx.fourier.items()},
        "steps": [[s.title, s.text, table.refs(s.math)] for s in approx.steps],
        "nodes": table.nodes,
    }
    if approx.notes:  # only when there are notes: other descriptions keep their bytes
        out["notes"] = list(approx.notes)
    return out


def approximation_from_table(
    data: Any, oscillator: Any, where: str = "serialised approximation"
) -> Approximation:
    """The approximation of ``oscillator`` that :func:`approximation_to_table` described,
    read through the oscillator's :class:`Vocabulary` (module docstring).

    Raises
    ------
    ValueError
        (:class:`~perturb.errors.ParseError` for content outside the vocabulary), or for a
        malformed description ``KeyError``/``TypeError``: nothing is built past the first
        refused node, nothing is evaluated.
    """
    if not isinstance(data, dict):
        raise ValueError("expected a JSON object")
    vocab = Vocabulary.for_oscillator(oscillator, where)
    built = expressions_from_table(data["nodes"], vocab)

    def at(i: Any) -> sp.Basic:
        if type(i) is not int or not 0 <= i < len(built):
            raise ValueError(f"bad reference {str(i)[:40]!r}")
        return built[i]

    def one(i: Any) -> sp.Basic | None:
        return None if i is None else at(i)

    def several(items: Any) -> tuple[sp.Basic, ...] | None:
        return None if items is None else tuple(at(i) for i in _literal_of(items, list))

    return Approximation(
        oscillator=oscillator,
        method=_literal_of(data["method"], str),
        options=MappingProxyType(
            {
                _literal_of(k, str): _option_from_table(v, built, vocab)
                for k, v in _literal_of(data["options"], dict).items()
            }
        ),
        unknowns=several(data["unknowns"]) or (),
        residuals=several(data["residuals"]) or (),
        slow_flow=several(data["slow_flow"]),
        frequency_polynomial=several(data["frequency_polynomial"]),
        phase_from=several(data["phase_from"]),
        fourier=MappingProxyType(
            {_literal_of(k, str): one(i) for k, i in _literal_of(data["fourier"], dict).items()}
        ),
        steps=tuple(
            Step(
                _literal_of(title, str, _MAX_TABLE_TEXT),
                tuple(at(i) for i in _literal_of(math, list)),
                _literal_of(text, str, _MAX_TABLE_TEXT),
            )
            for title, text, math in _literal_of(data["steps"], list)
        ),
        notes=tuple(
            _literal_of(note, str, _MAX_TABLE_TEXT)
            for note in _literal_of(data.get("notes", []), list)
        ),
        **{name: one(data[name]) for name in _SINGLE},
    )


def dumps(approx: Approximation) -> str:
    """JSON text of an approximation."""
    return json.dumps(approximation_to_dict(approx), indent=1, sort_keys=True)


_MAX_FILE = 256 * 2**20


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a number")


def loads(text: str | bytes, oscillator: Any, source: str = "serialised approximation"):
    """The approximation in JSON ``text`` (:func:`dumps`, ``perturb derive --json``).

    Raises
    ------
    ParseError
        For text that is not JSON (``NaN`` and ``Infinity`` included) or not a valid
        description (:func:`approximation_from_dict`), naming ``source``.
    """
    if not isinstance(text, str | bytes) or len(text) > _MAX_FILE:
        raise ParseError(f"{source}: expected JSON text of at most {_MAX_FILE} bytes")
    try:
        data = json.loads(text, parse_constant=_no_constant)
    except (ValueError, RecursionError) as exc:
        raise ParseError(f"{source} is not valid JSON: {str(exc)[:200]}") from None
    return approximation_from_dict(data, oscillator, source)


def load(path: Any, oscillator: Any) -> Approximation:
    """The approximation in the file ``path`` written by ``perturb derive --json``, read
    through the closed vocabulary of ``oscillator`` (module docstring).

    Raises
    ------
    ParseError
        For a file that cannot be read or is not a valid description, naming the file.
    """
    from pathlib import Path

    p = Path(path)
    try:
        if p.stat().st_size > _MAX_FILE:
            raise ParseError(f"derivation file {str(p)!r} is larger than {_MAX_FILE} bytes")
        raw = p.read_bytes()
    except OSError as exc:
        raise ParseError(f"cannot read derivation file {str(p)!r}: {exc.strerror}") from None
    return loads(raw, oscillator, f"derivation file {str(p)!r}")
