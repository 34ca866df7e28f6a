"""Generated LaTeX compiles with pdflatex (CI installs TeX; locally skipped without it)."""

from __future__ import annotations

import pytest

from perturb import builtin_model
from perturb.methods.harmonic_balance import single_harmonic_balance
from perturb.report.latex import escape, latex_document


@pytest.mark.parametrize("model", ["nsd", "duffing", "deadzone", "saturation"])
def test_derivation_document_compiles(model, tmp_path, compile_tex):
    tex = tmp_path / "doc.tex"
    latex_document(single_harmonic_balance(builtin_model(model)), tex)
    compile_tex(tex, timeout=120)


def test_text_is_escaped():
    assert escape("a_1 & 50% #x {y} ~ ^ \\") == (
        r"a\_1 \& 50\% \#x \{y\} \textasciitilde{} \textasciicircum{} \textbackslash{}"
    )


def test_heaviside_prints_as_H_and_coefficients_by_name():
    doc = latex_document(single_harmonic_balance(builtin_model("nsd")))
    assert "\\theta\\left(x" not in doc  # SymPy's default name for Heaviside
    assert "H\\left(x - 1\\right)" in doc
    assert "a^{R}_{1}" in doc


# ------------------------------------------------------------------------------------------
# the writer: reading order, words, line breaking (issue 17)
# ------------------------------------------------------------------------------------------
def test_terms_in_the_order_a_person_writes_them():
    import sympy as sp

    from perturb.report.layout import DocPrinter

    p = DocPrinter()
    x, xp, xpp, mu, k, eps, w1, w2 = sp.symbols("x x' x'' mu k epsilon omega_1 omega_2")
    assert p.doprint(k * x + mu * xp + xpp) == "x'' + \\mu x' + k x"
    assert (
        p.doprint(w1 * eps + eps**2 * w2 + 1)
        == "1 + \\epsilon \\omega_{1} + \\epsilon^{2} \\omega_{2}"
    )
    tau, phi = sp.symbols("tau phi")
    assert p.doprint(tau - phi) == "\\tau - \\phi"
    assert p.doprint(x - 1) == "x - 1"
    psi, A = sp.symbols("psi A")
    e = sp.sin(2 * psi) + A * sp.cos(2 * psi) + 3 * sp.cos(psi) + mu * sp.sin(psi) + k
    assert p.doprint(e) == (
        "k + 3 \\cos {\\psi} + \\mu \\sin {\\psi} + A \\cos {2 \\psi} + \\sin {2 \\psi}"
    )


def test_titles_and_settings_in_words():
    from perturb.methods import modified_lindstedt, multiple_scales

    doc = latex_document(modified_lindstedt(builtin_model("nsd"), order=2))
    assert (
        "\\section*{Second-order modified Lindstedt--Poincar\\'e expansion of the "
        "negative-stiffness oscillator}" in doc
    )
    assert "first\\_harmonic" not in doc and "mlp(" not in doc
    doc = latex_document(multiple_scales(builtin_model("duffing"), order=3))
    assert "\\section*{Third-order multiple-scales expansion of the Duffing oscillator}" in doc


def test_step_text_keeps_its_mathematics():
    from perturb.report.latex import escape_text

    assert escape_text("shift $\\omega_0^2 + \\nu$ of k_eq, 5%") == (
        "shift $\\omega_0^2 + \\nu$ of k\\_eq, 5\\%"
    )
    assert escape_text("costs $5") == "costs \\$5"  # an unpaired dollar is text


def test_long_equations_are_broken_within_the_page():
    import sympy as sp

    from perturb.report.layout import TEXT_WIDTH, DocPrinter, equation_rows, tex_width

    p = DocPrinter()
    a = sp.symbols("a0:40")
    psi = sp.Symbol("psi")
    rhs = sum(a[n] * a[n + 1] / (n + 7) * sp.cos(n % 5 * psi) for n in range(39))
    rows, _ = equation_rows(p, sp.Symbol("y"), rhs)
    assert len(rows) > 3
    assert all(tex_width(r.split("&", 1)[1]) < TEXT_WIDTH for r in rows)
    # grouped by harmonic: each cos n psi is written once
    assert sum(r.count("\\cos {2 \\psi}") for r in rows) == 1


def test_derivation_body_defines_its_coefficients_for_a_larger_document():
    from perturb.methods import modified_lindstedt
    from perturb.report.latex import derivation_body

    ap = modified_lindstedt(builtin_model("nsd"), order=1)
    body = derivation_body(ap.steps)
    assert body.index("\\theta &= \\arccos\\frac{1}{A}") < body.index("\\subsection*")
    assert "a^{R}_{1}" in body and "\\!\\left(A\\cos\\psi" not in body
    assert body in latex_document(ap)


def test_one_orbit_several_switching_points_print_as_a_n_of_d():
    doc = latex_document(single_harmonic_balance(builtin_model("nsd")))
    assert "a^{R}_{1}(1)" in doc and "a^{R}_{1}(-1)" in doc
    assert "$d \\in \\{-1, 1\\}$" in doc and "\\theta &= \\arccos\\frac{d}{A}" in doc
