"""Every engine's derivation document, for every applicable builtin model and orders 1-3,
compiles with pdflatex without an overfull box wider than 5 pt, without an undefined control
sequence and without Python reprs or raw SymPy names in its text (issue 17).

The closed forms the documents print for the Fourier coefficients (``a^H_n``, ``a^R_n`` and
the identity linking them) are checked against the numeric forms of
:mod:`perturb.fourier.coefficients`,
and the simplified first-order frequency-amplitude equation of mLP against the engine's own
residuals. The default run compiles first orders, methods without orders and the two worst
cases of the issue; the other orders are marked slow.
"""

from __future__ import annotations

import inspect
import re

import numpy as np
import pytest
import sympy as sp

import perturb
from perturb import builtin_model
from perturb.apps.cli import main
from perturb.errors import PerturbError
from perturb.io.cache import cached_derivation
from perturb.methods import METHODS
from perturb.report.latex import latex_document

OVERFULL = re.compile(r"Overfull \\hbox \((\d+(?:\.\d+)?)pt too wide\)")
# anywhere in the document, mathematics included
FORBIDDEN = {
    "Python repr": re.compile(r"\w+\(\w+="),
    "raw acos": re.compile(r"\bacos\b|operatorname\{a(?:cos|sin|tan)\}"),
    "SymPy Heaviside": re.compile(r"Heaviside"),
    "SymPy function name": re.compile(r"(?:Step|Ramp|Dirac)Coefficient|_Continued"),
}
# in the text (mathematics removed)
FORBIDDEN_TEXT = {
    "escaped underscore (a variable name in words)": re.compile(r"\\_"),
    "suffix _r": re.compile(r"_r\b"),
    "omega_0 in words": re.compile(r"omega_?0"),
    "Greek letter in words": re.compile(
        r"\b(?:epsilon|alpha|omega|theta|psi|sigma|nu|delta|tau|phi|gamma|beta)\b"
    ),
    "NST": re.compile(r"\bNST\b"),
    "exp(i ...)": re.compile(r"exp\(i"),
    "sqrt(...)": re.compile(r"sqrt\("),
    "squared in words": re.compile(r"squared plus"),
    "cos(psi) in words": re.compile(r"\b(?:cos|sin)\((?:psi|tau|phi|n psi)\)"),
}
_MATH = re.compile(
    r"\\begin\{(align\*|equation\*|multline\*)\}.*?\\end\{\1\}|\$[^$]*\$|\\\[.*?\\\]", re.S
)


def _cases():
    for name, fn in METHODS.items():
        orders = [1, 2, 3] if "order" in inspect.signature(fn).parameters else [None]
        for model in perturb.BUILTIN_MODELS:
            for order in orders:
                slow = order is not None and order > 1
                if (name, model, order) in {("ms", "duffing", 3), ("mlp", "nsd", 2)}:
                    slow = False  # the two worst cases run by default
                marks = [pytest.mark.slow] if slow else []
                yield pytest.param(name, model, order, marks=marks, id=f"{name}-{model}-{order}")


def text_outside_math(doc: str) -> str:
    """The document body without its mathematics and commands' names."""
    body = doc.split("\\begin{document}", 1)[1]
    body = _MATH.sub(" ", body)
    return re.sub(r"\\[A-Za-z]+\*?", " ", body)


def check_document(doc: str, log: str) -> list[str]:
    """Every complaint about one compiled document."""
    bad = []
    wide = [float(w) for w in OVERFULL.findall(log) if float(w) > 5.0]
    if wide:
        bad.append(f"{len(wide)} overfull boxes wider than 5 pt: {wide}")
    if "Undefined control sequence" in log:
        bad.append("undefined control sequence")
    for what, pattern in FORBIDDEN.items():
        if m := pattern.search(doc):
            bad.append(f"{what}: ...{doc[max(0, m.start() - 40) : m.end() + 40]!r}...")
    text = text_outside_math(doc)
    for what, pattern in FORBIDDEN_TEXT.items():
        if m := pattern.search(text):
            bad.append(f"{what} in the text: ...{text[max(0, m.start() - 60) : m.end() + 40]!r}")
    return bad


@pytest.mark.parametrize(("method", "model", "order"), list(_cases()))
def test_engine_document_compiles_cleanly(method, model, order, tmp_path, compile_tex):
    options = {} if order is None else {"order": order}
    try:
        approx = cached_derivation(method, METHODS[method], builtin_model(model), **options)
    except PerturbError as exc:  # a refusal names what applies; anything else is a crash
        assert str(exc)
        pytest.skip(f"refused: {type(exc).__name__}")
    summary = approx.summary(width=100)  # what perturb derive prints
    assert max(map(len, summary.splitlines())) <= 100 and len(summary.splitlines()) <= 20
    tex = tmp_path / "doc.tex"
    doc = latex_document(approx, tex)
    compile_tex(tex, timeout=120)
    log = tex.with_suffix(".log").read_text(errors="replace")
    assert check_document(doc, log) == []


