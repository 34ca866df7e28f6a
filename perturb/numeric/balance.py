"""Numeric solutions of symbolic balance equations: an approximation's residuals by Newton.

:func:`solve_residuals` solves any approximation's residuals (plus extra equations, e.g. to fix
the peak of a cosine series) at given values of the other symbols; :func:`balance_solutions`
finds every solution of a forced single-harmonic (plus bias) balance
(:func:`perturb.methods.harmonic_balance.harmonic_balance` with ``harmonics=(1,)``) at one
frequency, from a grid of sign changes, with Hill's one-harmonic stability estimate.  They
moved here from :mod:`perturb.methods.harmonic_balance`: the symbolic engines derive the
equations and never import the numeric layer (contract ``methods-without-numerics``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from types import MappingProxyType

import numpy as np
import sympy as sp

from perturb.approximation import Approximation
from perturb.errors import ParameterError, PerturbError
from perturb.model.oscillator import Oscillator
from perturb.model.parsing import expression_argument, real_symbol
from perturb.numeric.compile import bind_parameters, lambdify
from perturb.numeric.stability import hill_exponents

__all__ = ["BalanceSolution", "balance_solutions", "solve_residuals"]


def _resolve(approx: Approximation, key: sp.Symbol | str) -> sp.Symbol:
    if isinstance(key, sp.Symbol):
        return key
    pool = set(approx.unknowns) | {s for r in approx.residuals for s in r.free_symbols}
    for s in pool:
        if s.name == key:
            return s
    raise ParameterError(f"no symbol named {key!r} in {approx.label}")


def solve_residuals(
    approximation: Approximation,
    guess: Mapping[sp.Symbol | str, float],
    *,
    fixed: Mapping[sp.Symbol | str, float] | None = None,
    extra: Sequence[sp.Expr] = (),
    tol: float = 1e-10,
) -> Mapping[sp.Symbol, float]:
    """Solve ``approximation.residuals`` (plus ``extra`` equations) by Newton's method.

    Parameters
    ----------
    guess
        Starting values of the symbols to solve for (as many as equations).
    fixed
        Values of other symbols (the forcing frequency, the amplitude of a free oscillation);
        every remaining parameter takes the oscillator's value.
    extra
        Additional equations, e.g. ``a_1 + a_3 + a_5 - X`` to fix the peak of a cosine series.
    tol
        Accepted max-norm of the residuals.

    Returns
    -------
    Mapping
        Symbol -> value.

    Raises
    ------
    ParameterError
        Counts that do not match, unknown names, parameters without values.
    PerturbError
        If Newton's method does not converge.
    """
    from scipy.optimize import root

    approx = approximation
    unknowns = [_resolve(approx, k) for k in guess]
    fixed_syms = {_resolve(approx, k): float(val) for k, val in (fixed or {}).items()}
    eqs = list(approx.residuals) + [
        expression_argument(e, f"extra[{i}]") for i, e in enumerate(extra)
    ]
    if len(eqs) != len(unknowns):
        raise ParameterError(
            f"{len(eqs)} equations for {len(unknowns)} unknowns "
            f"({', '.join(map(str, unknowns))}): pass one guess per equation"
        )
    bound = bind_parameters(approx, eqs, keep=unknowns + list(fixed_syms))
    bound = [e.xreplace({s: sp.Float(val) for s, val in fixed_syms.items()}) for e in bound]
    n = len(unknowns)
    f = lambdify(unknowns, bound)
    jac = lambdify(unknowns, list(sp.Matrix(bound).jacobian(unknowns)))

    def fun(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return (
            np.array([float(r) for r in f(*z)]),
            np.array([float(j) for j in jac(*z)]).reshape(n, n),
        )

    x0 = np.array([float(guess[k]) for k in guess])
    sol = root(fun, x0, jac=True, method="hybr", options={"xtol": 1e-14})
    res = np.max(np.abs(fun(sol.x)[0])) if np.all(np.isfinite(sol.x)) else np.inf
    if not np.isfinite(res) or res > tol * max(1.0, float(np.max(np.abs(sol.x)))):
        raise PerturbError(
            f"Newton's method on {approx.label} did not converge from "
            f"{dict(zip(map(str, unknowns), x0, strict=True))}: residual {res:.3g} "
            f"({sol.message})"
        )
    return MappingProxyType(dict(zip(unknowns, map(float, sol.x), strict=True)))


@dataclass(frozen=True)
class BalanceSolution:
    """One solution of a forced single-harmonic (plus bias) balance at one frequency.

    ``x(t) = bias + amplitude * cos(frequency t + p - phase)``; ``peak`` is max |x|;
    ``max_multiplier`` is Hill's (one harmonic) estimate of the largest Floquet multiplier
    of the equation of motion linearised about that orbit (NaN when not computed).
    """

    frequency: float
    amplitude: float
    bias: float
    phase: float
    residual: float
    max_multiplier: float
    stable: bool | None

    @property
    def peak(self) -> float:
        return abs(self.bias) + self.amplitude


def _scale(osc: Oscillator, F: float) -> float:
    scale = max(1.0, abs(F))
    if osc.nonsmooth != 0:
        try:
            bps = osc.piecewise_linear().numeric().breakpoints
            scale = max([scale, *(abs(float(d)) for d in bps)])
        except PerturbError:
            pass
    return scale


def balance_solutions(
    approximation: Approximation,
    Omega: float | None = None,
    *,
    amplitude_range: tuple[float, float] | None = None,
    bias_range: tuple[float, float] | None = None,
    points: tuple[int, int] = (320, 241),
    stability: bool = True,
) -> tuple[BalanceSolution, ...]:
    """Every solution of a forced ``harmonic_balance(..., (1,), bias=...)`` at one frequency.

    The mean balance ``g_0(A, b) = F_0`` and the phase-eliminated equation
    ``(g_c - Omega^2 A)^2 + g_s^2 = F^2`` are evaluated on an ``(A, b)`` grid (logarithmic in
    ``A``); every grid cell where both change sign seeds Newton's method on the full residuals
    in ``(A, b, phi)``; converged solutions are de-duplicated.

    Parameters
    ----------
    approximation
        From :func:`harmonic_balance` with ``harmonics=(1,)`` on a forced oscillator (with or
        without bias); parameters other than the frequency need values.
    Omega
        The forcing frequency (default: the oscillator's value).
    amplitude_range, bias_range
        Search window (default: ``A`` in ``[1e-3 s, 30 s]``, ``b`` in ``[-10 s, 10 s]``, with
        ``s`` the largest of 1, the forcing amplitude and the breakpoints).
    points
        Grid size in ``A`` and ``b``.
    stability
        Compute Hill's multipliers (one harmonic).

    Returns
    -------
    tuple of BalanceSolution
        Sorted by amplitude, then bias.

    Raises
    ------
    PerturbError
        For an approximation of another kind; ParameterError for missing values.
    """
    from scipy.optimize import root

    approx = approximation
    osc = approx.oscillator
    if (
        approx.method != "hb"
        or approx.phase_from is None
        or approx.options.get("harmonics") != 1
        or not osc.forcing.harmonics
    ):
        raise PerturbError(
            f"balance_solutions needs a forced single-harmonic balance, got {approx.label}"
        )
    Om = approx.frequency
    if Omega is None:
        Omega = osc.params.get(Om.name)
        if Omega is None:
            raise ParameterError(f"no value for the forcing frequency {Om.name!r}: pass Omega=")
    Omega = float(Omega)
    if not (np.isfinite(Omega) and Omega > 0):
        raise ParameterError(f"Omega = {Omega}: expected a positive finite frequency")
    has_bias = len(approx.unknowns) == 3
    A, phi = approx.unknowns[0], approx.unknowns[-1]
    b = approx.unknowns[1] if has_bias else real_symbol("b")
    harmonic = osc.forcing.harmonics[0]
    keep = [A, b, phi, Om]
    at = {Om: sp.Float(Omega)}
    res = [e.xreplace(at) for e in bind_parameters(approx, list(approx.residuals), keep)]
    cos_p, sin_p, F_e = (
        e.xreplace(at)
        for e in bind_parameters(approx, [*approx.phase_from, harmonic.amplitude], keep)
    )
    F = float(F_e)
    scale = _scale(osc, F)
    a_lo, a_hi = amplitude_range or (1e-3 * scale, 30.0 * scale)
    b_lo, b_hi = bias_range or (-10.0 * scale, 10.0 * scale)
    if not (0 < a_lo < a_hi and b_lo < b_hi):
        raise ParameterError(
            f"amplitude_range {a_lo, a_hi} / bias_range {b_lo, b_hi}: expected increasing ranges "
            "with positive amplitudes"
        )
    na, nb = (int(p) for p in points)
    P = lambdify((A, b), cos_p**2 + sin_p**2 - F**2)
    Ag = np.geomspace(a_lo, a_hi, na)
    if has_bias:
        mean = lambdify((A, b), res[0])
        bg = np.linspace(b_lo, b_hi, nb)
        AA, BB = np.meshgrid(Ag, bg, indexing="ij")
        grids = [mean(AA, BB), P(AA, BB)]

        def changes(G: np.ndarray) -> np.ndarray:
            corners = np.stack([G[:-1, :-1], G[1:, :-1], G[:-1, 1:], G[1:, 1:]])
            return (corners.min(axis=0) <= 0) & (corners.max(axis=0) >= 0)

        ia, ib = np.nonzero(changes(grids[0]) & changes(grids[1]))
        seeds = [
            (np.sqrt(Ag[i] * Ag[i + 1]), 0.5 * (bg[j] + bg[j + 1]))
            for i, j in zip(ia, ib, strict=True)
        ]
    else:
        vals = P(Ag, 0.0 * Ag)
        (ia,) = np.nonzero(vals[:-1] * vals[1:] <= 0)
        seeds = [(np.sqrt(Ag[i] * Ag[i + 1]), 0.0) for i in ia]
    cos_f = lambdify((A, b), cos_p)
    sin_f = lambdify((A, b), sin_p)
    unknowns = [A, b, phi] if has_bias else [A, phi]
    res_s = [e.xreplace({} if has_bias else {b: 0}) for e in res]
    f = lambdify(unknowns, res_s)
    jf = lambdify(unknowns, list(sp.Matrix(res_s).jacobian(unknowns)))
    n = len(unknowns)

    def fun(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return (
            np.array([float(r) for r in f(*z)]),
            np.array([float(j) for j in jf(*z)]).reshape(n, n),
        )

    found: list[tuple[float, float, float, float]] = []
    for a0, b0 in seeds:
        p0 = float(np.arctan2(sin_f(a0, b0), cos_f(a0, b0)))
        z0 = np.array([a0, b0, p0] if has_bias else [a0, p0])
        with np.errstate(all="ignore"):
            sol = root(fun, z0, jac=True, method="hybr", options={"xtol": 1e-13})
            z = sol.x
            r = float(np.max(np.abs(fun(z)[0]))) if np.all(np.isfinite(z)) else np.inf
        if not np.isfinite(r) or r > 1e-9 * scale or z[0] <= 0:
            continue
        a_s, b_s = float(z[0]), float(z[1]) if has_bias else 0.0
        ph = float(np.mod(z[-1] + np.pi, 2 * np.pi) - np.pi)
        if any(abs(a_s - s[0]) < 1e-7 * scale and abs(b_s - s[1]) < 1e-7 * scale for s in found):
            continue
        found.append((a_s, b_s, ph, r))
    found.sort()
    out = []
    if found and stability:
        N = 256
        taus = np.linspace(0, 2 * np.pi, N, endpoint=False)
        p0 = float(harmonic.phase.xreplace(osc.substitutions()))
        arr = np.array(found)
        arg = taus[None, :] + p0 - arr[:, 2:3]
        xs = arr[:, 1:2] + arr[:, 0:1] * np.cos(arg)
        vs = -Omega * arr[:, 0:1] * np.sin(arg)
        period = np.full(len(found), 2 * np.pi / Omega)
        lam = hill_exponents(osc, xs, vs, period, 1, Om)
        mults = np.exp(np.clip(np.max(lam.real, axis=1) * period, -700, 700))
    else:
        mults = np.full(len(found), np.nan)
    for (a_s, b_s, ph, r), mu in zip(found, mults, strict=True):
        out.append(
            BalanceSolution(
                frequency=Omega,
                amplitude=a_s,
                bias=b_s,
                phase=ph,
                residual=r,
                max_multiplier=float(mu),
                stable=None if not np.isfinite(mu) else bool(mu < 1 - 1e-9),
            )
        )
    return tuple(out)
