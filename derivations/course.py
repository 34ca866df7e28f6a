r"""The course: the classical results of a nonlinear-vibration course, rederived by perturb and
each measured against an exact or numerical reference.

The results are those of the course notes summarised in docs/references.md §2 (with the −10/−12
remark of §3): the free Duffing frequency by every method against the exact elliptic-integral
frequency; the quadratic-plus-cubic oscillator, where one-term harmonic balance loses the
quadratic term; the forced Duffing oscillator at primary resonance (multiple-scales slow flow,
stability, jumps) and at superharmonic resonance, against shooting; the van der Pol limit cycle
and its forced response curves; the Ince–Strutt chart of the Mathieu equation from Floquet
multipliers with the perturbation transition curves on top.

Only the public perturb API is used. Output (default ``derivations/out/course/``; ``--out``)::

    section.tex              \section{The course}, figures named relative to derivations/out/
    summary.json             the numbers the text quotes (read by tests/test_derivations_course.py)
    *.csv, *.png             tables and figures

Run ``python derivations/course.py`` (about a minute of CPU time) or ``--fast`` (coarser
grids, about 25 s).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import mpmath as mp  # noqa: E402
import numpy as np  # noqa: E402
import sympy as sp  # noqa: E402
from scipy.integrate import solve_ivp  # noqa: E402
from scipy.optimize import brentq, minimize_scalar  # noqa: E402

from perturb import Oscillator, builtin_model, frequency_response  # noqa: E402
from perturb.errors import PerturbError  # noqa: E402
from perturb.methods import (  # noqa: E402
    harmonic_balance,
    krylov_bogoliubov,
    lindstedt_poincare,
    modified_lindstedt,
    single_harmonic_balance,
)
from perturb.methods.harmonic_balance import backbone_series  # noqa: E402
from perturb.methods.multiple_scales import modulation_equations, transition_curves  # noqa: E402
from perturb.model.parsing import real_symbol  # noqa: E402
from perturb.numeric.amplitude import (  # noqa: E402
    approximation_response as traced_response,
)
from perturb.numeric.balance import solve_residuals  # noqa: E402
from perturb.numeric.stability import expm2  # noqa: E402
from perturb.simulate.flows.base import ODEFlow  # noqa: E402
from perturb.simulate.orbits.shooting import limit_cycle, periodic_orbit  # noqa: E402

DEFAULT_OUT = Path(__file__).resolve().parent / "out" / "course"

# Parameters of the studies (non-dimensional, builtin models' names)
DUFFING_EPS = (0.1, 1.0, 10.0)
PRIMARY = {"mu": 0.04, "alpha": 0.2, "F": 0.04, "omega0": 1.0}
PRIMARY_WINDOW = (0.85, 1.2)
SUPER = {"mu": 0.02, "alpha": 0.05, "F": 1.0, "omega0": 1.0}
SUPER_WINDOW = (0.33, 0.37)
VDP_EPS_FULL = (0.01, 0.02, 0.05, 0.1, 0.2, 0.3, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 4.0, 5.0)
VDP_EPS_FAST = (0.01, 0.1, 0.3, 1.0, 2.0, 5.0)
FORCED_VDP_EPS = 0.05
FORCED_VDP_F = (0.4, 0.8, 1.2)
MATHIEU_EPS_TABLE = (0.1, 0.5, 1.0)


# ------------------------------------------------------------------------------- output --
class Out:
    """The output folder: files, the LaTeX body and the numbers for summary.json."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        folder.mkdir(parents=True, exist_ok=True)
        self.tex: list[str] = []
        self.summary: dict = {}

    def ref(self, name: str) -> str:
        # the assembled document lives in the parent folder (derivations/out/)
        return f"{self.folder.name}/{name}"

    def csv(self, name: str, header: Sequence[str], rows: Iterable[Sequence]) -> None:
        with open(self.folder / name, "w", newline="") as fh:
            w = csv.writer(fh, lineterminator="\n")
            w.writerow(header)
            for row in rows:
                w.writerow([repr(float(v)) if isinstance(v, float) else v for v in row])

    def figure(self, fig, name: str, caption: str, width: str = "0.85\\textwidth") -> None:
        fig.savefig(self.folder / name, dpi=150, bbox_inches="tight")
        plt.close(fig)
        label = "fig:course-" + name.rsplit(".", 1)[0]
        self.tex.append(
            "\\begin{figure}[htbp]\n\\centering\n"
            f"\\includegraphics[width={width}]{{{self.ref(name)}}}\n"
            f"\\caption{{{caption}}}\\label{{{label}}}\n\\end{{figure}}\n"
        )

    def add(self, text: str) -> None:
        self.tex.append(text.strip("\n") + "\n")

    def finish(self) -> None:
        # \sloppy: long \texttt names must not overrun the margin; grouped so that it does not
        # leak into the sections input after this one
        head, *body = self.tex
        text = "\n".join([head, "\\begingroup\\sloppy", *body, "\\endgroup"])
        (self.folder / "section.tex").write_text(text + "\n")
        (self.folder / "summary.json").write_text(json.dumps(self.summary, indent=2) + "\n")


def sci(x: float, digits: int = 2) -> str:
    """``x`` for LaTeX: plain for moderate values, ``m\\times10^{e}`` otherwise."""
    if x == 0 or not math.isfinite(x):
        return f"{x:g}"
    if 1e-3 <= abs(x) < 1e4:
        return f"{x:.{digits + 2}g}"
    m, e = f"{x:.{digits}e}".split("e")
    return f"{m}\\times10^{{{int(e)}}}"


_GREEK = {"eps": r"\varepsilon", "epsilon": r"\varepsilon", "phi": r"\varphi"}


def tex(expr: sp.Basic) -> str:
    names = {s: _GREEK[s.name] for s in sp.sympify(expr).free_symbols if s.name in _GREEK}
    return sp.latex(expr, symbol_names=names)


def numeric(expr: sp.Expr, *args: sp.Symbol) -> Callable:
    return sp.lambdify(args, expr, modules="numpy")


# ============================================================ 1. free Duffing oscillator --
def exact_duffing_omega(eps: float, a: float = 1.0) -> float:
    r"""x'' + x + eps x^3 = 0 with x(0) = a, x'(0) = 0.

    x = a cn(W t | m) solves it when W^2 (1 - 2m) = 1 and 2 m W^2 / a^2 = eps (cn'' = -(1 - 2m)
    cn - 2m cn^3), so W^2 = 1 + eps a^2, m = eps a^2 / (2 (1 + eps a^2)); cn has period 4K(m),
    hence omega = 2 pi / T = pi W / (2 K(m)).
    """
    m = eps * a**2 / (2 * (1 + eps * a**2))
    return float(mp.pi * mp.sqrt(1 + eps * a**2) / (2 * mp.ellipk(m)))


def hb_frequency_at_turning_point(osc: Oscillator, harmonics: Sequence[int], a: float) -> float:
    """Free harmonic balance with the waveform's value at tau = 0 fixed to ``a`` (x(0) = a, the
    turning point, the convention of the exact solution)."""
    hb = harmonic_balance(osc, harmonics)
    guess = {u: 0.0 for u in hb.unknowns}
    guess[hb.amplitude] = a
    guess[hb.frequency] = math.sqrt(1 + 0.75 * float(osc.params["eps"]) * a**2)
    sol = solve_residuals(hb, guess, extra=[hb.waveform.xreplace({hb.tau: 0}) - a])
    return sol[hb.frequency]


