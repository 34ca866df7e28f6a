"""The plotting API (`Response.plot`, `perturb.report.figures.plot`), figure text, and atomic
scene outputs."""

from __future__ import annotations

import io
import subprocess
import sys

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

import perturb  # noqa: E402
from perturb.apps.scene import parse_scene, run_scene  # noqa: E402
from perturb.errors import ParameterError  # noqa: E402
from perturb.report import figures  # noqa: E402
from perturb.response import Branch, Response, responses_to_csv  # noqa: E402


def _response(method: str, first_stable: bool, scale: float = 1.0) -> Response:
    w = np.linspace(0.5, 1.5, 21)
    stable = np.array([first_stable] * 7 + [not first_stable] * 7 + [first_stable] * 7)
    br = Branch(w, scale * (1 + w), scale * (1 + w), 0 * w, stable, np.where(stable, 0.5, 2.0))
    return Response((br,), method, "duffing", {"mu": 0.1, "F": 0.5})


def test_import_perturb_does_not_import_matplotlib():
    code = "import sys, perturb; print('matplotlib' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_response_plot_returns_axes_with_solid_stable_dashed_unstable():
    resp = _response("numeric HB H=15 exact", first_stable=True)
    ax = resp.plot()
    try:
        assert isinstance(ax, matplotlib.axes.Axes)
        data_lines = [ln for ln in ax.get_lines() if len(ln.get_xdata()) > 1]
        assert len(data_lines) == 3  # stable, unstable, stable runs
        styles = [ln.get_linestyle() for ln in data_lines]
        assert styles[0] == "-" and styles[2] == "-" and styles[1] != "-"
        # runs overlap by one point so the curve is continuous
        assert data_lines[0].get_xdata()[-1] == data_lines[1].get_xdata()[0]
    finally:
        plt.close(ax.figure)


def test_legend_uses_proxy_entries_not_the_first_segment_style():
    # the first segment of the exact response is unstable (dashed): its legend entry must
    # still be a plain solid colour key, with separate "stable" / "unstable" style keys
    exact = _response("exact", first_stable=False)
    hb = _response("numeric HB H=15 exact", first_stable=True, scale=1.01)
    ax = figures.plot(exact, hb)
    try:
        leg = ax.get_legend()
        texts = [t.get_text() for t in leg.get_texts()]
        assert texts == [
            "exact periodic orbits",
            "numeric harmonic balance, 15 harmonics (exact Galerkin projection)",
            "stable",
            "unstable",
        ]
        handles = leg.legend_handles
        assert handles[0].get_linestyle() == "-" and handles[1].get_linestyle() == "-"
        assert handles[2].get_linestyle() == "-" and handles[3].get_linestyle() != "-"
        assert handles[0].get_color() != handles[1].get_color()
    finally:
        plt.close(ax.figure)


def test_plot_into_a_given_axes_and_custom_labels():
    fig, ax = plt.subplots()
    try:
        out = _response("hb1(harmonics=1)", True).plot(ax=ax, labels=["mine"], title="")
        assert out is ax
        assert [t.get_text() for t in ax.get_legend().get_texts()][0] == "mine"
        assert ax.get_title() == ""
    finally:
        plt.close(fig)


@pytest.mark.parametrize(
    "method, words",
    [
        ("exact", "exact periodic orbits"),
        ("numeric HB H=15 exact", "numeric harmonic balance, 15 harmonics (exact Galerkin"),
        ("numeric HB H=9 AFT481", "numeric harmonic balance, 9 harmonics (AFT, 481 samples)"),
        ("hb1(harmonics=1)", "single-harmonic balance"),
        ("mlp(order=2, amplitude=first_harmonic)", "modified Lindstedt–Poincaré, order 2"),
        ("kb(order=1, harmonics=1)", "Krylov–Bogoliubov averaging, order 1"),
    ],
)
def test_method_labels_in_words(method, words):
    assert figures.method_label(method).startswith(words)


def test_custom_equation_title_is_the_equation_in_mathtext():
    osc = perturb.Oscillator.parse(
        "x'' + 0.1*x' + x + 4*(x-0.5)*Heaviside(x-0.5) = 0.8*cos(Omega*t)", {}
    )
    title = figures.equation_title(osc)
    assert not title.startswith("custom")
    assert r"\ddot{x}" in title and r"\Omega" in title and "H(" in title
    nsd = figures.equation_title(perturb.builtin_model("nsd", k=-2.0))
    assert r"\mu" in nsd and r"\Omega" in nsd and "k = -2" in nsd
    # it renders: mathtext errors would raise on draw
    fig, ax = plt.subplots()
    try:
        ax.set_title(title)
        fig.savefig(io.BytesIO(), format="png")
    finally:
        plt.close(fig)


def test_a_long_equation_is_shortened_plain_text_that_renders():
    terms = " + ".join(f"{i + 1}*x**{i % 7 + 3}*Heaviside(x - {i})" for i in range(20))
    osc = perturb.Oscillator.parse(f"x'' + 0.1*x' + x + {terms} = cos(Omega*t)", {})
    title = figures.equation_title(osc)
    assert len(title.splitlines()[0]) <= 120 and "…" in title
    fig, ax = plt.subplots()
    try:
        ax.set_title(title)
        fig.savefig(io.BytesIO(), format="png")
    finally:
        plt.close(fig)


