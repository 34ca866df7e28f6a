r"""Backbones of nonlinear normal modes of two-coordinate systems: L-P and mLP against shooting.

What this script derives and checks (issue 16, item 2):

1. *Cubic spring to ground* on the first of two unit masses,
   ``x1'' + 2 x1 - x2 + eps x1^3 = 0``, ``x2'' + 2 x2 - x1 = 0`` (linear frequencies 1 and
   sqrt(3), no internal resonance). :func:`perturb.methods.system_lindstedt.nnm_backbone`
   gives the modal matrix, the Lindstedt–Poincaré (L-P) and modified L-P (mLP) expansions of
   each nonlinear normal mode (NNM) to second order and the backbone omega(A) in closed form;
   the derivation is printed as generated LaTeX. The numerical NNM is found by shooting
   (written here: a symmetric orbit from rest, ``q(0) = (a, c)``, ``q'(0) = 0``, with ``c`` and
   the period such that the velocities vanish at half the period; DOP853, rtol = atol = 1e-12),
   continued in amplitude from the linear mode; ``A`` is measured on the orbit as the
   first-harmonic amplitude of the modal coordinate. The errors at one amplitude for
   eps = 0.4, 0.2, 0.1 give the observed orders (2 at first order, 3 at second).
2. *Hardening coupling spring* ``eps (x1 - x2)^3`` between the masses: mode 1 is exactly
   linear, mode 2 is a Duffing oscillator; at large amplitude mLP against L-P.
3. *The negative-stiffness device* (builtin ``nsd2`` without damping and forcing): the
   piecewise-linear element enters at first order through its closed-form Fourier
   coefficients; both modes against shooting, from the switching amplitude to 40 times it.

Run ``python derivations/two_dof_nnm_backbone.py [--fast] [--out DIR]``; outputs go to ``DIR``
(default ``derivations/out/two_dof_nnm_backbone/``): section.tex, a PNG figure, CSV tables,
summary.json. The script exits 1 if a check fails.
"""

from __future__ import annotations

import json
import math
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from scipy.integrate import solve_ivp  # noqa: E402
from scipy.optimize import root  # noqa: E402

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:  # imported by path (tests) rather than run as a script
    sys.path.insert(0, str(HERE))

from _common import Study, study  # noqa: E402

from perturb.methods.system_lindstedt import NNMBackbone, nnm_backbone  # noqa: E402
from perturb.model.system import System  # noqa: E402
from perturb.model.system_builtins import builtin_system  # noqa: E402
from perturb.report.latex import derivation_body  # noqa: E402

NAME = "two_dof_nnm_backbone"
GROUND = ["x1'' + 2*x1 - x2 + eps*x1**3 = 0", "x2'' + 2*x2 - x1 = 0"]
COUPLING = ["x1'' + 2*x1 - x2 + eps*(x1 - x2)**3 = 0", "x2'' + 2*x2 - x1 - eps*(x1 - x2)**3 = 0"]
K_CHAIN = np.array([[2.0, -1.0], [-1.0, 2.0]])
K_NSD2 = np.array([[2.0, -1.0], [-1.0, 1.0]])  # outer slope 1 of the device plus k2 = 1
METHODS = (("lp", 1), ("lp", 2), ("mlp", 1), ("mlp", 2))
Rhs = Callable[[float, np.ndarray], list]


# ----------------------------------------------------------------- the numerical NNM --
def ground_rhs(eps: float) -> Rhs:
    def rhs(t, y):
        x1, x2, v1, v2 = y
        return [v1, v2, -(2 * x1 - x2 + eps * x1**3), -(2 * x2 - x1)]

    return rhs


def coupling_rhs(eps: float) -> Rhs:
    def rhs(t, y):
        x1, x2, v1, v2 = y
        f = eps * (x1 - x2) ** 3
        return [v1, v2, -(2 * x1 - x2 + f), -(2 * x2 - x1 - f)]

    return rhs