def duffing_free(out: Out) -> None:
    osc = Oscillator.parse("x'' + x + eps*x**3 = 0")
    eps = real_symbol("eps")
    exact = {e: exact_duffing_omega(e) for e in DUFFING_EPS}
    rows: list[tuple[str, str, Callable[[float], float]]] = []

    def backbone(ap) -> Callable[[float], float]:
        f = numeric(ap.backbone.xreplace({ap.amplitude: 1}), eps)
        return lambda e: float(f(e))

    lp = {n: lindstedt_poincare(osc, n, amplitude="initial") for n in (1, 2, 3)}
    mlp = {n: modified_lindstedt(osc, n, amplitude="initial") for n in (1, 2)}
    kb = krylov_bogoliubov(osc)
    for n, ap in lp.items():
        rows.append((f"L-P order {n}", tex(sp.expand(ap.backbone)), backbone(ap)))
    for n, ap in mlp.items():
        rows.append((f"mLP order {n}", tex(ap.backbone), backbone(ap)))
    for label, hs in (("HB 1 term", (1,)), ("HB 3 terms", (1, 3, 5))):
        rows.append(
            (
                label,
                "x = " + " + ".join(f"a_{{{h}}}\\cos {h if h > 1 else ''}\\tau" for h in hs),
                lambda e, hs=hs: hb_frequency_at_turning_point(osc.with_params(eps=e), hs, 1.0),
            )
        )
    rows.append(("averaging (K-B)", tex(kb.backbone), backbone(kb)))

    table, csv_rows, summary = [], [], {"exact": exact}
    for label, _, f in rows:
        vals = {e: f(e) for e in DUFFING_EPS}
        errs = {e: vals[e] / exact[e] - 1 for e in DUFFING_EPS}
        summary[label] = {"omega": vals, "rel_error": errs}
        csv_rows += [(label, e, vals[e], exact[e], errs[e]) for e in DUFFING_EPS]
        cells = " & ".join(f"{vals[e]:.6f} & ${sci(errs[e], 1)}$" for e in DUFFING_EPS)
        table.append(f"{label} & {cells} \\\\")
    out.csv(
        "duffing_free.csv", ("method", "eps", "omega", "omega_exact", "relative_error"), csv_rows
    )
    out.summary["duffing_free"] = summary
    formulas = "\n".join(
        f"  {label}: & $\\omega = {formula}$ \\\\"
        for label, formula, _ in rows
        if not label.startswith("HB")
    )
    exact_row = " & ".join(f"\\multicolumn{{2}}{{c}}{{{exact[e]:.6f}}}" for e in DUFFING_EPS)
    heads = " & ".join(f"\\multicolumn{{2}}{{c}}{{$\\varepsilon = {e:g}$}}" for e in DUFFING_EPS)
    subheads = " & ".join(["$\\omega$ & rel.\\ error"] * len(DUFFING_EPS))
    out.add(
        rf"""
\subsection{{Free Duffing oscillator: every method against the exact frequency}}
For $x'' + x + \varepsilon x^3 = 0$ with $x(0) = a$, $x'(0) = 0$ (the amplitude is the turning
point, $a = \max|x| = 1$ throughout), $x = a\,\mathrm{{cn}}(W t \mid m)$ is exact: since
$\mathrm{{cn}}'' = -(1 - 2m)\,\mathrm{{cn}} - 2m\,\mathrm{{cn}}^3$, matching the linear and cubic
terms gives $W^2(1 - 2m) = 1$ and $2mW^2/a^2 = \varepsilon$, so
\[
  W^2 = 1 + \varepsilon a^2,\qquad m = \frac{{\varepsilon a^2}}{{2(1 + \varepsilon a^2)}},\qquad
  \omega_{{\mathrm{{exact}}}} = \frac{{2\pi}}{{4K(m)/W}}
  = \frac{{\pi\sqrt{{1 + \varepsilon a^2}}}}{{2K(m)}},
\]
with $K$ the complete elliptic integral of the first kind (parameter convention of mpmath's
\texttt{{ellipk}}). Lindstedt--Poincar\'e (L-P) and the modified method (mLP) are used in the
same convention (\texttt{{amplitude="initial"}}); harmonic balance (HB, odd harmonics $1$ and
$1,3,5$) is solved with the extra condition $x(0) = 1$; first-order Krylov--Bogoliubov averaging
has only one amplitude at its order (it coincides with L-P order 1). The formulas, with
$A = a$:
\begin{{center}}
\begin{{tabular}}{{ll}}
{formulas}
\end{{tabular}}
\end{{center}}
\begin{{table}}[htbp]
\centering\small
\begin{{tabular}}{{l{"rr" * len(DUFFING_EPS)}}}
\toprule
 & {heads} \\
method & {subheads} \\
\midrule
exact & {exact_row} \\
{chr(10).join(table)}
\bottomrule
\end{{tabular}}
\caption{{Frequency of $x'' + x + \varepsilon x^3 = 0$, $x(0) = 1$: exact (elliptic integral)
against the approximations; relative error $\omega/\omega_{{\mathrm{{exact}}}} - 1$
(\texttt{{duffing\_free.csv}}).}}\label{{tab:course-duffing}}
\end{{table}}
The plain L-P series is asymptotic in $\varepsilon a^2$: excellent at $\varepsilon = 0.1$, useless
at $\varepsilon = 10$, where each added order makes it worse. The modified method's
$\alpha$-expansion and harmonic balance stay accurate for large $\varepsilon$.
"""
    )


