r"""Words and definitions of a derivation document: its title, its settings and the closed
forms of the Fourier-coefficient functions it uses.

The closed forms are those of :mod:`perturb.fourier.coefficients` (and
:func:`perturb.fourier.symbols.
closed_form`): along ``x = A cos(psi) + b``, with ``theta = arccos((d - b)/A)`` while the orbit
crosses the switching point ``d``,

- ``a^H_0 = 2 theta/pi``, ``a^H_n = 2 sin(n theta)/(n pi)``  (of ``H(x - d)``),
- ``a^R_n = (A (a^H_{n-1} + a^H_{n+1}) - 2 (d - b) a^H_n)/2`` with ``a^H_{-1} = a^H_1``
  (of ``(x - d) H(x - d)``), in closed form ``a^R_0 = 2 (A sin theta - (d - b) theta)/pi``,
  ``a^R_1 = A (theta - sin theta cos theta)/pi``,
- ``a^delta_n = 2 cos(n theta)/(pi A sin theta)``  (of ``delta(x - d)``),

``f = a_0/2 + sum_{n >= 1} a_n cos(n psi)``. ``tests/test_latex_engines.py`` checks them
against the numeric forms.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import sympy as sp

from perturb.fourier.symbols import DiracCoefficient, RampCoefficient, StepCoefficient

# plain text in LaTeX (latex.py re-exports escape and escape_text)
_SPECIAL = {
    "\\": r"\textbackslash{}",
    "&": r"\&",
    "%": r"\%",
    "$": r"\$",
    "#": r"\#",
    "_": r"\_",
    "{": r"\{",
    "}": r"\}",
    "~": r"\textasciitilde{}",
    "^": r"\textasciicircum{}",
}
_DASHES = {
    "Krylov-Bogoliubov": "Krylov--Bogoliubov",
    "Lindstedt-Poincare": "Lindstedt--Poincar\\'e",
}
_UNICODE = {"–": "--", "—": "---", "é": "\\'e", "µ": "$\\mu$", "ε": "$\\varepsilon$"}


def escape(text: str) -> str:
    """Escape LaTeX's special characters in plain text."""
    return "".join(_SPECIAL.get(c, c) for c in text)


def escape_text(text: str) -> str:
    """A step's sentence as LaTeX: plain text escaped, mathematics between ``$`` signs kept
    as it is (so ``"the shift $\\omega_0^2 + \\nu$"`` prints the formula)."""
    parts = text.split("$")
    if len(parts) % 2 == 0:  # an unpaired dollar: all plain text
        parts = [text]
    out = []
    for k, part in enumerate(parts):
        if k % 2:
            out.append(f"${part}$")
        else:
            plain = escape(part)
            for a, b in _DASHES.items():
                plain = plain.replace(a, b)
            for a, b in _UNICODE.items():
                plain = plain.replace(a, b)
            out.append(plain)
    return "".join(out)


__all__ = [
    "document_title",
    "settings_sentence",
    "coefficient_calls",
    "coefficient_definitions",
    "escape",
    "escape_text",
]

_METHODS = {
    "hb1": "single-harmonic balance",
    "hb": "harmonic balance",
    "kb": "Krylov–Bogoliubov averaging",
    "vdp": "van der Pol averaging",
    "multiple_scales": "multiple-scales expansion",
    "ms": "multiple-scales expansion",
    "lp": "Lindstedt–Poincaré expansion",
    "mlp": "modified Lindstedt–Poincaré expansion",
}
_MODELS = {
    "nsd": "the negative-stiffness oscillator",
    "duffing": "the Duffing oscillator",
    "quadratic_cubic": "the oscillator with quadratic and cubic stiffness",
    "vanderpol": "the van der Pol oscillator",
    "mathieu": "the Mathieu equation",
    "pendulum": "the pendulum",
    "clearance": "the oscillator with a one-sided clearance spring",
    "deadzone": "the dead-zone oscillator",
    "saturation": "the oscillator with a saturating spring",
    "bilinear": "the bilinear oscillator",
}
_ORDINALS = ["Zeroth", "First", "Second", "Third", "Fourth", "Fifth", "Sixth", "Seventh"]
_ORDINALS += ["Eighth", "Ninth", "Tenth", "Eleventh", "Twelfth"]
_OPTION_WORDS = {
    "harmonics": "harmonics",
    "bias": "mean (bias) term",
    "amplitude": "amplitude",
    "scaling": "scaling",
    "resonance": "resonance",
    "detuning": "detuning",
    "epsilon": "bookkeeping parameter",
}
_VALUE_WORDS = {
    "first_harmonic": "of the first harmonic",
    "peak": "the peak value",
    "scaled": "scaled",
    "uniform": "uniform",
    "frequency": "in the frequency",
    "stiffness": "in the stiffness",
}