def nsd2_rhs(k: float = -0.5) -> Rhs:
    def rhs(t, y):
        x1, x2, v1, v2 = y
        f = k * x1 + (1 - k) * ((x1 - 1) * (x1 > 1) + (x1 + 1) * (x1 < -1))
        return [v1, v2, -(f + (x1 - x2)), -(x2 - x1)]

    return rhs


def shoot(rhs: Rhs, a: float, c0: float, T0: float) -> tuple[float, float]:
    """The symmetric orbit through q = (a, c) at rest: (c, T) with q'(T/2) = 0."""

    def res(z):
        sol = solve_ivp(
            rhs, (0.0, z[1] / 2), [a, z[0], 0.0, 0.0], method="DOP853", rtol=1e-12, atol=1e-12
        )
        return sol.y[2:, -1]

    out = root(res, [c0, T0], method="hybr", options={"xtol": 1e-13})
    # accepted on the residual, not on hybr's progress test: the device's kinks hold DOP853's
    # velocities at ~1e-9 (a period error of the same size), the smooth systems at ~1e-13
    if np.max(np.abs(res(out.x))) > 1e-8 or abs(out.x[1] / T0 - 1) > 0.3:
        raise RuntimeError(f"shooting failed at a = {a}: {out.message}")
    return float(out.x[0]), float(out.x[1])


def modes(K: np.ndarray) -> np.ndarray:
    _, vecs = np.linalg.eigh(K)  # unit masses: M = I
    return vecs * np.sign(vecs[0])


def numeric_backbone(rhs: Rhs, K: np.ndarray, mode: int, turning: Sequence[float], sub: int):
    """Rows (a, c, A, omega) of the numerical NNM continued through the turning points
    q1(0) = a (``sub`` shooting steps per interval); A = first harmonic of u_mode."""
    phi = modes(K)[:, mode - 1]
    T = 2 * math.pi / math.sqrt(phi @ K @ phi)
    c, prev, rows = None, 0.0, []
    for a in turning:
        for b in np.linspace(prev, a, sub + 1)[1:]:
            c, T = shoot(rhs, b, phi[1] / phi[0] * b if c is None else c * b / prev, T)
            prev = b
        n = 256
        t = np.arange(n) * T / n
        sol = solve_ivp(
            rhs, (0.0, T), [a, c, 0.0, 0.0], method="DOP853", rtol=1e-12, atol=1e-12, t_eval=t
        )
        A = 2 / n * float(np.sum((phi @ sol.y[:2]) * np.cos(2 * math.pi * t / T)))
        rows.append((a, c, A, 2 * math.pi / T))
    return rows


# ------------------------------------------------------------------------ the studies --
def expansions(system: System, mode: int, methods=METHODS) -> dict[str, NNMBackbone]:
    return {f"{m}{o}": nnm_backbone(system, mode, o, method=m) for m, o in methods}


def errors(results: dict[str, NNMBackbone], rows) -> dict[str, list[float]]:
    return {
        key: [float(r.frequency_at(A, invalid="nan")) - om for _, _, A, om in rows]
        for key, r in results.items()
    }


def slope(err: Sequence[float], scale: Sequence[float]) -> float:
    return float(np.polyfit(np.log(scale), np.log(np.abs(err)), 1)[0])


def order_study(fast: bool) -> dict:
    """Errors at q1(0) = 1 for eps = 0.4, 0.2, 0.1 (both modes of the cubic spring to ground)."""
    epss = [0.4, 0.2, 0.1] if fast else [0.4, 0.2, 0.1, 0.05]
    out = {}
    for mode in (1, 2):
        errs: dict[str, list[float]] = {k: [] for k in ("lp1", "lp2", "mlp1", "mlp2")}
        for eps in epss:
            rows = numeric_backbone(ground_rhs(eps), K_CHAIN, mode, [1.0], 2)
            sysm = System.parse(GROUND, {"eps": eps})
            for key, e in errors(expansions(sysm, mode), rows).items():
                errs[key] += e
        out[mode] = {
            "eps": epss,
            "errors": errs,
            "orders": {k: slope(v, epss) for k, v in errs.items()},
        }
    return out