def test_the_checks_can_fail():
    """The document checks flag what issue 17 found in the old documents."""
    old = (
        "\\begin{document}\\section*{mlp(order=2, amplitude=first\\_harmonic) of the nsd "
        "oscillator}Dividing by omega\\_0 squared plus nu. NST stands for the rest. The "
        "coefficient of exp(i theta). $\\operatorname{acos}{\\left(1/A \\right)}$"
    )
    log = "Overfull \\hbox (871.2pt too wide) detected at line 77\nOverfull \\hbox (3.1pt too wide)"
    bad = " | ".join(check_document(old, log))
    for what in ("1 overfull", "Python repr", "raw acos", "escaped underscore", "NST", "exp(i"):
        assert what in bad
    assert "Undefined control sequence" not in bad


# ------------------------------------------------------------------------------------------
# the closed forms the documents define
# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize(("A", "b", "d"), [(1.7, 0.0, 1.0), (3.2, 0.4, 1.0), (2.5, -0.3, -1.1)])
def test_printed_closed_forms_match_the_numeric_coefficients(A, b, d):
    from perturb.fourier import coefficients as fourier

    s = d - b
    theta = np.arccos(s / A)
    n = np.arange(1, 12)
    aH = fourier.step_coefficients(np.arange(0, 14), A, b, d)
    aR = fourier.ramp_coefficients(np.arange(0, 12), A, b, d)
    # a^H_0 = 2 theta/pi, a^H_n = 2 sin(n theta)/(n pi)
    assert aH[0] == pytest.approx(2 * theta / np.pi, rel=1e-12)
    assert aH[1:12] == pytest.approx(2 * np.sin(n * theta) / (n * np.pi), rel=1e-10, abs=1e-14)
    # a^R_n = (A (a^H_{n-1} + a^H_{n+1}) - 2 (d - b) a^H_n) / 2, a^H_{-1} = a^H_1
    for k in range(0, 11):
        lower = aH[1] if k == 0 else aH[k - 1]
        assert aR[k] == pytest.approx((A * (lower + aH[k + 1]) - 2 * s * aH[k]) / 2, abs=1e-13)
    # a^R_0 = 2 (A sin theta - (d - b) theta)/pi, a^R_1 = A (theta - sin theta cos theta)/pi
    assert aR[0] == pytest.approx(2 * (A * np.sin(theta) - s * theta) / np.pi, rel=1e-12)
    assert aR[1] == pytest.approx(A * (theta - np.sin(theta) * np.cos(theta)) / np.pi, rel=1e-12)


def test_the_document_defines_the_coefficients_before_using_them():
    doc = latex_document(perturb.methods.modified_lindstedt(builtin_model("nsd"), order=2))
    defined = doc.index("\\theta &= \\arccos\\frac{1}{A}")
    assert "a^R_n &= \\frac{A\\,\\bigl(a^H_{n-1} + a^H_{n+1}\\bigr) - 2\\,a^H_n}{2}" in doc
    assert defined < doc.index("a^{R}_{1}")
    assert "\\!\\left(A\\cos\\psi" not in doc  # the argument is stated once, in the definition


def test_mlp_first_order_frequency_amplitude_equation_is_the_residuals_phase_eliminated():
    """(A(Omega^2 - k) - 2(1 - k) a^R_1)^2 + (mu Omega A)^2 = F^2, as printed, equals the
    engine's residuals with the phase eliminated (numbers substituted)."""
    osc = builtin_model("nsd")
    approx = perturb.methods.modified_lindstedt(osc, order=1)
    doc = latex_document(approx)
    assert (
        "\\left(A \\left(\\Omega^{2} - k\\right) - 2 \\left(1 - k\\right) a^{R}_{1}\\right)^{2}"
        " + \\left(A \\Omega \\mu\\right)^{2} &= F^{2}"
    ) in doc
    step = next(s for s in approx.steps if s.title.startswith("Frequency-amplitude"))
    printed = step.math[0]
    A, phi = approx.unknowns
    cos_res, sin_res = approx.residuals
    F = next(s for s in cos_res.free_symbols if s.name == "F")
    P = sp.expand(cos_res - F * sp.cos(phi))  # cos_res = F cos(phi) + P(A, Omega)
    Q = sp.expand(sin_res - F * sp.sin(phi))
    assert not P.has(phi) and not Q.has(phi)
    rng = np.random.default_rng(17)
    names = {s.name: s for s in printed.free_symbols | cos_res.free_symbols}
    for _ in range(5):
        values = {
            names["A"]: rng.uniform(1.2, 4.0),
            names["Omega"]: rng.uniform(0.2, 2.0),
            names["k"]: rng.uniform(-3.0, 0.5),
            names["mu"]: rng.uniform(0.01, 0.3),
            names["F"]: rng.uniform(0.5, 3.0),
        }
        printed_value = float((printed.lhs - printed.rhs).xreplace(values).evalf())
        eliminated = float((P**2 + Q**2 - F**2).xreplace(values).evalf())
        assert printed_value == pytest.approx(eliminated, rel=1e-12, abs=1e-12)