def document_title(method: str, options: Mapping[str, Any], model: str) -> str:
    """The title of a derivation in words, e.g. "Second-order modified Lindstedt–Poincaré
    expansion of the negative-stiffness oscillator" (plain text, unescaped)."""
    what = _METHODS.get(method, method.replace("_", " "))
    order = options.get("order")
    if isinstance(order, int) and 0 <= order < len(_ORDINALS) and method not in ("kb", "vdp"):
        what = f"{_ORDINALS[order]}-order {what}"
    else:
        what = what[0].upper() + what[1:]
    of = _MODELS.get(model, "the oscillator")
    return f"{what} of {of}"


def settings_sentence(options: Mapping[str, Any], latex) -> str:
    """The method's settings as a LaTeX sentence ("" when there are none worth stating)."""
    parts = []
    for key, value in options.items():
        if key == "order":
            continue
        if key == "harmonics":
            parts.append(f"harmonics up to ${int(value)}$" if int(value) > 1 else "")
            continue
        if key == "bias":
            parts.append("with a mean (bias) term" if value else "")
            continue
        if key == "omega0":
            value = sp.sympify(value)
            if isinstance(value, sp.Symbol):  # the model's own omega_0
                parts.append(f"reference frequency ${latex(value)}$")
            else:
                parts.append(f"reference frequency $\\omega_0 = {latex(value)}$")
            continue
        if key == "resonance":
            parts.append(f"resonance ${str(value).replace('/', ':')}$")
            continue
        word = _OPTION_WORDS.get(key, key.replace("_", " "))
        val = _VALUE_WORDS.get(str(value), str(value).replace("_", " "))
        parts.append(f"{word} {val}")
    parts = [p for p in parts if p]
    if not parts:
        return ""
    return "Settings: " + "; ".join(escape_text(p) for p in parts) + "."


def coefficient_calls(items: Iterable[sp.Basic]) -> dict[tuple, set[type]]:
    """The argument triples ``(A, b, d)`` of the Fourier-coefficient functions in ``items``
    and which functions take each."""
    out: dict[tuple, set[type]] = {}
    for item in items:
        if not isinstance(item, sp.Basic):
            continue
        for c in item.atoms(StepCoefficient, RampCoefficient, DiracCoefficient):
            out.setdefault(tuple(c.args[1:]), set()).add(type(c))
    return out


def _abs(tex: str) -> str:
    return tex if tex.isdigit() else f"|{tex}|"


def _times(tex: str) -> str:
    return "" if tex == "1" else f"{tex}\\,"


