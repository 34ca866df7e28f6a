r"""Numeric multi-harmonic harmonic balance (Galerkin) with exact projection of PWL forces.

Ansatz
------
For ``x'' + g(x, x') = f(t)`` forced at frequency :math:`\Omega` and a period of ``m`` forcing
periods (``m = 1`` harmonic, ``m > 1`` subharmonic responses), with :math:`\theta = \Omega t/m`,

.. math::

    x(\theta) = a_0 + \sum_{k \in K} a_k \cos k\theta + b_k \sin k\theta,

``K = 1..H`` (or the odd ``k`` only, without :math:`a_0`, for odd-symmetric systems). Harmonic
``k`` has frequency :math:`k\Omega/m`. The unknown vector is ``u = [a0, a_1, b_1, a_2, b_2,
...]`` (no ``a0`` without bias). The residual is the Galerkin projection of the equation of
motion, :math:`\omega = \Omega/m`,

.. math::

    R_0 = \frac{1}{2\pi}\int_0^{2\pi} r\,d\theta,\quad
    R_{a_k} = \frac{1}{\pi}\int_0^{2\pi} r\cos k\theta\,d\theta,\quad
    R_{b_k} = \frac{1}{\pi}\int_0^{2\pi} r\sin k\theta\,d\theta,

    r = \omega^2 x_{\theta\theta} + g(x, \omega x_\theta) - f,

so the projection of a function already in the basis is the function's own coefficients.
Inertia and linear damping are projected exactly (diagonal and :math:`2\times 2`-block terms).

Exact projection of a piecewise-linear force (``projection="exact"``)
---------------------------------------------------------------------
The Galerkin projection of a piecewise-linear force and its exact Jacobian (switching angles
found on the multi-harmonic signal by certified isolation, closed-form spectra of the
piecewise-constant slope and offset, a finite convolution: no sampling, no aliasing) live in
the Fourier layer, :mod:`perturb.fourier.projection` (its module docstring has the formulas
and the isolation method); this module adds inertia, damping and forcing, and uses the
crossing intervals for the exact monodromy of the Hill test.

AFT (``projection="aft"``)
--------------------------
The nonlinear part :math:`g_{nl} = g - \mu x' - k x` is sampled at ``samples`` equally spaced
:math:`\theta` (default ``4 max(K) + 1``, which projects cubic polynomials exactly) and
projected by the trapezoidal rule (a DFT); the Jacobian uses the sampled derivatives
:math:`\partial g_{nl}/\partial x, \partial g_{nl}/\partial x'` (Dirac terms of jumps dropped:
the sampled residual has none). Hill's pencil does add the Dirac term of a force that jumps
across :math:`x' = 0` (Coulomb friction :math:`r\,\mathrm{sign}(x')`) at the velocity
reversals of the series, the saltation of the exact monodromy (``_reversal_terms``).
Exact for polynomial forces up to the aliasing order, slowly convergent (and aliased) for
nonsmooth ones — the comparison option for PWL forces.

Stability (Hill)
----------------
A perturbation :math:`y = e^{\lambda t} p(\theta)` with :math:`p` in the same basis gives the
quadratic eigenproblem :math:`(\lambda^2 I + \lambda(2\omega D + P) + J_u)c = 0`, with
:math:`D` the derivative matrix, :math:`P` the Galerkin matrix of :math:`\partial g/\partial
x'` and :math:`J_u` the residual Jacobian, so the exponents change sign exactly at the folds of
the truncated branch. Of its :math:`2n` eigenvalues (copies :math:`\lambda + ik\omega` and
truncation artefacts) the two physical Floquet exponents are those whose eigenvectors are
centred on harmonic 0 (smallest :math:`|\sum_n n|c_n|^2| / \sum_n |c_n|^2|` in complex form,
Lazarus & Thomas 2010), reported shifted into the strip :math:`|\mathrm{Im}\,\lambda| \le
\omega/2` (an exponent is defined modulo :math:`i\omega`).

For constant damping (all PWL models, either projection) the spectrum is symmetric under
:math:`\lambda \to -\mu - \bar\lambda` (the undamped part is Hamiltonian: the Galerkin matrix
of a real function is Hermitian Toeplitz in complex form), so one exponent fixes both, and a
complex pair has real part exactly :math:`-\mu/2`. The continuation (and
:meth:`HarmonicBalanceSystem.hill_exponents` unless ``full=True``) uses that: the exact
monodromy of the linearisation about the HB orbit (a product of :math:`2\times 2` matrix
exponentials over the crossing intervals, saltation at jumps) classifies the pair; a complex
pair then needs nothing more for ``max_multiplier`` (its imaginary part is taken from the
monodromy unless ``refine_complex``), a real pair is refined on the pencil by Ruhe's
nonlinear inverse iteration from the monodromy's exponent; the full eigenproblem is the
fallback. Single orbits (:func:`harmonic_balance_orbit`) use the full eigenproblem.
``max_multiplier`` is :math:`\max|e^{\lambda T}|`, :math:`T = 2\pi m/\Omega`.

Cost per Newton step
--------------------
Assembling the residual and its Jacobian is O(H^2) (plus O(H) per crossing): the Toeplitz
Jacobian is gathered from the ``4H + 1`` spectra ``Q_n`` and combined two columns per
harmonic (no dense matrix product), the crossings are isolated on ``4H`` grid intervals with
O(H) work each. The dense solves (Newton's LU, Hill's pencil) are O(H^3) with a small
constant; ``benchmarks/bench_scaling_hb.py`` measures both.

Set-up
------
A system is built once per process and options (:func:`compiled_system`, which every entry
point here uses): an equal oscillator built again reuses it. A polynomial force (AFT) is
evaluated from a numeric monomial table with exact derivatives
(:class:`perturb.numeric.compile.PolynomialTable`), and a forcing free of the frequency from
its numbers, so no SymPy code is generated; the dense Newton solves need no SciPy. A cold
process running one Duffing H = 7 response imports numpy and SymPy (needed to build the
model) and nothing of SciPy: ``benchmarks/bench_duffing_harmonicbalance.py`` compares such a
process with the ``harmonicbalance`` package's.

Frequency responses are continued with the Hermite predictor of
:func:`perturb.numeric.continuation.continue_curve` and acceptance after one Newton
correction when the measured quadratic convergence allows it: about 1.3 residual and
Jacobian evaluations per point instead of 2.3, every point still solved to ``tol``.

Every branch
------------
:func:`harmonic_balance_branches` (and ``harmonic_balance_response(..., all_branches=True)``)
adds the branches that continuation from the start cannot reach, detached loops included:
it seeds Newton from the caller's ``seeds`` (the front door passes points of every branch of
the single-harmonic balance response, which amplitude parametrisation traces without
continuation: :func:`perturb.seeds.single_harmonic_seeds`), and from the closed-form orbits of
the linear segments of a PWL force (linear responses about the equilibria otherwise) at
five frequencies across the window, and traces each seed that lies on no branch found so
far. The zero-mean single-harmonic seeds of an odd system are symmetric, and continuation
passes straight through the symmetry-breaking pitchforks on a symmetric branch, so the
asymmetric branches born there are found by *branch switching*: every branch is traced with
the branch-point test function of :func:`perturb.numeric.continuation.continue_curve`, the
sign of :math:`\det\begin{pmatrix} J_u & J_\Omega \\ t^T & 0\end{pmatrix}`. On a branch
of HB solutions :math:`\det J_u` changes sign wherever a real Hill exponent crosses zero
(a real Floquet multiplier through +1): at folds and at branch points alike; the augmented
determinant changes sign at branch points only (the curve stays regular at a fold), so the
two are told apart without looking at :math:`d\Omega/ds`. A branch point is located by
regula falsi along the arclength (each trial a corrected point of the branch), the second
null vector of :math:`[J_u \mid J_\Omega]` there (for the symmetric pitchfork it lies in the
bias and even-harmonic subspace) is stepped along both ways and corrected onto the other
branch (:func:`perturb.numeric.continuation.branch_off`), which is traced both ways and
searched in turn. For odd systems the mirror image :math:`x(t) \to -x(t + T/2)` of every
branch (bias and even harmonics change sign for ``m = 1``) is added without continuation
when it is not on a branch already: the symmetry is checked on the residual itself.

Cost of ``all_branches=True``, nsd (mu = 0.05, F = 2, window (0.2, 2), H = 15), CPU time
(``time.process_time``) of a repeated call in one process (the first call in a process
adds ~0.5 s for the symbolic single-harmonic balance), development machine shared with
another job: k = -3, 7 branches (one switched at the branch point Omega = 0.48352 of the
cross-well loop, two in-well ones from segment orbits), ~1.0 s against ~0.3 s for the three
branches before branch switching; k = -0.5, 4 branches (three switched at branch points on
the connected branch), ~1.0 s against ~0.3 s for its one branch. The branch-point test adds
one ``(2H + 2)``-square LU per point (a few per cent); the rest is the continuation of the
branches found (the connected branch of k = -0.5, with its four branch points: 0.18 s
without and 0.24 s with their detection and location; k = -3: 0.054 s and 0.056 s).

Branches that neither the seeds nor a branch point inside the window reach (a stable isola;
an isola that straddles a window edge; a branch that enters at an edge and folds back out)
come from stage 3b of :func:`harmonic_balance_branches`: Newton from the stable orbits that a
short fixed-step simulation reaches from a grid of initial states at frequencies 2 % apart
across the window (PWL forces), and at both edges from the solutions found there with their
bias shifted, and from the orbits a second simulation reaches from beside every unstable
orbit traced. CPU time of a repeated call, bench windows (0.2, 2.5), H = 15, loaded machine:
nsd k = -0.5 0.67 -> 1.32 s (4 branches, as before), k = -3 0.69 -> 2.36 s (7 -> 21
branches, each new one checked to be an exact orbit by shooting), then 2.18 -> 2.76 s (in
one process, load ~6.5) with the starts beside the unstable orbits (21 -> 23: the pair on
0.2-0.2351, stable only on 0.23487-0.23515, which the exact response also has), k = 2
0.25 -> 1.02 s (1 -> 2: the stable isola on 0.5915-0.6151); clearance
(window (0.5, 1.6)) 0.13 -> 0.80 s (1 -> 2: the stable superharmonic isola on 0.508-0.654).

Starting without a guess
------------------------
At one frequency the first of: the closed-form steady state of a linear segment of a PWL
force that stays inside its segment (an exact orbit, and an exact HB solution for any
``H``), Newton from the linear response about a stable static equilibrium, continuation in
the forcing amplitude from an equilibrium. Frequency responses start at the high end of the
window by default, where the response is closest to linear.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from functools import cached_property
from types import MappingProxyType
from typing import Any, Literal

import numpy as np
import sympy as sp
from numpy.typing import ArrayLike

from perturb import checks
from perturb.errors import ModelError, ParameterError, PerturbError
from perturb.fourier.projection import (
    CrossingIntervals,
    ExactProjector,
    HarmonicBasis,
    TruncatedSeries,
    crossing_intervals,
)
from perturb.model.oscillator import Oscillator
from perturb.model.pwl import NumericPWL
from perturb.model.symmetry import mirror_harmonic
from perturb.numeric.compile import PolynomialTable, polynomial_table
from perturb.numeric.continuation import (
    BranchPoint,
    ContinuationCurve,
    ContinuationError,
    FoldPoint,
    branch_off,
    continue_curve,
    newton_fixed,
)
from perturb.response import Branch, Response

__all__ = [
    "HarmonicBalanceSystem",
    "HarmonicBalanceSolution",
    "HarmonicBalanceBranch",
    "HarmonicBalanceOptions",
    "compiled_system",
    "harmonic_balance_orbit",
    "harmonic_balance_branch",
    "harmonic_balance_branches",
    "harmonic_balance_branch_through",
    "harmonic_balance_response",
    "mirror_branch",
    "odd_symmetry",
]

Projection = Literal["auto", "exact", "aft"]
Stability = Literal["hill", "hill_full", "none"]
#: ``seeds(system, window, per_branch) -> [(Omega, u), ...]``: starting guesses for
#: :func:`harmonic_balance_branches` from outside this layer (e.g. an approximation's
#: branches, :func:`perturb.seeds.single_harmonic_seeds`)
SeedFunction = Callable[
    ["HarmonicBalanceSystem", tuple[float, float], int], Sequence[tuple[float, np.ndarray]]
]


@dataclass(frozen=True)
class HarmonicBalanceOptions:
    """Tuning knobs of numeric harmonic balance (:func:`harmonic_balance_branch`,
    :func:`harmonic_balance_branches`, :func:`harmonic_balance_response`).

    Each function also takes the fields as keyword arguments (they replace the fields of
    ``options``); a function uses the fields it needs (the last five only
    :func:`harmonic_balance_branches`, and :func:`harmonic_balance_response` with
    ``all_branches``). Values are checked by the functions (a
    :class:`~perturb.errors.ParameterError` names a bad one).

    Attributes
    ----------
    harmonics, m, odd_only, projection, samples
        The balanced system: see :class:`HarmonicBalanceSystem`.
    stability : {'hill', 'hill_full', 'none'}
        Hill stability at every point: the fast path of the module docstring (PWL forces;
        the full eigenproblem otherwise), always the full eigenproblem, or none
        (``max_multiplier`` NaN in the branch, -1 in the response).
    ds_max : float
        Largest continuation step, in units where the window width and the current
        solution's largest coefficient are 1: the output spacing.
    max_points : int
        Points per continuation run at most.
    tol : float
        Newton tolerance (scaled).
    seeds_per_branch : int
        Passed to the ``seeds`` function of :func:`harmonic_balance_branches`: guesses per
        branch of the approximation.
    branch_points : bool
        Locate branch points and switch branches there (stage 3 of
        :func:`harmonic_balance_branches`).
    mirror : bool
        Add mirror images for odd systems (stage 4).
    max_branches : int
        Stop looking for more branches once this many are found.
    attractors : bool
        Look for the stable orbits across the window (a short simulation from a grid of
        initial states) and for more solutions at both window edges, and trace the new ones
        (stage 3b of :func:`harmonic_balance_branches`).
    """

    harmonics: int = 15
    m: int = 1
    odd_only: bool = False
    projection: Projection = "auto"
    samples: int | None = None
    stability: Stability = "hill"
    ds_max: float = 0.05
    max_points: int = 5000
    tol: float = 1e-10
    seeds_per_branch: int = 3
    branch_points: bool = True
    mirror: bool = True
    max_branches: int = 40
    attractors: bool = True


#: The fields of :class:`HarmonicBalanceOptions` that shape one branch (the rest choose which
#: branches :func:`harmonic_balance_branches` looks for).
_BRANCH_FIELDS = frozenset(
    ("harmonics", "m", "odd_only", "projection", "samples", "stability", "ds_max")
    + ("max_points", "tol")
)
_ALL_FIELDS = frozenset(HarmonicBalanceOptions.__dataclass_fields__)


def _options(
    options: HarmonicBalanceOptions | None,
    knobs: dict[str, Any],
    allowed: frozenset[str],
    where: str,
) -> HarmonicBalanceOptions:
    return checks.options_with(HarmonicBalanceOptions, options, knobs, where, allowed)


#: Grid points per highest harmonic for the extrema of x (refined by Newton afterwards).
_EXTREMA_PER_HARMONIC = 8
_TWO_PI = 2.0 * math.pi
_EPS = float(np.finfo(float).eps)


# =============================================================================================
# the harmonic-balance equations of an oscillator
# =============================================================================================
def _frequency_symbol(osc: Oscillator) -> sp.Symbol:
    syms: set[sp.Symbol] = set()
    for w in osc.forcing.frequencies:
        syms |= w.free_symbols
    if not osc.forcing.harmonics:
        raise ModelError(
            f"model {osc.name!r} has no harmonic forcing: harmonic balance here needs a forced "
            "oscillator (the period is the forcing period)"
        )
    if len(syms) != 1:
        raise ModelError(
            f"the forcing frequencies {[str(w) for w in osc.forcing.frequencies]} of model "
            f"{osc.name!r} must be rational multiples of one frequency parameter"
        )
    return next(iter(syms))


def _without_dirac(expr: sp.Expr) -> sp.Expr:
    return expr.replace(sp.DiracDelta, lambda *args: sp.Integer(0))


def _velocity_dirac(g: sp.Expr, x: sp.Symbol, v: sp.Symbol) -> Callable[..., list] | None:
    """``C(x)`` of the Dirac term ``C(x) delta(v)`` of ``dg/dv`` (a force that jumps across
    ``v = 0``: ``sign(v)`` counts as ``2 Heaviside(v) - 1``), lambdified; None without one.
    Dirac terms at other switching surfaces are not handled (dropped, as before)."""
    if not g.has(v) or not (g.has(sp.sign) or g.has(sp.Heaviside)):
        return None
    h = g.replace(sp.sign, lambda a: 2 * sp.Heaviside(a) - 1)
    dv = sp.expand(sp.diff(h, v))
    delta = sp.DiracDelta(v)
    coef = sp.Integer(0)
    for term in sp.Add.make_args(dv):
        if term.has(delta):
            c = sp.simplify(term / delta)
            if c.has(sp.DiracDelta):
                return None
            coef += c.subs(v, 0)
    coef = sp.simplify(coef)
    if coef == 0 or coef.free_symbols - {x}:
        return None
    return _lambdify((x,), [coef])


def _lambdify(args: Sequence[sp.Symbol], exprs: Sequence[sp.Expr]) -> Callable[..., list]:
    mods = [{"Heaviside": lambda z, h0=0.5: np.heaviside(z, h0)}, "numpy"]
    fn = sp.lambdify(args, list(exprs), modules=mods)

    def call(*values: Any) -> list:
        shape = np.broadcast_shapes(*(np.shape(v) for v in values))
        with np.errstate(all="ignore"):
            return [np.broadcast_to(np.asarray(o, dtype=float), shape) for o in fn(*values)]

    return call


def _table_function(table: PolynomialTable) -> Callable[..., list]:
    """``(x, v) -> [g, dg/dx, dg/dv]`` of a polynomial ``g``, broadcast like :func:`_lambdify`."""
    gx, gv = table.derivative(0), table.derivative(1)

    def call(x: Any, v: Any) -> list:
        return [table(x, v), gx(x, v), gv(x, v)]

    return call


def _numeric_or_lambdify(args: Sequence[sp.Symbol], exprs: Sequence[sp.Expr]) -> Callable:
    """:func:`_lambdify`, or for expressions that are all numbers (a forcing amplitude and
    phase free of the frequency: the usual case) their values, with no code generation."""
    if not all(sp.sympify(e).is_number for e in exprs):
        return _lambdify(args, exprs)
    values = [float(e) for e in exprs]

    def call(*given: Any) -> list:
        shape = np.broadcast_shapes(*(np.shape(g) for g in given))
        return [np.broadcast_to(np.asarray(c, dtype=float), shape) for c in values]

    return call


@dataclass(frozen=True)
class _ForcingTerm:
    index: int  # position of a_k in u
    amplitude: Callable[[float], list]  # Omega -> [A, phase, dA, dphase]


class HarmonicBalanceSystem:
    """The harmonic-balance equations ``R(u, Omega) = 0`` of one oscillator.

    Parameters
    ----------
    oscillator : Oscillator
        A forced oscillator ``x'' + g(x, x') = f(t)`` whose forcing frequencies are rational
        multiples of one parameter (the continuation parameter ``Omega``); every other
        parameter needs a value.
    harmonics : int
        ``H``: harmonics ``1..H`` of the orbit frequency ``Omega/m``.
    m : int
        Forcing periods per orbit period (1: harmonic response).
    odd_only : bool
        Odd harmonics only, no bias (odd-symmetric systems).
    projection : {'auto', 'exact', 'aft'}
        ``'exact'`` needs a piecewise-linear restoring force with linear damping; ``'auto'``
        picks it when possible and AFT otherwise.
    samples : int, optional
        AFT samples per period; default ``4 max(K) + 1``.

    Raises
    ------
    ParameterError
        Bad ``harmonics``, ``m``, ``samples`` or ``projection``; parameters without values.
    ModelError
        Models outside the method: no harmonic forcing, parametric terms, a restoring force
        depending on the forcing frequency, forcing harmonics outside the basis.
    """

    def __init__(
        self,
        oscillator: Oscillator,
        *,
        harmonics: int = 15,
        m: int = 1,
        odd_only: bool = False,
        projection: Projection = "auto",
        samples: int | None = None,
    ) -> None:
        if not isinstance(oscillator, Oscillator):
            raise ParameterError(f"oscillator = {oscillator!r}: expected an Oscillator")
        if isinstance(m, bool) or not isinstance(m, int | np.integer) or m < 1:
            raise ParameterError(f"m = {m!r}: expected an integer >= 1 (forcing periods)")
        if projection not in ("auto", "exact", "aft"):
            raise ParameterError(f"projection = {projection!r}: expected 'auto', 'exact' or 'aft'")
        osc = oscillator
        self.oscillator = osc
        self.basis = HarmonicBasis.make(harmonics, odd_only=odd_only)
        self.m = int(m)
        self.harmonics = int(harmonics)
        if osc.parametric != 0:
            raise ModelError(
                f"model {osc.name!r} has parametric terms {osc.parametric}: not supported by "
                "numeric harmonic balance"
            )
        self.frequency = _frequency_symbol(osc)
        subs = {s: v for s, v in osc.substitutions().items() if s != self.frequency}
        missing = sorted(n for n, v in osc.params.items() if v is None and n != self.frequency.name)
        if missing:
            raise ParameterError(
                f"model {osc.name!r} needs values for {', '.join(missing)} for harmonic balance"
            )
        g = osc.g.xreplace(subs)
        if self.frequency in g.free_symbols:
            raise ModelError(
                f"the equation of model {osc.name!r} depends on the forcing frequency "
                f"{self.frequency} outside the forcing: not supported"
            )
        pwl_ok = osc.is_piecewise_linear
        if projection == "exact" and not pwl_ok:
            raise ParameterError(
                f"projection = 'exact' needs a piecewise-linear restoring force with linear "
                f"damping; model {osc.name!r} is not piecewise linear: use projection='aft'"
            )
        self.projection = "exact" if projection == "auto" and pwl_ok else projection
        if self.projection == "auto":
            self.projection = "aft"
        self.damping = float(osc.damping.xreplace(subs))
        self.pwl: NumericPWL | None = None
        if pwl_ok:
            self.pwl = (
                osc.with_params({s.name: float(v) for s, v in subs.items()})
                .piecewise_linear()
                .numeric()
            )
        self._jumps = self.pwl is not None and not bool(np.all(self.pwl.jumps == 0.0))
        self.D = self.basis.derivative_matrix()
        k2 = np.zeros(self.basis.size)
        k2[self.basis.a_index] = self.basis.k**2
        k2[self.basis.b_index] = self.basis.k**2
        self.k2 = k2
        self._forcing(osc, subs)
        kmax = self.basis.kmax
        if self.projection == "exact":
            assert self.pwl is not None
            if samples is not None:
                raise ParameterError(
                    f"samples = {samples!r} applies to projection='aft' only: the exact "
                    "projection does not sample"
                )
            self.samples = None
            self._exact = ExactProjector(self.pwl, self.basis)
        else:
            n_s = 4 * kmax + 1 if samples is None else samples
            if isinstance(n_s, bool) or not isinstance(n_s, int | np.integer) or n_s < 2 * kmax + 1:
                raise ParameterError(
                    f"samples = {samples!r}: expected an integer >= 2*{kmax} + 1 = {2 * kmax + 1}"
                )
            self.samples = int(n_s)
            x, v = osc.x, osc.v
            k_lin = float(osc.linear_stiffness.xreplace(subs))
            self.linear_stiffness = k_lin
            g_nl = g - self.damping * v - k_lin * x
            table = polynomial_table(g_nl, (x, v))
            if table is not None:
                # a polynomial force (Duffing, van der Pol terms): a numeric monomial table
                # and its exact derivatives, no code generation
                self._g = _table_function(table)
                self._dirac_v = None
            else:
                # sampled derivatives cannot hold the Dirac terms of jumps: dropped, except a
                # jump of the force across v = 0 (Coulomb friction r sign(x')), added at the
                # velocity reversals by _reversal_terms
                gx = _without_dirac(sp.diff(g_nl, x))
                gv = _without_dirac(sp.diff(g_nl, v))
                self._g = _lambdify((x, v), [g_nl, gx, gv])
                self._dirac_v = _velocity_dirac(g_nl, x, v)
            self.velocity_dependent = bool(g_nl.has(v))
            th = _TWO_PI * np.arange(self.samples) / self.samples
            self._Phi = self.basis.design(th)
            self._PhiD = self._Phi @ self.D
            Pr = self._Phi.T * (2.0 / self.samples)
            if self.basis.bias:
                Pr[0] *= 0.5
            self._Pr = Pr
        self._cache: tuple[bytes, float, tuple, CrossingIntervals | None] | None = None
        self._forcing_cache: tuple[float, tuple] | None = None

    # ---- forcing -----------------------------------------------------------------------------
    def _forcing(self, osc: Oscillator, subs: dict) -> None:
        W = self.frequency
        terms = []
        for h in osc.forcing.harmonics:
            ratio = h.frequency / W
            if not ratio.is_Rational:
                ratio = sp.nsimplify(sp.simplify(ratio))
            if not ratio.is_Rational or ratio <= 0:
                raise ModelError(
                    f"forcing frequency {h.frequency} is not a positive rational multiple of {W}"
                )
            k = ratio * self.m
            if not k.is_Integer:
                raise ModelError(
                    f"forcing frequency {h.frequency} is harmonic {k} of the orbit frequency "
                    f"{W}/{self.m}: expected an integer (choose m accordingly)"
                )
            pos = self.basis.index_of(int(k))
            if pos is None:
                raise ModelError(
                    f"forcing frequency {h.frequency} is harmonic {int(k)} of the orbit "
                    f"frequency, which the basis {self.basis.harmonics[:4]}... (H = "
                    f"{self.harmonics}) does not contain"
                )
            A = h.amplitude.xreplace(subs)
            p = h.phase.xreplace(subs)
            free = (A.free_symbols | p.free_symbols) - {W}
            if free:
                raise ParameterError(
                    f"forcing amplitude {A} needs values for {sorted(map(str, free))}"
                )
            terms.append(
                _ForcingTerm(pos, _numeric_or_lambdify([W], [A, p, sp.diff(A, W), sp.diff(p, W)]))
            )
        self._terms = tuple(terms)
        c = osc.forcing.constant.xreplace(subs)
        if c.free_symbols - {W}:
            raise ParameterError(f"static load {c} needs values for its parameters")
        if c != 0 and not self.basis.bias:
            raise ModelError(f"a static load {c} needs the bias term: odd_only=True drops it")
        self._constant = _numeric_or_lambdify([W], [c, sp.diff(c, W)])
        depends = c.has(W) or any(
            h.amplitude.xreplace(subs).has(W) or h.phase.xreplace(subs).has(W)
            for h in osc.forcing.harmonics
        )
        # the usual case, a forcing free of the frequency: one vector for every Omega
        self._fixed_forcing = None if depends else self._forcing_at(1.0)

    def forcing_vector(self, Omega: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(harmonic part, static part, d/dOmega of both)`` of the projected forcing."""
        if self._fixed_forcing is not None:
            return self._fixed_forcing
        if self._forcing_cache is not None and self._forcing_cache[0] == Omega:
            return self._forcing_cache[1]
        out = self._forcing_at(float(Omega))
        self._forcing_cache = (Omega, out)
        return out

    def _forcing_at(self, Omega: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        n = self.basis.size
        fh, dfh = np.zeros(n), np.zeros(n)
        for term in self._terms:
            A, p, dA, dp = (float(v) for v in term.amplitude(Omega))
            i = term.index
            fh[i] += A * math.cos(p)
            fh[i + 1] += -A * math.sin(p)
            dfh[i] += dA * math.cos(p) - A * math.sin(p) * dp
            dfh[i + 1] += -dA * math.sin(p) - A * math.cos(p) * dp
        fs = np.zeros(n)
        if self.basis.bias:
            c, dc = (float(v) for v in self._constant(Omega))
            fs[0] = c
            dfh[0] += dc
        return fh, fs, dfh

    # ---- residual and Jacobian ---------------------------------------------------------------
    def evaluate(self, u: ArrayLike, Omega: float, jacobian: bool = True) -> tuple:
        """``(R, J_u, J_Omega)`` (the last two None without ``jacobian``); the last evaluation
        is cached, so ``residual`` then ``jacobian`` at one point cost one evaluation."""
        u = np.asarray(u, dtype=float).reshape(-1)
        Omega = float(Omega)
        key = u.tobytes()
        if self._cache is not None and self._cache[0] == key and self._cache[1] == Omega:
            out = self._cache[2]
            if out[1] is not None or not jacobian:
                return out
        w = Omega / self.m
        Du = self.D @ u
        mu = self.damping
        fh, fs, dfh = self.forcing_vector(Omega)
        R = -(w * w) * self.k2 * u + mu * w * Du - fh - fs
        Ju = Jw = pieces = None
        if self.projection == "exact":
            proj, Jnl, pieces = self._exact.project(u, jacobian)
            R = R + proj
            if jacobian:
                Ju = Jnl + mu * w * self.D
                Ju.flat[:: Ju.shape[0] + 1] -= (w * w) * self.k2
                Jw = (-2.0 * w * self.k2 * u + mu * Du) / self.m - dfh
        else:
            x = self._Phi @ u
            xt = self._PhiD @ u
            g, gx, gv = self._g(x, w * xt)
            R = R + self.linear_stiffness * u + self._Pr @ g
            if jacobian:
                Jnl = self._Pr @ (gx[:, None] * self._Phi + (w * gv)[:, None] * self._PhiD)
                Ju = Jnl + mu * w * self.D
                Ju.flat[:: Ju.shape[0] + 1] += self.linear_stiffness - (w * w) * self.k2
                Jw = (-2.0 * w * self.k2 * u + mu * Du + self._Pr @ (gv * xt)) / self.m - dfh
        out = (R, Ju, Jw)
        self._cache = (key, Omega, out, pieces)
        return out

    def residual(self, u: ArrayLike, Omega: float) -> np.ndarray:
        """``R(u, Omega)``."""
        return self.evaluate(u, Omega, jacobian=True)[0]

    def jacobian(self, u: ArrayLike, Omega: float) -> tuple[np.ndarray, np.ndarray]:
        """``(dR/du, dR/dOmega)``."""
        _, Ju, Jw = self.evaluate(u, Omega, jacobian=True)
        return Ju, Jw

    # ---- orbit statistics --------------------------------------------------------------------
    def statistics(self, U: ArrayLike) -> dict[str, np.ndarray]:
        """Amplitude (max ``|x|``), first-harmonic amplitude (the component at the forcing
        frequency, harmonic ``m``) and mean of each row of ``U``."""
        U = np.atleast_2d(self.basis.check(U))
        amp = _amplitudes(self.basis, U)
        a0, a, b = self.basis.split(U)
        pos = self.basis.index_of(self.m)
        if pos is None:
            first = np.zeros(U.shape[0])
        else:
            first = np.hypot(U[:, pos], U[:, pos + 1])
        return {"amplitude": amp, "first_harmonic_amplitude": first, "mean": a0}

    # ---- stability ---------------------------------------------------------------------------
    def _damping_matrix(self, u: np.ndarray, Omega: float) -> np.ndarray:
        n = self.basis.size
        P = self.damping * np.eye(n)
        if self.projection == "aft" and self.velocity_dependent:
            w = Omega / self.m
            _, _, gv = self._g(self._Phi @ u, w * (self._PhiD @ u))
            P = P + self._Pr @ (gv[:, None] * self._Phi)
            for val, phi, _ in self._reversal_terms(u):
                P = P + np.outer(self._dirac_weight * phi, (val / w) * phi)
        return P

    def _reversal_terms(self, u: np.ndarray) -> list[tuple[float, np.ndarray, np.ndarray]]:
        """The Dirac part of ``dg/dx'`` for a force that jumps by ``C(x)`` across ``x' = 0``
        (e.g. ``C = 2 r`` for ``r sign(x')``): ``C delta(v)`` with ``v = w x_theta`` is, in
        theta, ``sum_c C(x_c) delta(theta - theta_c) / (w |x_thetatheta(theta_c)|)`` over the
        velocity reversals ``theta_c`` of the series. Returns ``(C / |x_thetatheta|, phi,
        phi')`` at each reversal (``phi`` the basis functions there), so that the stiffness
        matrix of Hill's pencil (the Galerkin Jacobian) gains ``sum wts phi phi'^T C /
        |x_thetatheta|`` and its damping matrix ``sum wts phi phi^T C / (w |x_thetatheta|)``.
        With these the Hill multipliers of a Coulomb oscillator converge to the exact ones,
        whose monodromy has the saltation ``diag(1, a+/a-)`` at each reversal (the truncated
        series takes the mean ``(a+ + a-)/2`` there, for which the Dirac update reproduces
        ``a+/a-`` exactly).
        Reversals where ``|x_thetatheta|`` is at rounding level (sticking) are skipped."""
        if getattr(self, "_dirac_v", None) is None:
            return []
        basis = self.basis
        xt = self._PhiD @ u
        n = xt.size
        step = _TWO_PI / n
        idx = np.flatnonzero(np.sign(xt) != np.sign(np.roll(xt, -1)))
        if idx.size == 0 or idx.size > 4 * basis.kmax:
            return []
        D = self.D
        Du = D @ u
        DDu = D @ Du
        scale = max(1.0, float(np.max(np.abs(u))))
        out = []
        for i in idx:
            a, fa, fb = i * step, xt[i], xt[(i + 1) % n]
            th = a + step * fa / (fa - fb) if fa != fb else a
            for _ in range(8):  # Newton on x_theta = 0, kept within the bracket
                row = basis.design(np.array([th]))[0]
                f1, f2 = float(row @ Du), float(row @ DDu)
                if f2 == 0.0:
                    break
                new = th - f1 / f2
                if not a <= new <= a + step:
                    break
                done = abs(new - th) < 1e-14
                th = new
                if done:
                    break
            row = basis.design(np.array([th]))[0]
            curv = abs(float(row @ DDu))
            if curv <= 1e-9 * scale:
                continue
            C = float(self._dirac_v(np.array([float(row @ u)]))[0][0])
            if C != 0.0 and np.isfinite(C):
                out.append((C / curv, row, row @ D))
        return out

    @cached_property
    def _dirac_weight(self) -> np.ndarray:
        """``(1/pi)`` for the harmonic rows of a Galerkin projection, ``1/(2 pi)`` for bias."""
        wts = np.full(self.basis.size, 1.0 / np.pi)
        if self.basis.bias:
            wts[0] = 0.5 / np.pi
        return wts

    def hill_exponents(
        self,
        u: ArrayLike,
        Omega: float,
        J_u: np.ndarray | None = None,
        *,
        full: bool = False,
        refine_complex: bool = True,
    ) -> np.ndarray:
        """The two Floquet exponents (complex) of the HB solution ``u`` by Hill's method.

        Parameters
        ----------
        u, Omega
            The solution.
        J_u : numpy.ndarray, optional
            ``dR/du`` at (or within a last Newton correction of) ``u``; evaluated when absent.
        full : bool
            Always solve the full ``2n`` eigenproblem (eigenvector-centred selection).
            Otherwise, for piecewise-linear forces (constant damping, either projection), the
            Newton path of the module docstring, with the full problem as fallback.
        refine_complex : bool
            On the Newton path, when the exponents are a complex pair their real part is
            ``-mu/2`` exactly (the symmetry of the pencil), which is all ``max_multiplier``
            needs; ``False`` then takes the imaginary part from the exact monodromy about
            the HB orbit instead of refining it on the pencil (no linear solve instead of
            about five; continuation uses it).

        Returns
        -------
        numpy.ndarray
            Two complex exponents, shifted into the strip ``|Im| <= w/2`` (``w`` the orbit
            frequency ``Omega/m``): a Floquet exponent is defined modulo ``i w``.
        """
        u = np.asarray(u, dtype=float).reshape(-1)
        Omega = float(Omega)
        pieces = None
        if J_u is None:
            J_u = self.evaluate(u, Omega)[1]
        c = self._cache
        if c is not None and c[2][1] is J_u:
            pieces = c[3]  # the crossing intervals of the iterate J_u belongs to
        w = Omega / self.m
        C = 2.0 * w * self.D + self._damping_matrix(u, Omega)
        if self.projection == "aft" and self.velocity_dependent:
            # the Dirac part of dg/dx' at velocity reversals (Coulomb friction): in Hill's
            # pencil only; Newton and continuation keep the derivative of the sampled
            # residual, which has none (each sample of sign(x') is constant in u)
            for val, phi, dphi in self._reversal_terms(u):
                J_u = J_u + np.outer(self._dirac_weight * phi, val * dphi)
        if not full and self.pwl is not None:
            lam = self._hill_newton(u, w, C, J_u, pieces, refine_complex)
            if lam is not None:
                return _principal(lam, w)
        return _principal(_hill_full(self.basis, C, J_u, w), w)

    def monodromy(self, u: ArrayLike, Omega: float) -> np.ndarray:
        """Exact monodromy matrix of the linearisation about the (PWL) HB orbit ``u``:
        a product of ``2x2`` exponentials over the crossing intervals, with saltation matrices
        at jumps of the force."""
        if self.pwl is None:
            raise PerturbError("the exact monodromy needs a piecewise-linear force")
        u = np.asarray(u, dtype=float).reshape(-1)
        w = float(Omega) / self.m
        pc = crossing_intervals(self.pwl, self.basis, TruncatedSeries(self.basis, u))
        return _monodromy(self.pwl, self.damping, w, pc, self._jumps)

    def _hill_newton(
        self,
        u: np.ndarray,
        w: float,
        C: np.ndarray,
        K: np.ndarray,
        pieces: CrossingIntervals | None,
        refine_complex: bool,
    ) -> np.ndarray | None:
        assert self.pwl is not None
        T = _TWO_PI / w
        mu = self.damping
        if pieces is None:
            pieces = crossing_intervals(self.pwl, self.basis, TruncatedSeries(self.basis, u))
        try:
            M = _monodromy(self.pwl, mu, w, pieces, self._jumps)
        except (PerturbError, OverflowError, ZeroDivisionError):
            return None
        half_tr = 0.5 * (M[0, 0] + M[1, 1])
        det = M[0, 0] * M[1, 1] - M[0, 1] * M[1, 0]
        disc = half_tr * half_tr - det
        if not (math.isfinite(disc) and det > 0.0):
            return None
        if disc < 0.0:
            big = complex(half_tr, math.sqrt(-disc))
        else:
            root = math.sqrt(disc)
            big = complex(half_tr + math.copysign(root, half_tr))
        seed = complex(np.log(big)) / T
        if disc < 0.0 and not refine_complex:
            return np.array([complex(-0.5 * mu, seed.imag), complex(-0.5 * mu, -seed.imag)])
        lam = _ruhe(C, K, seed, w)
        if lam is None:
            return None
        partner = -mu - np.conj(lam)
        if abs(partner - lam) <= 1e-9 * (abs(lam) + w):
            partner = np.conj(lam)
        return np.array([lam, partner])


#: Systems built in this process, by (oscillator, options): the symbolic set-up (derivatives,
#: the PWL form, compiled functions) is done once per system, not on every call.
_SYSTEMS: OrderedDict[tuple, HarmonicBalanceSystem] = OrderedDict()
_SYSTEMS_KEPT = 32


def compiled_system(
    oscillator: Oscillator,
    *,
    harmonics: int = 15,
    m: int = 1,
    odd_only: bool = False,
    projection: Projection = "auto",
    samples: int | None = None,
) -> HarmonicBalanceSystem:
    """The :class:`HarmonicBalanceSystem` of ``oscillator`` with these options, built once per
    process and then reused (the last ``_SYSTEMS_KEPT`` kept).

    The key is what the system is built from: the model's name, equation and parameter
    values, and the options; so an equal oscillator built again (``builtin_model`` in
    another call) finds the same system. A system's evaluation memo (the last residual and
    Jacobian) is only a cache of pure functions of its arguments, so sharing it is safe.
    Arguments that cannot be keyed (unhashable) are passed to the constructor unkeyed, which
    checks them.
    """
    try:
        params = tuple(sorted((str(k), v) for k, v in oscillator.params.items()))
        key = (
            oscillator.name,
            oscillator.equation,
            params,
            harmonics,
            m,
            odd_only,
            projection,
            samples,
        )
        hash(key)
    except (AttributeError, TypeError):
        key = None
    if key is not None:
        hit = _SYSTEMS.get(key)
        if hit is not None:
            _SYSTEMS.move_to_end(key)
            return hit
    system = HarmonicBalanceSystem(
        oscillator,
        harmonics=harmonics,
        m=m,
        odd_only=odd_only,
        projection=projection,
        samples=samples,
    )
    if key is not None:
        _SYSTEMS[key] = system
        while len(_SYSTEMS) > _SYSTEMS_KEPT:
            _SYSTEMS.popitem(last=False)
    return system


def _expm2(p: float, q: float, h: float) -> tuple[float, float, float, float]:
    """``exp(h [[0, 1], [-q, -p]])`` as ``(m00, m01, m10, m11)``: the closed form of
    :func:`perturb.numeric.stability.expm2` in scalar arithmetic (a monodromy has a handful of
    pieces, where array overhead would dominate)."""
    b2 = 0.25 * p * p - q
    root = math.sqrt(abs(b2))
    z = root * h
    if z < 1e-4:
        c = 1.0 + b2 * h * h / 2.0
        sh = h * (1.0 + b2 * h * h / 6.0)
    elif b2 > 0.0:
        c, sh = math.cosh(z), math.sinh(z) / root
    else:
        c, sh = math.cos(z), math.sin(z) / root
    e = math.exp(-0.5 * p * h)
    return e * (c + 0.5 * p * sh), e * sh, -e * q * sh, e * (c - 0.5 * p * sh)


def _monodromy(
    pwl: NumericPWL, mu: float, w: float, pc: CrossingIntervals, jumps: bool = True
) -> np.ndarray:
    """Ordered product over the crossing intervals, with the saltation ``[[1, 0], [-J/v, 1]]``
    where the force jumps by ``J`` at a crossing with velocity ``v``."""
    slopes, offsets, bps = pwl.slopes, pwl.offsets, pwl.breakpoints
    seg = pc.segment.tolist()
    lengths = (pc.length / w).tolist()
    d1 = pc.d1.tolist()
    m00, m01, m10, m11 = 1.0, 0.0, 0.0, 1.0
    n = len(seg)
    for i in range(n):
        if jumps and d1 and seg[i] != seg[i - 1]:
            # the crossing that starts interval i (interval -1 wraps around the period)
            b, a = seg[i - 1], seg[i]
            d = bps[min(a, b)]
            jump = (slopes[a] - slopes[b]) * d + offsets[a] - offsets[b]
            sigma = -jump / (w * d1[i])
            m10, m11 = m10 + sigma * m00, m11 + sigma * m01
        e00, e01, e10, e11 = _expm2(mu, float(slopes[seg[i]]), lengths[i])
        m00, m01, m10, m11 = (
            e00 * m00 + e01 * m10,
            e00 * m01 + e01 * m11,
            e10 * m00 + e11 * m10,
            e10 * m01 + e11 * m11,
        )
    return np.array([[m00, m01], [m10, m11]])


def _ruhe(C: np.ndarray, K: np.ndarray, seed: complex, w: float) -> complex | None:
    """Eigenvalue of ``lam^2 I + lam C + K`` near ``seed`` by nonlinear inverse iteration
    (Ruhe 1973): ``y = A(lam)^-1 A'(lam) x``, ``lam <- lam - 1/(v^H y)``."""
    n = K.shape[0]
    eye = np.eye(n)
    # a real seed (a real pair of exponents, the case that needs refining) stays real: the
    # pencil is real, and real LU solves cost a quarter of complex ones
    lam: float | complex = float(seed.real) if seed.imag == 0.0 else complex(seed)
    try:
        x = np.linalg.solve(lam * lam * eye + lam * C + K, np.ones(n))
    except np.linalg.LinAlgError:
        # exactly singular: the seed is an eigenvalue (an orbit inside one linear segment,
        # whose exact and Hill exponents coincide)
        return complex(lam)
    x = x / np.linalg.norm(x)
    v = x.conj()
    for _ in range(12):
        A = lam * lam * eye + lam * C + K
        try:
            y = np.linalg.solve(A, (2.0 * lam * eye + C) @ x)
        except np.linalg.LinAlgError:
            return complex(lam)  # exactly singular: lam is the eigenvalue
        vy = v @ y
        if vy == 0 or not np.isfinite(vy):
            return None
        step = 1.0 / vy
        lam -= step
        x = y / vy
        if abs(step) <= 1e-13 * (abs(lam) + w):
            # trust it only if it stayed in the strip of the seed (not a copy lam + i k w)
            return complex(lam) if abs(lam - seed) < 0.25 * w else None
    return None


def _hill_full(basis: HarmonicBasis, C: np.ndarray, K: np.ndarray, w: float) -> np.ndarray:
    n = K.shape[0]
    # mean of dg/dx' (Liouville: the two exponents sum to -p0 modulo i w): the diagonal of
    # C = 2 w D + P is that of P (D has none), p0 + Re p_2k and p0 - Re p_2k at a_k, b_k
    if basis.bias:
        p0 = float(C[0, 0])
    else:
        ia, ib = basis.a_index[0], basis.b_index[0]
        p0 = 0.5 * float(C[ia, ia] + C[ib, ib])
    A = np.zeros((2 * n, 2 * n))
    A[:n, n:] = np.eye(n)
    A[n:, :n] = -K
    A[n:, n:] = -C
    lam, vec = np.linalg.eig(A)
    c = vec[:n]
    # harmonic content of each eigenvector in complex form: +k <- (c_a - i c_b)/2 and
    # -k <- (c_a + i c_b)/2; the physical exponents are centred on harmonic 0
    ca, cb = c[basis.a_index], c[basis.b_index]
    plus = np.abs(ca - 1j * cb) ** 2
    minus = np.abs(ca + 1j * cb) ** 2
    ks = basis.k[:, None]
    weight = plus.sum(0) + minus.sum(0) + (np.abs(c[0]) ** 2 if basis.bias else 0.0)
    centre = (ks * (plus - minus)).sum(0) / np.where(weight > 0, weight, 1.0)
    order = np.lexsort((np.abs(lam.imag), np.round(np.abs(centre), 6)))
    return _distinct_pair(lam, order, w, p0)


def _distinct_pair(lam: np.ndarray, order: np.ndarray, w: float, p0: float) -> np.ndarray:
    """The two physical exponents from eigenvalues ``lam`` ranked by ``order`` (best first).

    The first is the best ranked. The second is not simply the runner-up: where the
    multipliers are real and negative, ``a + i w/2`` and its conjugate ``a - i w/2`` are
    equally centred, yet they are one multiplier ``-e^{aT}`` counted twice (they differ by
    ``i w``), and the other multiplier would be lost. Liouville's formula fixes the partner:
    ``lam1 + lam2 = -p0`` modulo ``i w`` (``p0`` the mean of ``dg/dx'``; for constant damping
    the truncated pencil has this symmetry exactly), so among the best-ranked few the
    partner is the one closest to ``-p0 - lam1`` modulo ``i w``. A complex pair (``lam2 =
    conj lam1``, real part ``-p0/2``) and a real positive pair are chosen as before; a copy
    ``lam1 + i k w`` satisfies the relation only where both multipliers coincide anyway.
    """
    first = order[0]
    pool = order[1 : min(order.size, 8)]
    if pool.size == 0:
        return lam[order[:2]]
    target = -p0 - lam[first]
    d = lam[pool] - target
    d = d - 1j * w * np.round(d.imag / w)
    # ranking breaks near-ties (within rounding of the eigensolver) in favour of centredness
    score = np.abs(d) + 1e-9 * (np.abs(lam[first]) + w) * np.arange(pool.size)
    return lam[[first, pool[int(np.argmin(score))]]]


def _principal(lam: np.ndarray, w: float) -> np.ndarray:
    """Exponents shifted by multiples of ``i w`` into the strip ``|Im| <= w/2`` (a Floquet
    exponent is defined modulo ``i w``; the centred eigenvector may pick any copy)."""
    return lam - 1j * w * np.round(lam.imag / w)


def _amplitudes(basis: HarmonicBasis, U: np.ndarray) -> np.ndarray:
    """``max |x(theta)|`` of each row: grid maxima and minima refined by Newton on ``x' = 0``."""
    N = max(64, _EXTREMA_PER_HARMONIC * basis.kmax)
    h = _TWO_PI / N
    th = h * np.arange(N)
    X = U @ basis.design(th).T  # (P, N)
    left, right = np.roll(X, 1, axis=1), np.roll(X, -1, axis=1)
    is_ext = ((X >= left) & (X >= right)) | ((X <= left) & (X <= right))
    rows, cols = np.nonzero(is_ext)
    t = th[cols]
    a0, a, b = basis.split(U[rows])
    ks = basis.k.astype(float)
    c = a - 1j * b
    lo, hi = t - h, t + h
    for _ in range(8):
        e = np.exp(1j * np.outer(t, ks))
        d1 = (e * (c * (1j * ks))).sum(1).real
        d2 = (e * (c * (-(ks**2)))).sum(1).real
        with np.errstate(divide="ignore", invalid="ignore"):
            tn = t - d1 / d2
        tn = np.where(np.isfinite(tn) & (tn > lo) & (tn < hi), tn, t)
        if np.all(np.abs(tn - t) <= 1e-15):
            t = tn
            break
        t = tn
    e = np.exp(1j * np.outer(t, ks))
    vals = a0 + (e * c).sum(1).real
    amp = np.abs(X).max(axis=1)
    np.maximum.at(amp, rows, np.abs(vals))
    return amp


# =============================================================================================
# solutions
# =============================================================================================
@dataclass(frozen=True, eq=False)
class HarmonicBalanceSolution:
    """One harmonic-balance solution ``x(t) = a0 + sum a_k cos(k Omega t/m) + b_k sin(...)``.

    Attributes
    ----------
    Omega : float
        Forcing frequency.
    m : int
        Forcing periods per orbit period.
    basis : HarmonicBasis
    coefficients : numpy.ndarray
        ``u = [a0, a_1, b_1, ...]``.
    amplitude : float
        ``max |x|`` over the period.
    first_harmonic_amplitude : float
        ``sqrt(a_m^2 + b_m^2)``: the component at the forcing frequency.
    mean : float
        ``a0``.
    exponents : numpy.ndarray
        The two Hill exponents (complex), or empty without stability.
    max_multiplier : float
        ``max |exp(lambda T)|``, NaN without stability.
    stable : bool
    residual : float
        ``max |R|`` at the solution.
    iterations : int
        Newton iterations.
    projection : str
        ``'exact'`` or ``'aft'``.
    samples : int or None
        AFT samples per period.
    """

    Omega: float
    m: int
    basis: HarmonicBasis
    coefficients: np.ndarray
    amplitude: float
    first_harmonic_amplitude: float
    mean: float
    exponents: np.ndarray
    max_multiplier: float
    stable: bool
    residual: float
    iterations: int
    projection: str
    samples: int | None = None

    @property
    def harmonics(self) -> tuple[int, ...]:
        return self.basis.harmonics

    @property
    def a0(self) -> float:
        return float(self.basis.split(self.coefficients)[0])

    @property
    def a(self) -> np.ndarray:
        return self.basis.split(self.coefficients)[1]

    @property
    def b(self) -> np.ndarray:
        return self.basis.split(self.coefficients)[2]

    def __call__(self, t: ArrayLike) -> np.ndarray:
        """``x(t)``."""
        th = np.asarray(t, dtype=float) * self.Omega / self.m
        return self.basis.evaluate(self.coefficients, th.reshape(-1)).reshape(np.shape(t))

    def velocity(self, t: ArrayLike) -> np.ndarray:
        """``x'(t)``."""
        th = np.asarray(t, dtype=float) * self.Omega / self.m
        xt = self.basis.evaluate(self.coefficients, th.reshape(-1), 1)
        return (xt * self.Omega / self.m).reshape(np.shape(t))

    def __repr__(self) -> str:
        return (
            f"HarmonicBalanceSolution(Omega={self.Omega:.6g}, H={self.basis.kmax}, "
            f"{self.projection}, amplitude={self.amplitude:.10g}, "
            f"{'stable' if self.stable else 'unstable'}, max_multiplier={self.max_multiplier:.4g})"
        )


def _check_stability(stability: str) -> str:
    if stability not in ("hill", "hill_full", "none"):
        raise ParameterError(f"stability = {stability!r}: expected 'hill', 'hill_full' or 'none'")
    return stability


def _omega_value(system: HarmonicBalanceSystem, Omega: float | None) -> float:
    if Omega is None:
        Omega = system.oscillator.params.get(system.frequency.name)
        if Omega is None:
            raise ParameterError(
                f"no value for the forcing frequency {system.frequency.name!r}: pass Omega="
            )
    try:
        value = float(Omega)
    except (TypeError, ValueError):
        raise ParameterError(f"Omega = {Omega!r}: expected a positive number") from None
    if not (math.isfinite(value) and value > 0):
        raise ParameterError(f"Omega = {Omega!r}: expected a positive finite number")
    return value


def _equilibria(system: HarmonicBalanceSystem, Omega: float) -> list[float]:
    """Static equilibria of the mean equation ``f(x) = c`` (stable ones first, nearest 0
    first), the starting points of the forcing homotopy."""
    _, fs, _ = system.forcing_vector(Omega)
    c = float(fs[0]) if system.basis.bias else 0.0
    found: list[tuple[bool, float]] = []
    if system.pwl is not None:
        pwl = system.pwl
        edges = np.concatenate([[-np.inf], pwl.breakpoints, [np.inf]])
        for i, (s, o) in enumerate(zip(pwl.slopes, pwl.offsets, strict=True)):
            if s != 0.0:
                x = (c - o) / s
                if edges[i] < x < edges[i + 1]:
                    found.append((s > 0, float(x)))
    else:
        # f(x) = k x + g_nl(x, 0) on a wide grid, roots by bisection of sign changes
        xs = np.linspace(-20.0, 20.0, 4001)
        g, gx, _ = system._g(xs, np.zeros_like(xs))
        f = system.linear_stiffness * xs + g - c
        fp = system.linear_stiffness + gx
        sgn = np.sign(f)
        for i in np.flatnonzero(sgn[:-1] * sgn[1:] <= 0):
            a, b = xs[i], xs[i + 1]
            fa = f[i]
            for _ in range(60):
                mid = 0.5 * (a + b)
                gm, _, _ = system._g(np.array([mid]), np.zeros(1))
                fm = float(system.linear_stiffness * mid + gm[0] - c)
                if (fm >= 0) == (fa >= 0):
                    a, fa = mid, fm
                else:
                    b = mid
            found.append((bool(fp[i] > 0), 0.5 * (a + b)))
    found.sort(key=lambda p: (not p[0], abs(p[1])))
    out = [x for _, x in found]
    return out or [0.0]


def _linear_response(
    system: HarmonicBalanceSystem, Omega: float, centre: float, stiffness: float, damping: float
) -> np.ndarray:
    """Coefficients of the steady state of ``x'' + damping x' + stiffness (x - centre) =
    forcing`` (the projected forcing's harmonics through the linear receptance)."""
    basis = system.basis
    fh, _, _ = system.forcing_vector(Omega)
    w = Omega / system.m
    u = np.zeros(basis.size)
    if basis.bias:
        u[0] = centre
    kw = basis.k * w
    ia, ib = basis.a_index, basis.b_index
    Z = (fh[ia] - 1j * fh[ib]) / (stiffness - kw * kw + 1j * damping * kw)
    u[ia], u[ib] = Z.real, -Z.imag
    return u


def _segment_orbits(
    system: HarmonicBalanceSystem, Omega: float, inside: bool = True
) -> list[np.ndarray]:
    """The closed-form steady states of the linear segments of a PWL force that stay strictly
    inside their segment: exact periodic orbits, and exact HB solutions for any harmonics.
    Stiffening segments first. ``inside=False``: every segment's, also those that leave it
    (guesses only: an orbit that dips just across a breakpoint is one Newton solve away)."""
    pwl = system.pwl
    if pwl is None:
        return []
    _, fs, _ = system.forcing_vector(Omega)
    c = float(fs[0]) if system.basis.bias else 0.0
    edges = np.concatenate([[-np.inf], pwl.breakpoints, [np.inf]])
    found = []
    for i, (slope, offset) in enumerate(zip(pwl.slopes, pwl.offsets, strict=True)):
        if slope == 0.0:
            continue
        centre = (c - offset) / slope
        if centre != 0.0 and not system.basis.bias:
            continue
        u = _linear_response(system, Omega, centre, slope, system.damping)
        reach = float(np.abs(u[system.basis.a_index] - 1j * u[system.basis.b_index]).sum())
        if not inside or (edges[i] < centre - reach and centre + reach < edges[i + 1]):
            found.append((slope <= 0.0, u))
    found.sort(key=lambda p: p[0])
    return [u for _, u in found]


def _equilibrium_guesses(system: HarmonicBalanceSystem, Omega: float) -> list[np.ndarray]:
    """Linear responses about each static equilibrium (stable first)."""
    out = []
    for x_eq in _equilibria(system, Omega):
        if system.pwl is not None:
            stiffness = float(system.pwl.slopes[system.pwl.segment_index(x_eq)])
            damping = system.damping
        else:
            _, gx, gv = system._g(np.array([x_eq]), np.zeros(1))
            stiffness = system.linear_stiffness + float(gx[0])
            damping = system.damping + float(gv[0])
        if x_eq != 0.0 and not system.basis.bias:
            continue
        out.append(_linear_response(system, Omega, x_eq, stiffness, damping))
    return out


def _start_solution(system: HarmonicBalanceSystem, Omega: float, tol: float) -> np.ndarray:
    """A solution at ``Omega`` without a guess: an exact linear-segment orbit (PWL forces),
    else Newton from the linear response about a stable equilibrium, else continuation in the
    forcing amplitude (:func:`_homotopy_start`)."""
    for u in _segment_orbits(system, Omega) + _equilibrium_guesses(system, Omega):
        scale = max(1.0, float(np.abs(u).max()))
        try:
            return newton_fixed(
                system.residual,
                system.jacobian,
                u,
                Omega,
                u_scale=scale,
                tol=tol,
                max_iterations=30,
            )[0]
        except ContinuationError:
            continue
    return _homotopy_start(system, Omega, tol)


def _homotopy_start(system: HarmonicBalanceSystem, Omega: float, tol: float) -> np.ndarray:
    """A solution at ``Omega`` by continuation in the forcing amplitude from a static
    equilibrium (forcing scale 0 -> 1): no guess needed, and folds in the amplitude are
    passed."""
    basis = system.basis
    fh, _, _ = system.forcing_vector(Omega)
    scale = max(1.0, float(np.abs(fh).max()))
    errors = []
    for x_eq in _equilibria(system, Omega)[:3]:
        u0 = np.zeros(basis.size)
        if basis.bias:
            u0[0] = x_eq

        def residual(u: np.ndarray, eps: float) -> np.ndarray:
            return system.evaluate(u, Omega)[0] + (1.0 - eps) * fh

        def jacobian(u: np.ndarray, eps: float) -> tuple[np.ndarray, np.ndarray]:
            return system.evaluate(u, Omega)[1], -fh

        try:
            curve = continue_curve(
                residual,
                jacobian,
                u0,
                0.0,
                (0.0, 1.0),
                u_scale=1e-2 * max(scale, abs(x_eq)),
                lam_scale=1.0,
                adaptive_scale=True,
                ds_max=0.1,
                tol=tol,
                max_points=1000,
                refine_folds=False,
            )
        except ContinuationError as exc:
            errors.append(str(exc))
            continue
        if curve.stop_reason == "window" and abs(curve.lam[-1] - 1.0) < 1e-12:
            return curve.u[-1]
        errors.append(f"homotopy from x = {x_eq:.6g} stopped: {curve.stop_reason}")
    raise PerturbError(
        f"no harmonic-balance solution found at Omega = {Omega}: " + "; ".join(errors)
    )


def _solution(
    system: HarmonicBalanceSystem,
    u: np.ndarray,
    Omega: float,
    iterations: int,
    stability: str,
    J_u: np.ndarray | None = None,
) -> HarmonicBalanceSolution:
    R = system.evaluate(u, Omega)[0]
    stats = system.statistics(u[None, :])
    if stability == "none":
        lam = np.empty(0, dtype=complex)
        mm, stable = math.nan, False
    else:
        # one orbit: the full eigenproblem costs little, and its centred selection also
        # refines the imaginary parts of a complex pair
        lam = system.hill_exponents(u, Omega, J_u, full=True)
        mm = _max_multiplier(lam, Omega / system.m)
        stable = bool(mm < 1.0)
    return HarmonicBalanceSolution(
        Omega=Omega,
        m=system.m,
        basis=system.basis,
        coefficients=u.copy(),
        amplitude=float(stats["amplitude"][0]),
        first_harmonic_amplitude=float(stats["first_harmonic_amplitude"][0]),
        mean=float(stats["mean"][0]),
        exponents=lam,
        max_multiplier=mm,
        stable=stable,
        residual=float(np.abs(R).max()),
        iterations=int(iterations),
        projection=system.projection,
        samples=system.samples,
    )


def _max_multiplier(lam: np.ndarray, w: float) -> float:
    T = _TWO_PI / w
    return float(min(math.exp(min(700.0, float(np.max(lam.real)) * T)), 1e300))


def _guess_vector(system: HarmonicBalanceSystem, guess: Any) -> np.ndarray:
    basis = system.basis
    if isinstance(guess, HarmonicBalanceSolution):
        # map by harmonic number, so a solution with fewer (or more) harmonics seeds this one
        u = np.zeros(basis.size)
        if basis.bias:
            u[0] = guess.a0
        for k, a, b in zip(guess.basis.harmonics, guess.a, guess.b, strict=True):
            pos = basis.index_of(k)
            if pos is not None:
                u[pos], u[pos + 1] = a, b
        return u
    if all(hasattr(guess, a) for a in ("sample", "period", "m", "autonomous")):
        # a periodic orbit (perturb.simulate.PeriodicOrbit): duck-typed, so the numeric layer
        # does not import the reference solvers
        return _orbit_coefficients(system, guess)
    try:
        u = np.asarray(guess, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        u = None
    if u is None or u.size != basis.size or not np.all(np.isfinite(u)):
        what = f"guess = {guess!r:.80}" if u is None else f"guess of {u.size} values"
        raise ParameterError(
            f"{what}: expected {basis.size} finite coefficients [a0, a_1, b_1, ...], "
            "a HarmonicBalanceSolution or a PeriodicOrbit"
        )
    return u


def _orbit_coefficients(system: HarmonicBalanceSystem, orbit: Any) -> np.ndarray:
    """The basis coefficients of a forced periodic orbit (e.g. an exact one from shooting):
    its Fourier series in the HB phase ``tau = 2 pi t / P`` (``P = m 2 pi / Omega``), by the
    trapezoidal rule on equally spaced samples, which is spectrally accurate for a periodic
    function and exact for every basis harmonic below half the sample count."""
    if orbit.autonomous or orbit.m != system.m:
        raise ParameterError(
            f"guess: a forced period-{system.m} orbit expected, got "
            + ("an autonomous limit cycle" if orbit.autonomous else f"period {orbit.m}")
        )
    basis = system.basis
    kmax = max(basis.harmonics, default=0)
    t, x, _ = orbit.sample(max(256, 8 * kmax))
    tau = _TWO_PI * t / orbit.period
    u = np.zeros(basis.size)
    if basis.bias:
        u[0] = float(np.mean(x))
    for k in basis.harmonics:
        pos = basis.index_of(k)
        u[pos] = 2.0 * float(np.mean(x * np.cos(k * tau)))
        u[pos + 1] = 2.0 * float(np.mean(x * np.sin(k * tau)))
    return u


def harmonic_balance_orbit(
    oscillator: Oscillator,
    Omega: float | None = None,
    *,
    harmonics: int = 15,
    m: int = 1,
    odd_only: bool = False,
    projection: Projection = "auto",
    samples: int | None = None,
    guess: ArrayLike | HarmonicBalanceSolution | None = None,
    tol: float = 1e-12,
    stability: Stability = "hill",
) -> HarmonicBalanceSolution:
    """One harmonic-balance solution at forcing frequency ``Omega``.

    Parameters
    ----------
    oscillator : Oscillator
        See :class:`HarmonicBalanceSystem`.
    Omega : float, optional
        Forcing frequency (default: the oscillator's value).
    harmonics, m, odd_only, projection, samples
        See :class:`HarmonicBalanceSystem`.
    guess : array_like, HarmonicBalanceSolution or PeriodicOrbit, optional
        Starting coefficients; a solution of another truncation is mapped by harmonic
        number. Default: continuation in the forcing amplitude from a static equilibrium.
    tol : float
        Newton tolerance on the scaled correction.
    stability : {'hill', 'hill_full', 'none'}
        Hill exponents (for one orbit both solve the full Hill eigenproblem), or none.

    Returns
    -------
    HarmonicBalanceSolution

    Raises
    ------
    ParameterError
        Bad input (the message names it).
    PerturbError
        When Newton does not converge.
    """
    system = compiled_system(
        oscillator,
        harmonics=harmonics,
        m=m,
        odd_only=odd_only,
        projection=projection,
        samples=samples,
    )
    stability = _check_stability(stability)
    W = _omega_value(system, Omega)
    tol = _positive_tol(tol)
    if guess is None:
        u = _start_solution(system, W, tol)
    else:
        u = _guess_vector(system, guess)
    scale = max(1.0, float(np.abs(u).max()))
    fh, fs, _ = system.forcing_vector(W)
    # a residual at rounding level is a solution even where Newton's steps are meaningless
    # (a fold: singular Jacobian)
    floor = 64 * _EPS * max(1.0, float(np.abs(fh).max() + np.abs(fs).max()))
    u, its = newton_fixed(
        system.residual, system.jacobian, u, W, u_scale=scale, tol=tol, residual_tol=floor
    )
    return _solution(system, u, W, its, stability)


def _positive_tol(tol: float) -> float:
    try:
        value = float(tol)
    except (TypeError, ValueError):
        raise ParameterError(f"tol = {tol!r}: expected a positive number") from None
    if not (math.isfinite(value) and value > 0):
        raise ParameterError(f"tol = {tol!r}: expected a positive finite number")
    return value


# =============================================================================================
# frequency responses
# =============================================================================================
@dataclass(frozen=True, eq=False)
class HarmonicBalanceBranch:
    """A continued branch of harmonic-balance solutions over a frequency window.

    Attributes
    ----------
    omega, amplitude, first_harmonic_amplitude, mean, stable, max_multiplier : numpy.ndarray
        Per point, as in :class:`~perturb.response.Branch`.
    coefficients : numpy.ndarray
        Shape ``(n_points, n)``.
    exponents : numpy.ndarray
        Shape ``(n_points, 2)`` complex (empty second axis without stability).
    folds : tuple of (float, float)
        ``(Omega, amplitude)`` at each fold.
    fold_coefficients : tuple of numpy.ndarray
    curve : ContinuationCurve
        The raw continuation result (tangents, iterations, stop reason).
    system : HarmonicBalanceSystem
    params : mapping
        The oscillator's other parameter values.
    branch_points : tuple of (float, float)
        ``(Omega, amplitude)`` at each branch point located on the branch (only when it was
        traced with branch-point detection: :func:`harmonic_balance_branches`).
    branch_point_coefficients : tuple of numpy.ndarray
    branch_point_records : tuple of BranchPoint
        The located points with the other branch's direction
        (:func:`perturb.numeric.continuation.branch_off`).
    origin : str
        How the branch was found: ``'start'`` (from the window's edge), ``'seed'`` (from a
        single-harmonic balance or a linear-segment / equilibrium seed), ``'branch point'``
        (switched onto at a branch point of another branch), ``'edge'`` (a solution at a
        window edge found by :func:`harmonic_balance_branches`' edge search) or ``'mirror'``
        (image of another branch under the symmetry of an odd system).
    """

    omega: np.ndarray
    amplitude: np.ndarray
    first_harmonic_amplitude: np.ndarray
    mean: np.ndarray
    stable: np.ndarray
    max_multiplier: np.ndarray
    coefficients: np.ndarray
    exponents: np.ndarray
    folds: tuple[tuple[float, float], ...]
    fold_coefficients: tuple[np.ndarray, ...]
    curve: ContinuationCurve
    system: HarmonicBalanceSystem
    params: Any = field(default_factory=lambda: MappingProxyType({}))
    branch_points: tuple[tuple[float, float], ...] = ()
    branch_point_coefficients: tuple[np.ndarray, ...] = ()
    branch_point_records: tuple[BranchPoint, ...] = ()
    origin: str = "start"

    def __len__(self) -> int:
        return int(self.omega.size)

    @property
    def method(self) -> str:
        s = self.system
        proj = "exact" if s.projection == "exact" else f"AFT{s.samples}"
        odd = " odd" if not s.basis.bias else ""
        sub = f" m={s.m}" if s.m != 1 else ""
        return f"numeric HB H={s.harmonics}{odd}{sub} {proj}"

    def to_branch(self) -> Branch:
        """The :class:`~perturb.response.Branch` (``max_multiplier`` -1 without stability)."""
        max_mult = np.where(np.isfinite(self.max_multiplier), self.max_multiplier, -1.0)
        return Branch(
            omega=self.omega,
            amplitude=self.amplitude,
            first_harmonic_amplitude=self.first_harmonic_amplitude,
            mean=self.mean,
            stable=self.stable,
            max_multiplier=max_mult,
        )

    def to_response(self) -> Response:
        """The :class:`~perturb.response.Response` (one branch, the project's CSV columns)."""
        branch = self.to_branch()
        notes = (
            f"continuation stopped: {self.curve.stop_reason}; {len(self)} points, "
            f"{self.curve.residual_evaluations} residual evaluations",
        )
        if self.branch_points:
            notes += (_branch_point_note(self.branch_points),)
        if not np.all(np.isfinite(self.max_multiplier)):
            notes += ("stability not computed: max_multiplier = -1",)
        return Response(
            (branch,),
            self.method,
            self.system.oscillator.name,
            dict(self.params),
            folds=self.folds,
            notes=notes,
        )


def _check_window(window: Sequence[float]) -> tuple[float, float]:
    return checks.window(window, "Omega_window")


def harmonic_balance_branch(
    oscillator: Oscillator,
    Omega_window: Sequence[float],
    options: HarmonicBalanceOptions | None = None,
    *,
    start: ArrayLike | HarmonicBalanceSolution | None = None,
    direction: int = -1,
    **knobs: Any,
) -> HarmonicBalanceBranch:
    """Continue harmonic-balance solutions through a frequency window.

    The branch starts at the window's high end by default (``direction=-1``), where the
    response is closest to linear (amplitude ~ F/Omega^2), from ``start`` or, without it,
    from the first of: an exact linear-segment orbit (PWL forces), Newton from the linear
    response about a stable equilibrium, continuation in the forcing amplitude from an
    equilibrium. Pseudo-arclength continuation
    (:func:`perturb.numeric.continuation.continue_curve`) follows it through folds until it
    leaves the window; the points are returned in increasing order along the curve from its
    low-frequency end when it was traced downwards. Branches not connected to the start
    (isolas, symmetry-broken branches born at branch points) are not searched for, nor are
    branch points (:func:`harmonic_balance_branches` does both).

    Parameters
    ----------
    oscillator : Oscillator
    Omega_window : (float, float)
        ``0 < low < high``.
    options : HarmonicBalanceOptions, optional
        The tuning knobs (``harmonics``, ``stability``, ``ds_max``, ...; default: the
        defaults); those of one branch only, the branch-search fields are not used here.
    start : array_like or HarmonicBalanceSolution, optional
        Coefficients of a solution (or a guess, corrected by Newton) at the starting end.
    direction : {-1, 1}
        Start at the high end going down (-1) or at the low end going up (1).
    **knobs
        Fields of :class:`HarmonicBalanceOptions` that shape one branch (``harmonics``, ``m``,
        ``odd_only``, ``projection``, ``samples``, ``stability``, ``ds_max``,
        ``max_points``, ``tol``), replacing those of ``options``.

    Returns
    -------
    HarmonicBalanceBranch

    Raises
    ------
    ParameterError
        Bad input (the message names it).
    PerturbError
        When no starting solution is found.
    """
    o = _options(options, knobs, _BRANCH_FIELDS, "harmonic_balance_branch")
    harmonics, m, odd_only, projection, samples = (
        o.harmonics,
        o.m,
        o.odd_only,
        o.projection,
        o.samples,
    )
    stability, ds_max, max_points, tol = o.stability, o.ds_max, o.max_points, o.tol
    lo, hi = _check_window(Omega_window)
    system = compiled_system(
        oscillator,
        harmonics=harmonics,
        m=m,
        odd_only=odd_only,
        projection=projection,
        samples=samples,
    )
    stability = _check_stability(stability)
    tol = _positive_tol(tol)
    if direction not in (1, -1):
        raise ParameterError(f"direction = {direction!r}: expected 1 or -1")
    return _edge_branch(system, (lo, hi), start, direction, stability, ds_max, tol, max_points)


def _edge_branch(
    system: HarmonicBalanceSystem,
    window: tuple[float, float],
    start: Any,
    direction: int,
    stability: str,
    ds_max: float,
    tol: float,
    max_points: int,
    branch_points: bool = False,
) -> HarmonicBalanceBranch:
    """The branch from the window's edge (:func:`harmonic_balance_branch` after checks)."""
    lo, hi = window
    W0 = lo if direction == 1 else hi
    u0 = _start_solution(system, W0, tol) if start is None else _guess_vector(system, start)
    curve = _trace(
        system, u0, W0, (lo, hi), direction, stability, ds_max, tol, max_points, branch_points
    )
    return _assemble(system, [(curve, direction == -1)], stability)


def _trace(
    system: HarmonicBalanceSystem,
    u0: np.ndarray,
    W0: float,
    window: tuple[float, float],
    direction: int,
    stability: str,
    ds_max: float,
    tol: float,
    max_points: int,
    branch_points: bool = False,
) -> ContinuationCurve:
    """One continuation run from ``(u0, W0)``, with Hill exponents at every point (and the
    branch-point test function with ``branch_points``)."""
    lo, hi = window
    scale = max(1e-10, float(np.abs(u0).max()))
    full = stability == "hill_full"

    def point_stability(u: np.ndarray, W: float, J_u: np.ndarray, _: np.ndarray) -> np.ndarray:
        # runs while the system's cache still holds the point's last iterate, so the crossing
        # intervals for the monodromy seed come for free
        return system.hill_exponents(u, W, J_u, full=full, refine_complex=False)

    return continue_curve(
        system.residual,
        system.jacobian,
        u0,
        W0,
        (lo, hi),
        direction=direction,
        u_scale=1e-2 * scale,
        lam_scale=hi - lo,
        adaptive_scale=True,
        ds_max=ds_max,
        tol=tol,
        max_points=max_points,
        callback=None if stability == "none" else point_stability,
        # fourth-order predictor and acceptance after one correction when the measured
        # quadratic convergence allows it: about one evaluation per point instead of 2.3
        predictor="hermite",
        early_accept=True,
        detect_branch_points=branch_points,
    )


def _assemble(
    system: HarmonicBalanceSystem,
    parts: Sequence[tuple[ContinuationCurve, bool]],
    stability: str,
    origin: str = "start",
) -> HarmonicBalanceBranch:
    """A branch from continuation runs ``(curve, reversed)`` that share their end points
    (the second run starts where the first one did, traced the other way)."""
    Us, Ws, lams = [], [], []
    for i, (curve, rev) in enumerate(parts):
        U, W = curve.u, curve.lam
        lam = (
            np.array(curve.callback_values)
            if stability != "none" and curve.callback_values is not None
            else np.empty((W.size, 0), dtype=complex)
        )
        if rev:
            U, W, lam = U[::-1], W[::-1], lam[::-1]
        if i > 0:
            U, W, lam = U[1:], W[1:], lam[1:]  # the shared starting point
        Us.append(U)
        Ws.append(W)
        lams.append(lam)
    U, W, lam = np.concatenate(Us), np.concatenate(Ws), np.concatenate(lams)
    stats = system.statistics(U)
    n_pts = W.size
    if stability == "none":
        lam = np.empty((n_pts, 0), dtype=complex)
        mm = np.full(n_pts, np.nan)
        stable = np.zeros(n_pts, dtype=bool)
    else:
        T = _TWO_PI * system.m / W
        mm = np.minimum(np.exp(np.minimum(700.0, lam.real.max(axis=1) * T)), 1e300)
        stable = mm < 1.0
    fold_pts = [f for curve, _ in parts for f in curve.folds]
    fold_u = tuple(f.u for f in fold_pts)
    fold_amp = system.statistics(np.array(fold_u))["amplitude"] if fold_u else np.empty(0)
    folds = tuple((float(f.lam), float(a)) for f, a in zip(fold_pts, fold_amp, strict=True))
    bp_records = tuple(b for curve, _ in parts for b in curve.branch_points)
    bp_u = tuple(b.u for b in bp_records)
    bp_amp = system.statistics(np.array(bp_u))["amplitude"] if bp_u else np.empty(0)
    bps = tuple((float(b.lam), float(a)) for b, a in zip(bp_records, bp_amp, strict=True))
    oscillator = system.oscillator
    params = {
        k: v for k, v in oscillator.params.items() if v is not None and k != system.frequency.name
    }
    return HarmonicBalanceBranch(
        omega=W,
        amplitude=stats["amplitude"],
        first_harmonic_amplitude=stats["first_harmonic_amplitude"],
        mean=stats["mean"],
        stable=stable,
        max_multiplier=mm,
        coefficients=U,
        exponents=lam,
        folds=folds,
        fold_coefficients=fold_u,
        curve=parts[0][0],
        system=system,
        params=MappingProxyType(params),
        branch_points=bps,
        branch_point_coefficients=bp_u,
        branch_point_records=bp_records,
        origin=origin,
    )


def _on_branch(branch: HarmonicBalanceBranch, u: np.ndarray, W: float, rtol: float) -> bool:
    """Whether the solution ``u`` at ``W`` lies on ``branch``: within ``rtol`` (relative to
    its largest coefficient) of the chord of a segment that brackets ``W``. The chords are
    ``ds_max`` apart along the curve, so they deviate from it by ``~ds_max^2/8``, far below
    the distance between two different solutions at one frequency."""
    Wb, Ub = branch.omega, branch.coefficients
    seg = np.nonzero((Wb[:-1] - W) * (Wb[1:] - W) <= 0.0)[0]
    scale = max(1e-12, float(np.abs(u).max()))
    for i in seg:
        dw = Wb[i + 1] - Wb[i]
        f = 0.5 if dw == 0 else (W - Wb[i]) / dw
        chord = (1 - f) * Ub[i] + f * Ub[i + 1]
        if float(np.abs(chord - u).max()) <= rtol * scale:
            return True
    return False


def odd_symmetry(system: HarmonicBalanceSystem, window: tuple[float, float]) -> np.ndarray | None:
    """The matrix ``S`` of the symmetry ``x(theta) -> -x(theta + pi/m)`` (half a forcing
    period) on the coefficients, if it maps solutions to solutions, else None.

    The symmetry and its blocks on each harmonic are those of :mod:`perturb.model.symmetry`
    (:func:`~perturb.model.symmetry.mirror_harmonic`); what is decided here is whether this
    *discretised* system commutes with it.

    For an odd restoring force (and damping), no static load and forcing harmonics that the
    half-period shift negates, ``R(S u) = S R(u)``: the image of a solution is a solution.
    With ``theta -> theta + delta``, ``delta = pi/m``, harmonic ``k`` turns by ``k delta``,
    ``(a_k, b_k) -> -(a_k cos k delta + b_k sin k delta, b_k cos k delta - a_k sin k
    delta)``, and ``a0 -> -a0``; for ``m = 1`` the odd harmonics stay and the even ones and the
    bias change sign. Rather than inspecting the equation, the property is checked on the
    residual itself at two random coefficient vectors (so it holds for whatever this system
    evaluates, PWL or AFT). None too for a basis without bias and even harmonics, where ``S``
    is the identity on every solution (nothing to mirror, and no branch point can break the
    symmetry inside the basis)."""
    basis = system.basis
    S = np.zeros((basis.size, basis.size))
    if basis.bias:
        S[0, 0] = -1.0
    for k, ia in zip(basis.k, basis.a_index, strict=True):
        S[ia : ia + 2, ia : ia + 2] = mirror_harmonic(k, system.m)
    if np.allclose(S, np.eye(basis.size), atol=1e-12):
        return None
    rng = np.random.default_rng(2024)
    W = 0.5 * (window[0] + window[1])
    for _ in range(2):
        # coefficients decaying with k, and a bias, so that a PWL force switches unevenly
        u = rng.normal(size=basis.size) / (1.0 + np.arange(basis.size))
        u *= 3.0 / max(1e-12, float(np.abs(u).max()))
        R1 = system.evaluate(S @ u, W, jacobian=False)[0]
        R2 = S @ system.evaluate(u, W, jacobian=False)[0]
        if float(np.abs(R1 - R2).max()) > 1e-9 * (1.0 + float(np.abs(R2).max())):
            return None
    return S


def mirror_branch(branch: HarmonicBalanceBranch, S: np.ndarray) -> HarmonicBalanceBranch:
    """The image of ``branch`` under the symmetry ``S`` (:func:`odd_symmetry`): exact, with
    no continuation (the Hill exponents and stability of an image are those of the orbit).
    Scaled tangents map by ``S`` too, since the scale of the unknowns is the same number for
    every coefficient."""
    system = branch.system
    n = S.shape[0]

    def tangent(t: np.ndarray) -> np.ndarray:
        return np.append(S @ t[:n], t[n:])

    def mirror_bp(b: BranchPoint) -> BranchPoint:
        return replace(b, u=S @ b.u, tangent=tangent(b.tangent), direction=tangent(b.direction))

    curve = branch.curve
    curve = replace(
        curve,
        u=curve.u @ S.T,
        tangents=np.array([tangent(t) for t in curve.tangents]),
        folds=tuple(FoldPoint(f.index, f.lam, S @ f.u, f.refined) for f in curve.folds),
        branch_points=tuple(mirror_bp(b) for b in curve.branch_points),
    )
    U = branch.coefficients @ S.T
    stats = system.statistics(U)
    return replace(
        branch,
        amplitude=stats["amplitude"],
        first_harmonic_amplitude=stats["first_harmonic_amplitude"],
        mean=stats["mean"],
        coefficients=U,
        fold_coefficients=tuple(S @ u for u in branch.fold_coefficients),
        branch_point_coefficients=tuple(S @ u for u in branch.branch_point_coefficients),
        branch_point_records=tuple(mirror_bp(b) for b in branch.branch_point_records),
        curve=curve,
        origin="mirror",
    )


def _linear_seeds(
    system: HarmonicBalanceSystem, window: tuple[float, float], count: int
) -> list[tuple[float, np.ndarray]]:
    """Starting guesses ``(Omega, u)`` at ``count`` frequencies spread over the window (its
    edges included): for a PWL force the closed-form orbits of its linear segments that stay
    in their segment (exact HB solutions, wherever they exist), otherwise the linear
    responses about every static equilibrium (the linear responses of a PWL force's
    equilibria are its segment orbits, or poor guesses where those leave the segment: a
    failed Newton solve costs more than a traced branch). They reach the branches of orbits
    around one well that the zero-mean single-harmonic seeds miss and that no branch point in
    the window connects to the others (e.g. the in-well branches of nsd at k = -3 below
    Omega ~ 0.6, which continue from the segment orbit about x = -4 at the low edge)."""
    out = []
    for W in np.linspace(window[0], window[1], count):
        W = float(W)
        guesses = (
            _segment_orbits(system, W)
            if system.pwl is not None
            else _equilibrium_guesses(system, W)
        )
        out.extend((W, u) for u in guesses)
    return out


def _near_polyline(
    branch: HarmonicBalanceBranch, u: np.ndarray, W: float, rtol: float, width: float
) -> bool:
    """Whether ``(u, W)`` lies within ``rtol`` of the polyline of ``branch`` in coordinates
    scaled as the continuation scales them (coefficients by the point's largest, ``Omega`` by
    the window width). Unlike :func:`_on_branch` it needs no segment that brackets ``W``, so
    it also recognises a point at the tip of a fold, beyond every sample of the branch."""
    scale = max(1e-12, float(np.abs(u).max()))
    P = np.column_stack([branch.coefficients / scale, branch.omega / width])
    q = np.append(np.asarray(u, dtype=float) / scale, W / width)
    a, d = P[:-1], np.diff(P, axis=0)
    dd = np.einsum("ij,ij->i", d, d)
    t = np.clip(np.einsum("ij,ij->i", q - a, d) / np.where(dd > 0.0, dd, 1.0), 0.0, 1.0)
    dist = np.sqrt(np.min(np.einsum("ij,ij->i", a + t[:, None] * d - q, a + t[:, None] * d - q)))
    return bool(dist <= rtol)


def _duplicate(
    branch: HarmonicBalanceBranch,
    found: Sequence[HarmonicBalanceBranch],
    rtol: float,
    width: float,
) -> bool:
    """Whether every one of nine points spread along ``branch`` lies on one of ``found``
    (:func:`_near_polyline`): a branch traced again from another start, or the mirror image
    of a branch that is its own image (a closed loop of an odd system traced the other way
    round, whose end points are fold tips)."""
    if len(branch) < 2:
        return any(
            len(b) >= 2 and _near_polyline(b, branch.coefficients[0], float(branch.omega[0]),
                                           rtol, width)
            for b in found
        )  # fmt: skip
    idx = np.unique(np.linspace(0, len(branch) - 1, 9).round().astype(int))
    return all(
        any(
            len(b) >= 2
            and _near_polyline(b, branch.coefficients[i], float(branch.omega[i]), rtol, width)
            for b in found
        )
        for i in idx
    )


def _branch_point_note(points: Sequence[tuple[float, float]]) -> str:
    return "branch points at Omega = " + ", ".join(f"{w:.6g} (A={a:.6g})" for w, a in points)


#: Frequencies (window edges included) of the linear-segment and equilibrium seeds.
_LINEAR_SEED_FREQUENCIES = 5
#: Initial conditions per axis of the simulations of :func:`_attractor_guesses`: at the
#: window edges, and at the frequencies in between (the coarse grid there when the fine one
#: would exceed ``_ATTRACTOR_MAX_WORK``). A 5 x 5 grid reaches small basins that 3 x 3 and
#: 4 x 4 miss (nsd k = -3 at Omega 0.3155: the stable tip of the branch on 0.2-0.3164).
_ATTRACTOR_GRID_EDGE = 5
_ATTRACTOR_GRID = 5
_ATTRACTOR_GRID_COARSE = 3
#: Most state-steps (RK4 steps times trajectories) of the simulation of
#: :func:`_attractor_guesses` (~0.11 us each: 1e7 is ~1.1 s): beyond it the coarse grid of
#: states is used between the window's edges, and beyond that again (very light damping,
#: stiff segments, a very wide window) the search is skipped.
_ATTRACTOR_MAX_WORK = 10_000_000
#: Largest ratio of neighbouring frequencies of the attractor search across the window, and
#: most frequencies: a stable isola narrower than that ratio can be missed.
_ATTRACTOR_RATIO = 1.02
_ATTRACTOR_FREQUENCIES = 128
#: Bias shifts of each known solution at a window edge (:func:`_bias_shifted`), in units of
#: the smallest nonzero breakpoint magnitude (1 without breakpoints).
_EDGE_BIAS_SHIFT = 0.5
#: Offset of the simulation starts beside an unstable traced orbit (:func:`_saddle_starts`,
#: relative to ``max(1, |x0|, |v0|)``) and most such orbits (each gives four starts).
_SADDLE_OFFSET = 0.01
_SADDLE_MAX_ORBITS = 400
#: Settling test of those trajectories (``x(t)`` and ``x(t - P)`` within this share of the
#: amplitude), looser than the grid's 5 %: a start beside a saddle that lingers near a weakly
#: unstable orbit is a guess Newton corrects onto it (nsd k = -3 at Omega 0.2345, just off the
#: stable band 0.2349-0.2352 of the pair it belongs to: only the looser test keeps it).
_SADDLE_SETTLED = 0.2
#: Newton iterations of an edge guess: a guess that has not converged by then is far from
#: every solution (edge guesses are many; a failure should cost little).
_EDGE_NEWTON_ITERATIONS = 20


def _acceleration(system: HarmonicBalanceSystem) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """``(x, v) -> g(x, v)`` of the equation ``x'' + g(x, x') = f(t)``, vectorised."""
    mu = system.damping
    if system.pwl is not None:
        pwl = system.pwl
        return lambda x, v: mu * v + pwl(x)
    k_lin = system.linear_stiffness

    def g(x: np.ndarray, v: np.ndarray) -> np.ndarray:
        return mu * v + k_lin * x + system._g(x, v)[0]

    return g


def _attractor_guesses(
    system: HarmonicBalanceSystem,
    Omegas: Sequence[float],
    grids: Sequence[int],
    starts: Sequence[tuple[float, float, float]] = (),
    settled: float = 0.05,
) -> list[tuple[float, np.ndarray]]:
    """``(Omega, coefficients)`` of the attractors reached at each of ``Omegas`` from a grid
    of initial states (``grids[i]**2`` of them at ``Omegas[i]``; ``_ATTRACTOR_GRID_COARSE``
    per axis between the first and the last frequency when that would exceed the work cap).

    One fixed-step RK4 simulation of ``x'' + g(x, x') = f(t)`` for every frequency and
    initial state at once (states in ``[-e, e]^2``, ``e`` three times the largest
    breakpoint, at least 3), for eight damping times (a transient decays by ``e^-4``, close
    enough for Newton) and at least three orbit periods; the last orbit period of each
    trajectory that has settled (``x(t)`` and ``x(t - P)`` within 5 % of its amplitude) is
    resampled on ``4 K + 4`` phases and projected onto the basis. Only a guess for Newton on
    the HB residual, so the step is coarse (0.15 over the largest natural frequency, and at
    least 32 steps per shortest period, whatever ``K``): the stable orbits, of whatever
    branch, are
    reached without any approximation's help, where Newton from a generic guess rarely
    converges (the basins of a non-smooth force are small). Nothing for an undamped system
    (no attractor to settle on) or when the work would exceed ``_ATTRACTOR_MAX_WORK``
    state-steps; at most one guess per attractor (1 % apart) and frequency. PWL forces only:
    their Newton basins are the small ones, and a smooth force's stiffness grows with the
    state box (Duffing: the search costs ~0.7 s, 2.5x its whole response with every branch,
    and found nothing new on the bench problem).

    ``starts``: further trajectories ``(Omega, x0, v0)`` (at ``Omega``, which need not be one
    of ``Omegas``; ``Omegas`` with grids of 0 states is allowed), simulated with the others."""
    mu = system.damping
    if system.pwl is None or not mu > 0.0 or not (len(Omegas) or len(starts)):
        return []
    starts = list(starts)
    if starts:
        Omegas = [*Omegas, *(s[0] for s in starts)]
        grids = [*grids, *([0] * len(starts))]
    ext = 3.0
    if system.pwl is not None and system.pwl.breakpoints.size:
        ext = max(ext, 3.0 * float(np.abs(system.pwl.breakpoints).max()))
    g = _acceleration(system)
    xs = np.linspace(-ext, ext, 201)
    with np.errstate(all="ignore"):
        # largest local stiffness over the grid of states, by differences of g(x, 0)
        gx = np.abs(np.diff(g(xs, np.zeros_like(xs)))) / (xs[1] - xs[0])
    if not np.all(np.isfinite(gx)):
        return []
    periods = _TWO_PI * system.m / np.asarray(Omegas, dtype=float)
    kmax = max(system.basis.kmax, 1)
    w_max = max(math.sqrt(float(gx.max())), _TWO_PI / float(periods.min()), mu)
    # the step resolves the dynamics, not the basis: the guess's high harmonics are only as
    # good as the interpolation, and Newton corrects them (so the cost does not grow with H)
    h = min(0.15 / w_max, float(periods.min()) / 32.0)
    t_end = max(8.0 / mu, 3.0 * float(periods.max()))
    steps = math.ceil(t_end / h)
    n_keep = math.ceil(2.0 * float(periods.max()) / h) + 2
    n_grid = len(grids) - len(starts)
    grids = list(grids[:n_grid])
    if steps * sum(n * n for n in grids) > _ATTRACTOR_MAX_WORK:
        # over budget: the coarse grid of states between the first and last frequency
        grids[1:-1] = [min(n, _ATTRACTOR_GRID_COARSE) for n in grids[1:-1]]
        if steps * sum(n * n for n in grids) > _ATTRACTOR_MAX_WORK:
            return []
    if steps * (sum(n * n for n in grids) + len(starts)) > _ATTRACTOR_MAX_WORK:
        starts = []  # the grid first: the starts beside known orbits are the extra
    W = np.repeat(np.asarray(Omegas[:n_grid], dtype=float), [n * n for n in grids])
    x = np.concatenate([[], *(np.repeat(np.linspace(-ext, ext, n), n) for n in grids)])
    v = np.concatenate([[], *(np.tile(np.linspace(-ext, ext, n), n) for n in grids)])
    if starts:
        W = np.concatenate((W, [s[0] for s in starts]))
        x = np.concatenate((x, [s[1] for s in starts]))
        v = np.concatenate((v, [s[2] for s in starts]))
    if not x.size:
        return []
    w_orbit = W / system.m
    P = _TWO_PI / w_orbit
    # the forcing of each column: its static part and its harmonics (few are nonzero)
    W_distinct, column_of = np.unique(W, return_inverse=True)
    F = np.array([np.add(*system.forcing_vector(float(w))[:2]) for w in W_distinct])
    F = F[column_of]
    used = np.flatnonzero(np.any(F != 0.0, axis=0))
    terms = []
    for i in used:
        if system.basis.bias and i == 0:
            terms.append((0, 0, F[:, 0]))
            continue
        j = (i - (1 if system.basis.bias else 0)) // 2
        k = int(system.basis.k[j])
        terms.append((k, 1 if i == system.basis.a_index[j] else 2, F[:, i]))

    def force(t: float) -> np.ndarray:
        th = w_orbit * t
        out = np.zeros_like(th)
        for k, kind, c in terms:
            out += c if kind == 0 else c * (np.cos(k * th) if kind == 1 else np.sin(k * th))
        return out

    keep = np.empty((n_keep, x.size))
    with np.errstate(all="ignore"):
        t = 0.0
        f0 = force(0.0)
        for i in range(steps):
            fm, f1 = force(t + 0.5 * h), force(t + h)
            k1v = f0 - g(x, v)
            k2x = v + 0.5 * h * k1v
            k2v = fm - g(x + 0.5 * h * v, k2x)
            k3x = v + 0.5 * h * k2v
            k3v = fm - g(x + 0.5 * h * k2x, k3x)
            k4x = v + h * k3v
            k4v = f1 - g(x + h * k3x, k4x)
            x = x + (h / 6.0) * (v + 2.0 * k2x + 2.0 * k3x + k4x)
            v = v + (h / 6.0) * (k1v + 2.0 * k2v + 2.0 * k3v + k4v)
            t, f0 = t + h, f1
            if i >= steps - n_keep:
                keep[i - (steps - n_keep)] = x
    times = t - h * np.arange(n_keep - 1, -1, -1)
    q = np.arange(4 * kmax + 4) / (4 * kmax + 4)
    out: list[tuple[float, np.ndarray]] = []
    for c in range(x.size):
        col = keep[:, c]
        if not np.all(np.isfinite(col)):
            continue
        t_last = t - P[c] + P[c] * q
        now = np.interp(t_last, times, col)
        before = np.interp(t_last - P[c], times, col)
        amp = max(1e-12, float(np.abs(now).max()))
        if float(np.abs(now - before).max()) > settled * amp:
            continue
        # phase of each sample in the HB variable theta = Omega t / m
        design = system.basis.design(w_orbit[c] * t_last)
        u = np.linalg.lstsq(design, now, rcond=None)[0]
        scale = max(1.0, float(np.abs(u).max()))
        if not any(Wo == W[c] and float(np.abs(u - w).max()) <= 1e-2 * scale for Wo, w in out):
            out.append((float(W[c]), u))
    return out


def _saddle_starts(
    system: HarmonicBalanceSystem,
    branches: Sequence[HarmonicBalanceBranch],
    Omegas: Sequence[float],
) -> list[tuple[float, float, float]]:
    """``(Omega, x0, v0)``: beside every unstable orbit of ``branches`` that crosses one of
    ``Omegas`` (coefficients interpolated between neighbouring points), its state at
    ``t = 0`` shifted by ``+-_SADDLE_OFFSET max(1, |state|)`` in ``x`` and in ``x'``: the
    sides of its unstable manifold, which lead to the attractors connected to it (a stable
    stretch near a fold whose basin a grid of states rarely meets: nsd k = -3, the pair
    stable only on Omega 0.2349-0.2352). At most ``_SADDLE_MAX_ORBITS`` orbits, spread
    evenly over the crossings."""
    orbits: list[tuple[float, np.ndarray]] = []
    for b in branches:
        Wb, Ub, stable = b.omega, b.coefficients, np.asarray(b.stable, dtype=bool)
        if Wb.size < 2 or stable.size != Wb.size:
            continue
        for W in Omegas:
            for i in np.nonzero((Wb[:-1] - W) * (Wb[1:] - W) <= 0.0)[0]:
                if stable[i] and stable[i + 1]:
                    continue
                dw = Wb[i + 1] - Wb[i]
                f = 0.5 if dw == 0 else (W - Wb[i]) / dw
                orbits.append((float(W), (1 - f) * Ub[i] + f * Ub[i + 1]))
    if len(orbits) > _SADDLE_MAX_ORBITS:
        pick = np.linspace(0, len(orbits) - 1, _SADDLE_MAX_ORBITS).round().astype(int)
        orbits = [orbits[j] for j in pick]
    out = []
    for W, u in orbits:
        x0 = float(system.basis.evaluate(u, [0.0])[0])
        v0 = float(system.basis.evaluate(u, [0.0], derivative=1)[0]) * W / system.m
        d = _SADDLE_OFFSET * max(1.0, abs(x0), abs(v0))
        for dx, dv in ((d, 0.0), (-d, 0.0), (0.0, d), (0.0, -d)):
            out.append((W, x0 + dx, v0 + dv))
    return out


def _solutions_on(branches: Sequence[HarmonicBalanceBranch], Omega: float) -> list[np.ndarray]:
    """The points of ``branches`` at ``Omega``: samples there and chords that bracket it."""
    out = []
    for b in branches:
        Wb, Ub = b.omega, b.coefficients
        for i in np.nonzero((Wb[:-1] - Omega) * (Wb[1:] - Omega) <= 0.0)[0]:
            dw = Wb[i + 1] - Wb[i]
            f = 0.5 if dw == 0 else (Omega - Wb[i]) / dw
            out.append((1 - f) * Ub[i] + f * Ub[i + 1])
    return out


def _bias_shifted(system: HarmonicBalanceSystem, known: Sequence[np.ndarray]) -> list[np.ndarray]:
    """Each of ``known`` with its bias shifted by ``+-_EDGE_BIAS_SHIFT`` times the smallest
    nonzero breakpoint magnitude (1 without breakpoints): guesses for asymmetric orbits near a
    known one (an unstable branch next to one that crosses a window edge); nothing without a
    bias term."""
    if not system.basis.bias:
        return []
    d = 1.0
    if system.pwl is not None:
        bp = np.abs(system.pwl.breakpoints)
        bp = bp[bp > 0.0]
        if bp.size:
            d = float(bp.min())
    out = []
    for u in known:
        for sign in (-1.0, 1.0):
            w = np.array(u, dtype=float)
            w[0] += sign * _EDGE_BIAS_SHIFT * d
            out.append(w)
    return out


#: Distance (scaled: coefficients over their largest, Omega over the window width) of the
#: first point on the other branch from a branch point, as a multiple of ``ds_max``.
_BRANCH_OFF_STEP = 1.0


def harmonic_balance_branches(
    oscillator: Oscillator,
    Omega_window: Sequence[float],
    options: HarmonicBalanceOptions | None = None,
    *,
    start: ArrayLike | HarmonicBalanceSolution | None = None,
    direction: int = -1,
    seeds: SeedFunction | None = None,
    **knobs: Any,
) -> tuple[HarmonicBalanceBranch, ...]:
    """Every harmonic-balance branch that continuation reaches from the automatic start, from
    seeds, and by branch switching.

    In order:

    1. :func:`harmonic_balance_branch` from the window's edge (``origin='start'``).
    2. Seeds (``origin='seed'``): the caller's ``seeds(system, window, seeds_per_branch)``
       (the front door :func:`perturb.solve.frequency_response` passes
       :func:`perturb.seeds.single_harmonic_seeds`: ``seeds_per_branch`` points along each
       branch of the single-harmonic balance response, detached loops included); then, at five
       frequencies across the window (edges included), the closed-form orbits of the linear
       segments of a PWL force that stay in their segment and the linear responses about
       each static equilibrium (:func:`_linear_seeds`: the one-well branches that the
       zero-mean single-harmonic seeds cannot reach). Each is corrected by Newton into an
       ``H``-harmonic solution, and one that lies on no branch found so far
       (:func:`_on_branch`, 5 % of the largest coefficient) starts a new branch, traced both
       ways until it closes or leaves the window.
    3. Branch switching (``branch_points``, ``origin='branch point'``): every branch is
       traced with the branch-point test function of
       :func:`perturb.numeric.continuation.continue_curve` (the sign of the augmented
       determinant, which changes at a branch point and not at a fold; for an odd system
       on a symmetric branch it is where a real Hill/Floquet multiplier crosses +1 without
       a fold: a symmetry-breaking pitchfork). At each located branch point
       (:attr:`HarmonicBalanceBranch.branch_points`) the other branch's direction, the
       second null vector of ``[dR/du | dR/dOmega]`` (for the pitchfork: the bias and the
       even harmonics), is stepped along both ways by ``ds_max`` and corrected onto the
       other branch (:func:`perturb.numeric.continuation.branch_off`); a point on no known
       branch starts a new one, traced both ways and searched for branch points in turn.
    3b. Attractors and window edges (``attractors``, ``origin='attractor'`` or ``'edge'``): Newton
       from the stable orbits reached by one short fixed-step simulation from a grid of initial
       states at frequencies spaced by a ratio of at most 1.02 across the window (at most 128 of
       them, 5 x 5 states each, 3 x 3 between the edges when that would exceed the work cap:
       :func:`_attractor_guesses`), and at each edge from each solution already found there with its
       bias shifted both ways by half the smallest breakpoint and from every linear segment's
       closed-form orbit, also one that leaves its segment (nsd k = -2, window from 0.2: the
       unstable pair on 0.2-0.2021 with mean +-3, the outer segment's orbit dipping just below
       x = 1); then from the orbits one more such
       simulation reaches from the states beside every unstable orbit traced so far at those
       frequencies (``+-1 %`` in ``x`` and in ``x'``, at most 400 orbits: :func:`_saddle_starts`; a
       looser settling test). A guess or solution on no branch found so far (nor, for an odd system,
       its mirror image) starts a branch, traced both ways and searched for branch points. This
       finds what neither a seed nor a branch point inside the window reaches: a stable isola (nsd,
       k = 2: the one on Omega 0.5915-0.6151; clearance: 0.508-0.654), an isola that straddles an
       edge (k = -0.5: the asymmetric pair on 0.2991-0.3021, window from 0.3), a branch that enters
       at an edge and folds back out (k = -3, window from 0.2: the stable pair on 0.2-0.2116 and,
       from bias shifts, the unstable one on 0.2-0.4073; beside the saddles, the pair on 0.2-0.2351
       stable only on ~0.2349-0.2352). PWL forces only (:func:`_attractor_guesses`); skipped without
       damping or when the simulation would exceed ``_ATTRACTOR_MAX_WORK`` state-steps.
    4. Mirror images (``mirror``, odd systems: :func:`odd_symmetry`, ``origin='mirror'``):
       each branch that is not its own image under ``x(t) -> -x(t + T/2)`` gets its image,
       exactly and without continuation.

    Branches that none of these reach can still be missed: ones born at a branch point
    outside the window that reach the window's edges only as unstable orbits far from the
    bias-shifted known ones, isolas inside the window far from every seed.

    Cost: the symbolic single-harmonic balance and its compilation (about 1-2 s the first
    time in a process; SymPy caches make repeats cheaper), the continuation of every branch,
    and with ``branch_points`` one ``(n + 1)``-square LU per point (``n = 2H + 1``: ~3 % of
    a point's cost at ``H = 15``), 10-40 corrections to locate each branch point (~13 ms at
    ``H = 15``) and a few per side of it. Measured on nsd (mu = 0.05, F = 2, window (0.2,
    2), H = 15, CPU time of a repeated call): k = -3, seven branches, ~1.0 s; k = -0.5, four
    branches, ~1.0 s; about 0.3 s each before (three and one branches); see the module
    docstring.

    Parameters
    ----------
    oscillator, Omega_window
        See :func:`harmonic_balance_branch`.
    options : HarmonicBalanceOptions, optional
        The tuning knobs, the branch-search fields (``seeds_per_branch``,
        ``branch_points``, ``mirror``, ``max_branches``) included.
    start, direction
        See :func:`harmonic_balance_branch` (for the first branch only).
    seeds : callable, optional
        ``seeds(system, window, per_branch)`` returning starting guesses ``(Omega, u)``
        (coefficient vectors of ``system``), e.g. :func:`perturb.seeds.single_harmonic_seeds`
        (an approximation's branches).  They only start Newton on this system's residual.
        Default: none (the linear-segment and equilibrium seeds only).
    **knobs
        Any field of :class:`HarmonicBalanceOptions`, replacing that of ``options``.

    Returns
    -------
    tuple of HarmonicBalanceBranch
        The connected branch first, then the others in the order found (for a branch traced
        both ways from its seed, ``curve`` is the first run only).

    Raises
    ------
    ParameterError
        Bad input (the message names it).
    PerturbError
        When no starting solution is found for the first branch.
    """
    o = _options(options, knobs, _ALL_FIELDS, "harmonic_balance_branches")
    harmonics, m, odd_only, projection, samples = (
        o.harmonics,
        o.m,
        o.odd_only,
        o.projection,
        o.samples,
    )
    stability, ds_max, max_points, tol = o.stability, o.ds_max, o.max_points, o.tol
    seeds_per_branch, branch_points, mirror, max_branches, attractors = (
        o.seeds_per_branch,
        o.branch_points,
        o.mirror,
        o.max_branches,
        o.attractors,
    )
    for name, value, least in (
        ("seeds_per_branch", seeds_per_branch, 1),
        ("max_branches", max_branches, 1),
    ):
        if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < least:
            raise ParameterError(f"{name} = {value!r}: expected an integer >= {least}")
    for name, value in (
        ("branch_points", branch_points),
        ("mirror", mirror),
        ("attractors", attractors),
    ):
        checks.flag(value, name)
    window = _check_window(Omega_window)
    system = compiled_system(
        oscillator,
        harmonics=harmonics,
        m=m,
        odd_only=odd_only,
        projection=projection,
        samples=samples,
    )
    stability = _check_stability(stability)
    tol = _positive_tol(tol)
    if direction not in (1, -1):
        raise ParameterError(f"direction = {direction!r}: expected 1 or -1")
    detect = bool(branch_points)
    first = _edge_branch(
        system, window, start, direction, stability, ds_max, tol, max_points, detect
    )
    found = [first]

    def trace_from(u: np.ndarray, W: float, origin: str) -> HarmonicBalanceBranch | None:
        try:
            br = harmonic_balance_branch_through(
                system,
                u,
                W,
                window,
                stability=stability,
                ds_max=ds_max,
                tol=tol,
                max_points=max_points,
                branch_points=detect,
            )
        except ContinuationError:
            return None
        return replace(br, origin=origin)

    starts = list(seeds(system, window, int(seeds_per_branch))) if seeds is not None else []
    starts += _linear_seeds(system, window, _LINEAR_SEED_FREQUENCIES)
    for W, guess in starts:
        if len(found) >= max_branches:
            break
        if any(_on_branch(b, guess, W, 0.05) for b in found):
            continue  # the seed is already near a traced branch: save the Newton solve
        try:
            u, _ = newton_fixed(
                system.residual,
                system.jacobian,
                guess,
                W,
                u_scale=max(1.0, float(np.abs(guess).max())),
                tol=tol,
                max_iterations=30,
            )
        except ContinuationError:
            continue
        if any(_on_branch(b, u, W, 0.05) for b in found):
            continue
        br = trace_from(u, W, "seed")
        if br is not None:
            found.append(br)

    width = window[1] - window[0]
    # each branch point is met from both branches through it: switch once
    done: list[BranchPoint] = []
    step = _BRANCH_OFF_STEP * float(ds_max)

    def switch_branches(i: int) -> None:
        """Branch switching at the branch points of ``found[i:]`` (and of what it adds)."""
        while detect and i < len(found) and len(found) < max_branches:
            for bp in found[i].branch_point_records:
                scale = max(1e-12, float(np.abs(bp.u).max()))
                if any(
                    abs(d.lam - bp.lam) <= 1e-6 * (window[1] - window[0])
                    and float(np.abs(d.u - bp.u).max()) <= 1e-4 * scale
                    for d in done
                ):
                    continue
                done.append(bp)
                for u, W in branch_off(system.residual, system.jacobian, bp, step=step, tol=tol):
                    if len(found) >= max_branches or not window[0] <= W <= window[1]:
                        continue
                    # the point is ~step * max|u| off the branch it came from: a tolerance
                    # well below that tells the two apart, and well above the chord error
                    # ~ds_max^2/8 of a traced branch
                    if any(_on_branch(b, u, W, 0.2 * step) for b in found):
                        continue
                    br = trace_from(u, W, "branch point")
                    if br is not None and not _duplicate(br, found, 0.2 * step, width):
                        found.append(br)
            i += 1

    switch_branches(0)
    S = odd_symmetry(system, window) if mirror else None
    if attractors:
        # stage 3b: the stable orbits across the window and every solution found at its
        # edges, for the branches that neither a seed nor a branch point inside the window
        # reaches: a stable isola, or a branch that lies in the window only near an edge (an
        # isola straddling it, a branch that folds back out of it)
        n_before = len(found)
        lo, hi = window
        count = min(
            _ATTRACTOR_FREQUENCIES,
            max(2, math.ceil(math.log(hi / lo) / math.log(_ATTRACTOR_RATIO)) + 1),
        )
        grids = [_ATTRACTOR_GRID] * count
        grids[0] = grids[-1] = _ATTRACTOR_GRID_EDGE
        scan = np.geomspace(lo, hi, count)
        guesses = _attractor_guesses(system, scan, grids)
        for W_edge in window:
            known = _solutions_on(found, W_edge)
            if S is not None:
                known += [S @ u for u in known]
            guesses += [(W_edge, u) for u in _bias_shifted(system, known)]
            guesses += [(W_edge, u) for u in _segment_orbits(system, W_edge, inside=False)]

        def start_guesses(guesses: Sequence[tuple[float, np.ndarray]]) -> None:
            for W, guess in guesses:
                if len(found) >= max_branches:
                    break
                # an odd system's mirror images are added below: one of a pair is enough
                images = [guess] if S is None else [guess, S @ guess]
                if any(_on_branch(b, w, W, 0.05) for b in found for w in images):
                    continue  # near a traced branch: save the Newton solve
                try:
                    u, _ = newton_fixed(
                        system.residual,
                        system.jacobian,
                        guess,
                        W,
                        u_scale=max(1.0, float(np.abs(guess).max())),
                        tol=tol,
                        max_iterations=_EDGE_NEWTON_ITERATIONS,
                    )
                except ContinuationError:
                    continue
                images = [u] if S is None else [u, S @ u]
                if any(_on_branch(b, w, W, 0.05) for b in found for w in images):
                    continue
                br = trace_from(u, W, "attractor" if W not in window else "edge")
                if br is not None and not _duplicate(br, found, 0.01, width):
                    found.append(br)

        start_guesses(guesses)
        switch_branches(n_before)
        # then the attractors beside the unstable orbits traced so far (mirror images left
        # out: their attractors are the images), in one more simulation
        n_before = len(found)
        beside = _saddle_starts(system, found, scan)
        if beside and len(found) < max_branches:
            start_guesses(_attractor_guesses(system, [], [], beside, _SADDLE_SETTLED))
            switch_branches(n_before)

    if S is not None:
        for br in list(found):
            if len(found) >= max_branches:
                break
            image = mirror_branch(br, S)
            if not _duplicate(image, found, 0.01, width):
                found.append(image)
    return tuple(found)


def harmonic_balance_branch_through(
    system: HarmonicBalanceSystem,
    u: ArrayLike,
    Omega: float,
    Omega_window: Sequence[float],
    *,
    stability: Stability = "hill",
    ds_max: float = 0.05,
    tol: float = 1e-10,
    max_points: int = 5000,
    branch_points: bool = False,
) -> HarmonicBalanceBranch:
    """The branch through the solution ``u`` at ``Omega`` inside the window, traced down and
    then up (one run only when the first closes on itself: an isola).

    :func:`harmonic_balance_branch` starts at an end of the window; this starts anywhere, from
    a solution found some other way (a seed of :func:`harmonic_balance_branches`, or Newton
    from an exact orbit's Fourier coefficients).

    Parameters
    ----------
    system : HarmonicBalanceSystem
    u : array_like
        Coefficients of a solution at ``Omega`` (to ``tol``; it is not corrected first).
    Omega : float
        Inside ``Omega_window``.
    Omega_window, stability, ds_max, tol, max_points
        See :func:`harmonic_balance_branch`.
    branch_points : bool
        Watch for branch points and locate them
        (:attr:`HarmonicBalanceBranch.branch_points`; one extra LU per point).

    Returns
    -------
    HarmonicBalanceBranch
        Points in increasing order along the curve from its low-frequency end; ``curve`` is
        the downward run.

    Raises
    ------
    ParameterError
        Bad input (the message names it).
    ContinuationError
        When the continuation fails at its first step.
    """
    window = _check_window(Omega_window)
    stability = _check_stability(stability)
    tol = _positive_tol(tol)
    W = float(Omega)
    if not window[0] <= W <= window[1]:
        raise ParameterError(f"Omega = {Omega!r}: expected a value inside the window {window}")
    u0 = np.asarray(u, dtype=float).reshape(-1)
    if u0.size != system.basis.size or not np.all(np.isfinite(u0)):
        raise ParameterError(
            f"u: expected {system.basis.size} finite coefficients, got shape {np.shape(u)}"
        )
    bp = bool(branch_points)
    down = _trace(system, u0, W, window, -1, stability, ds_max, tol, max_points, bp)
    parts = [(down, True)]
    if down.stop_reason != "closed":
        up = _trace(system, u0, W, window, 1, stability, ds_max, tol, max_points, bp)
        parts.append((up, False))
    return _assemble(system, parts, stability, origin="seed")


def harmonic_balance_response(
    oscillator: Oscillator,
    Omega_window: Sequence[float],
    options: HarmonicBalanceOptions | None = None,
    *,
    start: ArrayLike | HarmonicBalanceSolution | None = None,
    direction: int = -1,
    all_branches: bool = False,
    seeds: SeedFunction | None = None,
    **knobs: Any,
) -> Response:
    """Frequency response by numeric harmonic balance as a :class:`~perturb.response.Response`.

    Same arguments as :func:`harmonic_balance_branch`; ``amplitude`` is ``max |x|`` over the
    period (refined extrema of the Fourier series), ``first_harmonic_amplitude`` the component
    at the forcing frequency, ``mean`` the bias ``a0``, ``max_multiplier`` ``max |exp(lambda
    T)|`` over the two Hill exponents (``-1`` when ``stability='none'``).

    With ``all_branches``, every branch of :func:`harmonic_balance_branches` (the connected
    one, those seeded from ``seeds`` — the front door passes the single-harmonic balance
    response's, :func:`perturb.seeds.single_harmonic_seeds` — and from linear-segment
    orbits, those switched onto at branch points, and mirror images for odd systems), at the
    cost of the symbolic single-harmonic balance and of tracing each branch with the
    branch-point test function (see there); the branch points are listed in ``notes``
    (:class:`~perturb.response.Response` has no field for them). Otherwise the connected
    branch only, traced without branch-point detection.

    ``options`` (:class:`HarmonicBalanceOptions`) and ``**knobs`` (its fields as keywords)
    as for :func:`harmonic_balance_branches`; the branch-search fields only matter with
    ``all_branches``.
    """
    o = _options(options, knobs, _ALL_FIELDS, "harmonic_balance_response")
    if all_branches:
        found = harmonic_balance_branches(
            oscillator,
            Omega_window,
            o,
            start=start,
            direction=direction,
            seeds=seeds,
        )
        first = found[0]
        origins = [b.origin for b in found]
        notes = (
            f"{len(found)} branches: the connected one, {origins.count('seed')} seeded (single-"
            f"harmonic balance, linear segments), {origins.count('branch point')} switched onto "
            f"at branch points, "
            + (
                f"{origins.count('edge')} from solutions at the window edges, "
                if "edge" in origins
                else ""
            )
            + f"{origins.count('mirror')} mirror images",
        )
        # a branch point lies on two branches (and an odd system's on their mirror images
        # too): listed once
        bps: list[tuple[float, float]] = []
        for w, a in (p for b in found for p in b.branch_points):
            if not any(abs(w - v) <= 1e-4 * v and abs(a - c) <= 1e-3 * c for v, c in bps):
                bps.append((w, a))
        if bps:
            notes += (_branch_point_note(sorted(bps)),)
        if not np.all(np.isfinite(first.max_multiplier)):
            notes += ("stability not computed: max_multiplier = -1",)
        return Response(
            tuple(b.to_branch() for b in found),
            first.method,
            first.system.oscillator.name,
            dict(first.params),
            folds=tuple(f for b in found for f in b.folds),
            notes=notes,
        )
    return harmonic_balance_branch(
        oscillator, Omega_window, o, start=start, direction=direction
    ).to_response()
