"""Safe parsing of equations and expressions typed by users.

Nothing here calls :func:`eval`, :func:`exec` or :func:`sympy.sympify` on user text. The text
is split into tokens by one regular expression and read by a small recursive-descent parser
that builds SymPy objects directly, so the only things a string can ever produce are numbers,
symbols and calls of the whitelisted functions in :data:`FUNCTIONS`.

Grammar (informal)::

    equation   := expression [ '=' expression ]
    expression := term { ('+' | '-') term }
    term       := unary { ('*' | '/') unary }
    unary      := [ '+' | '-' ] power
    power      := primary [ ('**' | '^') unary ]
    primary    := NUMBER | NAME [ "'" | "''" ] | NAME '(' arguments ')' | '(' expression ')'
    condition  := expression ( '<' | '<=' | '>' | '>=' | '==' | '!=' ) expression | True | False

A sign directly after another binary ``+``/``-`` (``x + + y``) is rejected: it is almost always
a typo, and accepting it silently would hide a missing term.

Bounded work
------------
Everything downstream (expansion, ``Poly``, Fourier coefficients, ``lambdify``) costs time that
grows with the size of the expression, its polynomial degree and the size of its numbers, and a
single pathological literal such as ``1e-9999999`` (an exact rational with ten million digits)
used to stall the toolkit for the better part of an hour. So the parser refuses, with a
one-line :class:`~perturb.errors.ParseError` that names the offending text, anything outside
these limits (module constants, see each one's comment):

* :data:`MAX_LENGTH` characters and :data:`MAX_TOKENS` tokens in the text;
* :data:`MAX_DEPTH` levels of nesting (parentheses, signs, powers, calls), and at most
  :data:`MAX_SWITCH_NESTING` switch functions (``Max``, ``Abs``, ``Heaviside``...) inside one
  another, and at most :data:`MAX_SWITCH_ARGUMENTS` arguments per call;
* number literals of at most :data:`MAX_LITERAL_DIGITS` digits whose magnitude, unless zero,
  lies in ``[MIN_MAGNITUDE, MAX_MAGNITUDE]`` = ``[1e-300, 1e300]`` (so nothing under- or
  overflows a float); the same range for every constant the parser computes from them
  (``10**400``, ``1e200*1e200``, ``exp(1000)``);
* exponents that are plain numbers (``x**3``, ``x**(1/2)``; no symbol in an exponent, so no
  ``x**x``) of magnitude at most :data:`MAX_EXPONENT` on non-constant bases, and a polynomial
  degree of at most :data:`MAX_DEGREE` (``(x**10)**10`` and towers of powers are refused);
* at most :data:`MAX_EXPANDED_TERMS` terms when the expression is expanded;
* no undefined or non-real constants (``log(0)``, ``sqrt(-1)``, ``acos(2)``).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from fractions import Fraction
from typing import Any

import sympy as sp

from perturb.errors import ParseError

__all__ = [
    "expression_argument",
    "FUNCTIONS",
    "CONSTANTS",
    "MAX_LENGTH",
    "MAX_TOKENS",
    "MAX_DEPTH",
    "MAX_SWITCH_NESTING",
    "MAX_SWITCH_ARGUMENTS",
    "MAX_LITERAL_DIGITS",
    "MIN_MAGNITUDE",
    "MAX_MAGNITUDE",
    "MAX_EXPONENT",
    "MAX_DEGREE",
    "MAX_POWER_DIGITS",
    "MAX_EXPANDED_TERMS",
    "parse_number",
    "ParsedEquation",
    "parse_expression",
    "parse_equation",
    "real_symbol",
]

#: Functions a user string may call, by the name typed.
FUNCTIONS: dict[str, object] = {
    "Heaviside": sp.Heaviside,
    "heaviside": sp.Heaviside,
    "DiracDelta": sp.DiracDelta,
    "Max": sp.Max,
    "max": sp.Max,
    "Min": sp.Min,
    "min": sp.Min,
    "Abs": sp.Abs,
    "abs": sp.Abs,
    "sign": sp.sign,
    "Piecewise": sp.Piecewise,
    "sin": sp.sin,
    "cos": sp.cos,
    "tan": sp.tan,
    "sinh": sp.sinh,
    "cosh": sp.cosh,
    "tanh": sp.tanh,
    "asin": sp.asin,
    "acos": sp.acos,
    "atan": sp.atan,
    "exp": sp.exp,
    "log": sp.log,
    "sqrt": sp.sqrt,
}

_SWITCH_FUNCTIONS = (sp.Heaviside, sp.DiracDelta, sp.Max, sp.Min, sp.Abs, sp.sign, sp.Piecewise)

#: Names that stand for constants rather than parameters.
CONSTANTS: dict[str, sp.Expr] = {"pi": sp.pi}

#: Longest accepted input, in characters. An equation of motion is a line or two; 10 000
#: characters leave room for long generated expressions while bounding the tokenizer.
MAX_LENGTH = 10_000

#: Most tokens (numbers, names, operators) in one input. Parsing is linear in the tokens but
#: the symbolic stages after it (expand, Poly, simplify) are not; 2 000 tokens are ~30 times
#: the longest builtin model.
MAX_TOKENS = 2_000

#: Deepest nesting of parentheses, signs, powers and function calls. Bounds the recursion of
#: this parser and of SymPy's tree walks (Python's stack is ~1000 frames).
MAX_DEPTH = 100

#: Deepest nesting of switch functions (Heaviside, DiracDelta, Max, Min, Abs, sign, Piecewise)
#: inside one another. Saturation ``Max(-d, Min(d, x))`` needs 2; SymPy's own ``Max``/``Min``
#: constructor and the piecewise-linear canonicaliser work harder with every level (24 levels
#: of ``Max(Min(...))`` took 17 s to parse and nested ``Abs`` can double the breakpoints per
#: level).
MAX_SWITCH_NESTING = 8

#: Most arguments of one ``Max`` or ``Min``. SymPy's constructor compares the arguments
#: pairwise and every pair can be a breakpoint: ``Max`` of 80 lines took 5 s to parse and 30 s
#: to canonicalise, ``Min`` of 16 ``Max`` of 16 lines 26 s to parse (8 and 8: 1 s); a physical
#: force needs 2 or 3.
MAX_SWITCH_ARGUMENTS = 8

#: Most digits in one number literal (mantissa, leading zeros included). 100 digits are far more
#: than any measured constant has; a 5 000-digit literal only costs time downstream.
MAX_LITERAL_DIGITS = 100

#: Smallest magnitude of a nonzero number (literal or constant computed from literals).
#: Below ~2.2e-308 a float is subnormal and below ~5e-324 it is 0, so ``1e-9999999`` would be
#: a zero coefficient in the numeric layer while the symbolic layer carries an exact rational
#: with ten million digits; 1e-300 leaves a margin for products in the numeric stages.
MIN_MAGNITUDE = 1e-300

#: Largest magnitude of a number (literal or computed constant): floats overflow to ``inf``
#: above ~1.8e308; 1e300 leaves a margin for products in the numeric stages.
MAX_MAGNITUDE = 1e300

#: Largest ``|exponent|`` of a power whose base is not a constant (``x**50``). A restoring force
#: of degree 50 is already far beyond any physical model; the cost of expansion and of the
#: exact Fourier coefficients (``power_coefficient``) grows with the degree.
MAX_EXPONENT = 50

#: Largest polynomial degree of the whole expression, counted in all its symbols (a product
#: adds degrees, a power multiplies them): bounds what ``expand`` and ``Poly`` may produce from
#: a short text such as ``(x**10)**10`` or ``(x+1)**50*(x+2)**50``.
MAX_DEGREE = 50

#: Most terms the full expansion of the expression (or of any part of it) may have, counting
#: function calls as variables: ``(a+b+c+d+e+f+g+h)**25`` is 25 tokens long and expands to
#: 3.4 million terms. The largest builtin model expands to 6 terms.
MAX_EXPANDED_TERMS = 300

#: Most digits an exact power of two numbers may have (SymPy evaluates ``(1 + 1e-99)**1000``
#: exactly, as a rational); 10 000 digits take well under a millisecond.
MAX_POWER_DIGITS = 10_000

_LOG10_MIN = math.log10(MIN_MAGNITUDE)
_LOG10_MAX = math.log10(MAX_MAGNITUDE)
_NUMBER = re.compile(r"(?P<int>\d*)(?:\.(?P<frac>\d*))?(?:[eE](?P<exp>[+-]?\d+))?")
_MAX_EXPONENT_DIGITS = 6
_BAD = (sp.nan, sp.zoo, sp.oo, -sp.oo)

_TOKEN = re.compile(
    r"""
    (?P<space>\s+)
  | (?P<number>(?:\d+\.\d*|\.\d+|\d+)(?:[eE][+-]?\d+)?)
  | (?P<name>[A-Za-z_][A-Za-z0-9_]*)
  | (?P<primes>'+)
  | (?P<op>\*\*|<=|>=|==|!=|[-+*/^(),=<>])
    """,
    re.VERBOSE,
)


@dataclass(frozen=True)
class _Token:
    kind: str
    text: str
    pos: int


def _range_text() -> str:
    return f"0 or a magnitude from {MIN_MAGNITUDE:g} to {MAX_MAGNITUDE:g}"


def _literal(text: str) -> tuple[sp.Rational | None, str]:
    """The exact value of a number literal, or ``(None, reason)`` if it is out of bounds.

    Works on the digits of the text, so that no huge integer is ever built: ``1e-9999999`` is
    refused from its exponent alone.
    """
    m = _NUMBER.fullmatch(text)
    if m is None:  # the tokenizer only produces matching text
        return None, "not a number"
    int_part, frac, exp = m.group("int") or "", m.group("frac") or "", m.group("exp") or "0"
    mantissa = int_part + frac
    if len(mantissa) > MAX_LITERAL_DIGITS:
        return None, (
            f"it has {len(mantissa)} digits: expected at most {MAX_LITERAL_DIGITS} digits"
        )
    significant = mantissa.lstrip("0")
    if not significant:
        return sp.Integer(0), ""
    if len(exp.lstrip("+-").lstrip("0")) > _MAX_EXPONENT_DIGITS:
        return None, f"it is out of range: expected {_range_text()}"
    # value = int(mantissa) * 10**shift; its leading digit is worth 10**order
    shift = int(exp) - len(frac)
    order = len(significant) - 1 + shift
    too_big = order > _LOG10_MAX or (order == _LOG10_MAX and significant.rstrip("0") != "1")
    if order < _LOG10_MIN or too_big:
        return None, f"it is out of range: expected {_range_text()}"
    p = int(mantissa)
    value = sp.Integer(p * 10**shift) if shift >= 0 else sp.Rational(p, 10**-shift)
    return value, ""


def _log10_abs(value: sp.Expr) -> float | None:
    """``log10 |value|`` of a nonzero constant without building anything big; None if it is
    zero, undefined or not real."""
    if value.is_Rational:
        if value == 0:
            return None
        return math.log10(abs(value.p)) - math.log10(value.q)
    if value.has(*_BAD, sp.DiracDelta):
        return None
    try:
        num = sp.N(value, 15)
        if not num.is_number or num.has(*_BAD) or num == 0:
            return None
        re_, im = num.as_real_imag()
        if not (re_.is_Float or re_.is_Rational) or not (im.is_Float or im.is_Rational):
            return None  # not evaluable to a number
        if im != 0 and abs(im) > 1e-12 * abs(re_):
            return None
        return float(sp.log(abs(re_), 10).evalf(15)) if re_ != 0 else None
    except (TypeError, ValueError, ArithmeticError, RecursionError):  # SymPy's own limits
        return None


def _in_range(log10: float) -> bool:
    return _LOG10_MIN - 1e-12 <= log10 <= _LOG10_MAX + 1e-12


_Bounds = tuple[float, float, frozenset]


def _bounds(expr: sp.Basic, memo: dict[sp.Basic, _Bounds]) -> _Bounds:
    """Upper bounds ``(degree, terms, generators)`` of ``expr`` once fully expanded.

    ``degree`` is the polynomial degree in all its generators (symbols, and function calls,
    which ``expand`` treats as new variables): a product adds degrees, a power multiplies them.
    ``terms`` bounds the number of terms of the expansion: a sum adds, a product multiplies,
    ``s**n`` of a sum of ``s`` terms has at most ``C(n + s - 1, s - 1)``, and nothing of degree
    ``D`` in ``k`` generators has more than ``C(D + k, k)``. Every sub-expression is entered
    in ``memo``, so the caller can check the worst one.
    """
    if expr in memo:
        return memo[expr]
    if not expr.free_symbols:
        out: _Bounds = (0.0, 1.0, frozenset())
    elif expr.is_Symbol:
        out = (1.0, 1.0, frozenset((expr,)))
    elif expr.is_Add or expr.is_Mul:
        parts = [_bounds(a, memo) for a in expr.args]
        gens = frozenset().union(*(p[2] for p in parts))
        if expr.is_Add:
            out = (max(p[0] for p in parts), sum(p[1] for p in parts), gens)
        else:
            out = (sum(p[0] for p in parts), math.prod(p[1] for p in parts), gens)
    elif expr.is_Pow:
        base, exponent = expr.args
        degree, terms, gens = _bounds(base, memo)
        try:
            n = abs(float(exponent)) if not exponent.free_symbols else math.inf
        except TypeError:  # a non-real exponent
            n = math.inf
        if exponent.is_Integer and n <= 10 * MAX_DEGREE and terms <= 1e6:
            count = float(math.comb(int(n) + int(terms) - 1, int(terms) - 1)) if terms > 1 else 1.0
        else:
            count = 1.0 if math.isfinite(n) else math.inf
        out = (degree * n if degree else 0.0, count, gens)
    else:  # a function call, Piecewise or condition: a new variable for expand
        for a in expr.args:
            _bounds(a, memo)
        out = (1.0, 1.0, frozenset((expr,)))
    degree, terms, gens = out
    if math.isfinite(degree) and terms > 1 and len(gens) < 10_000:
        terms = min(terms, float(math.comb(math.ceil(degree) + len(gens), len(gens))))
    out = (degree, terms, gens)
    memo[expr] = out
    return out


def _degree(expr: sp.Basic) -> float:
    """Polynomial degree bound of ``expr`` (see :func:`_bounds`)."""
    return _bounds(expr, {})[0]


def _clip(expr: sp.Basic, width: int = 60) -> str:
    text = sp.sstr(expr)
    return text if len(text) <= width else text[: width - 3] + "..."


def parse_number(text: str, what: str = "value") -> float:
    """A number typed on its own (a ``--param`` value, a scene entry), with the literal rules
    of the equation parser: at most :data:`MAX_LITERAL_DIGITS` digits, 0 or a magnitude from
    :data:`MIN_MAGNITUDE` to :data:`MAX_MAGNITUDE`, an optional sign; no ``nan``/``inf``.

    Parameters
    ----------
    text
        For example ``"-2"``, ``"0.05"``, ``"1e-3"``.
    what
        How to name the value in an error message (``"--param k"``).

    Returns
    -------
    float

    Raises
    ------
    ParseError
        Naming ``what`` and the text, for anything else (``1e-400`` underflows and is refused
        rather than read as 0).
    """
    if not isinstance(text, str):
        raise ParseError(f"{what}: expected the number as a string, got {type(text).__name__}")
    stripped = text.strip()
    sign, body = (stripped[0], stripped[1:]) if stripped[:1] in ("+", "-") else ("", stripped)
    if len(body) > MAX_LITERAL_DIGITS + 16:
        raise ParseError(
            f"{what} = {text[:40]!r}...: {len(body)} characters, expected a number of at most "
            f"{MAX_LITERAL_DIGITS} digits"
        )
    if not body or _NUMBER.fullmatch(body) is None:
        raise ParseError(f"{what} = {text[:40]!r}: expected a number such as 2, -0.05 or 1e-3")
    if not any(c.isdigit() for c in body.split("e")[0].split("E")[0]):
        raise ParseError(f"{what} = {text[:40]!r}: expected a number such as 2, -0.05 or 1e-3")
    value, reason = _literal(body)
    if value is None:
        raise ParseError(f"{what} = {text[:40]!r}: {reason}")
    return -float(value) if sign == "-" else float(value)


def real_symbol(name: str) -> sp.Symbol:
    """The symbol perturb uses for ``name``: real-valued, so that ``Abs``, ``sign`` and
    comparisons simplify the way an engineer expects."""
    return sp.Symbol(name, real=True)


def _tokenize(text: str) -> list[_Token]:
    if not isinstance(text, str):
        raise ParseError(f"expected the equation as a string, got {type(text).__name__}")
    if len(text) > MAX_LENGTH:
        raise ParseError(f"input is {len(text)} characters long; at most {MAX_LENGTH} are accepted")
    tokens: list[_Token] = []
    pos = 0
    while pos < len(text):
        m = _TOKEN.match(text, pos)
        if m is None:
            raise ParseError(
                f"unexpected character {text[pos]!r} at column {pos + 1} in {text!r}: "
                "expected numbers, names, + - * / ** ^ ( ) , = and primes (x', x'')"
            )
        kind = m.lastgroup
        assert kind is not None
        if kind != "space":
            if len(tokens) >= MAX_TOKENS:
                raise ParseError(
                    f"input has more than {MAX_TOKENS} tokens (numbers, names, operators): "
                    f"expected at most {MAX_TOKENS}; the text starts {text[:40]!r}"
                )
            tokens.append(_Token(kind, m.group(), pos))
        pos = m.end()
    tokens.append(_Token("end", "", len(text)))
    return tokens


class _Parser:
    """Recursive-descent reader over the token list; see the module docstring."""

    def __init__(self, text: str, allow_derivatives: bool):
        self.text = text
        self.tokens = _tokenize(text)
        self.i = 0
        self.depth = 0
        self.switch_depth = 0
        self.allow_derivatives = allow_derivatives
        self.state_name: str | None = None
        self.derivative_order = 0
        self.symbols: dict[str, sp.Symbol] = {}

    # -- helpers -------------------------------------------------------------------------
    @property
    def tok(self) -> _Token:
        return self.tokens[self.i]

    def _where(self, tok: _Token) -> str:
        what = repr(tok.text) if tok.kind != "end" else "end of input"
        return f"{what} at column {tok.pos + 1} in {self.text!r}"

    def error(self, expected: str, tok: _Token | None = None) -> ParseError:
        tok = tok or self.tok
        return ParseError(f"unexpected {self._where(tok)}: expected {expected}")

    def accept(self, *texts: str) -> _Token | None:
        if self.tok.kind == "op" and self.tok.text in texts:
            tok = self.tok
            self.i += 1
            return tok
        return None

    def expect(self, text: str, expected: str) -> _Token:
        tok = self.accept(text)
        if tok is None:
            raise self.error(expected)
        return tok

    def symbol(self, name: str) -> sp.Symbol:
        if name not in self.symbols:
            self.symbols[name] = real_symbol(name)
        return self.symbols[name]

    def enter(self) -> None:
        self.depth += 1
        if self.depth > MAX_DEPTH:
            raise ParseError(
                f"expression nested deeper than {MAX_DEPTH} levels at column {self.tok.pos + 1} "
                f"in {self._short()}: expected at most {MAX_DEPTH} levels of parentheses, "
                "signs, powers and calls"
            )

    def _short(self) -> str:
        """The input for an error message, cut to a readable length."""
        return repr(self.text) if len(self.text) <= 200 else repr(self.text[:197] + "...")

    def check_constant(self, value: sp.Expr, tok: _Token, what: str) -> None:
        """Refuse a constant (``value`` free of symbols) that is undefined, not real or out
        of range; ``what`` names it for the message."""
        if value.has(*_BAD):
            raise ParseError(
                f"{what} at column {tok.pos + 1} in {self._short()} is undefined or infinite: "
                "expected a finite real number"
            )
        if value == 0:
            return
        log10 = _log10_abs(value)
        if log10 is None:
            raise ParseError(
                f"{what} at column {tok.pos + 1} in {self._short()} is {_clip(value)}, which "
                "is not a finite real number: expected a finite real number"
            )
        if not _in_range(log10):
            raise ParseError(
                f"{what} at column {tok.pos + 1} in {self._short()} is about 1e{log10:.0f}: "
                f"expected {_range_text()}"
            )

    def check_coefficient(self, value: sp.Expr, tok: _Token) -> None:
        """The numeric coefficient and constant term of ``value`` must stay in range."""
        if not value.free_symbols:
            if value.is_Rational:
                self.check_constant(value, tok, "the number computed by this operation")
            return
        coeff = value.as_coeff_Mul()[0] if value.is_Mul else value.as_coeff_Add()[0]
        if coeff.is_Rational and coeff != 0:
            self.check_constant(coeff, tok, "the number computed by this operation")

    # -- grammar -------------------------------------------------------------------------
    def expression(self) -> sp.Expr:
        self.enter()
        value = self.term()
        terms: list[sp.Expr] = []
        last: _Token | None = None
        while True:
            op = self.accept("+", "-")
            if op is None:
                break
            if self.tok.kind == "op" and self.tok.text in "+-":
                raise ParseError(
                    f"two signs in a row, {op.text!r} then {self._where(self.tok)}: "
                    "expected a term after the operator"
                )
            rhs = self.term()
            terms.append(rhs if op.text == "+" else -rhs)
            last = op
        self.depth -= 1
        if last is None:
            return value
        # one Add of all the terms: adding them one by one costs time quadratic in their number
        value = sp.Add(value, *terms)
        self.check_coefficient(value, last)
        return value

    def term(self) -> sp.Expr:
        value = self.unary()
        while True:
            op = self.accept("*", "/")
            if op is None:
                break
            rhs = self.unary()
            if op.text == "*":
                value = value * rhs
            else:
                if rhs == 0:
                    raise ParseError(f"division by zero at column {op.pos + 1} in {self.text!r}")
                value = value / rhs
            self.check_coefficient(value, op)
        return value

    def unary(self) -> sp.Expr:
        op = self.accept("+", "-")
        if op is not None:
            self.enter()
            value = self.unary()
            self.depth -= 1
            return -value if op.text == "-" else value
        return self.power()

    def power(self) -> sp.Expr:
        base = self.primary()
        op = self.accept("**", "^")
        if op is None:
            return base
        self.enter()
        exp_tok = self.tok
        exponent = self.unary()
        self.depth -= 1
        where = f"at column {op.pos + 1} in {self._short()}"
        if exponent.free_symbols:
            names = ", ".join(sorted(str(s) for s in exponent.free_symbols))
            raise ParseError(
                f"exponent {_clip(exponent)} {where} contains {names}: expected a number as "
                "exponent (x**3, x**(1/2)); write exp(...) for an exponential"
            )
        self.check_constant(exponent, exp_tok, f"exponent {_clip(exponent)}")
        e = float(exponent)
        if base.free_symbols:
            if abs(e) > MAX_EXPONENT:
                raise ParseError(
                    f"exponent {_clip(exponent)} {where} is too large: expected |exponent| <= "
                    f"{MAX_EXPONENT} on an expression with symbols"
                )
            degree = _degree(base) * abs(e)
            if degree > MAX_DEGREE:
                raise ParseError(
                    f"power {where} has polynomial degree about {degree:.3g}: expected a "
                    f"degree of at most {MAX_DEGREE} (towers such as (x**10)**10 are refused)"
                )
            return base**exponent
        if base == 0:
            if e < 0:
                raise ParseError(f"0 raised to a negative power {where}")
            return base**exponent
        log10 = _log10_abs(base)
        if log10 is not None and not _in_range(log10 * e):
            raise ParseError(
                f"power {where} would be about 10**{log10 * e:.0f}, a number with about "
                f"{abs(log10 * e):.3g} digits (zeros included): expected {_range_text()}"
            )
        if base.is_Rational and exponent.is_Rational:
            # SymPy evaluates a power of two exact numbers eagerly: bound its digits so that
            # (1 + 1e-99)**1000**... cannot stall the parser
            p, q = base.p, base.q
            digits = abs(e) * (len(str(abs(p))) + len(str(q)))
            if digits > MAX_POWER_DIGITS:
                raise ParseError(
                    f"power {where} would have about {digits:.3g} digits: expected a number "
                    f"of at most {MAX_POWER_DIGITS} digits"
                )
        value = base**exponent
        self.check_constant(value, op, "the power")
        return value

    def primary(self) -> sp.Expr:
        tok = self.tok
        if tok.kind == "number":
            self.i += 1
            # Rational keeps typed decimals exact ("0.05" is 1/20), as a person means them.
            value, reason = _literal(tok.text)
            if value is None:
                shown = tok.text if len(tok.text) <= 40 else tok.text[:37] + "..."
                raise ParseError(
                    f"number {shown!r} at column {tok.pos + 1} in {self._short()}: {reason}"
                )
            return value
        if tok.kind == "name":
            self.i += 1
            return self.named(tok)
        if self.accept("("):
            value = self.expression()  # one nesting level per parenthesis
            self.expect(")", "')' to close the parenthesis")
            return value
        raise self.error("a number, a name or '('")

    def named(self, tok: _Token) -> sp.Expr:
        name = tok.text
        if name.startswith("_"):
            raise ParseError(
                f"name {name!r} at column {tok.pos + 1} is not allowed: names may not start "
                "with an underscore"
            )
        if self.tok.kind == "primes":
            return self.derivative(tok)
        if self.tok.kind == "op" and self.tok.text == "(":
            if name not in FUNCTIONS:
                allowed = ", ".join(sorted(set(FUNCTIONS)))
                raise ParseError(
                    f"unknown function {name!r} at column {tok.pos + 1} in {self.text!r}: "
                    f"expected one of {allowed}"
                )
            return self.call(name, tok)
        if name in CONSTANTS:
            return CONSTANTS[name]
        if name in FUNCTIONS:
            raise ParseError(
                f"function {name!r} at column {tok.pos + 1} is used without arguments: "
                f"expected {name}(...)"
            )
        if name in ("True", "False"):
            raise ParseError(f"{name!r} at column {tok.pos + 1} is only allowed as a condition")
        return self.symbol(name)

    def derivative(self, name_tok: _Token) -> sp.Expr:
        primes = self.tok
        self.i += 1
        order = len(primes.text)
        if not self.allow_derivatives:
            raise ParseError(
                f"derivative {name_tok.text}{primes.text} at column {name_tok.pos + 1} is not "
                "allowed here: expected an expression in the state variable only"
            )
        if order > 2:
            raise ParseError(
                f"{name_tok.text}{primes.text} at column {name_tok.pos + 1}: only first (x') "
                "and second (x'') derivatives are supported"
            )
        if self.state_name is None:
            self.state_name = name_tok.text
        elif self.state_name != name_tok.text:
            raise ParseError(
                f"derivatives of two different variables, {self.state_name!r} and "
                f"{name_tok.text!r}: expected a single-degree-of-freedom equation"
            )
        self.derivative_order = max(self.derivative_order, order)
        return self.symbol(name_tok.text + primes.text)

    def call(self, name: str, name_tok: _Token) -> sp.Expr:
        switch = FUNCTIONS[name] in _SWITCH_FUNCTIONS
        if switch:
            self.switch_depth += 1
            if self.switch_depth > MAX_SWITCH_NESTING:
                raise ParseError(
                    f"{name} at column {name_tok.pos + 1} in {self._short()} is nested "
                    f"{self.switch_depth} switch functions deep: expected at most "
                    f"{MAX_SWITCH_NESTING} of Heaviside, DiracDelta, Max, Min, Abs, sign and "
                    "Piecewise inside one another"
                )
        try:
            return self._call(name, name_tok)
        finally:
            if switch:
                self.switch_depth -= 1

    def _call(self, name: str, name_tok: _Token) -> sp.Expr:
        self.expect("(", "'('")
        self.enter()
        if name == "Piecewise":
            args = self.piecewise_args(name_tok)
            self.depth -= 1
            return sp.Piecewise(*args)
        args = [self.expression()]
        while self.accept(","):
            if len(args) >= MAX_SWITCH_ARGUMENTS:
                raise ParseError(
                    f"{name} at column {name_tok.pos + 1} in {self._short()} has more than "
                    f"{MAX_SWITCH_ARGUMENTS} arguments: expected at most {MAX_SWITCH_ARGUMENTS} "
                    "(split a long Max/Min into nested ones)"
                )
            args.append(self.expression())
        self.expect(")", f"')' or ',' in the arguments of {name}")
        self.depth -= 1
        func = FUNCTIONS[name]
        nargs = len(args)
        if func in (sp.Max, sp.Min):
            if nargs < 2:
                raise ParseError(f"{name} at column {name_tok.pos + 1} needs at least 2 arguments")
        elif func is sp.log:
            if nargs not in (1, 2):
                raise ParseError(f"{name} at column {name_tok.pos + 1} takes 1 or 2 arguments")
        elif nargs != 1:
            raise ParseError(
                f"{name} at column {name_tok.pos + 1} takes exactly 1 argument, got {nargs}"
            )
        try:
            value = func(*args)  # type: ignore[operator]
        except (TypeError, ValueError) as exc:  # SymPy's own complaint, made readable
            raise ParseError(f"cannot apply {name} at column {name_tok.pos + 1}: {exc}") from None
        if not value.free_symbols:
            self.check_constant(value, name_tok, f"{name}(...)")
        elif value.has(*_BAD):
            raise ParseError(
                f"{name}(...) at column {name_tok.pos + 1} in {self._short()} is undefined or "
                "infinite: expected a finite expression"
            )
        return value

    def piecewise_args(self, name_tok: _Token) -> list[tuple[sp.Expr, object]]:
        pairs: list[tuple[sp.Expr, object]] = []
        while True:
            self.expect("(", "'(' starting a (value, condition) pair of Piecewise")
            value = self.expression()
            self.expect(",", "',' between the value and the condition of a Piecewise pair")
            cond = self.condition()
            self.expect(")", "')' closing a Piecewise pair")
            pairs.append((value, cond))
            if not self.accept(","):
                break
        self.expect(")", "')' closing Piecewise")
        if not pairs:
            raise ParseError(f"Piecewise at column {name_tok.pos + 1} has no pairs")
        return pairs

    def condition(self) -> object:
        if self.tok.kind == "name" and self.tok.text in ("True", "False"):
            tok = self.tok
            self.i += 1
            return sp.true if tok.text == "True" else sp.false
        lhs = self.expression()
        ops = {
            "<": sp.StrictLessThan,
            "<=": sp.LessThan,
            ">": sp.StrictGreaterThan,
            ">=": sp.GreaterThan,
            "==": sp.Eq,
            "!=": sp.Ne,
        }
        for text, rel in ops.items():
            if self.accept(text):
                rhs = self.expression()
                return rel(lhs, rhs)
        raise self.error("a comparison (<, <=, >, >=, ==, !=) or True/False")


def parse_expression(text: str, *, allow_derivatives: bool = False) -> sp.Expr:
    """Parse a mathematical expression such as ``"k*x + (1-k)*Max(x-1, 0)"``.

    Parameters
    ----------
    text
        The expression. Names become real SymPy symbols; ``pi`` is the constant; only the
        functions in :data:`FUNCTIONS` may be called.
    allow_derivatives
        Whether ``x'`` and ``x''`` are allowed (they become the symbols ``x'`` and ``x''``).

    Returns
    -------
    sympy.Expr

    Raises
    ------
    ParseError
        For malformed text, unknown functions, disallowed names; the message names the
        offending text and its column.
    """
    parser = _Parser(text, allow_derivatives)
    value = parser.expression()
    if parser.tok.kind != "end":
        if parser.tok.kind == "op" and parser.tok.text == "=":
            raise parser.error("an expression, not an equation")
        raise parser.error("an operator or the end of the expression")
    _check_result(value, parser)
    return value


def _check_result(expr: sp.Expr, parser: _Parser) -> None:
    """The limits that concern the whole expression: every number in range, the degree and
    the size of its expansion."""
    for number in expr.atoms(sp.Rational):
        if number != 0 and not _in_range(_log10_abs(number) or 0.0):
            raise ParseError(
                f"the number {_clip(number)} computed from {parser._short()} is out of range: "
                f"expected {_range_text()}"
            )
    if expr.has(*_BAD):
        raise ParseError(f"{parser._short()} is undefined or infinite somewhere")
    memo: dict[sp.Basic, _Bounds] = {}
    _bounds(expr, memo)
    node, (degree, _, _) = max(memo.items(), key=lambda item: item[1][0])
    if degree > MAX_DEGREE:
        raise ParseError(
            f"{_clip(node)} in {parser._short()} has polynomial degree about {degree:.3g}: "
            f"expected a degree of at most {MAX_DEGREE}"
        )
    node, (_, terms, _) = max(memo.items(), key=lambda item: item[1][1])
    if terms > MAX_EXPANDED_TERMS:
        raise ParseError(
            f"expanding {_clip(node)} in {parser._short()} could give about {terms:.3g} terms: "
            f"expected at most {MAX_EXPANDED_TERMS} (write fewer or smaller powers of sums)"
        )


@dataclass(frozen=True)
class ParsedEquation:
    """The result of :func:`parse_equation`: both sides and what the text contained."""

    lhs: sp.Expr
    rhs: sp.Expr
    state: str | None
    derivative_order: int
    symbols: tuple[sp.Symbol, ...]


def parse_equation(text: str) -> ParsedEquation:
    """Parse an equation of motion such as ``"x'' + mu*x' + x = F*cos(Omega*t)"``.

    A text without ``=`` means ``... = 0``.

    Raises
    ------
    ParseError
        See :func:`parse_expression`; also for more than one ``=``.
    """
    parser = _Parser(text, allow_derivatives=True)
    lhs = parser.expression()
    rhs: sp.Expr = sp.Integer(0)
    if parser.accept("="):
        rhs = parser.expression()
    if parser.tok.kind != "end":
        if parser.tok.kind == "op" and parser.tok.text == "=":
            raise parser.error("a single '=' in the equation")
        raise parser.error("an operator, '=' or the end of the equation")
    _check_result(lhs, parser)
    _check_result(rhs, parser)
    return ParsedEquation(
        lhs=lhs,
        rhs=rhs,
        state=parser.state_name,
        derivative_order=parser.derivative_order,
        symbols=tuple(parser.symbols.values()),
    )


def expression_argument(value: Any, what: str, *, allow_derivatives: bool = False) -> sp.Expr:
    """A caller's value as a SymPy expression, without ``sympify`` on text.

    The one safe door for expressions given as arguments (the symbolic engines and
    :func:`perturb.fourier.trig.harmonics` use it): strings only through
    :func:`parse_expression`.

    Parameters
    ----------
    value
        A SymPy expression, a number (int, float, Fraction) or a string; strings go through
        :func:`parse_expression`.
    what
        The argument's name, for the message.
    allow_derivatives
        Whether a string may contain ``x'``.

    Raises
    ------
    ParseError
        For a string the safe parser refuses.
    ParameterError
        For any other type.
    """
    import numpy as np  # only for its scalar types; the parser itself needs no NumPy

    from perturb.errors import ParameterError

    if isinstance(value, str):
        return parse_expression(value, allow_derivatives=allow_derivatives)
    if isinstance(value, sp.Basic):
        return value
    if isinstance(value, bool):
        raise ParameterError(f"{what} = {value!r}: expected a number or an expression")
    if isinstance(value, int | np.integer):
        return sp.Integer(int(value))
    if isinstance(value, Fraction):
        return sp.Rational(value.numerator, value.denominator)
    if isinstance(value, float | np.floating):
        return sp.Float(float(value))
    raise ParameterError(
        f"{what} = {value!r} (type {type(value).__name__}): expected a SymPy expression, a "
        "number or a string (parsed by perturb.model.parsing.parse_expression)"
    )