def coefficient_definitions(calls: Mapping[tuple, set[type]], latex, mode: str) -> str:
    """A paragraph and display defining the coefficient functions in closed form.

    ``mode``: ``"short"`` (one argument triple, written ``a^R_n``), ``"by_switch"`` (one
    orbit ``A cos psi + b``, several switching points, written ``a^R_n(d)``) or ``"full"``.
    """
    if not calls:
        return ""
    kinds = set().union(*calls.values())
    if RampCoefficient in kinds or DiracCoefficient in kinds:
        kinds.add(StepCoefficient)  # a^R and a^delta are written with a^H
    A, b, d = (sp.Symbol("A"), sp.Integer(0), sp.Symbol("d"))
    if mode == "short":
        A, b, d = next(iter(calls))
    elif mode == "by_switch":
        A, b, _ = next(iter(calls))
    tA = latex(A)
    shift = d - b
    ts = latex(shift) if not isinstance(shift, sp.Add) else f"({latex(shift)})"
    x = f"{tA}\\cos\\psi" + ("" if b == 0 else f" + {latex(b)}")
    names = {
        StepCoefficient: f"$a^H_n$ of $H(x - {ts})$" if b == 0 else "$a^H_n$ of $H(x - d)$",
        RampCoefficient: f"$a^R_n$ of $(x - {ts})\\,H(x - {ts})$" if b == 0 else "$a^R_n$",
        DiracCoefficient: f"$a^\\delta_n$ of $\\delta(x - {ts})$" if b == 0 else "$a^\\delta_n$",
    }
    which = ", ".join(
        names[k] for k in (StepCoefficient, RampCoefficient, DiracCoefficient) if k in kinds
    )
    if mode == "by_switch":
        points = ", ".join(latex(k[2]) for k in sorted(calls, key=lambda k: str(k[2])))
        lead = (
            f"Here {which} are the Fourier cosine coefficients along $x = {x}$, written with "
            f"their switching point $d$ only ($a_n(d) = a_n({x};\\, d)$, "
            f"$d \\in \\{{{points}\\}}$), "
            "so that a term equals $a_0/2 + \\sum_{n \\ge 1} a_n \\cos n\\psi$."
        )
    elif mode == "short":
        lead = (
            f"Here {which} are the Fourier cosine coefficients along $x = {x}$, written without "
            f"their argument ($a_n = a_n({x};\\, {latex(d)})$), so that a term equals "
            "$a_0/2 + \\sum_{n \\ge 1} a_n \\cos n\\psi$."
        )
    else:
        generic = {
            StepCoefficient: "$a^H_n(A\\cos\\psi + b;\\, d)$ of $H(x - d)$",
            RampCoefficient: "$a^R_n(A\\cos\\psi + b;\\, d)$ of $(x - d)H(x - d)$",
            DiracCoefficient: "$a^\\delta_n(A\\cos\\psi + b;\\, d)$ of $\\delta(x - d)$",
        }
        used = [generic[k] for k in (StepCoefficient, RampCoefficient, DiracCoefficient)]
        used = [u for k, u in zip(generic, used, strict=True) if k in kinds]
        lead = (
            "Here " + ", ".join(used) + " are the Fourier cosine coefficients along "
            "$x = A\\cos\\psi + b$ ($a_0/2 + \\sum_{n \\ge 1} a_n \\cos n\\psi$); below, "
            "$A$, $b$ and $d$ stand for each call's arguments."
        )
        tA, ts = "A", "(d - b)"
    one = mode != "full"
    sin_cos_rows = [
        f"\\theta &= \\arccos\\frac{{{ts if one else 'd - b'}}}{{{tA}}}, "
        f"\\qquad\\text{{while }} {_abs(ts) if one else '|d - b|'} < {tA},",
        "a^H_0 &= \\frac{2\\theta}{\\pi}, \\qquad a^H_n = \\frac{2\\sin n\\theta}{n\\pi}"
        " \\quad (n \\ge 1),",
    ]
    if RampCoefficient in kinds:
        two_s = "2" if ts == "1" else f"2{ts}"
        sin_cos_rows += [
            f"a^R_n &= \\frac{{{tA}\\,\\bigl(a^H_{{n-1}} + a^H_{{n+1}}\\bigr) - {two_s}\\,a^H_n}}"
            "{2}, \\qquad a^H_{-1} = a^H_1,",
            f"a^R_0 &= \\frac{{2}}{{\\pi}}\\bigl({tA}\\sin\\theta - {_times(ts)}\\theta\\bigr), "
            f"\\qquad a^R_1 = \\frac{{{tA}}}{{\\pi}}"
            "\\bigl(\\theta - \\sin\\theta\\cos\\theta\\bigr),",
        ]
    if DiracCoefficient in kinds:
        sin_cos_rows.append(f"a^\\delta_n &= \\frac{{2\\cos n\\theta}}{{\\pi {tA} \\sin\\theta}},")
    sin_cos_rows[-1] = sin_cos_rows[-1].rstrip(",") + "."
    tail = (
        "Outside that range the coefficients are exact zeros or those of a linear term "
        "(the numeric layer evaluates every regime)."
    )
    return lead + "\n\\begin{align*}\n" + " \\\\\n".join(sin_cos_rows) + "\n\\end{align*}\n" + tail