# ============================================= 2. quadratic + cubic: the -10 versus -12 remark --
def quadratic_cubic(out: Out) -> None:
    qc = builtin_model("quadratic_cubic", omega0=None, alpha2=None, alpha3=None)
    w0, a2, a3 = (real_symbol(n) for n in ("omega0", "alpha2", "alpha3"))
    a = sp.Symbol("a", positive=True)

    def kappa(omega: sp.Expr, amp: sp.Symbol) -> sp.Expr:
        # omega = w0 [1 + kappa a^2 / (24 w0^4)] + O(a^3): kappa from the a^2 coefficient
        c2 = sp.expand(omega).coeff(amp, 2)
        return sp.expand(sp.simplify(c2 * 24 * w0**3))

    lp = lindstedt_poincare(qc, 2)
    ms = modulation_equations(qc, 2)
    ms_omega = ms.backbone.xreplace({ms.epsilon: 1})
    kb = krylov_bogoliubov(qc)
    hb1 = backbone_series(harmonic_balance(qc), 2)
    hb1b = backbone_series(harmonic_balance(qc, (1,), bias=True), 2)
    hb3 = backbone_series(harmonic_balance(qc, (1, 2), bias=True), 2)
    results = [
        ("Lindstedt--Poincar\\'e, order 2", kappa(lp.backbone, lp.amplitude)),
        ("multiple scales, order 2", kappa(ms_omega, ms.amplitude)),
        (
            "HB, $c_0 + a_1\\cos\\tau + a_2\\cos 2\\tau$ (3 terms)",
            kappa(hb3.frequency, hb3.amplitude),
        ),
        ("HB, $c_0 + a_1\\cos\\tau$ (bias + 1 harmonic)", kappa(hb1b.frequency, hb1b.amplitude)),
        ("HB, $a_1\\cos\\tau$ (1 term)", kappa(hb1.frequency, hb1.amplitude)),
        ("averaging (K-B), first order", kappa(kb.backbone, kb.amplitude)),
    ]
    drift = {u.name: tex(v.xreplace({hb3.amplitude: a})) for u, v in hb3.unknowns.items()}
    rows = "\n".join(f"{name} & ${tex(k)}$ \\\\" for name, k in results)
    coeffs = {
        name: {"alpha2^2": int(k.coeff(a2, 2)), "alpha3*omega0^2": int(k.coeff(a3).coeff(w0, 2))}
        for name, k in results
    }
    out.summary["quadratic_cubic"] = {
        "kappa": {name: str(k) for name, k in results},
        "coefficients": coeffs,
        "lp_equals_hb3": bool(sp.expand(results[0][1] - results[2][1]) == 0),
        "lp_equals_ms": bool(sp.expand(results[0][1] - results[1][1]) == 0),
        "hb1_differs": bool(sp.expand(results[0][1] - results[4][1]) != 0),
    }
    out.csv(
        "quadratic_cubic.csv",
        ("method", "kappa", "alpha2^2 coefficient", "alpha3 omega0^2 coefficient"),
        [
            (name.replace("\\'", "").replace("$", ""), str(k), c["alpha2^2"], c["alpha3*omega0^2"])
            for (name, k), c in zip(results, coeffs.values(), strict=True)
        ],
    )
    out.add(
        rf"""
\subsection{{Quadratic and cubic stiffness: $-10$ against $-12$}}
For $x'' + \omega_0^2 x + \alpha_2 x^2 + \alpha_3 x^3 = 0$ every method gives, for the amplitude
$a$ of the first harmonic,
\[
  \omega = \omega_0\Big[1 + \frac{{\kappa\, a^2}}{{24\,\omega_0^4}}\Big] + O(a^3),
\]
and the methods differ in $\kappa$ (computed symbolically by each engine; harmonic balance
expanded in $a$ by \texttt{{backbone\_series}}):
\begin{{center}}
\begin{{tabular}}{{ll}}
\toprule
method & $\kappa$ \\
\midrule
{rows}
\bottomrule
\end{{tabular}}
\end{{center}}
Lindstedt--Poincar\'e, multiple scales and three-term harmonic balance agree exactly,
$\kappa = 9\alpha_3\omega_0^2 - 10\alpha_2^2$. The quadratic force $\alpha_2 x^2$ acts on the
first harmonic only through the mean and the second harmonic it creates, which the three-term
ansatz carries: $c_0 = {drift["c_0"]}$, $a_2 = {drift["a_2"]}$, $b_2 = {drift.get("b_2", "0")}$,
the L-P drift $-\frac{{\alpha_2 a^2}}{{2\omega_0^2}}[1 - \frac13\cos 2\omega t]$. A single cosine
(and first-order averaging) loses $\alpha_2$ entirely; with the bias alone the mean is balanced
but the second harmonic is not, which gives the $-12\alpha_2^2$ quoted as the ``one-term''
result in the literature study, against the correct $-10\alpha_2^2$.
"""
    )


# ========================================================== 3. forced Duffing, primary --
def ms_primary_curve(me, osc: Oscillator, n: int):
    """The first-order multiple-scales response curve by amplitude, with slow-flow stability.

    The phase-eliminated relation R(a, Omega) = 0 is a quadratic in Omega at fixed a; its two
    roots meet at the top of the resonance curve. Returns the curve (Omega, a, stable) ordered
    along it, the folds (R = dR/da = 0) and the callables used.
    """
    W = me.frequency
    vals = {s: v for s, v in osc.substitutions().items() if s != W}
    a, g = me.amplitude, me.phase
    R = sp.expand(me.in_frequency(me.response).xreplace(vals))
    poly = sp.Poly(R, W)
    if poly.degree() != 2:
        raise PerturbError(f"expected a quadratic in {W}, got degree {poly.degree()}")
    cs = [numeric(c, a) for c in poly.all_coeffs()]
    Ra = numeric(sp.diff(R, a), a, W)

    def roots(am: float) -> tuple[float, float] | None:
        c2, c1, c0 = (float(c(am)) for c in cs)
        disc = c1 * c1 - 4 * c2 * c0
        if disc < 0:
            return None
        r = math.sqrt(disc)
        return tuple(sorted(((-c1 - r) / (2 * c2), (-c1 + r) / (2 * c2))))

    def disc(am: float) -> float:
        c2, c1, c0 = (float(c(am)) for c in cs)
        return c1 * c1 - 4 * c2 * c0

    # the top of the curve: the largest amplitude with real roots
    grid = np.geomspace(1e-4, 100.0, 2000)
    ok = np.array([disc(x) >= 0 for x in grid])
    last = int(np.nonzero(ok)[0][-1])
    a_top = brentq(disc, grid[last], grid[last + 1], xtol=1e-15)
    amps = a_top * np.sin(np.linspace(1e-4, np.pi / 2, n)) ** 0.5
    amps[-1] = a_top * (1 - 1e-12)
    lo = np.array([roots(x)[0] for x in amps])
    hi = np.array([roots(x)[1] for x in amps])
    curve_W = np.concatenate([lo, hi[::-1]])
    curve_a = np.concatenate([amps, amps[::-1]])

    # stability: the phase from the steady-state equations, then the polar Jacobian
    coeffs = numeric([me.in_frequency(c).xreplace(vals) for c in me.response_coefficients], a, W)
    jac = numeric([me.in_frequency(e).xreplace(vals) for e in me.jacobian()], a, g, W)

    def stable(am: float, Wv: float) -> bool:
        p1, c1, s1, p2, c2, s2 = (float(v) for v in coeffs(am, Wv))
        cos_g, sin_g = np.linalg.solve([[c1, s1], [c2, s2]], [-p1, -p2])
        gam = math.atan2(sin_g, cos_g)
        eig = np.linalg.eigvals(np.asarray(jac(am, gam, Wv), dtype=float).reshape(2, 2))
        return bool(np.all(eig.real < 0))

    curve_s = np.array([stable(x, w) for x, w in zip(curve_a, curve_W, strict=True)])
    # folds on the upper root: dR/da = 0 (then dOmega/da = -R_a/R_Omega = 0)
    fa = np.linspace(amps[0], amps[-2], 4000)
    fv = np.array([Ra(x, roots(x)[1]) for x in fa])
    folds = []
    for i in np.nonzero(np.sign(fv[:-1]) * np.sign(fv[1:]) < 0)[0]:
        af = brentq(lambda x: Ra(x, roots(x)[1]), fa[i], fa[i + 1], xtol=1e-14)
        folds.append((roots(af)[1], af))
    return curve_W, curve_a, curve_s, sorted(folds)


