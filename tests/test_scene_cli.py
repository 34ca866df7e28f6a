"""The perturb command and scene files."""

from __future__ import annotations

import csv
from pathlib import Path

import mpmath as mp
import pytest

from perturb import PerturbError, __version__
from perturb.apps.cli import main, parse_param
from perturb.apps.scene import default_scene, parse_scene, run_scene
from perturb.errors import ParameterError
from perturb.model.builtins import BUILTIN_MODELS, builtin_model
from perturb.response import CSV_COLUMNS

ROOT = Path(__file__).resolve().parents[1]


def test_version(capsys):
    with pytest.raises(SystemExit) as info:
        main(["--version"])
    assert info.value.code == 0
    assert __version__ in capsys.readouterr().out


def test_models_lists_every_builtin_with_its_equation(capsys):
    assert main(["models"]) == 0
    out = capsys.readouterr().out
    for name, spec in BUILTIN_MODELS.items():
        assert f"\n{name}\n" in "\n" + out
        assert spec.equation in out


def test_fourier_command_against_mpmath_quadrature(capsys):
    assert (
        main(
            ["fourier", "k*Max(x - 1, 0)", "--A", "2.5", "--b", "0.3", "--n", "6", "--param", "k=3"]
        )
        == 0
    )
    rows = [
        line.split(",")
        for line in capsys.readouterr().out.splitlines()
        if line and line[0].isdigit()
    ]
    assert len(rows) == 7
    mp.mp.dps = 30
    psi_c = mp.acos((1 - mp.mpf("0.3")) / mp.mpf("2.5"))
    for n_text, value in rows:
        n = int(n_text)
        ref = (
            2
            / mp.pi
            * mp.quad(
                lambda p, n=n: 3 * (mp.mpf("2.5") * mp.cos(p) + mp.mpf("0.3") - 1) * mp.cos(n * p),
                [0, psi_c],
            )
        )
        assert float(value) == pytest.approx(float(ref), rel=1e-12, abs=1e-14)