def backbone_study(fast: bool) -> dict:
    """Backbones over amplitude: cubic to ground (eps = 1, both modes), coupling spring
    (eps = 1, mode 2), nsd2 (both modes)."""
    n = 6 if fast else 14
    cases = {
        "ground, mode 1": (
            System.parse(GROUND, {"eps": 1.0}),
            ground_rhs(1.0),
            K_CHAIN,
            1,
            np.linspace(0.15, 1.5, n),
        ),
        "ground, mode 2": (
            System.parse(GROUND, {"eps": 1.0}),
            ground_rhs(1.0),
            K_CHAIN,
            2,
            np.linspace(0.15, 2.0, n),
        ),
        "coupling, mode 2": (
            System.parse(COUPLING, {"eps": 1.0}),
            coupling_rhs(1.0),
            K_CHAIN,
            2,
            np.linspace(0.15, 3.0, n),
        ),
        "nsd2, mode 1": (
            builtin_system("nsd2").with_params(mu1=0, mu2=0, F=0),
            nsd2_rhs(),
            K_NSD2,
            1,
            np.geomspace(40.0, 4.0, n),
        ),
        "nsd2, mode 2": (
            builtin_system("nsd2").with_params(mu1=0, mu2=0, F=0),
            nsd2_rhs(),
            K_NSD2,
            2,
            np.geomspace(40.0, 2.0, n),
        ),
    }
    out = {}
    for label, (sysm, rhs, K, mode, turning) in cases.items():
        pwl = label.startswith("nsd2")
        methods = (("lp", 1), ("mlp", 1)) if pwl else METHODS
        results = expansions(sysm, mode, methods)
        rows = numeric_backbone(rhs, K, mode, list(turning), 3 if pwl else 4)
        out[label] = {"results": results, "rows": rows, "errors": errors(results, rows)}
    return out


# ---------------------------------------------------------------------------- outputs --
def figure(st: Study, bb: dict) -> None:
    fig, grid = plt.subplots(2, 3, figsize=(9.6, 6.4))
    axes = list(grid.ravel())
    axes.pop().set_visible(False)  # five cases on a 2 x 3 grid
    style = {"lp1": ("C0", ":"), "lp2": ("C0", "-"), "mlp1": ("C3", ":"), "mlp2": ("C3", "-")}
    for ax, (label, d) in zip(axes, bb.items(), strict=True):
        rows = np.array(d["rows"])
        A = np.linspace(min(rows[:, 2]) * 0.5, max(rows[:, 2]) * 1.05, 300)
        for key, r in d["results"].items():
            color, ls = style[key]
            ax.plot(
                r.frequency_at(A, invalid="nan"),
                A,
                color=color,
                ls=ls,
                lw=1.2,
                label=key.replace("lp", " L-P ").replace("m L-P", "mLP").strip(),
            )
        ax.plot(rows[:, 3], rows[:, 2], "k.", ms=5, label="shooting")
        if label.startswith("nsd2"):  # amplitudes over a decade and more
            ax.set_yscale("log")
        ax.set_title(label, fontsize=9)
        ax.set_xlabel(r"$\omega$")
        ax.set_ylabel("modal amplitude $A$")
        ax.tick_params(labelsize=7)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(st.path("backbones.png"), dpi=150, bbox_inches="tight")
    plt.close(fig)