def primary_resonance(out: Out, fast: bool) -> None:
    osc = builtin_model("duffing", **PRIMARY)
    me = modulation_equations(osc, 1)
    mu, alpha, F = PRIMARY["mu"], PRIMARY["alpha"], PRIMARY["F"]
    a, sig = me.amplitude, me.sigma
    # the course's form, with Nayfeh's 2 eps mu_N = mu and k = F (omega0 = 1 here, symbols kept)
    w0s, mus, als, Fs = (real_symbol(n) for n in ("omega0", "mu", "alpha", "F"))
    course = ((mus / 2) ** 2 + (sig - 3 * als * a**2 / (8 * w0s)) ** 2) * a**2 - Fs**2 / (
        4 * w0s**2
    )
    ratio = sp.cancel(me.response / course)
    same_as_course = not ratio.has(a, sig)
    W_ms, a_ms, s_ms, folds_ms = ms_primary_curve(me, osc, 300 if fast else 1200)

    t0 = time.perf_counter()
    if fast:
        opts = {"sweep_points": 0, "ds_max": 0.05, "tol": 1e-8, "approximation_seeds": 3}
    else:
        opts = {"sweep_points": 30, "ds_max": 0.01, "approximation_seeds": 8}
    resp = frequency_response(
        osc,
        "exact",
        Omega=PRIMARY_WINDOW,
        approximation=single_harmonic_balance(osc),
        branch_points=False,
        progress=False,
        **opts,
    )
    exact_seconds = time.perf_counter() - t0
    resp.to_csv(out.folder / "duffing_primary_exact.csv")
    out.csv(
        "duffing_primary_ms.csv",
        ("omega", "amplitude", "stable"),
        [(float(w), float(x), int(s)) for w, x, s in zip(W_ms, a_ms, s_ms, strict=True)],
    )
    folds_ex = sorted(resp.folds)
    jumps = {
        "ms": {"up_sweep_jump_down": folds_ms[-1][0], "down_sweep_jump_up": folds_ms[0][0]},
        "exact": {"up_sweep_jump_down": folds_ex[-1][0], "down_sweep_jump_up": folds_ex[0][0]},
    }
    out.summary["primary"] = {
        "params": PRIMARY,
        "ms_response_is_course_form": same_as_course,
        "ms_folds": folds_ms,
        "exact_folds": [list(f) for f in folds_ex],
        "jumps": jumps,
        "ms_peak_amplitude": float(a_ms.max()),
        "exact_seconds": exact_seconds,
    }

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for i, b in enumerate(resp.branches):
        for mask, style in ((b.stable, "-"), (~b.stable, ":")):
            y = np.where(mask, b.first_harmonic_amplitude, np.nan)
            lab = f"exact (shooting), {'stable' if style == '-' else 'unstable'}"
            ax.plot(b.omega, y, "k" + style, lw=2.2, alpha=0.45, label=lab if i == 0 else None)
    for mask, style, lab in ((s_ms, "-", "MMS, stable"), (~s_ms, "--", "MMS, unstable")):
        ax.plot(W_ms, np.where(mask, a_ms, np.nan), "C0" + style, lw=1.2, label=lab)
    bb = numeric(me.in_frequency(me.backbone).xreplace(osc.substitutions()), a)
    ab = np.linspace(0, a_ms.max() * 1.05, 100)
    ax.plot(bb(ab) * np.ones_like(ab), ab, "C2-.", lw=0.8, label="backbone")
    for (w, x), lab in zip(folds_ms, ("jump up", "jump down"), strict=False):
        ax.plot(w, x, "C3o", ms=5)
        ax.annotate(lab, (w, x), textcoords="offset points", xytext=(6, -12), fontsize=8)
    for w, _ in folds_ex:
        ax.axvline(w, color="0.5", lw=0.6, ls=":")
    ax.set_xlim(*PRIMARY_WINDOW)
    ax.set_xlabel(r"forcing frequency $\Omega$")
    ax.set_ylabel("first-harmonic amplitude")
    ax.legend(fontsize=8, loc="upper left")
    ax.set_title(rf"$x'' + {mu}x' + x + {alpha}x^3 = {F}\cos\Omega t$", fontsize=10)

    rows = "\n".join(
        f"{what} & {jumps['ms'][key]:.5f} & {jumps['exact'][key]:.5f} & "
        f"${sci(jumps['ms'][key] / jumps['exact'][key] - 1, 1)}$ \\\\"
        for key, what in (
            ("down_sweep_jump_up", "jump up (sweeping down), lower fold"),
            ("up_sweep_jump_down", "jump down (sweeping up), upper fold"),
        )
    )
    J = me.jacobian()
    out.add(
        rf"""
\subsection{{Forced Duffing oscillator: primary resonance and jumps}}
The builtin \texttt{{duffing}} model $x'' + \mu x' + \omega_0^2 x + \alpha x^3 = F\cos\Omega t$ at
$\mu = {mu}$, $\omega_0 = 1$, $\alpha = {alpha}$, $F = {F}$. First-order multiple scales
(automatic weak-nonlinearity scaling, $\Omega = \omega_0 + \varepsilon\sigma$, $\varepsilon = 1$ at
the end; $x \approx a\cos(\Omega t - \gamma)$) gives the slow flow
\[
  \dot a = {tex(me.polar[0])},\qquad
  \dot\gamma = {tex(me.polar[1])},
\]
whose fixed points satisfy (phase eliminated)
\[
  0 = {tex(me.response)}.
\]
This is
{"" if same_as_course else "not "}a constant multiple of the course's
$[\mu_N^2 + (\sigma - \frac{{3\alpha a^2}}{{8\omega_0}})^2]a^2 = \frac{{k^2}}{{4\omega_0^2}}$ with
Nayfeh's $2\mu_N = \mu$ and $k = F$. Stability is decided by the eigenvalues of the slow-flow
Jacobian
\[
  J = \begin{{pmatrix}} {tex(J[0, 0])} & {tex(J[0, 1])} \\ {tex(J[1, 0])} & {tex(J[1, 1])}
  \end{{pmatrix}}
\]
at each fixed point; $\det J = 0$ where the curve has a vertical tangent, and the upper and lower
folds are the jump frequencies of slow sweeps. The reference is the exact frequency response
(\texttt{{frequency\_response(osc, "exact")}}: shooting on the equation of motion with
pseudo-arclength continuation, Floquet multipliers for stability),
Fig.~\ref{{fig:course-duffing_primary}}.
\begin{{center}}
\begin{{tabular}}{{lrrr}}
\toprule
 & MMS $\Omega$ & exact $\Omega$ & rel.\ difference \\
\midrule
{rows}
\bottomrule
\end{{tabular}}
\end{{center}}
The first-order theory puts the jumps within a few per cent; its error is of the order of the
frequency shift $3\alpha a^2/8$ it predicts (the first-order peak amplitude
$a = F/(\mu\omega_0) = {a_ms.max():.3f}$ ignores the $\Omega$ in the damping force
$\mu\Omega a$).
"""
    )
    out.figure(
        fig,
        "duffing_primary.png",
        "Primary resonance of the forced Duffing oscillator: first-order multiple scales "
        "(solid stable, dashed unstable; dots at the folds) against the exact response by "
        "shooting and continuation (grey; dotted lines at its folds).",
    )


# ====================================================== 4. forced Duffing, superharmonic --
def shooting_sweep(osc: Oscillator, freqs: np.ndarray, y_start, harmonic: int) -> np.ndarray:
    """Follow the periodic orbit along ``freqs`` (each orbit seeds the next); where shooting
    fails (a fold passed) settle on the attractor by integrating 80 forcing periods first.
    Returns rows (Omega, harmonic amplitude, max|x|, stable)."""
    rows, y = [], np.asarray(y_start, dtype=float)
    for W in freqs:
        flow = ODEFlow(osc, Omega=float(W), rtol=1e-9, atol=1e-10)
        try:
            orb = periodic_orbit(flow, y, tol=1e-9)
            if not orb.is_stable:
                raise PerturbError("unstable: not what a sweep follows")
        except PerturbError:
            y = flow(y, 0.0, 80 * 2 * np.pi / W).y
            orb = periodic_orbit(flow, y, tol=1e-9)
        y = orb.y0
        _, x, _ = orb.sample(256)
        spec = np.abs(np.fft.rfft(x)) / 128
        rows.append((float(W), float(spec[harmonic]), orb.amplitude, orb.is_stable))
    return np.array(rows)


