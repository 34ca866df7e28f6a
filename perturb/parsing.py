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
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import sympy as sp

from .errors import ParseError

__all__ = [
    "FUNCTIONS",
    "CONSTANTS",
    "MAX_LENGTH",
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

#: Names that stand for constants rather than parameters.
CONSTANTS: dict[str, sp.Expr] = {"pi": sp.pi}

#: Longest accepted input, in characters (a guard against pathological input).
MAX_LENGTH = 10_000
_MAX_DEPTH = 100
_MAX_EXPONENT = 1000
_MAX_DIGITS = 10_000

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


def _digits(number: sp.Number) -> float:
    """Decimal digits needed to write an exact SymPy number (at least 1)."""
    p, q = sp.fraction(sp.nsimplify(number) if number.is_Float else number)
    return float(max(1, len(str(abs(int(p)))) + len(str(abs(int(q)))) - 1))


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
        if self.depth > _MAX_DEPTH:
            raise ParseError(f"expression nested deeper than {_MAX_DEPTH} levels in {self.text!r}")

    # -- grammar -------------------------------------------------------------------------
    def expression(self) -> sp.Expr:
        self.enter()
        value = self.term()
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
            value = value + rhs if op.text == "+" else value - rhs
        self.depth -= 1
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
        exponent = self.unary()
        self.depth -= 1
        if exponent.is_number and exponent.is_finite is not False:
            if abs(complex(exponent)) > _MAX_EXPONENT:
                raise ParseError(
                    f"exponent {exponent} at column {op.pos + 1} in {self.text!r} is too large: "
                    f"expected |exponent| <= {_MAX_EXPONENT}"
                )
        if base.is_Number and exponent.is_Number and base != 0:
            # An exact power of two numbers is evaluated eagerly by SymPy: bound its size so
            # that "(10**1000)**1000**..." cannot stall the parser.
            digits = abs(float(exponent)) * _digits(base)
            if digits > _MAX_DIGITS:
                raise ParseError(
                    f"power at column {op.pos + 1} in {self.text!r} would have about "
                    f"{digits:.3g} digits: expected a number of at most {_MAX_DIGITS} digits"
                )
        if base == 0 and exponent.is_number and exponent.is_negative:
            raise ParseError(f"0 raised to a negative power at column {op.pos + 1}")
        return base**exponent

    def primary(self) -> sp.Expr:
        tok = self.tok
        if tok.kind == "number":
            self.i += 1
            if re.fullmatch(r"\d+", tok.text):
                return sp.Integer(int(tok.text))
            value = float(tok.text)
            if not math.isfinite(value):
                raise ParseError(f"number {tok.text!r} at column {tok.pos + 1} is not finite")
            # Rational keeps typed decimals exact ("0.05" is 1/20), as a person means them.
            return sp.Rational(tok.text)
        if tok.kind == "name":
            self.i += 1
            return self.named(tok)
        if self.accept("("):
            self.enter()
            value = self.expression()
            self.depth -= 1
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
        self.expect("(", "'('")
        self.enter()
        if name == "Piecewise":
            args = self.piecewise_args(name_tok)
            self.depth -= 1
            return sp.Piecewise(*args)
        args = [self.expression()]
        while self.accept(","):
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
            return func(*args)  # type: ignore[operator]
        except (TypeError, ValueError) as exc:  # SymPy's own complaint, made readable
            raise ParseError(f"cannot apply {name} at column {name_tok.pos + 1}: {exc}") from None

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
    return value


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
    return ParsedEquation(
        lhs=lhs,
        rhs=rhs,
        state=parser.state_name,
        derivative_order=parser.derivative_order,
        symbols=tuple(parser.symbols.values()),
    )