@pytest.mark.parametrize(
    "argv, fragment",
    [
        (["fourier", "foo(x)", "--A", "1"], "unknown function 'foo'"),
        (["fourier", "k*x", "--A", "1"], "without values: k"),
        (["fourier", "x", "--A", "-1"], "--A -1"),
        (["fourier", "x", "--A", "1", "--param", "k"], "expected NAME=VALUE"),
        (["fourier", "x", "--A", "1", "--param", "k=nan"], "finite"),
        (["run", "/nonexistent/scene.toml"], "cannot read scene file"),
        (["run", "--rtol", "1e-3"], "applies to frequency-response scenes"),
        (["run", str(ROOT / "scenes" / "zou_fig17_k-3.toml"), "--rtol", "2"], "rtol = 2.0"),
    ],
)
def test_user_errors_exit_2_with_one_clear_line(argv, fragment, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("perturb: error:") and fragment in err
    assert "Traceback" not in err


def test_parse_param():
    assert parse_param("k=-2") == ("k", -2.0)
    assert parse_param(" mu = 0.05 ") == ("mu", 0.05)
    for bad in ("=1", "1k=2", "k=abc", "k=inf", "__import__=1"):
        with pytest.raises(ParameterError):
            parse_param(bad)


def test_default_scene_is_the_shipped_scene_file():
    shipped = (ROOT / "scenes" / "nsd_frequency_response.toml").read_text()
    embedded = (ROOT / "perturb" / "scenes" / "default.toml").read_text()
    assert shipped == embedded
    scene = default_scene()
    assert scene.model == "nsd" and dict(scene.params) == {"k": -2.0, "mu": 0.05, "F": 2.0}


def test_run_default_scene_writes_csv_png_latex(tmp_path):
    paths = run_scene(default_scene(), tmp_path, log=open(tmp_path / "log.txt", "w"))
    with open(paths["csv"]) as fh:
        reader = csv.reader(fh)
        # the fixed columns first; the default scene adds rel_error (against exact) at the end
        assert tuple(next(reader))[: len(CSV_COLUMNS)] == CSV_COLUMNS
        rows = list(reader)
    assert len(rows) > 1000
    assert paths["png"].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    tex = paths["latex"].read_text()
    assert "\\begin{document}" in tex and "\\end{document}" in tex
    assert "H\\left(" in tex or "a^{R}" in tex
    assert '"method": "hb1"' in paths["report"].read_text()


@pytest.mark.parametrize(
    "text, fragment",
    [
        ("[modle]\nname='nsd'", "unknown section [modle]"),
        ("[model]\nname='nsd'\ncolour=1", "unknown key 'colour'"),
        ("[model]\nname='nsd'\n[ask]\nomega=[2, 1]", "omega"),
        ("[model]\nname='nsd'\n[ask]\nkind='bifurcation'", "kind"),
        ("[model]\nname='nsd'\n[params]\nk=nan", "finite"),
        ("[model]\nname='nsd'\n[output]\ncsv='../evil.csv'", "plain file name"),
        ("[model]\nname='nsd'\n[method]\nname='magic'", "method"),
        ("[model\nname='nsd'", "invalid TOML"),
        ("[params]\nk=1", "needs a builtin"),
    ],
)
def test_bad_scenes(text, fragment):
    with pytest.raises(PerturbError) as info:
        parse_scene(text, "test.toml")
    assert fragment in str(info.value)


def test_equation_scene_is_parsed_safely():
    scene = parse_scene(
        "[model]\nequation = \"x'' + mu*x' + x + x**3 = F*cos(Omega*t)\"\n"
        "[params]\nmu = 0.1\nF = 0.5\n"
    )
    osc = scene.oscillator()
    assert osc.params["mu"] == 0.1
    with pytest.raises(PerturbError):
        parse_scene("[model]\nequation = \"__import__('os').system('id')\"\n").oscillator()


def test_parse_omega_forms():
    from perturb.apps.cli import parse_omega

    assert parse_omega("0.2:2") == ("range", [0.2, 2.0])
    kind, values = parse_omega("0.2:2.0:5")
    assert kind == "points" and values == [0.2, 0.65, 1.1, 1.55, 2.0]
    assert parse_omega("0.6, 0.9") == ("points", [0.6, 0.9])
    for bad in ("2:1", "a:b", "1:2:3:4", "1:2:2.5", "0.6,-1", "", "0.6,nan", "0:1"):
        with pytest.raises(ParameterError):
            parse_omega(bad)


def test_frc_listed_frequencies_appear_exactly_and_solve_the_amplitude_equation(tmp_path):
    out = tmp_path / "frc.csv"
    png = tmp_path / "frc.png"
    argv = [
        "frc",
        "nsd",
        "--param",
        "k=-2",
        "--param",
        "mu=0.05",
        "--param",
        "F=2",
        "--omega",
        "0.6,0.9",
        "--out",
        str(out),
        "--plot",
        str(png),
    ]
    assert main(argv) == 0
    with open(out) as fh:
        rows = list(csv.DictReader(fh))
    assert tuple(rows[0].keys()) == CSV_COLUMNS
    assert {float(r["omega"]) for r in rows} == {0.6, 0.9}
    assert png.read_bytes()[:4] == b"\x89PNG"
    # every row solves the first-order (describing-function) equation of the paper
    import numpy as np

    for r in rows:
        A, W = float(r["first_harmonic_amplitude"]), float(r["omega"])
        th = np.arccos(min(1.0, 1.0 / A))
        c1 = A * (2 * th / np.pi + np.sin(2 * th) / np.pi) - 4 * np.sin(th) / np.pi
        res = ((W**2 + 2) * A - 3 * c1) ** 2 + (0.05 * W * A) ** 2 - 4
        assert abs(res) < 1e-8
    # at Omega = 0.6 the three symmetric solutions: large stable, middle and in-well unstable
    at = sorted((float(r["amplitude"]), int(r["stable"])) for r in rows if r["omega"] == "0.6")
    assert [s for _, s in at] == [0, 0, 1]


def test_frc_exact_with_a_frequency_grid_writes_exactly_those_frequencies(tmp_path):
    out = tmp_path / "frc.csv"
    argv = ["frc", "nsd", "--method", "exact", "--param", "k=-2", "--param", "mu=0.05"]
    argv += ["--param", "F=2", "--omega", "0.5:0.7:5", "--out", str(out)]
    assert main(argv) == 0
    with open(out) as fh:
        rows = list(csv.DictReader(fh))
    assert tuple(rows[0].keys()) == CSV_COLUMNS
    assert {r["omega"] for r in rows} == {"0.5", "0.55", "0.6", "0.65", "0.7"}
    assert {r["method"] for r in rows} == {"exact"}
    # at 0.65 three symmetric orbits (in-well saddle, middle unstable, large stable) and,
    # since the all-orbits search seeds asymmetric ones too, an unstable mirror pair
    at = [r for r in rows if r["omega"] == "0.65"]
    sym = [r for r in at if abs(float(r["mean"])) < 1e-9 * float(r["amplitude"])]
    assert [int(r["stable"]) for r in sorted(sym, key=lambda r: float(r["amplitude"]))] == [0, 0, 1]
    pair = [r for r in at if r not in sym]
    if pair:  # the mirror pair: same amplitude, opposite means
        assert len(pair) == 2
        assert float(pair[0]["amplitude"]) == pytest.approx(float(pair[1]["amplitude"]), rel=1e-9)
        assert float(pair[0]["mean"]) == pytest.approx(-float(pair[1]["mean"]), rel=1e-6)


def test_frc_errors(capsys):
    assert main(["frc", "nope"]) == 2
    assert "builtin name" in capsys.readouterr().err
    assert main(["frc", "nsd", "--method", "magic"]) == 2
    assert "--method 'magic'" in capsys.readouterr().err
    assert main(["frc", "nsd", "--omega", "2:1"]) == 2
    assert "0 < start < stop" in capsys.readouterr().err


def test_front_door_dispatches_methods():
    import perturb

    osc = perturb.builtin_model("nsd")
    resp = perturb.frequency_response(osc, "hb1", frequencies=[0.6, 0.9])
    assert {w for br in resp.branches for w in br.omega} == {0.6, 0.9}
    with pytest.raises(ParameterError, match="method"):
        perturb.frequency_response(osc, "magic")
    assert callable(perturb.periodic_orbits) and callable(perturb.time_history)
    with pytest.raises(AttributeError):
        perturb.no_such_thing  # noqa: B018


def test_frc_compare_exact_adds_rel_error_against_exact_orbits(tmp_path):
    out = tmp_path / "frc.csv"
    argv = ["frc", "nsd", "--method", "mlp", "--order", "1", "--param", "k=-0.5"]
    argv += ["--param", "mu=0.05", "--param", "F=2", "--omega", "0.6,0.9"]
    argv += ["--compare", "exact", "--out", str(out)]
    assert main(argv) == 0
    with open(out) as fh:
        rows = list(csv.DictReader(fh))
    assert tuple(rows[0].keys()) == (*CSV_COLUMNS, "rel_error")
    from perturb.solve import periodic_orbits

    osc = builtin_model("nsd", k=-0.5, mu=0.05, F=2.0)
    for r in rows:
        exact = periodic_orbits(osc, float(r["omega"]))
        ref = min(abs(float(r["amplitude"]) / o.amplitude - 1) for o in exact)
        assert float(r["rel_error"]) == pytest.approx(ref, rel=1e-6, abs=1e-12)


def test_frc_method_aliases_and_numeric_hb(tmp_path):
    out = tmp_path / "a.csv"
    base = ["frc", "nsd", "--param", "k=-0.5", "--param", "mu=0.05", "--param", "F=2"]
    assert main([*base, "--method", "avg", "--omega", "0.6,0.9", "--out", str(out)]) == 0
    assert "kb" in out.read_text().splitlines()[1]
    assert main([*base, "--method", "hb", "--harmonics", "5", "--omega", "0.8:1.2"]) == 0
    # listed frequencies for every method, numeric HB included: tests/test_method_registry.py


def test_run_on_a_sweep_scene_writes_the_map(tmp_path):
    scene = tmp_path / "map.toml"
    scene.write_text(
        '[model]\nname = "nsd"\n[params]\nF = 2.0\nmu = 0.05\nk = -2.0\n[ask]\n'
        'omega = [0.2, 2.0]\n[method]\nname = "hb1"\n[sweep]\nquantity = "peak_amplitude"\n'
        'solver = "approximation"\n[sweep.params]\nmu = "0.05:0.1:2"\nk = "-2:-1:2"\n'
    )
    assert main(["run", str(scene), "--out", str(tmp_path / "out")]) == 0
    from perturb.apps.grid import load_dataset

    ds = load_dataset(tmp_path / "out" / "map.nc")
    assert dict(ds.sizes)["mu"] == 2 and dict(ds.sizes)["k"] == 2
    assert (tmp_path / "out" / "map.png").read_bytes()[:4] == b"\x89PNG"


# ---------------------------------------------------------------------------------------------
# ask kinds beyond the frequency response
# ---------------------------------------------------------------------------------------------
def _csv_columns(path):
    import numpy as np

    with open(path) as fh:
        rows = list(csv.DictReader(fh))
    return {k: np.array([float(r[k]) for r in rows]) for k in rows[0]}


@pytest.mark.parametrize(
    "text, fragment",
    [
        ("[ask]\nkind='backbone'\nomega=[1, 2]", "'omega' does not apply to kind 'backbone'"),
        ("[ask]\nkind='time_history'\ny0=[1]", "y0"),
        ("[ask]\nkind='time_history'\n[method]\nname='hb1'", "expects an integrator"),
        ("[ask]\nkind='bifurcation_diagram'\nparameter='k'", "values"),
        ("[ask]\nkind='bifurcation_diagram'\nvalues=[0, 1]", "parameter"),
        ("[ask]\nkind='backbone'\namplitude=[2, 1]", "amplitude"),
        ("[ask]\nkind='step_response'\nsamples=1", "samples"),
        ("[method]\nname='hb'\nharmonics=0", "harmonics"),
    ],
)
def test_bad_ask_kinds(text, fragment):
    with pytest.raises(PerturbError) as info:
        parse_scene("[model]\nname='nsd'\n" + text, "test.toml")
    assert fragment in str(info.value)


def test_every_shipped_scene_parses():
    from perturb.apps.scene import load_scene

    for path in sorted((ROOT / "scenes").glob("*.toml")):
        if path.name == "peak_map.toml":
            continue  # a [sweep] scene, read by perturb.apps.grid_cli
        scene = load_scene(path)
        scene.oscillator()
        assert "docs/references.md" in path.read_text() or "course" in path.name, path


def test_backbone_scene_duffing_against_the_elliptic_integral(tmp_path):
    import dataclasses

    from perturb.apps.scene import load_scene

    scene = load_scene(ROOT / "scenes" / "course_duffing_backbone.toml")
    scene = dataclasses.replace(scene, points=12)
    paths = run_scene(scene, tmp_path, log=open(tmp_path / "log.txt", "w"))
    cols = _csv_columns(paths["csv"])
    assert cols["x0"].size == 12
    assert paths["png"].read_bytes()[:4] == b"\x89PNG"
    mp.mp.dps = 30
    for A, T in zip(cols["x0"], cols["period"], strict=True):
        A = mp.mpf(float(A))
        ref = 4 * mp.ellipk(A**2 / (2 * (1 + A**2))) / mp.sqrt(1 + A**2)
        assert T == pytest.approx(float(ref), rel=1e-9)


def test_backbone_of_the_nsd_oscillator_against_closed_forms():
    import math

    from perturb.apps.scene import backbone

    osc = builtin_model("nsd", k=-2.0, mu=0.05, F=2.0)
    # outer-segment orbits, 1 <= x <= x_c = 1 - 2k = 5: harmonic about x_b = 3, period 2 pi
    bb = backbone(osc, [1.5, 2.5, 4.5])
    assert bb["period"] == pytest.approx([2 * math.pi] * 3, rel=1e-10)
    assert bb["x1"] == pytest.approx([4.5, 3.5, 1.5], rel=1e-10)
    # beyond the separatrix x_d = 1 - k + sqrt(k (k - 1)): the orbit visits all three
    # segments; mpmath quadrature of the energy integral over [-A, A] as the reference
    A = 8.0
    k = mp.mpf(-2)

    def G(x):
        x = abs(x)
        return k * x**2 / 2 + ((1 - k) * (x - 1) ** 2 / 2 if x > 1 else 0)

    mp.mp.dps = 30
    half = mp.quad(lambda x: 1 / mp.sqrt(2 * (G(A) - G(x))), [-A, -1, 0, 1, A])
    bb = backbone(osc, [A])
    assert bb["x1"][0] == pytest.approx(-A, rel=1e-10)
    assert bb["period"][0] == pytest.approx(float(2 * half), rel=1e-8)


def test_step_response_scene_of_a_linear_oscillator_against_its_closed_form(tmp_path):
    import numpy as np

    from perturb.apps.scene import load_scene

    scene = load_scene(ROOT / "scenes" / "course_linear_step_response.toml")
    paths = run_scene(scene, tmp_path, log=open(tmp_path / "log.txt", "w"))
    cols = _csv_columns(paths["csv"])
    t = cols["t"]
    z = 0.05
    wd = np.sqrt(1 - z * z)
    ref = 1.0 - np.exp(-z * t) * (np.cos(wd * t) + z / wd * np.sin(wd * t))
    assert np.max(np.abs(cols["x"] - ref)) < 1e-9
    assert paths["png"].read_bytes()[:4] == b"\x89PNG"
    assert "step_response" in paths["report"].read_text()


def test_time_history_scene_against_dop853(tmp_path):
    import dataclasses
    import math

    import numpy as np
    from scipy.integrate import solve_ivp

    from perturb.apps.scene import load_scene

    scene = load_scene(ROOT / "scenes" / "zou_fig5_time_history.toml")
    scene = dataclasses.replace(scene, t=(0.0, 40.0), samples=401)
    paths = run_scene(scene, tmp_path, log=open(tmp_path / "log.txt", "w"))
    cols = _csv_columns(paths["csv"])

    def rhs(t, y):
        x, v = y
        f = -2 * x + 3 * ((x - 1) * (x > 1) + (x + 1) * (x < -1))
        return [v, 2 * math.cos(0.6 * t) - 0.05 * v - f]

    sol = solve_ivp(
        rhs,
        (0, 40),
        [0, 0],
        method="DOP853",
        rtol=1e-12,
        atol=1e-12,
        max_step=0.01,
        t_eval=cols["t"],
    )
    assert np.max(np.abs(cols["x"] - sol.y[0])) < 1e-6


def test_bifurcation_scene_period_one_points_are_periodic_orbits(tmp_path):
    import dataclasses

    import numpy as np

    from perturb.apps.scene import load_scene
    from perturb.solve import periodic_orbits

    scene = load_scene(ROOT / "scenes" / "zou_fig6_bifurcation.toml")
    scene = dataclasses.replace(
        scene, values=(-2.0, -1.0), points=10, transient_periods=100, record_periods=4
    )
    scene = dataclasses.replace(scene, points=10)
    paths = run_scene(scene, tmp_path, log=open(tmp_path / "log.txt", "w"))
    cols = _csv_columns(paths["csv"])
    assert set(np.unique(cols["k"])) == set(np.linspace(-2.0, -1.0, 10))
    assert paths["png"].read_bytes()[:4] == b"\x89PNG"
    # a period-1 attractor at k: its section point is the state of a stable exact orbit
    checked = 0
    for kv in (-2.0, -1.0):
        sel = (cols["k"] == kv) & (cols["period"] == 1)
        if not sel.any():
            continue
        osc = scene.oscillator().with_params(k=kv)
        orbits = [o for o in periodic_orbits(osc) if o.m == 1 and o.max_multiplier < 1]
        x = cols["x"][sel][0]
        assert min(abs(o.y0[0] - x) for o in orbits if o.t0 == 0) < 1e-6
        checked += 1
    assert checked


# ---------------------------------------------------------------------------------------------
# issue 18: friction of the command line (item 8), every HB branch by default (item 5)
NSD_HALF = {"k": -0.5, "mu": 0.05, "F": 2.0}


def _solutions(resp):
    """``(omega, amplitude, mean)`` of every point, sorted (a mirror pair, equal amplitudes,
    by its mean)."""
    return sorted(
        (
            (float(w), float(a), float(m))
            for b in resp.branches
            for w, a, m in zip(b.omega, b.amplitude, b.mean, strict=True)
        ),
        key=lambda s: (s[0], round(s[1], 3), s[2]),
    )


def test_hb_at_listed_frequencies_against_exact_orbits():
    """Numeric HB at exactly the requested frequencies: the same solutions as the exact orbits
    (independent: shooting on the exact flow), to within the H = 15 truncation error."""
    import perturb

    osc = builtin_model("nsd", **NSD_HALF)
    ws = [0.9, 1.3]  # one orbit at 0.9; at 1.3 an in-well one and an asymmetric mirror pair
    hb = perturb.frequency_response(osc, "hb", frequencies=ws)
    exact = perturb.frequency_response(osc, "exact", frequencies=ws)
    got, ref = _solutions(hb), _solutions(exact)
    assert {w for w, _, _ in got} == set(ws)  # exactly the requested values, nothing else
    assert len(got) == len(ref) == 4
    for (w, a, m), (we, ae, me) in zip(got, ref, strict=True):
        assert w == we
        assert a == pytest.approx(ae, rel=1e-3)
        assert m == pytest.approx(me, abs=1e-3 * ae)
    assert sum(abs(m) > 0.1 for _, _, m in got) == 2  # the asymmetric pair is there


def test_residual_traced_approximation_at_listed_frequencies():
    """Second-order mLP (residual-traced) at exact frequencies: the values of its own traced
    curve there (continuation, a different route) and of the exact orbits to its error."""
    import numpy as np

    import perturb

    osc = builtin_model("nsd", **NSD_HALF)
    ws = [0.5, 0.9]
    at = perturb.frequency_response(osc, "mlp", order=2, frequencies=ws)
    got = _solutions(at)
    assert [w for w, _, _ in got] == ws
    traced = perturb.frequency_response(osc, "mlp", (0.45, 1.0), order=2)
    for w, a, _ in got:
        near = []
        for b in traced.branches:
            for j in range(len(b) - 1):
                w0, w1 = b.omega[j], b.omega[j + 1]
                if min(w0, w1) <= w <= max(w0, w1):
                    near.append(
                        np.interp(
                            w,
                            sorted([w0, w1]),
                            [b.amplitude[j], b.amplitude[j + 1]][:: 1 if w0 <= w1 else -1],
                        )
                    )
        assert near and min(abs(v / a - 1) for v in near) < 2e-3
    exact = _solutions(perturb.frequency_response(osc, "exact", frequencies=ws))
    for (w, a, _), (we, ae, _) in zip(got, exact, strict=True):
        assert w == we and a == pytest.approx(ae, rel=1e-2)


def test_frc_hb_returns_every_branch_by_default_and_one_with_one_branch(tmp_path, capsys):
    base = ["frc", "nsd", "--method", "hb", "--harmonics", "5", "--omega", "0.2:2"]
    every, one = tmp_path / "every.csv", tmp_path / "one.csv"
    assert main([*base, "--out", str(every)]) == 0
    assert main([*base, "--one-branch", "--out", str(one)]) == 0
    rows_every = list(csv.DictReader(every.open()))
    rows_one = list(csv.DictReader(one.open()))
    assert {r["branch"] for r in rows_one} == {"0"}
    assert len({r["branch"] for r in rows_every}) >= 3
    # the 42-amplitude cross-well resonance that the connected branch alone misses
    assert max(float(r["amplitude"]) for r in rows_every) > 30
    assert max(float(r["amplitude"]) for r in rows_one) < 10
    capsys.readouterr()


def test_frc_plot_without_out_prints_a_summary_not_the_csv(tmp_path, capsys):
    png = tmp_path / "f.png"
    assert main(["frc", "nsd", "--plot", str(png)]) == 0
    out = capsys.readouterr().out
    assert png.read_bytes()[:4] == b"\x89PNG"
    assert "branch,omega" not in out and len(out.splitlines()) < 30
    assert "branches," in out and "points" in out and str(png) in out


def test_frc_without_plot_or_out_still_prints_the_csv(capsys):
    assert main(["frc", "nsd", "--omega", "0.6,0.9"]) == 0
    assert capsys.readouterr().out.startswith(",".join(CSV_COLUMNS))


def test_frc_method_auto_is_dispatched(monkeypatch, tmp_path, capsys):
    import perturb.solve
    from perturb.response import Branch, Response

    calls = []

    def fake(osc, method, *args, **kwargs):
        calls.append((method, args, kwargs))
        return Response(
            (Branch([1.0, 1.1], [1.0, 1.2], [1.0, 1.2], [0, 0], [1, 1], [0.5, 0.5]),), "auto"
        )

    monkeypatch.setattr(perturb.solve, "frequency_response", fake)
    assert (
        main(
            ["frc", "nsd", "--method", "auto", "--omega", "0.5:2", "--out", str(tmp_path / "a.csv")]
        )
        == 0
    )
    assert calls == [("auto", ([0.5, 2.0],), {"points": 2000})]
    capsys.readouterr()


@pytest.mark.slow
def test_frc_method_auto_end_to_end(tmp_path, capsys):
    out = tmp_path / "auto.csv"
    assert main(["frc", "duffing", "--method", "auto", "--omega", "0.5:2", "--out", str(out)]) == 0
    rows = list(csv.DictReader(out.open()))
    assert rows and "note: " in capsys.readouterr().err


def test_help_lists_methods_and_defaults(capsys):
    from perturb.methods import METHODS

    with pytest.raises(SystemExit) as info:
        main(["derive", "--help"])
    assert info.value.code == 0
    text = capsys.readouterr().out
    for name in METHODS:
        assert f"\n  {name} " in text
    assert "modified Lindstedt-Poincare" in text and "multiple scales" in text
    with pytest.raises(SystemExit):
        main(["frc", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    for default in ("(default: hb1)", "(default: 0.2:2.0)", "(default: 2000)", "(default: 15"):
        assert default in text
    assert "auto " in text and "--one-branch" in text


def test_compare_names_branch_numbers_not_a_bare_count():
    from perturb.comparison import compare
    from perturb.response import Branch, Response

    w = [1.0, 1.5, 2.0]
    ref = Response((Branch(w, [1.0] * 3, [1.0] * 3, [0.0] * 3, [True] * 3, [0.5] * 3),), "ref")
    far = Branch(w, [9.0] * 3, [9.0] * 3, [0.0] * 3, [True] * 3, [0.5] * 3)
    near = Branch(w, [1.0] * 3, [1.0] * 3, [0.0] * 3, [True] * 3, [0.5] * 3)
    text = str(compare(Response((far, near), "x"), ref))
    assert "spurious branches: 1 (branch #0)" in text
    assert "missed reference branches: none" in text


@pytest.mark.parametrize(
    "text, fragment",
    [
        ("[model]\nequation=3", "[model] equation = 3: expected a string"),
        ("[model]\nname='nsd'\n[params]\nk=true", "parameter 'k' = True"),
        ("[ask]\npoints=5", "[ask] points = 5: expected an integer in [10, 1e6]"),
        ("[ask]\npoints=100.0", "[ask] points = 100.0: expected an integer"),
        ("[ask]\nkind='time_history'\ny0=[0, inf]", "[ask] y0 = [0, inf]: expected [x0, v0]"),
        ("[ask]\nkind='time_history'\nt=[0, nan]", "[ask] t = [0, nan]: expected [low, high]"),
        (
            "[ask]\nkind='bifurcation_diagram'\nrecord_periods=0",
            "[ask] record_periods = 0: expected an integer in [1, 10000]",
        ),
        (
            "[ask]\nkind='bifurcation_diagram'\nparameter='2k'\nvalues=[0, 1]",
            "[ask] parameter = '2k': expected the name of a parameter",
        ),
        ("[method]\norder='2'", "[method] order = '2': expected a positive integer"),
        ("[method]\nall_branches=1", "[method] all_branches = 1: expected true or false"),
        (
            "[ask]\nkind='time_history'\n[method]\nname='exact'\norder=2",
            "[method] order: not options of the integrator 'exact'",
        ),
        ("[compare]\nreference='hb1'", "[compare] reference = 'hb1': expected 'exact'"),
        ("[compare]\nmethods=['nope']", "[compare] methods: 'nope' is not a method"),
        ("[compare]\nmethods=['hb1']", "[compare] methods = ['hb1']: a method twice"),
        ("[compare]\nreference='exact'\nmethods=['exact']", "'exact' is already the reference"),
        ("[method]\nname='exact'\n[compare]\nreference='exact'", "compare the exact response"),
        ("[ask]\nkind='backbone'\n[compare]\nreference='exact'", "[compare] does not apply"),
        ("[ask]\nkind='backbone'\n[plot]\nmean=true", "[plot] does not apply to kind 'backbone'"),
        ("[plot]\nmean=1", "[plot] mean = 1: expected true or false"),
        ("[plot]\nzoom=[1, 0, 2, 3]", "[plot] zoom = [1, 0, 2, 3]: expected [omega_lo"),
        ("[output]\ncsv='a.csv'\npng='a.csv'", "[output] two outputs are both written to 'a.csv'"),
        ("[accuracy]\nspots=[0.5, 'x']", "[accuracy] spots = [0.5, 'x']: expected a list"),
    ],
)
def test_each_scene_table_names_the_bad_value(text, fragment):
    if not text.startswith("[model]"):
        text = "[model]\nname='nsd'\n" + text
    with pytest.raises(PerturbError) as info:
        parse_scene(text, "t.toml")
    assert str(info.value).startswith("scene t.toml: ") and fragment in str(info.value)
