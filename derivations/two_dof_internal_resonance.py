r"""Two coordinates at an internal resonance: first-order multiple scales, checked by shooting.

What this script derives and checks (issue 16, item 2):

1. *1:3 internal resonance.*  Two unit masses, ``K = [[5, -4], [-4, 5]]`` (natural frequencies
   1 and 3 exactly), a cubic spring on ``x1`` and the harmonic force on ``x1``; damping,
   forcing and the cubic are of order ``eps``:

       x1'' + c x1' + 5 x1 - 4 x2 + alpha x1^3 = F cos(Omega t),
       x2'' + c x2' + 5 x2 - 4 x1 = 0,
       c = 0.4 eps, F = 2 eps, alpha = eps, Omega = 1 + eps sigma.

   :func:`perturb.methods.system_averaging.internal_resonance_slow_flow` gives the modal
   matrix, the secular terms (the ``a_1^3`` term that drives mode 2 at ``3 Omega``, the
   ``a_1^2 a_2`` term back on mode 1), the Cartesian and polar slow flows and the Jacobian; its
   derivation is printed as generated LaTeX.  The fixed points over ``sigma`` (every one
   ``scipy.optimize.fsolve`` reaches from a ring of starts) are the frequency response; each
   is checked against the periodic orbit of the full equations (perturb's shooting on a
   DOP853 flow, rtol = atol = 1e-12, started from the fixed point and accepted on its own
   residual): the modal first harmonics and the stability (Jacobian eigenvalues against
   Floquet multipliers).  At one frequency the error is measured for eps = 0.04, 0.02, 0.01:
   first order means a relative error O(eps).
2. *1:1 internal resonance with a dead zone.*  Two unit masses weakly coupled
   (``kc = 0.05``), a dead zone on ``x1`` (describing function in closed form); the slow flow's
   fixed points against the exact piecewise-linear orbits (perturb's exact flow).

Run ``python derivations/two_dof_internal_resonance.py [--fast] [--out DIR]``; outputs go to
``DIR`` (default ``derivations/out/two_dof_internal_resonance/``): section.tex, a PNG figure,
CSV tables.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
import sympy as sp
from scipy.optimize import fsolve

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:  # imported by path (tests) rather than run as a script
    sys.path.insert(0, str(HERE))

from _common import Study, study  # noqa: E402

from perturb.fourier.symbols import NUMERIC_IMPLEMENTATIONS  # noqa: E402
from perturb.methods.system_averaging import internal_resonance_slow_flow  # noqa: E402
from perturb.model.system import System, dead_zone  # noqa: E402
from perturb.report.latex import derivation_body  # noqa: E402
from perturb.simulate.flows.factory import make_flow  # noqa: E402
from perturb.simulate.orbits.shooting import periodic_orbit  # noqa: E402

NAME = "two_dof_internal_resonance"
EPS = 0.02


def pair13() -> System:
    return System.parse(
        [
            "x1'' + c*x1' + 5*x1 - 4*x2 + alpha*x1**3 = F*cos(Omega*t)",
            "x2'' + c*x2' + 5*x2 - 4*x1 = 0",
        ],
        name="pair13",
    )


def pair11_dead_zone() -> System:
    return System.from_matrices(
        [[1, 0], [0, 1]],
        [["c", 0], [0, "c"]],
        [["1+kc", "-kc"], ["-kc", "1+kc"]],
        elements=[dead_zone("x1", "d", "kd")],
        forcing=["F*cos(Omega*t)", 0],
        params={"kc": 0.05, "d": 0.5},
        name="pair11 dead zone",
    )


class SlowFlow:
    """The slow flow compiled (numpy), its fixed points and their stability."""

    def __init__(self, result, values: dict[str, float]):
        self.result = result
        self.names = [s.name for s in result.arguments[5:]]
        self.args = [values[n] for n in self.names]
        mods = [NUMERIC_IMPLEMENTATIONS, "numpy"]
        self.f = sp.lambdify(result.arguments, list(result.slow_flow), modules=mods)
        self.J = sp.lambdify(result.arguments, result.jacobian, modules=mods)
        self.Phi = np.array(result.modal_matrix.evalf(), float)
        self.ratios = (1, result.ratio)

    def rhs(self, x, Om):
        return np.array(self.f(*x, Om, *self.args), float)

    def fixed_points(self, Om, radii=(0.3, 0.8, 1.5, 2.5, 3.5, 4.5), angles=8):
        """Every fixed point fsolve reaches from mode-1 starts on rings (and the previous
        frequency's points, when given through ``self.previous``)."""
        starts = [
            np.array([a * np.cos(t), a * np.sin(t), 0.0, 0.0])
            for a in radii
            for t in np.linspace(0, 2 * np.pi, angles, endpoint=False)
        ]
        starts += list(getattr(self, "previous", []))
        found: list[np.ndarray] = []
        for x0 in starts:
            x, _, ier, _ = fsolve(lambda x: self.rhs(x, Om), x0, full_output=True, xtol=1e-13)
            if ier == 1 and np.max(np.abs(self.rhs(x, Om))) < 1e-10:
                if not any(np.allclose(x, y, atol=1e-7) for y in found):
                    found.append(x)
        self.previous = found
        return [(x, np.linalg.eigvals(np.array(self.J(*x, Om, *self.args), float))) for x in found]

    def guess(self, x, Om):
        """The state at t = 0 of the response the fixed point stands for (a Newton start)."""
        nu = np.array(self.ratios, float) * Om / self.ratios[self.result.near - 1]
        return np.concatenate([self.Phi @ x[[0, 2]], self.Phi @ (nu * x[[1, 3]])])


def orbit_check(sf: SlowFlow, system: System, x, lam, Om, n=256):
    """The periodic orbit from the fixed point: modal first harmonics and stability."""
    flow = make_flow(system, Om, rtol=1e-12, atol=1e-12)
    orb = periodic_orbit(flow, sf.guess(x, Om))
    T = 2 * np.pi / Om * sf.ratios[sf.result.near - 1]
    ts = np.arange(n) * T / n
    ys = flow(orb.y0, 0.0, T, t_eval=ts).ys
    ys = ys if ys.shape[0] == 4 else ys.T
    eta = sf.Phi.T @ ys[:2]
    base = 2 * np.pi / T
    h = []
    for k, r in enumerate(sf.ratios):
        h += [
            2 * np.mean(eta[k] * np.cos(r * base * ts)),
            2 * np.mean(eta[k] * np.sin(r * base * ts)),
        ]
    h = np.array(h)
    rate = float(np.log(np.abs(orb.multipliers)).max() / T)
    return {
        "error": float(np.linalg.norm(h - x) / np.linalg.norm(x)),
        "a_orbit": (float(np.hypot(h[0], h[1])), float(np.hypot(h[2], h[3]))),
        "rate_orbit": rate,
        "rate_slow": float(lam.real.max()),
        "stable_orbit": bool(np.abs(orb.multipliers).max() < 1),
        "stable_slow": bool(lam.real.max() < 0),
    }


def document(body: str) -> str:
    return "\n".join(
        [
            r"\documentclass[11pt]{article}",
            r"\usepackage[T1]{fontenc}",
            r"\usepackage{lmodern}",
            r"\usepackage{amsmath,amssymb,graphicx,booktabs}",
            r"\usepackage[margin=2cm]{geometry}",
            r"\allowdisplaybreaks",
            r"\begin{document}",
            r"\sloppy",
            body,
            r"\end{document}",
            "",
        ]
    )


def one_to_three(st: Study) -> tuple[str, dict]:
    system = pair13()
    t0 = time.process_time()
    res = internal_resonance_slow_flow(system, "1:3")
    derive_s = time.process_time() - t0
    vals = {"c": 0.4 * EPS, "F": 2.0 * EPS, "alpha": EPS}
    sf = SlowFlow(res, vals)
    sigmas = np.linspace(-1.5, 3.5, 26 if st.fast else 101)
    rows = []
    for s in sigmas:
        Om = 1 + EPS * s
        for x, lam in sf.fixed_points(Om):
            rows.append(
                (
                    float(s),
                    float(Om),
                    float(np.hypot(x[0], x[1])),
                    float(np.hypot(x[2], x[3])),
                    int(lam.real.max() < 0),
                )
            )
    st.write_csv("response_1_3.csv", ["sigma", "Omega", "a1", "a2", "stable"], rows)
    most = max((sum(1 for r in rows if r[0] == s) for s in sigmas), default=0)
    # checks against shooting
    check_sigmas = (0.0, 1.0) if st.fast else (0.0, 1.0, 2.5)
    checks = []
    sysn = system.with_params(vals)
    for s in check_sigmas:
        Om = 1 + EPS * s
        for x, lam in sf.fixed_points(Om):
            c = orbit_check(sf, sysn, x, lam, Om)
            checks.append((s, np.hypot(x[0], x[1]), np.hypot(x[2], x[3]), c))
    st.write_csv(
        "checks_1_3.csv",
        [
            "sigma",
            "a1_slow",
            "a2_slow",
            "a1_orbit",
            "a2_orbit",
            "rel_error",
            "rate_slow",
            "rate_orbit",
            "stable_slow",
            "stable_orbit",
        ],
        [
            (
                s,
                a1,
                a2,
                *c["a_orbit"],
                c["error"],
                c["rate_slow"],
                c["rate_orbit"],
                int(c["stable_slow"]),
                int(c["stable_orbit"]),
            )
            for s, a1, a2, c in checks
        ],
    )
    # convergence in eps at sigma = 0.6
    conv = []
    for eps in (0.04, 0.02, 0.01):
        sfe = SlowFlow(res, {"c": 0.4 * eps, "F": 1.0 * eps, "alpha": eps})
        Om = 1 + 0.6 * eps
        pts = sfe.fixed_points(Om, radii=(0.5, 2.0))
        x, lam = pts[0]
        c = orbit_check(
            sfe, system.with_params({"c": 0.4 * eps, "F": 1.0 * eps, "alpha": eps}), x, lam, Om
        )
        conv.append((eps, c["error"], len(pts)))
    st.write_csv("convergence_1_3.csv", ["eps", "rel_error", "fixed_points"], conv)
    orders = [np.log2(conv[i][1] / conv[i + 1][1]) for i in range(len(conv) - 1)]
    figure(st, rows, checks)
    agree = sum(c["stable_slow"] == c["stable_orbit"] for *_, c in checks)
    worst = max(c["error"] for *_, c in checks)
    worst_rate = max(abs(c["rate_slow"] - c["rate_orbit"]) for *_, c in checks)
    summary = {
        "derive_s": derive_s,
        "points": len(rows),
        "most": most,
        "checks": len(checks),
        "agree": agree,
        "worst": worst,
        "worst_rate": worst_rate,
        "orders": orders,
        "conv": conv,
    }
    table = "\n".join(
        f"{s:g} & {a1:.4f} & {c['a_orbit'][0]:.4f} & {a2:.4f} & {c['a_orbit'][1]:.4f} & "
        f"{c['error']:.2e} & {c['rate_slow']:.2e} & {c['rate_orbit']:.2e} & "
        f"{'stable' if c['stable_orbit'] else 'unstable'} \\\\"
        for s, a1, a2, c in checks
    )
    conv_rows = "\n".join(f"{e:g} & {err:.3e} \\\\" for e, err, _ in conv)
    text = rf"""
\subsection{{The 1:3 resonance: derivation}}
The system: $x_1'' + c x_1' + 5x_1 - 4x_2 + \alpha x_1^3 = F\cos\Omega t$,
$x_2'' + c x_2' + 5x_2 - 4x_1 = 0$ (natural frequencies 1 and 3). The derivation below is
generated by \texttt{{internal\_resonance\_slow\_flow(system, "1:3")}} ({derive_s:.2f}~s CPU).
{derivation_body(res.steps)}

\subsection{{The 1:3 resonance: frequency response and checks}}
With $\varepsilon = {EPS:g}$, $c = 0.4\varepsilon$, $F = 2\varepsilon$, $\alpha = \varepsilon$
and $\Omega = 1 + \varepsilon\sigma$, the fixed points of the slow flow over
$\sigma \in [{sigmas[0]:g}, {sigmas[-1]:g}]$ ({len(sigmas)} frequencies, {len(rows)} fixed points,
up to {most} at one frequency) are shown in Figure~\ref{{fig:ir13}}: mode 1 bends to higher
frequency like a hardening Duffing oscillator and drives mode 2 at $3\Omega$ through
$a_1^3$. Each fixed point at $\sigma \in \{{{", ".join(f"{s:g}" for s in check_sigmas)}\}}$
started perturb's shooting on the full equations (DOP853, $10^{{-12}}$); the orbit's modal
first harmonics differ from the fixed point by at most {worst:.2e} (relative), the growth rates
$\max\operatorname{{Re}}\lambda$ of the slow flow and $\log|\mu|_{{\max}}/T$ of the orbit by at
most {worst_rate:.1e}, and the stability verdicts agree at {agree} of {len(checks)} points.

\begin{{center}}\small
\begin{{tabular}}{{rrrrrrrrl}}
\toprule
$\sigma$ & $a_1$ & $a_1$ orbit & $a_2$ & $a_2$ orbit & rel.\ error
& $\max\operatorname{{Re}}\lambda$ & $\log|\mu|/T$ & orbit \\
\midrule
{table}
\bottomrule
\end{{tabular}}
\end{{center}}

\begin{{figure}}[ht]\centering
\includegraphics[width=0.85\textwidth]{{{st.tex_path("response_1_3.png")}}}
\caption{{1:3 internal resonance: modal amplitudes of the slow flow's fixed points (stable:
dots, unstable: crosses) and of the periodic orbits found by shooting from them (circles).}}
\label{{fig:ir13}}
\end{{figure}}

First order means a relative error $O(\varepsilon)$: at $\sigma = 0.6$, $F = \varepsilon$,
\begin{{center}}\small
\begin{{tabular}}{{rr}}\toprule $\varepsilon$ & relative error \\ \midrule
{conv_rows}
\bottomrule\end{{tabular}}
\end{{center}}
\noindent observed orders {", ".join(f"{o:.2f}" for o in orders)}.
"""
    return text, summary


def figure(st: Study, rows, checks) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    arr = np.array(rows)
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.6))
    for ax, col, label in ((axes[0], 2, "$a_1$"), (axes[1], 3, "$a_2$")):
        st_ = arr[:, 4] == 1
        ax.plot(arr[st_, 0], arr[st_, col], ".", ms=3, color="C0", label="slow flow, stable")
        ax.plot(arr[~st_, 0], arr[~st_, col], "x", ms=3, color="C3", label="slow flow, unstable")
        ax.plot(
            [c[0] for c in checks],
            [c[3]["a_orbit"][col - 2] for c in checks],
            "o",
            mfc="none",
            color="k",
            label="shooting",
        )
        ax.set_xlabel(r"$\sigma = (\Omega - 1)/\varepsilon$")
        ax.set_ylabel(label)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(st.path("response_1_3.png"), dpi=130)
    plt.close(fig)