def _refined_peak(f, grid: np.ndarray, at: float) -> tuple[float, float]:
    """The maximum of ``f`` between the grid neighbours of ``at`` (bounded Brent search, at
    most 40 evaluations), or the sampled value when the search finds nothing higher."""
    k = int(np.argmin(np.abs(grid - at)))
    lo, hi = float(grid[max(k - 1, 0)]), float(grid[min(k + 1, grid.size - 1)])
    best = (at, float(f(at)))
    res = minimize_scalar(
        lambda W: -f(W), bounds=(lo, hi), method="bounded", options={"xatol": 1e-5, "maxiter": 40}
    )
    if -res.fun > best[1]:
        best = (float(res.x), float(-res.fun))
    return best


def superharmonic(out: Out, fast: bool) -> None:
    osc = builtin_model("duffing", **SUPER)
    me = modulation_equations(osc, 1, resonance="superharmonic")
    n = 25 if fast else 161
    freqs = np.linspace(*SUPER_WINDOW, n)
    ms_rows = []
    for W in freqs:
        for st in me.steady_states(float(W), amplitude_range=(1e-4, 10.0), points=1500):
            ms_rows.append((float(W), st.amplitude, int(st.stable)))
    ms_arr = np.array(ms_rows)
    m = 17 if fast else 81
    sweep = np.linspace(*SUPER_WINDOW, m)
    F = SUPER["F"]
    start = [F / (1 - sweep[0] ** 2), 0.0]
    up = shooting_sweep(osc, sweep, start, 3)
    down = shooting_sweep(osc, sweep[::-1], [F / (1 - sweep[-1] ** 2), 0.0], 3)
    out.csv("duffing_superharmonic_ms.csv", ("omega", "a_superharmonic", "stable"), ms_rows)
    out.csv(
        "duffing_superharmonic_exact.csv",
        ("sweep", "omega", "a_superharmonic", "max_abs_x", "stable"),
        [("up", *r) for r in up] + [("down", *r) for r in down],
    )
    i_ms, i_ex = int(np.argmax(ms_arr[:, 1])), int(np.argmax(up[:, 1]))
    # the peaks refined between the grid neighbours of the sampled maxima, so that the
    # sentence on their distance and ratio does not depend on the grid (17 points in --fast)
    ms_peak = _refined_peak(
        lambda W: max(
            (st.amplitude for st in me.steady_states(W, amplitude_range=(1e-4, 10.0), points=1500)),
            default=0.0,
        ),
        freqs,
        float(ms_arr[i_ms, 0]),
    )
    y_peak = [F / (1 - float(up[i_ex, 0]) ** 2), 0.0]
    ex_peak = _refined_peak(
        lambda W: float(shooting_sweep(osc, np.array([W]), y_peak, 3)[0, 1]),
        sweep,
        float(up[i_ex, 0]),
    )
    W_check = float(sweep[np.argmin(np.abs(sweep - 0.34))])
    ms_check = [s.amplitude for s in me.steady_states(W_check)]
    ex_check = float(up[np.argmin(np.abs(up[:, 0] - W_check)), 1])
    # the sweeps differ only where two stable orbits coexist (hysteresis, jumps)
    hysteresis = float(np.max(np.abs(up[:, 1] - down[::-1, 1])))
    ms_unstable = int(np.sum(ms_arr[:, 2] == 0))
    out.summary["superharmonic"] = {
        "hysteresis": hysteresis,
        "ms_unstable_points": ms_unstable,
        "params": SUPER,
        "ms_peak": list(ms_peak),
        "exact_peak_up_sweep": [float(up[i_ex, 0]), float(up[i_ex, 1])],
        "exact_peak": list(ex_peak),
        "check_omega": W_check,
        "ms_at_check": ms_check,
        "exact_at_check": ex_check,
    }

    fig, ax = plt.subplots(figsize=(7, 4.2))
    st = ms_arr[:, 2] > 0
    ax.plot(ms_arr[st, 0], ms_arr[st, 1], "C0.", ms=4, label="MMS, stable")
    ax.plot(ms_arr[~st, 0], ms_arr[~st, 1], "C0x", ms=4, label="MMS, unstable")
    ax.plot(up[:, 0], up[:, 1], "k-", lw=1.5, alpha=0.6, label="shooting, sweep up")
    ax.plot(down[:, 0], down[:, 1], "C3--", lw=1.0, label="shooting, sweep down")
    ax.set_xlabel(r"forcing frequency $\Omega$")
    ax.set_ylabel(r"amplitude of the $3\Omega$ harmonic")
    ax.legend(fontsize=8)
    ax.set_title(
        rf"$x'' + {SUPER['mu']}x' + x + {SUPER['alpha']}x^3 = {F:g}\cos\Omega t$, "
        r"$3\Omega \approx \omega_0$",
        fontsize=10,
    )
    L = me.definitions[0]
    d_peak = ms_peak[0] - ex_peak[0]
    over = 100 * (ms_peak[1] / ex_peak[1] - 1)
    lean = (
        f" and predicts a fold ({ms_unstable} unstable states on the grid)" if ms_unstable else ""
    )
    if hysteresis < 1e-6:
        lean += "; the exact sweeps up and down coincide (no jump at these parameters)"
    else:
        lean += f"; the exact sweeps differ by up to {hysteresis:.3f} (a hysteresis loop)"
    out.add(
        rf"""
\subsection{{Superharmonic resonance}}
The multiple-scales engine treats $3\Omega \approx \omega_0$ with hard forcing: the forcing stays
at order one, $x = 2\Lambda\cos\Omega t + a\cos(3\Omega t - \gamma) + \dots$ with
${tex(L.lhs)} = {tex(L.rhs)}$ and $3\Omega = \omega_0 + \varepsilon\sigma$. The slow flow is
\[
  \dot a = {tex(me.polar[0])},\qquad \dot\gamma = {tex(me.polar[1])}
\]
(the course's superharmonic flow; $\Lambda^3$ drives the $3\Omega$ harmonic and $3\alpha\Lambda^2$
shifts its resonance). Parameters: $\mu = {SUPER["mu"]}$, $\alpha = {SUPER["alpha"]}$,
$F = {F:g}$. The reference is single shooting along the frequency (each orbit seeding the
next, sweeping up and down) with the $3\Omega$ harmonic taken from the orbit by FFT
(Fig.~\ref{{fig:course-duffing_superharmonic}}). At $\Omega = {W_check:.3f}$ on the rising flank,
multiple scales gives $a = {ms_check[0]:.4f}$ against ${ex_check:.4f}$; the peaks, located
to $10^{{-5}}$ in $\Omega$ between the neighbours of the largest of {len(freqs)} (multiple
scales) and {len(sweep)} (shooting) sampled frequencies, are
$a = {ms_peak[1]:.3f}$ at $\Omega = {ms_peak[0]:.4f}$ (first order) and
${ex_peak[1]:.3f}$ at $\Omega = {ex_peak[0]:.4f}$ (exact). The first-order theory follows
the low-frequency flank; near the peak, with the forcing at order one, the interactions of the
harmonics it drops are not small: it places the peak ${d_peak:.4f}$ higher in $\Omega$ and
overestimates it by ${over:.0f}\,\%${lean}.
"""
    )
    out.figure(
        fig,
        "duffing_superharmonic.png",
        "Superharmonic resonance of the forced Duffing oscillator: first-order multiple scales "
        "against periodic orbits by shooting.",
    )


# =========================================================== 5. van der Pol limit cycle --
def vdp_guess(flow: ODEFlow, period: float) -> tuple[np.ndarray, float]:
    """A state at a maximum of x and the period, from a transient started near the cycle:
    shooting from the previous cycle can slide to the equilibrium at large eps."""
    t = np.linspace(0.0, 6 * period, 4000)
    ys = flow(np.array([2.0, 0.0]), 0.0, float(t[-1]), t_eval=t).ys
    peaks = np.nonzero((ys[:-1, 1] > 0) & (ys[1:, 1] <= 0))[0]
    return np.array([ys[peaks[-1], 0], 0.0]), float(t[peaks[-1]] - t[peaks[-2]])