def test_zou_eq59_as_a_sum_over_odd_harmonics():
    doc = latex_document(perturb.methods.modified_lindstedt(builtin_model("nsd"), order=1))
    assert (
        "x_{1}{\\left(\\tau\\right)} &= \\sum_{n = 3, 5, \\ldots, 15} "
        "\\frac{2 \\left(1 - k\\right) a^{R}_{n}}{\\nu \\left(n^{2} - 1\\right)} \\cos {n \\psi}"
    ) in doc


# ------------------------------------------------------------------------------------------
# the terminal
# ------------------------------------------------------------------------------------------
def test_derive_terminal_output_is_wrapped_and_abbreviated(capsys, monkeypatch, tmp_path):
    monkeypatch.setenv("COLUMNS", "100")
    tex = tmp_path / "mlp2.tex"
    assert main(["derive", "mlp", "nsd", "--order", "2", "--latex", str(tex)]) == 0
    out = capsys.readouterr().out
    lines = out.splitlines()
    assert max(map(len, lines)) <= 100 and len(out) < 2000
    out = " ".join(out.split())  # the words, whatever the wrapping
    assert "x(tau) = 15 terms" in out and "aR_n for n = 1..15" in out
    assert "--latex FILE or --json FILE" in out
    assert "RampCoefficient" not in out
    assert "\\sum_{n = 3, 5, \\ldots, 15}" in tex.read_text()
    # a short equation is printed in full
    assert "equation 2: 0 = A*Omega*mu + F*sin(phi)" in out


def test_second_order_mlp_sums_over_the_coefficient_index():
    """Each harmonic of x_2 collects its products a^R_m a^H_{m +- j} as sums over m."""
    doc = latex_document(perturb.methods.modified_lindstedt(builtin_model("nsd"), order=2))
    assert "\\sum_{m = 3, 5, \\ldots, 15}" in doc
    assert "a^{R}_{m} a^{H}_{m - 3}" in doc and "a^{R}_{m} a^{H}_{m + 3}" in doc
    # the harmonic is written once in the equation for x_2 and once in its solution
    assert doc.count("\\cos {3 \\psi}") == 2


@pytest.mark.parametrize(
    ("method", "model"), [("kb", "deadzone"), ("hb1", "nsd"), ("shb", "saturation")]
)
def test_folded_closed_forms_equal_the_coefficient_functions(method, model):
    """The closed forms printed with one crossing angle (theta_1 = pi - theta_2 folded in)
    equal the first harmonic the engine uses, evaluated by perturb.fourier.coefficients; the
    dead-zone
    describing function is the textbook
    k_1 + k_2 (1 - 2/pi (arcsin(d/a) + d/a sqrt(1 - d^2/a^2)))."""
    approx = METHODS[method](builtin_model(model))
    step = next(s for s in approx.steps if "closed form" in s.title)
    eqs = [m for m in step.math if isinstance(m, sp.Equality)]
    theta = next(m for m in eqs if m.lhs.name.startswith("theta"))
    assert theta.lhs.name == "theta" and len([m for m in eqs if m.lhs.is_Symbol]) == 1
    closed = eqs[0]
    previous = approx.steps[approx.steps.index(step) - 1]
    named = {
        m.lhs: m.rhs for m in previous.math if isinstance(m, sp.Equality) and m.lhs == closed.lhs
    }
    assert named
    for amp in (1.3, 2.0, 4.5):
        values = {s: float(v) for s, v in zip(*_params(approx), strict=True)}
        a = next(s for s in closed.lhs.free_symbols)
        values[a] = amp
        th = float(theta.rhs.xreplace(values))
        printed = float(closed.rhs.xreplace({theta.lhs: th, **values}))
        # the coefficient functions of the step before, evaluated by perturb.fourier.coefficients
        reference = float(named[closed.lhs].xreplace(values).evalf())
        assert printed == pytest.approx(reference, rel=1e-12)
        if model == "deadzone":
            k1, k2, d = (values[next(s for s in values if s.name == n)] for n in ("k1", "k2", "d"))
            u = d / amp
            textbook = k1 + k2 * (1 - 2 / np.pi * (np.arcsin(u) + u * np.sqrt(1 - u**2)))
            assert printed == pytest.approx(textbook, rel=1e-12)


def _params(approx):
    osc = approx.oscillator
    symbols = {s.name: s for s in osc.equation.free_symbols}
    names = [n for n, v in osc.params.items() if v is not None and n in symbols]
    return [symbols[n] for n in names], [osc.params[n] for n in names]