def test_to_csv_is_atomic(tmp_path, monkeypatch):
    path = tmp_path / "frc.csv"
    resp = _response("exact", True)
    resp.to_csv(path)
    good = path.read_text()
    assert good.splitlines()[0].startswith("branch,omega,amplitude")
    # a failure while the new file is written (a full disk, say) leaves the previous file as
    # it was, and no debris
    import perturb.atomic

    def full_disk(fd):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(perturb.atomic.os, "fsync", full_disk)
    with pytest.raises(OSError, match="No space"):
        _response("exact", False, scale=2.0).to_csv(path)
    assert path.read_text() == good
    assert [p.name for p in tmp_path.iterdir()] == ["frc.csv"]
    monkeypatch.undo()
    with pytest.raises(ParameterError, match="does not exist"):
        _response("exact", True).to_csv(tmp_path / "missing" / "frc.csv")


def test_responses_to_csv_numbers_branches_through():
    a, b = _response("exact", True), _response("hb1(harmonics=1)", False)
    rows = responses_to_csv([a, b]).splitlines()[1:]
    assert {r.split(",")[0] for r in rows[:21]} == {"0"}
    assert {r.split(",")[0] for r in rows[21:]} == {"1"}
    assert rows[21].endswith(",hb1(harmonics=1)")


def test_two_outputs_of_one_scene_with_one_name_are_refused():
    text = '[model]\nname = "nsd"\n[output]\ncsv = "a.out"\npng = "a.out"\n'
    with pytest.raises(ParameterError, match="a.out"):
        parse_scene(text, "dup.toml")
    text = '[model]\nname = "nsd"\n[output]\nreport = "frc.csv"\n'  # clashes with the default
    with pytest.raises(ParameterError, match="frc.csv"):
        parse_scene(text, "dup.toml")


def test_an_empty_answer_is_a_note_printed_and_in_the_report(tmp_path, monkeypatch):
    import json

    import perturb.solve

    empty = Response((), "numeric HB H=5 exact", "duffing", {})
    monkeypatch.setattr(perturb.solve, "frequency_response", lambda *a, **k: empty)
    scene = parse_scene(
        '[model]\nname = "duffing"\n[ask]\nomega = [0.5, 1.5]\n[method]\nname = "hb"\n'
        "harmonics = 5\n",
        "empty.toml",
    )
    log = tmp_path / "log.txt"
    with open(log, "w") as fh:
        paths = run_scene(scene, tmp_path / "out", log=fh)
    notes = json.loads(paths["report"].read_text())["notes"]
    assert any("no periodic solution found" in n for n in notes)
    assert "note: " in log.read_text() and "no periodic solution found" in log.read_text()
    assert paths["csv"].read_text().count("\n") == 1  # the header only


def test_bifurcation_figure_title_fits_and_markers_are_visible(tmp_path, monkeypatch):
    saved = []
    monkeypatch.setattr(figures, "save_figure", lambda fig, path: saved.append(fig))
    monkeypatch.setattr(plt, "close", lambda fig=None: None)
    scene = parse_scene(
        '[model]\nname = "nsd"\n[params]\nk = -2.0\nmu = 0.05\nF = 2.0\nOmega = 1.5\n'
        '[ask]\nkind = "bifurcation_diagram"\nparameter = "F"\nvalues = [1.5, 2.0]\n'
        "points = 10\ntransient_periods = 20\nrecord_periods = 2\n"
        '[method]\nname = "exact"\n',
        "bif.toml",
    )
    run_scene(scene, tmp_path, log=open(tmp_path / "log.txt", "w"))
    (fig,) = saved
    try:
        ax = fig.axes[0]
        pts = [ln for ln in ax.get_lines() if ln.get_marker() not in ("", "None", ",")]
        assert pts and all(ln.get_markersize() >= 1.5 for ln in pts)
        assert fig.get_layout_engine() is not None  # constrained: nothing cut off
        fig.canvas.draw()
        box = ax.title.get_window_extent()
        width, height = fig.canvas.get_width_height()
        assert box.x0 >= 0 and box.x1 <= width and box.y1 <= height
        assert "\n" in ax.get_title()
    finally:
        matplotlib.pyplot.close("all")


@pytest.mark.parametrize(
    "text, fragment",
    [
        ("[compare]\nreference = 'hb1'", "expected 'exact'"),
        ("[compare]\nmethods = ['magic']", "'magic' is not a method"),
        ("[compare]\nmethods = ['hb1', 'hb1']", "a method twice"),
        ("[method]\nname = 'exact'\n[compare]\nreference = 'exact'", "compare the exact"),
        ("[plot]\nzoom = [0.5, 0.2, 1, 2]", "zoom"),
        ("[plot]\nmean = 1", "expected true or false"),
        ("[plot]\ncolour = 'red'", "unknown key 'colour'"),
        ("[method]\nname = 'hb'\nall_branches = 'yes'", "all_branches"),
        ("[ask]\nkind = 'backbone'\n[compare]\nreference = 'exact'", "does not apply"),
    ],
)
def test_bad_compare_and_plot_tables(text, fragment):
    from perturb.errors import PerturbError

    with pytest.raises(PerturbError, match=fragment):
        parse_scene("[model]\nname = 'nsd'\n" + text, "bad.toml")


def test_auto_scene_legend_carries_the_measured_spot_error(tmp_path):
    import json

    scene = parse_scene(
        '[model]\nname = "duffing"\n[ask]\nomega = [0.5, 1.0]\n[method]\nname = "auto"\n'
        "[accuracy]\nrtol = 0.05\nspots = [0.6, 0.9]\n",
        "auto.toml",
    )
    paths = run_scene(scene, tmp_path, log=open(tmp_path / "log.txt", "w"))
    report = json.loads(paths["report"].read_text())
    (label,) = report["legend"]
    spot = report["auto"]["chosen"]["max_spot_error"]
    assert 0 < spot <= 0.05
    assert f"max error {spot:.1e} at 2 exact spot checks" in label
    assert "chosen for rtol 0.05" in label and "(" not in label.split(":")[0]