def one_to_one(st: Study) -> tuple[str, dict]:
    system = pair11_dead_zone()
    t0 = time.process_time()
    res = internal_resonance_slow_flow(system, "1:1")
    derive_s = time.process_time() - t0
    vals = {"c": 0.02, "F": 0.05, "kd": 0.1}
    sf = SlowFlow(res, vals)
    sysn = system.with_params(vals)
    checks = []
    for Om in (0.98, 1.03) if st.fast else (0.98, 1.0, 1.03, 1.06):
        for x, lam in sf.fixed_points(Om, radii=(0.5, 1.5, 3.0, 6.0)):
            c = orbit_check(sf, sysn, x, lam, Om)
            checks.append((Om, np.hypot(x[0], x[1]), np.hypot(x[2], x[3]), c))
    st.write_csv(
        "checks_1_1.csv",
        [
            "Omega",
            "a1_slow",
            "a2_slow",
            "a1_orbit",
            "a2_orbit",
            "rel_error",
            "stable_slow",
            "stable_orbit",
        ],
        [
            (Om, a1, a2, *c["a_orbit"], c["error"], int(c["stable_slow"]), int(c["stable_orbit"]))
            for Om, a1, a2, c in checks
        ],
    )
    agree = sum(c["stable_slow"] == c["stable_orbit"] for *_, c in checks)
    worst = max(c["error"] for *_, c in checks)
    table = "\n".join(
        f"{Om:g} & {a1:.4f} & {c['a_orbit'][0]:.4f} & {a2:.4f} & {c['a_orbit'][1]:.4f} & "
        f"{c['error']:.2e} & {'stable' if c['stable_orbit'] else 'unstable'} \\\\"
        for Om, a1, a2, c in checks
    )
    text = rf"""
\subsection{{The 1:1 resonance with a dead zone}}
Two unit masses with springs $1$, a weak coupling spring $k_c = 0.05$ (natural frequencies
1 and $\sqrt{{1.1}}$), damping $c$, the force $F\cos\Omega t$ on $x_1$ and a dead zone of width
$d = 0.5$ and stiffness $k_d$ on $x_1$. Under a 1:1 resonance the dead zone's signal is one
harmonic, so it enters through its describing function in closed form
({derive_s:.2f}~s CPU):
{derivation_body(res.steps)}

\noindent With $c = {vals["c"]:g}$, $F = {vals["F"]:g}$, $k_d = {vals["kd"]:g}$ the fixed points
against the exact piecewise-linear orbits (perturb's exact flow, shooting started from each
fixed point): relative error at most {worst:.2e}, stability agreeing at {agree} of
{len(checks)} points.
\begin{{center}}\small
\begin{{tabular}}{{rrrrrrl}}
\toprule
$\Omega$ & $a_1$ & $a_1$ orbit & $a_2$ & $a_2$ orbit & rel.\ error & orbit \\
\midrule
{table}
\bottomrule
\end{{tabular}}
\end{{center}}
"""
    return text, {"derive_s": derive_s, "checks": len(checks), "agree": agree, "worst": worst}


