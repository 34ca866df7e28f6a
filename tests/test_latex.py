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
