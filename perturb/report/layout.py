r"""Typesetting of long derivation formulas: term order, harmonic grouping and line breaking.

:class:`DocPrinter` prints SymPy expressions the way a person writes them:

- the terms of a sum in the order of a methods paper: the highest derivative first
  (``x'' + \mu x' + k x``), powers of the expansion parameter ascending
  (``1 + \epsilon\omega_1 + \epsilon^2\omega_2``), then by harmonic (no trigonometric factor,
  ``\cos\psi``, ``\sin\psi``, ``\cos 2\psi`` ...), otherwise in SymPy's order (a sum
  built unevaluated keeps the order it was built in);
- the Fourier-coefficient functions of :mod:`perturb.fourier.symbols` as ``a^R_n`` when the
  document defines their common argument once (see :mod:`perturb.report.notation`);
- derivatives of the engines' unknown functions with primes (``x_2''``) or as
  ``\partial B/\partial T_1``.

:func:`equation_rows` breaks an equation whose right side is wider than the page at its
top-level ``+``/``-`` (and inside the largest bracket of a product when one term alone is
too wide), after collecting the terms by harmonic; widths are estimated from the LaTeX text
by :func:`tex_width` in points at 11 pt.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Sequence

import sympy as sp
from sympy.core.function import AppliedUndef

from perturb.fourier.symbols import DiracCoefficient, RampCoefficient, StepCoefficient
from perturb.printing import PerturbLatexPrinter

__all__ = [
    "DocPrinter",
    "TEXT_WIDTH",
    "equation_rows",
    "harmonic_groups",
    "ordered_terms",
    "sigma_form",
    "sigma_index_form",
    "tex_width",
]

#: Width of the text block in points: US letter (article's default) less 2 cm margins, less
#: a safety margin for the estimate of :func:`tex_width`.
TEXT_WIDTH = 0.9 * 497.0
_COEFFICIENTS = (StepCoefficient, RampCoefficient, DiracCoefficient)
# names of expansion parameters (ascending powers)
_SMALL = frozenset({"epsilon", "varepsilon", "eps", "alpha", "alphahat"})
# the state: powers ascending (omega_0^2 x + alpha_2 x^2 + alpha_3 x^3)
_STATE = frozenset({"x", "y"})
# display symbols of the engines, printed in words
_WORDS = {
    "NST": r"\text{(non-secular terms)}",
    "cc": r"\text{c.c.}",
    "...": r"\ldots",
    "eps": r"\operatorname{eps}",  # a model's parameter, not the bookkeeping epsilon
}
# names of the fast phase variables of the engines
_PHASES = frozenset({"tau", "psi", "theta", "t", "T_0", "T0", "phi_0"})
_TRIG = (sp.cos, sp.sin, sp.exp)


# ------------------------------------------------------------------------------------------
# term order
# ------------------------------------------------------------------------------------------
def _derivative_rank(term: sp.Expr) -> int:
    rank = 0
    for s in term.free_symbols:
        name = s.name
        if name.endswith("'"):
            rank = max(rank, len(name) - len(name.rstrip("'")))
    for d in term.atoms(sp.Derivative):
        rank = max(rank, int(d.derivative_count))
    return rank


def _power_of(term: sp.Expr, names: frozenset[str]) -> sp.Expr | int:
    total = 0
    for f in sp.Mul.make_args(term):
        base, e = f.as_base_exp()
        if isinstance(base, sp.Symbol) and base.name in names and e.is_number:
            total += e
    return total


def _trig_factor(term: sp.Expr, phases: frozenset[str]) -> tuple[sp.Expr, sp.Expr]:
    """``term`` as ``(trig, rest)``: the product of its cos/sin/exp factors of a phase."""
    trig, rest = [], []
    for f in sp.Mul.make_args(term):
        base = f.as_base_exp()[0]
        if isinstance(base, _TRIG) and any(s.name in phases for s in base.free_symbols):
            trig.append(f)
        else:
            rest.append(f)
    return sp.Mul(*trig), sp.Mul(*rest)


def _harmonic(trig: sp.Expr, phases: frozenset[str]) -> tuple:
    """Sort key of a trigonometric factor: (harmonic number, cos before sin)."""
    if trig == 1:
        return (0, 0)
    f = sp.Mul.make_args(trig)[0]
    base = f.as_base_exp()[0]
    arg = base.args[0]
    n = sp.Integer(0)
    for s in arg.free_symbols:
        if s.name in phases:
            c = arg.coeff(s)
            if c.is_number:
                n = abs(c) if not c.has(sp.I) else abs(c / sp.I)
                break
    kind = {sp.cos: 0, sp.sin: 1}.get(type(base), 2)
    try:
        return (float(n), kind, len(sp.Mul.make_args(trig)))
    except TypeError:
        return (1e9, kind, 0)


def _is_sum(term: sp.Expr) -> bool:
    """Whether ``term`` is (minus) a placeholder of a sum (:func:`sigma_form`)."""
    s = term.as_coeff_Mul()[1]
    return isinstance(s, sp.Symbol) and s.name.startswith("Sigma__")


def _term_key(term: sp.Expr, phases: frozenset[str]) -> tuple:
    if _is_sum(term):
        return (0, 1e9, (1e9, 8, 0), 0.0)  # a sum over harmonics after the lone terms
    if isinstance(term, sp.Symbol) and term.name in ("NST", "cc", "...", "\\ldots"):
        return (1, 0.0, (1e9, 9, 0), 0.0)  # "+ ..." and "+ c.c." close a sum
    if isinstance(term, sp.Order):
        return (1, 1e9, (1e9, 9, 0), 0.0)  # O(epsilon^n) closes a sum
    trig, _ = _trig_factor(term, phases)
    eps, state = _power_of(term, _SMALL), _power_of(term, _STATE)
    for s in term.free_symbols:
        if s.name in _STATE and not term.is_polynomial(s):
            state = 99  # a nonsmooth or transcendental term after the polynomial ones
    try:
        eps, state = float(eps), float(state)
    except TypeError:
        eps, state = 0.0, 0.0
    return (-_derivative_rank(term), eps, _harmonic(trig, phases), state)


def ordered_terms(terms: Sequence[sp.Expr], phases: frozenset[str] = _PHASES) -> list[sp.Expr]:
    """``terms`` in reading order (module docstring); ties keep SymPy's order, except that a
    sum starts with a positive term where one ties with the first (``tau - phi``)."""
    keys = [_term_key(t, phases) for t in terms]
    if not any(k[0] < 0 or 2 <= k[3] < 99 for k in keys):
        # powers of the state order an equation of motion or a polynomial force, not x - 1
        keys = [k[:3] + (0.0,) for k in keys]
    keyed = sorted(
        ((key, k, t) for k, (key, t) in enumerate(zip(keys, terms, strict=True))),
        key=lambda x: x[:2],
    )
    out = [t for _, _, t in keyed]
    if out and out[0].could_extract_minus_sign():
        for j, (key, _, t) in enumerate(keyed):
            if key != keyed[0][0]:
                break
            if not t.could_extract_minus_sign():
                out.insert(0, out.pop(j))
                break
    return out


# ------------------------------------------------------------------------------------------
# the printer
# ------------------------------------------------------------------------------------------
class DocPrinter(PerturbLatexPrinter):
    """perturb's LaTeX printer with the reading order and short names of a document.

    Parameters
    ----------
    short_coefficients
        The argument triples ``(A, b, d)`` of Fourier-coefficient functions that the document
        defines once; their calls print as ``a^R_n`` without the argument.
    by_switch
        Pairs ``(A, b)`` whose calls print with their switching point only, ``a^R_n(d)``.
    phases
        Names of the fast phase variables (harmonic grouping).
    """

    def __init__(
        self,
        settings: dict | None = None,
        *,
        short_coefficients: Iterable[tuple] = (),
        phases: frozenset[str] = _PHASES,
        by_switch: Iterable[tuple] = (),
    ) -> None:
        base = {"fold_func_brackets": True}
        base.update(settings or {})
        super().__init__(base)
        self._short = frozenset(tuple(k) for k in short_coefficients)
        self._by_switch = frozenset(tuple(k) for k in by_switch)
        self._phases = phases
        self._raw: dict[str, str] = {}  # placeholders of sums over harmonics (sigma_form)

    def _print(self, expr, **kwargs) -> str:
        if isinstance(expr, _COEFFICIENTS) and tuple(expr.args[1:3]) in self._by_switch:
            n, d = self._print(expr.args[0]), self._print(expr.args[3])
            tex = f"{expr._letter}^{{{expr._tag}}}_{{{n}}}({d})"
            exp = kwargs.get("exp")
            return f"\\left({tex}\\right)^{{{exp}}}" if exp else tex
        if isinstance(expr, _COEFFICIENTS) and tuple(expr.args[1:]) in self._short:
            n = self._print(expr.args[0])
            tex = f"{expr._letter}^{{{expr._tag}}}_{{{n}}}"
            exp = kwargs.get("exp")
            return f"\\left({tex}\\right)^{{{exp}}}" if exp else tex
        return super()._print(expr, **kwargs)

    def _print_Pow(self, expr, **kwargs):
        if isinstance(expr.base, _COEFFICIENTS) and tuple(expr.base.args[1:]) in self._short:
            if expr.exp.is_Integer and expr.exp > 0:
                n = self._print(expr.base.args[0])
                b = expr.base
                return f"\\bigl(a^{{{b._tag}}}_{{{n}}}\\bigr)^{{{self._print(expr.exp)}}}"
        return super()._print_Pow(expr, **kwargs)

    def _as_ordered_terms(self, expr, order=None):
        if isinstance(expr, sp.Add) and len(expr.args) < 50:
            given = list(expr.args)
            if given != list(sp.Add(*given).args):  # built unevaluated on purpose: as given
                return given
        terms = super()._as_ordered_terms(expr, order=order)
        return ordered_terms(list(terms), self._phases)

    def _print_Symbol(self, expr, style="plain"):
        name = expr.name
        if name in _WORDS:
            return _WORDS[name]
        if name in self._raw:
            return self._raw[name]
        return super()._print_Symbol(expr, style=style)

    def _print_Float(self, expr):
        value = float(expr)
        if value.is_integer() and abs(value) < 1e15:  # 1.0 from a substituted parameter
            return str(int(value))
        return super()._print_Float(expr)

    def _print_Derivative(self, expr):
        f = expr.expr
        variables = expr.variable_count
        if isinstance(f, sp.Symbol) and len(variables) == 1 and not f.name.endswith("'"):
            v, k = variables[0]
            power = "" if k == 1 else f"^{{{k}}}"
            # a rate (\dot a) differentiated by a state is a partial derivative (Jacobian)
            d = "\\partial" if f.name.startswith("\\dot") else "\\mathrm{d}"
            return f"\\frac{{{d}{power} {self._print(f)}}}{{{d} {self._print(v)}{power}}}"
        if isinstance(f, AppliedUndef):
            name = self._print(sp.Symbol(type(f).__name__))
            variables = expr.variable_count
            if len(f.args) == 1 and len(variables) == 1 and variables[0][1] <= 3:
                primes = "'" * int(variables[0][1])
                return f"{name}{primes}{{\\left({self._print(f.args[0])}\\right)}}"
            if all(c == 1 for _, c in variables) and len(variables) == 1:
                v = self._print(variables[0][0])
                return f"\\frac{{\\partial {name}}}{{\\partial {v}}}"
        return super()._print_Derivative(expr)

    def _print_Function(self, expr, exp=None):
        if isinstance(expr, AppliedUndef):
            tex = self._print(sp.Symbol(type(expr).__name__))
            slow_times = len(expr.args) > 1 and all(
                isinstance(a, sp.Symbol) and a.name.startswith("T_") for a in expr.args
            )
            if not slow_times:  # x_1(tau), g(a cos psi, -a Omega sin psi)
                args = ", ".join(self._print(a) for a in expr.args)
                tex += f"{{\\left({args}\\right)}}"
            # B(T_1, T_2, T_3): the slow times are stated in the text
            return f"{tex}^{{{exp}}}" if exp else tex
        return super()._print_Function(expr, exp=exp)

    def _print_Mul(self, expr):
        # the harmonic last, as a person writes it: (k - 1) a^R_3 cos 3psi / nu
        trig, rest = _trig_factor(expr, self._phases)
        if trig == 1 or rest == 1 or rest == -1:
            return super()._print_Mul(expr)
        sign = ""
        if rest.could_extract_minus_sign():
            sign, rest = "- ", -rest
        if isinstance(rest, sp.Add):
            body = f"\\left({self._print(rest)}\\right)"
        else:
            body = self._print(rest)
        harmonic = super()._print_Mul(trig) if isinstance(trig, sp.Mul) else self._print(trig)
        return f"{sign}{body} {harmonic}"


# ------------------------------------------------------------------------------------------
# widths
# ------------------------------------------------------------------------------------------
_CMD = re.compile(r"\\([A-Za-z]+|.)")
_ZERO = {"left", "right", "bigl", "bigr", "Bigl", "Bigr", "big", "Big", "displaystyle", "limits"}
_SPACE = {",": 1.8, ":": 2.4, ";": 3.1, "!": -1.8, " ": 3.7, "quad": 11.0, "qquad": 22.0}
_WIDE = {"cdot": 7.0, "times": 11.0, "ldots": 13.0, "cdots": 13.0, "partial": 6.0, "infty": 11.0}
_GROUPED = {"overline", "mathrm", "operatorname", "mathbf", "mathit", "bar", "hat", "tilde"}
_GROUPED |= {"dot", "ddot", "text", "textrm", "mathcal", "boldsymbol", "underline", "check"}


class _Width:
    def __init__(self, s: str) -> None:
        self.s = s
        self.i = 0

    def group(self) -> float:
        """Width of the next token or {group}."""
        s = self.s
        while self.i < len(s) and s[self.i] == " ":
            self.i += 1
        if self.i >= len(s):
            return 0.0
        if s[self.i] == "{":
            self.i += 1
            return self.run(closing=True)
        return self.token()

    def token(self) -> float:
        s = self.s
        c = s[self.i]
        if c == "\\":
            m = _CMD.match(s, self.i)
            self.i = m.end()
            name = m.group(1)
            if name in _ZERO:
                if self.i < len(s) and s[self.i] in "().[]|":
                    self.i += 1
                    return 4.3 if name.startswith("big") or name.startswith("Big") else 4.3
                if s.startswith("\\{", self.i) or s.startswith("\\}", self.i):
                    self.i += 2
                    return 5.5
                return 0.0
            if name in _SPACE:
                return _SPACE[name]
            if name in ("frac", "dfrac", "tfrac"):
                a, b = self.group(), self.group()
                return max(a, b) + 2.4
            if name == "sqrt":
                return self.group() + 9.0
            if name in _GROUPED:
                return self.group() * (0.9 if name.startswith("text") else 1.0)
            if name in _WIDE:
                return _WIDE[name]
            if name in ("cos", "sin", "tan", "exp", "log", "ln", "arccos", "arcsin", "sign"):
                return 5.0 * len(name) + 1.8
            if name in ("mid", "quad"):
                return 6.0
            return 7.0  # a Greek letter or a symbol
        self.i += 1
        if c in "^_":
            return 0.72 * self.group()
        if c in "+-":
            return 13.4
        if c in "=<>":
            return 14.8
        if c in "()[]|":
            return 4.3
        if c in ",;":
            return 4.9
        if c in " &":
            return 0.0
        if c == "'":
            return 3.0
        if c.isdigit():
            return 5.5
        if c == "{":
            return self.run(closing=True)
        if c.isupper():
            return 8.2
        return 6.0

    def run(self, closing: bool = False) -> float:
        total = 0.0
        s = self.s
        script, last = "", 0.0  # a sub- and a superscript stack: the wider one counts
        while self.i < len(s):
            c = s[self.i]
            if c == "}":
                self.i += 1
                if closing:
                    return total
                continue
            w = self.token()
            if c in "^_":
                if script and script != c:
                    w, script = max(0.0, w - last), ""
                else:
                    script, last = c, w
            elif c != " ":
                script = ""
            total += w
        return total


def tex_width(tex: str) -> float:
    """Estimated width in points of ``tex`` set in display math at 11 pt (a slight
    overestimate: the layout keeps a margin rather than run past the page)."""
    return _Width(tex).run()


# ------------------------------------------------------------------------------------------
# harmonic grouping and line breaking
# ------------------------------------------------------------------------------------------
def harmonic_groups(
    expr: sp.Expr, phases: frozenset[str] = _PHASES
) -> list[tuple[sp.Expr, list[sp.Expr]]]:
    """The terms of ``expr`` grouped by their trigonometric factor of a phase, in reading
    order: ``[(1, [terms without one]), (cos psi, [coefficients]), ...]``."""
    groups: dict[sp.Expr, list[sp.Expr]] = {}
    sums = []  # placeholders of sums over harmonics (sigma_form) come last
    for term in sp.Add.make_args(expr):
        if _is_sum(term):
            sums.append(term)
            continue
        trig, rest = _trig_factor(term, phases)
        groups.setdefault(trig, []).append(rest)
    keys = sorted(groups, key=lambda t: _harmonic(t, phases))
    out = [(k, ordered_terms(groups[k], phases)) for k in keys]
    return out + [(sp.Integer(1), [s]) for s in sums]


def _tidy_group(body: sp.Expr) -> sp.Expr:
    """The coefficient of one harmonic as a person writes it: a product is distributed over
    a sum of Fourier-coefficient terms (so that each carries its own factor and sums over
    the index can be recognised); parameter factors such as ``(k - 1)(k - nu - 1)`` stay."""
    out: list[sp.Expr] = []
    stack = list(reversed(sp.Add.make_args(body)))
    while stack:
        t = stack.pop()
        if isinstance(t, sp.Mul):
            adds = [f for f in t.args if isinstance(f, sp.Add) and f.has(*_COEFFICIENTS)]
            if adds:
                big = max(adds, key=lambda a: len(a.args))
                rest = sp.Mul(*(f for f in t.args if f is not big))
                stack.extend(reversed([rest * u for u in big.args]))
                continue
        out.append(t)
    return sp.Add(*out)


def _signed(printer: DocPrinter, term: sp.Expr) -> tuple[str, str]:
    """``("+" or "-", LaTeX of |term|)``."""
    if term.could_extract_minus_sign():
        return "-", printer.doprint(-term)
    return "+", printer.doprint(term)


class _Breaker:
    def __init__(self, printer: DocPrinter) -> None:
        self.p = printer

    def lines(self, expr: sp.Expr, first: float, rest: float, depth: int = 0) -> list[str]:
        """``expr`` (with a leading sign only when negative) as lines of at most ``first``
        and then ``rest`` points."""
        tex = self.p.doprint(expr)
        if tex_width(tex) <= first or depth > 6:
            return [tex]
        if isinstance(expr, sp.Add):
            return self._sum(expr, first, rest, depth)
        if isinstance(expr, sp.Mul):
            out = self._product(expr, first, rest, depth)
            if out is not None:
                return out
        if isinstance(expr, sp.Pow) and isinstance(expr.base, sp.Add) and expr.exp.is_Integer:
            if expr.exp > 0:
                e = self.p.doprint(expr.exp)
                inner = self.lines(expr.base, first - 8, rest - 8, depth + 1)
                return self._wrap("", inner, f"^{{{e}}}")
        return [tex]

    @staticmethod
    def _wrap(prefix: str, inner: list[str], suffix: str = "") -> list[str]:
        if len(inner) == 1:
            return [f"{prefix}\\left({inner[0]}\\right){suffix}"]
        out = [f"{prefix}\\bigl({inner[0]}"] + inner[1:]
        out[-1] = out[-1] + f"\\bigr){suffix}"
        return out

    def _units(self, expr: sp.Expr) -> list[tuple[str, sp.Expr | None, sp.Expr]]:
        """Units of a sum: ``(sign, trig, body)``; a harmonic group of several terms is one
        unit ``trig * (sum)`` (sign ``+``), a lone term is ``(sign, None, |term|)``."""
        units = []
        groups = harmonic_groups(expr, self.p._phases)
        for trig, coeffs in groups:
            if trig != 1:
                body = _tidy_group(sp.Add(*coeffs))
                if len(sp.Add.make_args(body)) > 1:
                    units.append(("+", trig, body))
                    continue
            for c in coeffs:
                term = trig * c
                if term.could_extract_minus_sign():
                    units.append(("-", None, -term))
                else:
                    units.append(("+", None, term))
        return units

    def _sum(self, expr: sp.Add, first: float, rest: float, depth: int) -> list[str]:
        if depth > 0:  # inside one harmonic's bracket: sums over the coefficients' index
            expr, _ = sigma_index_form(self.p, expr)
        lines: list[str] = []
        cur, room = "", first
        for k, (sign, trig, body) in enumerate(self._units(expr)):
            lead = "" if (k == 0 and sign == "+") else f"{sign} "
            if trig is None:
                tex = self.p.doprint(body)
                parts = [tex] if tex_width(tex) <= rest - 14 else None
                if parts is None:
                    parts = self.lines(body, rest - 14, rest - 14, depth + 1)
            else:
                t = self.p.doprint(trig)
                inner = self.lines(body, rest - tex_width(t) - 22, rest - 22, depth + 1)
                parts = self._wrap(t + "\\,", inner)
            first_part = lead + parts[0]
            w = tex_width(first_part)
            if cur and w > room:
                lines.append(cur)
                cur, room = "", rest
            cur = (cur + " " + first_part) if cur else first_part
            room -= w
            if len(parts) > 1:
                lines.append(cur)
                lines.extend(parts[1:-1])
                cur = parts[-1]
                room = rest - tex_width(cur)
        if cur:
            lines.append(cur)
        return lines

    def _product(self, expr: sp.Mul, first: float, rest: float, depth: int) -> list[str] | None:
        # epsilon^k (...) over a common denominator: epsilon^k outside, each term its own
        # fraction inside, as in the other orders' rows
        small = sp.Mul(
            *(
                f
                for f in expr.args
                if isinstance(f.as_base_exp()[0], sp.Symbol) and f.as_base_exp()[0].name in _SMALL
            )
        )
        if small != 1:
            inner = sp.expand(expr / small, power_base=False, power_exp=False, multinomial=False)
            if isinstance(inner, sp.Add):
                pre = self.p.doprint(small) + "\\,"
                w = tex_width(pre)
                return self._wrap(pre, self.lines(inner, first - w - 8, rest - 8, depth + 1))
        num, den = expr.as_numer_denom()
        sign = ""
        if num.could_extract_minus_sign():
            sign, num = "- ", -num
        if den != 1:
            prefix = f"{sign}\\frac{{1}}{{{self.p.doprint(den)}}}\\,"
            if isinstance(num, sp.Add):
                w = tex_width(prefix)
                return self._wrap(prefix, self.lines(num, first - w - 8, rest - 8, depth + 1))
            expr, sign = num, sign
        factors = sp.Mul.make_args(expr)
        adds = [f for f in factors if isinstance(f, sp.Add)]
        if not adds:
            return None if den == 1 else [prefix + self.p.doprint(expr)]
        big = max(adds, key=lambda a: len(self.p.doprint(a)))
        others = sp.Mul(*(f for f in factors if f is not big))
        pre = "" if others == 1 else self.p.doprint(others) + "\\,"
        if den != 1:
            pre = prefix + pre
        elif sign:
            pre = sign + pre
        w = tex_width(pre)
        if w > first / 2:
            return None
        return self._wrap(pre, self.lines(big, first - w - 8, rest - 8, depth + 1))


_N = sp.Symbol("n", integer=True, positive=True)
# candidate denominators q(n) of a coefficient c_n = C / q(n), simplest first
_FAMILY = [
    sp.Integer(1),
    _N,
    _N**2 - 1,
    _N**2,
    _N * (_N**2 - 1),
    (_N**2 - 1) ** 2 / _N,
    (_N**2 - 1) ** 2,
    _N**2 * (_N**2 - 1),
    1 / _N,
]


def _harmonic_of(trig: sp.Expr, phases: frozenset[str]) -> tuple[int, type, sp.Symbol] | None:
    """``(n, cos or sin, phase)`` of a factor ``cos(n phase)`` / ``sin(n phase)``."""
    if not isinstance(trig, (sp.cos, sp.sin)):
        return None
    arg = trig.args[0]
    phase = [s for s in arg.free_symbols if s.name in phases]
    if len(phase) != 1:
        return None
    n = arg / phase[0]
    if not n.is_Integer or n < 1:
        return None
    return int(n), type(trig), phase[0]


def sigma_form(printer: DocPrinter, expr: sp.Expr, minimum: int = 4) -> tuple[sp.Expr, int]:
    r"""``expr`` with each generic sum over harmonics replaced by one placeholder symbol that
    prints as ``\sum_n c(n) ... \cos n\psi`` (the number of sums replaced is returned).

    A family is at least ``minimum`` terms ``c_n R(n) cos(n psi)`` (or ``sin``) whose
    coefficient functions carry indices ``n + const``, whose rest ``R`` is otherwise the same
    and whose numbers fit ``c_n = C/q(n)`` for a simple ``q``; the harmonics step evenly."""
    if not isinstance(expr, sp.Add) or len(expr.args) < minimum:
        return expr, 0
    families: dict[tuple, list[tuple[int, sp.Expr, sp.Expr]]] = {}
    for term in expr.args:
        trig, rest = _trig_factor(term, printer._phases)
        h = _harmonic_of(trig, printer._phases)
        if h is None:
            continue
        n, kind, phase = h
        c, r = rest.as_coeff_Mul()
        if not c.is_Rational or r.has(_N):
            continue
        calls = r.atoms(*_COEFFICIENTS)
        if any(not k.args[0].is_Integer for k in calls):
            continue
        template = r.xreplace({k: k.func(_N + (k.args[0] - n), *k.args[1:]) for k in calls})
        families.setdefault((kind, phase, template), []).append((n, c, term))
    return _place_sums(
        printer,
        expr,
        {key: (key[2] * key[0](_N * key[1]), members) for key, members in families.items()},
        _N,
        minimum,
    )


_M = sp.Symbol("m", integer=True, positive=True)
_LEAD = {"RampCoefficient": 0, "StepCoefficient": 1, "DiracCoefficient": 2}


def sigma_index_form(printer: DocPrinter, expr: sp.Expr, minimum: int = 4) -> tuple[sp.Expr, int]:
    r"""``expr`` (one harmonic's coefficient) with each generic sum over the index of its
    Fourier coefficient functions replaced by a placeholder that prints as
    ``\sum_m c(m)\, a^R_m a^H_{m+3}``: at least ``minimum`` terms whose leading coefficient
    function (ramp before step before Dirac) has index ``m``, the others ``m + const``, with
    the same rest and numbers ``c_m = C/q(m)``."""
    if not isinstance(expr, sp.Add) or len(expr.args) < minimum:
        return expr, 0
    families: dict[sp.Expr, list[tuple[int, sp.Expr, sp.Expr]]] = {}
    for term in expr.args:
        c, r = term.as_coeff_Mul()
        if not c.is_Rational or r.has(_M):
            continue
        calls = sorted(
            r.atoms(*_COEFFICIENTS),
            key=lambda k: (_LEAD[type(k).__name__], sp.default_sort_key(k.args[0])),
        )
        if not calls or any(not k.args[0].is_Integer for k in calls):
            continue
        m = calls[0].args[0]
        template = r.xreplace({k: k.func(_M + (k.args[0] - m), *k.args[1:]) for k in calls})
        families.setdefault(template, []).append((int(m), c, term))
    return _place_sums(
        printer, expr, {key: (key, members) for key, members in families.items()}, _M, minimum
    )


def _place_sums(
    printer: DocPrinter,
    expr: sp.Expr,
    families: dict,
    var: sp.Symbol,
    minimum: int,
) -> tuple[sp.Expr, int]:
    """Replace each family ``template -> (summand(var), [(index, number, term)])`` whose
    indices step evenly and whose numbers fit ``C/q(index)`` by a placeholder symbol."""
    count, out = 0, expr
    for summand0, members in families.values():
        if len(members) < minimum:
            continue
        members = sorted(members, key=lambda m: m[0])
        ns = [m[0] for m in members]
        step = ns[1] - ns[0]
        if step < 1 or any(b - a != step for a, b in zip(ns, ns[1:], strict=False)):
            continue
        for q0 in _FAMILY:
            q = q0.xreplace({_N: var})
            if any(q.subs(var, n) == 0 for n in ns):
                continue
            values = {m[1] * q.subs(var, m[0]) for m in members}
            if len(values) == 1 and next(iter(values)).is_finite:
                C = next(iter(values))
                break
        else:
            continue
        summand = (C / q) * summand0
        sign = 1
        if summand.could_extract_minus_sign():
            sign, summand = -1, -summand
        v = printer.doprint(var)
        if step == 1:
            under = f"\\sum_{{{v}={ns[0]}}}^{{{ns[-1]}}}"
        else:
            under = f"\\sum_{{{v} = {ns[0]}, {ns[1]}, \\ldots, {ns[-1]}}}"
        name = f"Sigma__{len(printer._raw)}"
        printer._raw[name] = f"{under} {printer.doprint(summand)}"
        out = out.xreplace({m[2]: 0 for m in members}) + sign * sp.Symbol(name)
        count += 1
    return out, count


def equation_rows(
    printer: DocPrinter,
    lhs: sp.Expr | None,
    rhs: sp.Expr,
    width: float = TEXT_WIDTH,
    relation: str = "=",
    column: float = 0.0,
) -> tuple[list[str], bool]:
    """An equation as ``align*`` rows, broken to fit ``width``; ``column`` is the width of
    the widest left side the rows share their alignment with.

    Returns
    -------
    (rows, own_block)
        ``own_block`` is true when the left side is too wide to share the alignment column
        with other equations (the right side then starts on the next row).
    """
    right, _ = sigma_form(printer, rhs)
    lhs_tex = "" if lhs is None else printer.doprint(lhs)
    own = tex_width(lhs_tex) + (14.8 if lhs is not None else 0.0)
    wl = max(own, column) if own <= 0.4 * width else own
    tex = printer.doprint(right)
    if wl + tex_width(tex) <= width:
        if lhs is None:
            return [f"&{tex}"], False
        return [f"{lhs_tex} &{relation} {tex}"], own > 0.4 * width
    breaker = _Breaker(printer)
    if lhs is not None and wl <= 0.4 * width:
        body = breaker.lines(right, width - wl - 4, width - wl - 26)
        rows = [f"{lhs_tex} &{relation} {body[0]}"] + [f"&\\quad {b}" for b in body[1:]]
        return rows, False
    body = breaker.lines(right, width - 30, width - 40)
    if lhs is None:
        return [f"&{body[0]}"] + [f"&\\quad {b}" for b in body[1:]], True
    rows = (
        [f"&{lhs_tex} {relation} {{}}"] if wl <= width else [f"&{lhs_tex}", f"&\\quad {relation}"]
    )
    rows += [f"&\\qquad {b}" for b in body]
    return rows, True