def write_tables(st: Study, orders: dict, bb: dict) -> None:
    rows = []
    for mode, d in orders.items():
        for i, eps in enumerate(d["eps"]):
            rows.append([mode, eps] + [d["errors"][k][i] for k in ("lp1", "lp2", "mlp1", "mlp2")])
    st.write_csv("order_errors.csv", ["mode", "eps", "lp1", "lp2", "mlp1", "mlp2"], rows)
    rows = []
    for label, d in bb.items():
        for i, (a, c, A, om) in enumerate(d["rows"]):
            rows.append(
                [label, a, c, A, om]
                + [d["errors"].get(k, [math.nan] * 99)[i] for k in ("lp1", "lp2", "mlp1", "mlp2")]
            )
    st.write_csv(
        "backbones.csv",
        [
            "case",
            "q1_turning",
            "q2_turning",
            "A",
            "omega_shooting",
            "err_lp1",
            "err_lp2",
            "err_mlp1",
            "err_mlp2",
        ],
        rows,
    )


def _tex_text(text: str) -> str:
    """A check's name in text mode: its ``eps^k`` in mathematics."""
    for k in "123":
        text = text.replace(f"O(eps^{k})", f"$O(\\epsilon^{k})$")
    return text.replace("A > 1", "$A > 1$")


def _e(x: float) -> str:
    if math.isnan(x):
        return "--"
    m, e = f"{x:.2e}".split("e")
    return f"${m}\\times 10^{{{int(e)}}}$"


def document_part(title: str, steps) -> str:
    return f"\\subsection{{{title}}}\n" + derivation_body(steps).replace(
        "\\subsection*", "\\subsubsection*"
    )


def checks(orders: dict, bb: dict) -> list[tuple[str, bool, str]]:
    out = []
    for mode, d in orders.items():
        o = d["orders"]
        out.append(
            (
                f"ground mode {mode}: L-P order 1 error O(eps^2)",
                1.7 < o["lp1"] < 2.3,
                f"{o['lp1']:.2f}",
            )
        )
        out.append(
            (
                f"ground mode {mode}: L-P order 2 error O(eps^3)",
                2.7 < o["lp2"] < 3.3,
                f"{o['lp2']:.2f}",
            )
        )
        out.append(
            (
                f"ground mode {mode}: mLP order 2 error O(eps^3)",
                2.7 < o["mlp2"] < 3.3,
                f"{o['mlp2']:.2f}",
            )
        )
    for label in ("ground, mode 1", "coupling, mode 2"):
        e = bb[label]["errors"]
        big = [i for i, (_, _, A, _) in enumerate(bb[label]["rows"]) if A > 1.0]
        ok = all(math.isnan(e["lp2"][i]) or abs(e["mlp2"][i]) < abs(e["lp2"][i]) for i in big)
        out.append((f"{label}: mLP closer than L-P where A > 1", ok, f"{len(big)} points"))
    for label in ("nsd2, mode 2",):
        e = bb[label]["errors"]
        ok = abs(e["mlp1"][0]) < abs(e["lp1"][0]) and abs(e["lp1"][0]) < abs(e["lp1"][-1])
        out.append(
            (
                f"{label}: error falls with amplitude, mLP below L-P at the largest",
                ok,
                f"{e['lp1'][0]:.2e}, {e['mlp1'][0]:.2e}",
            )
        )
    return out