def vanderpol(out: Out, fast: bool) -> None:
    eps_values = VDP_EPS_FAST if fast else VDP_EPS_FULL
    eps = real_symbol("eps")
    vdp = builtin_model("vanderpol")
    kb = krylov_bogoliubov(vdp)
    (a_avg,) = [float(r) for r in sp.solve(kb.slow_flow[0], kb.amplitude)]
    w_avg = float(kb.backbone)
    ms = {n: modulation_equations(vdp, n, epsilon="eps") for n in (2, 4)}
    rows = []
    period = 2 * np.pi
    for e in eps_values:
        osc = builtin_model("vanderpol", eps=e)
        y0, T = vdp_guess(ODEFlow(osc, rtol=1e-8, atol=1e-9), max(period, 2 * np.pi))
        orb = limit_cycle(ODEFlow(osc), y0, T)
        period = orb.period
        row = {
            "eps": e,
            "exact_max_abs_x": orb.amplitude,
            "exact_first_harmonic": orb.first_harmonic_amplitude,
            "exact_omega": 2 * np.pi / orb.period,
            "exact_period": orb.period,
            "averaging_amplitude": a_avg,
            "averaging_omega": w_avg,
        }
        for n, me in ms.items():
            # the truncated amplitude equation has spurious roots far from the cycle at large
            # eps; the cycle is the one that continues a = 2
            lc = min(me.limit_cycles({"eps": e}), key=lambda c: abs(c.amplitude - 2))
            row[f"ms{n}_amplitude"] = lc.amplitude
            row[f"ms{n}_omega"] = lc.frequency
        rows.append(row)
    header = list(rows[0])
    out.csv("vanderpol_limit_cycle.csv", header, [[r[h] for h in header] for r in rows])
    out.summary["vanderpol"] = rows

    E = np.array([r["eps"] for r in rows])
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(9, 3.8))
    ax1.semilogx(E, [r["exact_max_abs_x"] for r in rows], "ko-", ms=4, label=r"exact $\max|x|$")
    ax1.semilogx(
        E,
        [r["exact_first_harmonic"] for r in rows],
        "ks--",
        ms=4,
        mfc="none",
        label="exact, first harmonic",
    )
    ax1.semilogx(E, [r["ms4_amplitude"] for r in rows], "C1^-", ms=4, label="MMS order 4")
    ax1.axhline(a_avg, color="C0", lw=1, label="averaging / MMS order 2: $a = 2$")
    ax1.set_xlabel(r"$\varepsilon$")
    ax1.set_ylabel("amplitude")
    ax1.legend(fontsize=7)
    ax2.semilogx(E, [r["exact_omega"] for r in rows], "ko-", ms=4, label="exact (shooting)")
    ax2.axhline(w_avg, color="C0", lw=1, label=r"averaging: $\omega = 1$")
    ax2.semilogx(E, [r["ms2_omega"] for r in rows], "C2v-", ms=4, label="MMS order 2")
    ax2.semilogx(E, [r["ms4_omega"] for r in rows], "C1^-", ms=4, label="MMS order 4")
    ax2.set_ylim(0, 1.3)
    ax2.set_xlabel(r"$\varepsilon$")
    ax2.set_ylabel(r"frequency $\omega$")
    ax2.legend(fontsize=7)
    fig.tight_layout()

    table = "\n".join(
        f"{r['eps']:g} & {r['exact_max_abs_x']:.5f} & {r['exact_first_harmonic']:.5f} & "
        f"{r['ms4_amplitude']:.5f} & {r['exact_omega']:.5f} & {r['ms2_omega']:.5f} & "
        f"{r['ms4_omega']:.5f} \\\\"
        for r in ({k: v + 0.0 for k, v in row.items()} for row in rows)  # no "-0.00000"
    )
    bb2 = sp.expand(ms[2].backbone.xreplace({ms[2].amplitude: 2}))
    # order 4 moves the cycle off a = 2: a = 2 + c eps^2 from the amplitude equation, then the
    # frequency on it
    m4, c = ms[4], sp.Symbol("c")
    lead = sp.series(
        sp.expand(m4.polar[0] / eps).xreplace({m4.amplitude: 2 + c * eps**2}), eps, 0, 3
    ).removeO()
    a4 = 2 + sp.solve(sp.expand(lead).coeff(eps, 2), c)[0] * eps**2
    w4 = sp.expand(sp.series(m4.backbone.xreplace({m4.amplitude: a4}), eps, 0, 5).removeO())
    out.summary["vanderpol_series"] = {"ms4_amplitude": str(a4), "ms4_omega": str(w4)}
    out.add(
        rf"""
\subsection{{Van der Pol oscillator: the limit cycle}}
For $x'' - \varepsilon(1 - x^2)x' + x = 0$, first-order averaging (Krylov--Bogoliubov) gives
$\dot a = {tex(kb.slow_flow[0])}$, so the limit cycle $a = {a_avg:g}$, stable, with frequency
$\omega = {w_avg:g}$. Multiple scales to higher order (the model's $\varepsilon$ as bookkeeping
parameter) keeps $a = 2$ at second order and corrects the frequency:
$\omega = {tex(bb2)}$ at order 2; at order 4 the amplitude equation becomes
$0 = {tex(sp.expand(m4.polar[0]))}$, whose root is $a = {tex(a4)} + O(\varepsilon^4)$, and on
it $\omega = {tex(w4)} + O(\varepsilon^6)$. The reference is the limit cycle by autonomous shooting
(bordered Newton with the phase condition $\dot x(0) = 0$), Table~\ref{{tab:course-vdp}} and
Fig.~\ref{{fig:course-vanderpol_limit_cycle}}.
\begin{{table}}[htbp]
\centering\small
\begin{{tabular}}{{rrrrrrr}}
\toprule
$\varepsilon$ & exact $\max|x|$ & exact 1st harm. & MMS-4 $a$ & exact $\omega$ & MMS-2 $\omega$
 & MMS-4 $\omega$ \\
\midrule
{table}
\bottomrule
\end{{tabular}}
\caption{{Van der Pol limit cycle: shooting against the perturbation results (averaging: $a = 2$,
$\omega = 1$) (\texttt{{vanderpol\_limit\_cycle.csv}}).}}\label{{tab:course-vdp}}
\end{{table}}
As $\varepsilon \to 0$ the exact amplitude tends to $2$ and the frequency to $1$ with errors
$O(\varepsilon^2)$, as averaging promises. The series are in $\varepsilon^2$ and fail for
$\varepsilon \gtrsim 1$, where the oscillation turns into a relaxation oscillation (period
$\approx (3 - 2\ln 2)\varepsilon$ for large $\varepsilon$), while the amplitude stays near $2$.
"""
    )
    out.figure(
        fig,
        "vanderpol_limit_cycle.png",
        "Van der Pol limit cycle: amplitude and frequency against $\\varepsilon$, shooting "
        "against averaging and multiple scales.",
    )