def main(argv=None) -> int:
    st = study(NAME, __doc__.splitlines()[0], argv)
    t0 = time.process_time()
    text13, s13 = one_to_three(st)
    text11, s11 = one_to_one(st)
    head = (
        r"\section{Two coordinates at an internal resonance}"
        "\n{\\sloppy First-order multiple scales (equivalently, first-order averaging in the frame "
        "rotating with the forcing) of weakly nonlinear two-coordinate systems, generated by "
        r"\texttt{perturb.methods.system\_averaging} and checked against periodic orbits of the "
        r"full equations. Generated by \texttt{derivations/}\allowbreak"
        r"\texttt{two\_dof\_internal\_resonance.py}"
        + (" (fast mode: coarse grids)." if st.fast else ".")
        + "\\par}"
    )
    st.write_section(head + text13 + text11)
    print(
        f"1:3: {s13['points']} fixed points, {s13['checks']} checked: worst rel. error "
        f"{s13['worst']:.2e}, stability agrees {s13['agree']}/{s13['checks']}, eps orders "
        f"{[round(float(o), 2) for o in s13['orders']]}; 1:1 dead zone: worst {s11['worst']:.2e}, "
        f"agrees {s11['agree']}/{s11['checks']}; {time.process_time() - t0:.1f} s CPU"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