def section(st: Study, orders: dict, bb: dict, checks_: list, seconds: float) -> str:
    ground_mlp = bb["ground, mode 1"]["results"]["mlp2"]
    nsd_lp = bb["nsd2, mode 2"]["results"]["lp1"]
    table = []
    for mode, d in orders.items():
        for i, eps in enumerate(d["eps"]):
            errs = " & ".join(_e(d["errors"][k][i]) for k in ("lp1", "lp2", "mlp1", "mlp2"))
            table.append(f"{mode} & {eps:g} & {errs} \\\\")
        o = d["orders"]
        table.append(
            f"\\multicolumn{{2}}{{l}}{{observed order}} & {o['lp1']:.2f} & {o['lp2']:.2f} & "
            f"{o['mlp1']:.2f} & {o['mlp2']:.2f} \\\\ \\midrule"
        )
    nsd = bb["nsd2, mode 2"]
    nsd_rows = "\n".join(
        f"{a:g} & {A:.4g} & {om:.6f} & {_e(nsd['errors']['lp1'][i])} & "
        f"{_e(nsd['errors']['mlp1'][i])} \\\\"
        for i, (a, _, A, om) in enumerate(nsd["rows"])
    )
    ok_lines = "\n".join(
        f"\\item {'passed' if ok else 'FAILED'}: {_tex_text(name)} ({val})"
        for name, ok, val in checks_
    )
    mode1 = bb["ground, mode 1"]["rows"][-1]
    g = bb["ground, mode 1"]
    rel = [e / om for e, (_, _, _, om) in zip(g["errors"]["mlp2"], g["rows"], strict=True)]
    rel_lp = [e / om for e, (_, _, _, om) in zip(g["errors"]["lp2"], g["rows"], strict=True)]
    g1 = (
        f"{abs(rel[-2]):.1%}".replace("%", "\\%"),
        f"{g['rows'][-2][2]:.2f}",
        f"{abs(rel[-1]):.1%}".replace("%", "\\%"),
        f"{g['rows'][-1][2]:.2f}",
        f"{abs(rel_lp[-2]):.1%}".replace("%", "\\%"),
    )
    c = bb["coupling, mode 2"]
    worst = max(
        abs(e) / om for e, (_, _, _, om) in zip(c["errors"]["mlp2"], c["rows"], strict=True)
    )
    cp = (f"{worst:.1%}".replace("%", "\\%"), f"{c['rows'][-1][2]:.2f}")
    return rf"""
\section{{Backbones of nonlinear normal modes of two coordinates}}
\label{{sec:nnm-backbone}}
This study{" (built in fast mode)" if st.fast else ""} expands the nonlinear normal mode (NNM)
that continues one linear mode of a conservative two-coordinate system by the
Lindstedt--Poincar\'e method (L-P) and its modified form (mLP, Cheung, Chen and Lau's
$\alpha$-transformation), to second order for polynomial springs and to first order for the
piecewise-linear negative-stiffness device, and measures every backbone against the numerical
NNM. The reference is written in the script: shooting for the symmetric orbit that starts at
rest, $q(0) = (a, c)$, with $c$ and the period such that both velocities vanish at half the
period (DOP853, tolerances $10^{{-12}}$), continued in amplitude from the linear mode; the
amplitude $A$ of the expansions (that of the first harmonic of the modal coordinate) is
measured on the orbit. Built in {seconds:.0f}\,s.

\subsection{{Errors and orders: cubic spring to ground}}
Two unit masses, $x_1'' + 2x_1 - x_2 + \epsilon x_1^3 = 0$, $x_2'' + 2x_2 - x_1 = 0$
(linear frequencies $1$ and $\sqrt 3$). At the turning point $x_1(0) = 1$ the error of the
frequency shrinks like $\epsilon^2$ at first order and $\epsilon^3$ at second order, for both
methods and both modes (Table~\ref{{tab:nnm-orders}}).
\begin{{table}}[ht]\centering\small
\caption{{Error $\omega_{{\mathrm{{expansion}}}}(A) - \omega_{{\mathrm{{shooting}}}}$ at
$x_1(0) = 1$; observed order: slope of $\log|\mathrm{{error}}|$ against $\log\epsilon$.}}
\label{{tab:nnm-orders}}
\begin{{tabular}}{{rrllll}}\toprule
mode & $\epsilon$ & L-P 1 & L-P 2 & mLP 1 & mLP 2 \\ \midrule
{chr(10).join(table)}
\bottomrule\end{{tabular}}
\end{{table}}

\subsection{{Backbones at large amplitude}}
Figure~\ref{{fig:nnm-backbones}} shows the backbones with $\epsilon = 1$, where
$\epsilon A^2$ reaches order one. On the in-phase mode of the spring to ground the relative
error of second-order mLP is {g1[0]} at $A = {g1[1]}$ and {g1[2]} at $A = {g1[3]}$, while the
second-order L-P backbone bends back ({g1[4]} at $A = {g1[1]}$) and then has no positive
frequency at all; the NNM itself changes shape there (at $x_1(0) =
{mode1[0]:g}$ the second mass swings to $x_2(0) = {mode1[1]:.3g}$: the mode localises on the
linear mass and its frequency saturates below $\sqrt 2$), which no expansion about the linear
mode shape captures. On the anti-phase mode the stiff nonlinear mass also takes over, and
both second-order expansions err by similar amounts. The hardening coupling spring leaves
both linear mode shapes invariant: mode 1 stays linear (the engine returns $\omega = 1$
exactly) and mode 2 is a Duffing oscillator, where mLP (relative error at most {cp[0]} up
to $A = {cp[1]}$) is far better than L-P at every large amplitude. For the
negative-stiffness device (builtin \texttt{{nsd2}}, $k = -0.5$, without
damping and forcing) the reference stiffness is the mean outer slope, so the correction falls
like $1/A$ at large amplitude; mLP converges faster (Table~\ref{{tab:nnm-nsd}}). Below the
switching amplitude the device's equilibrium is unstable: the in-phase mode's mLP backbone has
no real frequency there, and both first-order backbones are qualitative near the switches.
\begin{{figure}}[ht]\centering
\includegraphics[width=\textwidth]{{{st.tex_path("backbones.png")}}}
\caption{{Backbones (frequency against modal amplitude): L-P (blue) and mLP (red), first
order dotted and second order solid, against shooting (dots).}}
\label{{fig:nnm-backbones}}
\end{{figure}}
\begin{{table}}[ht]\centering\small
\caption{{\texttt{{nsd2}}, mode 2: first-order errors against shooting.}}
\label{{tab:nnm-nsd}}
\begin{{tabular}}{{rrrll}}\toprule
$x_1(0)$ & $A$ & $\omega$ (shooting) & L-P 1 & mLP 1 \\ \midrule
{nsd_rows}
\bottomrule\end{{tabular}}
\end{{table}}

\paragraph{{Where the expansions are invalid.}} L-P is a power series in the ratio of the
nonlinear to the linear force: beyond $\epsilon A^2 \approx \omega_j^2$ it bends away and
eventually gives no positive frequency. mLP's parameter $\alpha = \nu/(\omega_j^2 + \nu)$ stays
below one for hardening forces, but its truncation also fails once the mode shape changes
(localisation) or, for softening forces, where $\omega_j^2 + \nu \to 0$. Both exclude internal
resonances: the other mode's harmonic $m$ is divided by $\omega_k^2 - m^2\omega_j^2$, and
the engine refuses an exact resonance ($\omega_k = m\omega_j$ with harmonic $m$ present),
naming it.

\paragraph{{Checks.}}
\begin{{itemize}}
{ok_lines}
\end{{itemize}}

{document_part("Derivation: mLP, cubic spring to ground, mode 1, second order", ground_mlp.steps)}

{document_part("Derivation: L-P, negative-stiffness device, mode 2, first order", nsd_lp.steps)}
"""


def main(argv: Sequence[str] | None = None) -> int:
    st = study(NAME, "NNM backbones of two-coordinate systems by L-P and mLP", argv)
    start = time.perf_counter()
    orders = order_study(st.fast)
    bb = backbone_study(st.fast)
    checks_ = checks(orders, bb)
    figure(st, bb)
    write_tables(st, orders, bb)
    seconds = time.perf_counter() - start
    st.write_section(section(st, orders, bb, checks_, seconds))
    summary = {
        "orders": {str(m): d["orders"] for m, d in orders.items()},
        "checks": {name: ok for name, ok, _ in checks_},
    }
    st.path("summary.json").write_text(json.dumps(summary, indent=1))
    for name, ok, val in checks_:
        print(f"{'ok ' if ok else 'BAD'} {name}: {val}")
    print(f"wrote {st.dir} in {seconds:.1f} s")
    if not all(ok for _, ok, _ in checks_):
        print("FAILED", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