# ============================================================= 6. forced van der Pol --
def forced_vanderpol(out: Out, fast: bool) -> None:
    e = FORCED_VDP_EPS
    osc = Oscillator.parse(
        "x'' - eps*(1 - x**2)*x' + x = eps*F*cos(Omega*t)", {"eps": e, "F": FORCED_VDP_F[0]}
    )
    kb_sym = krylov_bogoliubov(osc.with_params(F=None))
    rho_grid = np.linspace(1e-3, 1.6, 2000)
    fig, ax = plt.subplots(figsize=(7, 4.5))
    csv_rows, checks = [], []
    sig_window = (-1.5, 1.5)
    Om_window = (1 + e * sig_window[0], 1 + e * sig_window[1])
    worst = 0.0
    for k, F in enumerate(FORCED_VDP_F):
        oscF = osc.with_params(F=F)
        kb = krylov_bogoliubov(oscF)
        resp = traced_response(kb, Om_window, points=800 if fast else 3000, stability="slow_flow")
        for b in resp.branches:
            sig = (b.omega - 1) / e
            rho = b.first_harmonic_amplitude**2 / 4
            worst = max(
                worst, float(np.max(np.abs(rho * ((1 - rho) ** 2 + 4 * sig**2) - F**2 / 4)))
            )
            csv_rows += [
                (F, float(s), float(r), int(st))
                for s, r, st in zip(sig, rho, b.stable, strict=True)
            ]
            ax.plot(sig, np.where(b.stable, rho, np.nan), f"C{k}-", lw=1.5)
            ax.plot(sig, np.where(~b.stable, rho, np.nan), f"C{k}:", lw=1.5)
        # the classical curve rho[(1 - rho)^2 + 4 sigma^2] = F^2/4, both signs of sigma
        s2 = (F**2 / (4 * rho_grid) - (1 - rho_grid) ** 2) / 4
        s2[s2 < 0] = np.nan  # two pieces for small F: do not join them
        for sgn in (-1, 1):
            ax.plot(sgn * np.sqrt(s2), rho_grid, "k-", lw=0.5, alpha=0.6)
        ax.plot([], [], f"C{k}-", label=f"$F = {F:g}$")
        # periodic orbits by shooting at a few detunings, seeded by the averaged states
        sigmas = (-1.0, -0.3, 0.0, 0.3, 1.0) if fast else np.linspace(-1.2, 1.2, 13)
        a, phi = kb.unknowns
        for s in sigmas:
            W = 1 + e * float(s)
            poly = sum(c * W ** (2 * j) for j, c in enumerate(kb.frequency_polynomial))
            poly = sp.Poly(sp.expand(poly.xreplace(oscF.substitutions())), a)
            for root in np.roots([float(c) for c in poly.all_coeffs()]):
                if abs(root.imag) > 1e-9 or root.real <= 0:
                    continue
                av = float(root.real)
                c, sn = (
                    float(v.xreplace({a: av, **oscF.substitutions(), kb.frequency: W}))
                    for v in kb.phase_from
                )
                ph = math.atan2(sn, c)
                try:
                    orb = periodic_orbit(
                        ODEFlow(oscF, Omega=W), [av * math.cos(ph), av * W * math.sin(ph)]
                    )
                except PerturbError:
                    continue
                rho_x = orb.first_harmonic_amplitude**2 / 4
                checks.append((F, float(s), av**2 / 4, rho_x, orb.stability))
                ax.plot(s, rho_x, f"C{k}o", ms=5, mfc="none" if not orb.is_stable else f"C{k}")
    ax.plot([], [], "k-", lw=0.5, label=r"$\rho[(1-\rho)^2 + 4\sigma^2] = F^2/4$")
    ax.plot([], [], "ko", ms=5, label="shooting (filled: stable)")
    ax.set_xlim(*sig_window)
    ax.set_ylim(0, 1.6)
    ax.set_xlabel(r"detuning $\sigma = (\Omega - 1)/\varepsilon$")
    ax.set_ylabel(r"$\rho = a^2/4$")
    ax.legend(fontsize=8, loc="upper right")
    out.csv("vanderpol_forced.csv", ("F", "sigma", "rho", "stable"), csv_rows)
    out.csv(
        "vanderpol_forced_shooting.csv",
        ("F", "sigma", "rho_averaging", "rho_shooting", "stability"),
        checks,
    )
    out.summary["forced_vanderpol"] = {
        "eps": e,
        "max_classical_residual": worst,
        "shooting": checks,
    }
    max_dev = max(abs(c[3] - c[2]) for c in checks) if checks else float("nan")
    out.add(
        rf"""
\subsection{{Forced van der Pol oscillator}}
With the classical scaling $x'' - \varepsilon(1 - x^2)x' + x = \varepsilon F\cos\Omega t$,
$\Omega = 1 + \varepsilon\sigma$, $x \approx a\cos(\Omega t - \varphi)$ and $\rho = a^2/4$,
averaging gives the response curves $\rho[(1 - \rho)^2 + 4\sigma^2] = F^2/4$. perturb's
Krylov--Bogoliubov averaging keeps the exact $\Omega$:
\[
  \dot a = {tex(kb_sym.slow_flow[0])},\qquad \dot\varphi = {tex(kb_sym.slow_flow[1])},
\]
and its phase-eliminated amplitude equation, traced by \texttt{{frequency\_response}} with
slow-flow stability at $\varepsilon = {e:g}$, lies on the classical curves to
${sci(worst, 1)}$ (the $O(\varepsilon)$ difference between $\Omega^2 - 1$ and $2\varepsilon\sigma$).
Fig.~\ref{{fig:course-vanderpol_forced}}: on the steady states the trace of the slow-flow
Jacobian is $\varepsilon(1 - 2\rho)$, so every state with $\rho < 1/2$ is unstable: there the
forcing does not entrain the self-excited oscillation and the motion is quasi-periodic. For small
$F$ the curve splits into a closed upper loop, whose upper part is the stable entrained
response, and a lower branch of unstable states; for larger $F$ it is one curve, stable near
resonance.
Periodic orbits found by shooting from the averaged states (circles, filled when their Floquet
multipliers say stable) agree with the averaged $\rho$ to ${sci(max_dev, 1)}$ at
$\varepsilon = {e:g}$.
"""
    )
    out.figure(
        fig,
        "vanderpol_forced.png",
        f"Forced van der Pol response curves at $\\varepsilon = {e:g}$: averaging (solid stable, "
        "dotted unstable), the classical curves (thin black) and periodic orbits by shooting.",
    )


# ======================================================================== 7. Mathieu --
def mathieu_trace(delta: np.ndarray, eps: np.ndarray, steps: int) -> np.ndarray:
    """Trace of the monodromy of x'' + (delta + eps cos 2t) x = 0 over its period pi, as the
    product of exact propagators with the stiffness frozen at sub-step midpoints (second
    order), extrapolated once (Richardson, fourth order)."""

    def product(n: int) -> np.ndarray:
        h = np.pi / n
        m00, m01 = np.ones_like(delta), np.zeros_like(delta)
        m10, m11 = np.zeros_like(delta), np.ones_like(delta)
        for k in range(n):
            P = expm2(0.0, delta + eps * np.cos(2 * (k + 0.5) * h), h)
            p00, p01, p10, p11 = P[..., 0, 0], P[..., 0, 1], P[..., 1, 0], P[..., 1, 1]
            m00, m01, m10, m11 = (
                p00 * m00 + p01 * m10,
                p00 * m01 + p01 * m11,
                p10 * m00 + p11 * m10,
                p10 * m01 + p11 * m11,
            )
        return m00 + m11

    return (4 * product(2 * steps) - product(steps)) / 3


def mathieu_trace_ivp(delta: float, eps: float) -> float:
    def rhs(t, y):
        k = delta + eps * np.cos(2 * t)
        return [y[1], -k * y[0], y[3], -k * y[2]]

    y = solve_ivp(rhs, (0, np.pi), [1, 0, 0, 1], method="DOP853", rtol=1e-12, atol=1e-13)
    return float(y.y[0, -1] + y.y[3, -1])


def mathieu(out: Out, fast: bool) -> None:
    m = builtin_model("mathieu")
    e = real_symbol("eps")
    orders = {0: 4, 1: 3, 2: 4}
    curves = {n: transition_curves(m, n, k, epsilon="eps") for n, k in orders.items()}
    nd, ne, steps = (141, 61, 48) if fast else (441, 201, 160)
    D, E = np.meshgrid(np.linspace(-1, 6, nd), np.linspace(0, 4, ne))
    tr = mathieu_trace(D, E, steps)
    unstable = np.abs(tr) > 2
    np.savetxt(
        out.folder / "mathieu_stability_map.csv",
        np.column_stack([D.ravel(), E.ravel(), tr.ravel(), unstable.ravel().astype(int)]),
        delimiter=",",
        header="delta,eps,trace,unstable",
        comments="",
    )
    # exact boundaries near each perturbation curve: tr = +2 (period pi, n even) or -2 (2 pi)
    table, bounds = [], []
    for n, cs in curves.items():
        sign = 1 if n % 2 == 0 else -1
        for c in cs:
            f = numeric(c, e)
            for ev in MATHIEU_EPS_TABLE:
                guess = float(f(ev))
                # the two curves from delta = 4 are only eps^2/8 apart: bracket one root only
                width = 0.3 * ev if n == 1 else 0.05 * ev**2
                lo, hi = guess - width, guess + width
                g = lambda d, ev=ev, s=sign: mathieu_trace_ivp(d, ev) - 2 * s  # noqa: E731
                if g(lo) * g(hi) > 0:
                    bounds.append((n, str(c), ev, guess, float("nan")))
                    continue
                exact = brentq(g, lo, hi, xtol=1e-13)
                bounds.append((n, str(c), ev, guess, exact))
    out.csv(
        "mathieu_transition_curves.csv",
        ("n", "curve", "eps", "delta_perturbation", "delta_floquet"),
        bounds,
    )
    out.summary["mathieu"] = {
        "curves": {str(n): [str(c) for c in cs] for n, cs in curves.items()},
        "boundaries": bounds,
    }
    for n, cs in curves.items():
        for c in cs:
            errs = [
                b[4] - b[3] for b in bounds if b[0] == n and b[1] == str(c) and math.isfinite(b[4])
            ]
            cells = " & ".join(f"${sci(abs(x), 1)}$" for x in errs)
            table.append(f"${n}$ & $\\delta = {tex(c)}$ & {cells} \\\\")

    fig, ax = plt.subplots(figsize=(7, 5))
    ax.contourf(D, E, unstable.astype(float), levels=[0.5, 1.5], colors=["0.8"])
    ax.contour(D, E, np.abs(tr) - 2, levels=[0], colors="k", linewidths=0.6)
    ee = np.linspace(0, 4, 200)
    for k, (n, cs) in enumerate(curves.items()):
        for j, c in enumerate(cs):
            ax.plot(
                np.asarray(numeric(c, e)(ee)) * np.ones_like(ee),
                ee,
                f"C{k}--",
                lw=1.3,
                label=f"$n = {n}$, order {orders[n]}" if j == 0 else None,
            )
    ax.set_xlim(-1, 6)
    ax.set_ylim(0, 4)
    ax.set_xlabel(r"$\delta$")
    ax.set_ylabel(r"$\varepsilon$")
    ax.legend(fontsize=8, loc="upper left")
    ax.set_title(
        r"$x'' + (\delta + \varepsilon\cos 2t)\,x = 0$: grey unstable (Floquet)", fontsize=10
    )

    heads = " & ".join(f"$\\varepsilon = {x:g}$" for x in MATHIEU_EPS_TABLE)
    listed = ", ".join(f"$\\delta = {tex(c)}$" for cs in curves.values() for c in cs)
    out.add(
        rf"""
\subsection{{Mathieu equation: the Ince--Strutt chart}}
The builtin \texttt{{mathieu}} model is $x'' + (\delta + \varepsilon\cos 2t)\,x = 0$ (period $\pi$;
the classical $x'' + (a - 2q\cos 2t)x = 0$ with $a = \delta$, $q = -\varepsilon/2$). The trivial
solution is unstable where a Floquet multiplier of the monodromy matrix $M$ over one period
leaves the unit circle, $|\mathrm{{tr}}\,M| > 2$; the transition curves, on which a solution of
period $\pi$ ($\mathrm{{tr}}\,M = 2$) or $2\pi$ ($\mathrm{{tr}}\,M = -2$) exists, emanate from
$\delta = n^2$. perturb's \texttt{{transition\_curves}} (multiple scales with the stiffness
detuning; a periodic expansion for $n = 0$) gives
{listed}.
The stability map (Fig.~\ref{{fig:course-mathieu_ince_strutt}}) is the trace of $M$ on a
${nd}\times{ne}$ grid, as products of the exact $2\times2$ propagators of
\texttt{{perturb.numeric.stability.expm2}} with the stiffness frozen on {steps} and {2 * steps}
sub-steps, Richardson-extrapolated. The exact boundaries below are roots of
$\mathrm{{tr}}\,M = \pm 2$ with $M$ from a DOP853 integration (tolerance $10^{{-12}}$); the table
gives $|\delta_{{\mathrm{{Floquet}}}} - \delta_{{\mathrm{{perturbation}}}}|$, which falls like the
first omitted power of $\varepsilon$.
\begin{{center}}\small
\begin{{tabular}}{{cl{"r" * len(MATHIEU_EPS_TABLE)}}}
\toprule
$n$ & curve & {heads} \\
\midrule
{chr(10).join(table)}
\bottomrule
\end{{tabular}}
\end{{center}}
"""
    )
    out.figure(
        fig,
        "mathieu_ince_strutt.png",
        "Ince--Strutt chart of the Mathieu equation: unstable region from Floquet multipliers "
        "(grey, black boundary) and the perturbation transition curves (dashed).",
    )


# ============================================================================ driver --
PARTS: tuple[tuple[str, Callable[..., None], bool], ...] = (
    ("free Duffing table", duffing_free, False),
    ("quadratic + cubic", quadratic_cubic, False),
    ("primary resonance", primary_resonance, True),
    ("superharmonic resonance", superharmonic, True),
    ("van der Pol limit cycle", vanderpol, True),
    ("forced van der Pol", forced_vanderpol, True),
    ("Mathieu chart", mathieu, True),
)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="output folder")
    parser.add_argument("--fast", action="store_true", help="coarser grids (under a minute)")
    args = parser.parse_args(argv)
    out = Out(args.out.resolve())
    out.add(
        r"""
\section{The course}
The classical results of the nonlinear-vibration course summarised in docs/references.md \S2 (and
the $-10/-12$ remark of \S3), rederived by perturb's symbolic engines and each measured
against an exact or numerical reference: the elliptic-integral frequency, periodic orbits by
shooting, Floquet multipliers. Generated by \texttt{derivations/course.py}"""
        + (" (fast mode: coarse grids)." if args.fast else ".")
    )
    timings = {}
    for name, part, has_fast in PARTS:
        t0 = time.perf_counter()
        if has_fast:
            part(out, args.fast)
        else:
            part(out)
        timings[name] = time.perf_counter() - t0
        print(f"{name}: {timings[name]:.1f} s ({time.process_time():.1f} s CPU so far)", flush=True)
    out.summary["fast"] = bool(args.fast)
    out.summary["seconds"] = timings
    out.finish()
    print(f"wrote {out.folder / 'section.tex'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
