"""The one dispatcher: ``frequency_response(osc, method, Omega)`` for every method.

``frequency_response(osc, method=..., Omega=...)`` answers with any method of the registry
(:mod:`perturb.methods.registry`: the symbolic approximations ``"hb1"``, ``"shb"``, ``"kb"``,
``"vdp"``, ``"ms"``, ``"lp"``, ``"mlp"``, numeric harmonic balance ``"hb"``, the exact
reference ``"exact"`` and the automatic choice ``"auto"``). The registry says which options a
method takes and checks their values; this module routes the request:

- symbolic: :func:`derive` (the engine, optionally through the derivation cache), then
  :func:`trace_approximation` (amplitude parametrisation or residual continuation);
- numeric ``"hb"``: :func:`perturb.numeric.harmonic_balance.harmonic_balance_response`;
- reference ``"exact"``: :mod:`perturb.simulate.exact_response`, started also from
  approximations (:mod:`perturb.seeds`);
- ``"auto"``: :func:`perturb.auto.auto_frequency_response`, resolved by name (auto imports
  this module, never the reverse).

``frequencies=`` works for every method: every solution at exactly those frequencies
(traced over a covering window, then each crossing solved again at the exact frequency;
``"auto"`` chooses its method with spot checks at those frequencies, then answers there).

Limits
------
Requests whose cost grows without bound are refused before any work starts, with a message
that names the value and the limit. The limits are the registry's
(:mod:`perturb.methods.registry`), re-exported here, for the Python API, the command line
and the scenes:

:data:`MAX_HARMONICS`
    Numeric HB with ``H`` harmonics solves ``(2H + 1)``-square systems and a
    ``2(2H + 1)``-square Hill eigenproblem at every point: time grows as ``H**3``. Measured
    (2026-11-27, two-core machine under load, ``nsd`` k = -0.5, one branch over Omega 0.8-2,
    176 points): H = 63 1.5 s, H = 127 16 s, H = 255 50 s and one orbit 14 s, 190 MB. Beyond
    255 a response takes minutes to hours (``harmonics = 10000`` grew to 20 GB).
:data:`MAX_ORDER`
    Symbolic expansions grow combinatorially with the order. Measured (same machine, forced
    Duffing): multiple scales order 6 0.7 s, order 8 4.2 s, order 10 18 s; modified
    Lindstedt-Poincare order 10 1.4 s (``order = 50`` ran past 120 s).
:data:`MAX_POINTS`
    Points of an amplitude-parametrised curve and of an ``start:stop:count`` grid.
:data:`MAX_FREQUENCIES`
    Listed frequencies (``frequencies=``; each one is a solve).

Systems of several coordinates
------------------------------
:func:`frequency_response` and :func:`periodic_orbits` also take a
:class:`~perturb.model.system.System`, answered by the methods of :data:`SYSTEM_METHODS`
(``"exact"``, numeric ``"hb"``, the symbolic single-harmonic balance ``"hb1"`` / ``"shb"``,
``"auto"``) and the internal-resonance slow flow ``"ms-ir"`` (:data:`SYSTEM_ONLY_METHODS`);
the other approximations take one coordinate and refuse a system naming those.
:func:`derive_system` gives a system's symbolic derivations (``hb1``, ``ms-ir``, ``nnm``).
``output=`` (a coordinate or a linear combination such as ``"x1 - x2"``, default the first
coordinate) is what the ``amplitude``, ``first_harmonic_amplitude`` and ``mean`` columns
measure; every coordinate's ``max |.|`` and mean come as ``amplitude_<name>`` /
``mean_<name>`` (:class:`SystemResponse`, :func:`orbit_columns`). :func:`system_time_history`
integrates a system (exact piecewise-affine flow, DOP853, or event-driven with stops and
friction contacts).

An autonomous system (no harmonic forcing, :func:`is_forced`: the belt, the drill string) has
limit cycles of their own period instead: :func:`limit_cycles` (cycles, equilibria, notes;
:func:`periodic_orbits` returns its cycles) and no frequency response (refused by name). A
system with conserved linear combinations (:meth:`System.invariants
<perturb.model.system.System.invariants>`, ``mount_linear``'s ``C1 p1 + C2 p2``) has a family
of orbits; :func:`periodic_orbits` pins the period-mean of each (default 0, the rest state's;
``invariants=``) and reports one orbit per frequency, and so does :func:`frequency_response` at
listed frequencies, while a traced window is refused for it (:func:`_check_frequency_response`).

Importing this module loads neither SymPy nor SciPy: each route imports its solver when
it runs.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from perturb import checks
from perturb.errors import ParameterError, PerturbError
from perturb.methods import registry
from perturb.methods.registry import (
    ALIASES,
    MAX_FREQUENCIES,
    MAX_HARMONICS,
    MAX_ORDER,
    MAX_POINTS,
    RESIDUAL_OPTIONS,
    check_harmonics,
    check_order,
    check_points,
)

if TYPE_CHECKING:
    from perturb.approximation import Approximation
    from perturb.model.oscillator import Oscillator
    from perturb.response import Response

__all__ = [
    "frequency_response",
    "periodic_orbits",
    "is_system",
    "system_output",
    "system_coordinates",
    "check_oscillator_output",
    "SYSTEM_METHODS",
    "system_method_text",
    "system_single_harmonic_residuals",
    "SystemResponse",  # noqa: F822 - built on first access (module __getattr__)
    "SYSTEM_INTEGRATORS",
    "orbit_columns",
    "system_errors",
    "limit_cycles",
    "LimitCycles",
    "BalanceCycle",
    "LIMIT_CYCLE_METHODS",
    "Equilibrium",
    "is_forced",
    "invariant_note",
    "combination_text",
    "system_time_history",
    "SystemHistory",
    "derive",
    "derive_system",
    "SYSTEM_DERIVATIONS",
    "trace_approximation",
    "ALIASES",
    "MAX_HARMONICS",
    "MAX_ORDER",
    "MAX_POINTS",
    "MAX_FREQUENCIES",
    "check_harmonics",
    "check_order",
    "check_points",
]

#: Harmonics of numeric HB when none are given.
DEFAULT_HARMONICS = 15


def frequency_response(
    oscillator: Oscillator,
    method: str | None = None,
    Omega: Sequence[float] = (0.2, 2.0),
    *,
    frequencies: Sequence[float] | None = None,
    output: str | None = None,
    **options: Any,
) -> Response:
    """The frequency response of ``oscillator`` by ``method``.

    Parameters
    ----------
    oscillator
        An :class:`~perturb.model.oscillator.Oscillator`, or a
        :class:`~perturb.model.system.System` of several coordinates (methods ``"exact"``,
        ``"hb"``, ``"hb1"``, ``"shb"``, ``"ms-ir"``, ``"auto"``: the answer is a
        :class:`SystemResponse`, see :func:`_system_response`).
    method
        A name (or alias) of :data:`perturb.methods.registry.REGISTRY`: ``"exact"``
        (continuation of exact periodic orbits), ``"hb"`` (numeric multi-harmonic balance,
        ``harmonics`` harmonics, exact Galerkin projection for PWL forces, every branch by
        default), ``"auto"`` (the cheapest method that meets ``rtol`` at exact spot checks,
        :func:`perturb.auto.auto_frequency_response`; the choice, its estimate and the
        spot-check errors are the first ``notes`` of the response) or a symbolic method
        (``"hb1"``, ``"shb"``, ``"kb"`` (alias ``"avg"``), ``"vdp"``, ``"ms"`` (alias
        ``"mms"``), ``"lp"``, ``"mlp"``).
    Omega
        ``(low, high)``.
    frequencies
        Exact frequencies to report instead of a traced curve: every solution found at
        each of them, and no other frequency (every method). With ``"hb"``
        and residual-traced approximations the branches are traced over a window covering
        the frequencies and each crossing of a branch with a requested frequency is solved
        again at exactly that frequency.
    options
        The method's options, and only those (:attr:`MethodSpec.options
        <perturb.methods.registry.MethodSpec.options>`), e.g. ``order`` (expansion order of
        ``mlp``, ``ms``, ``lp``, at most :data:`MAX_ORDER`), ``harmonics`` (of ``"hb"``,
        default 15, at most :data:`MAX_HARMONICS`; of the Fourier series of ``lp`` / ``mlp``;
        the harmonic set of ``"shb"``), ``points``, ``stability``. With ``"hb"``:
        ``all_branches`` (default ``True``; ``False`` traces only the branch connected to
        the window's high end), ``seeds`` (default :func:`perturb.seeds.single_harmonic_seeds`)
        and the options of :func:`perturb.numeric.harmonic_balance.harmonic_balance_response`.
        With ``"exact"``: ``approximation`` and ``approximation_seeds`` (see :func:`_exact`)
        and the options of :func:`perturb.simulate.exact_response.exact_branches`. With
        ``"auto"``: ``rtol`` (relative amplitude tolerance in ``(0, 1)``, default
        ``1e-3``), ``spots`` / ``n_spots`` (spot-check frequencies), ``points``.
        Default: ``"hb1"`` for an oscillator, ``"exact"`` for a system.
    output
        Systems: what the ``amplitude``, ``first_harmonic_amplitude`` and ``mean`` columns
        measure, a coordinate or a linear combination (``"x2"``, ``"x1 - x2"``; default the
        first coordinate). An oscillator takes its coordinate only (``"x"``).

    Raises
    ------
    ParameterError
        Unknown method, an option the method does not take (the message lists what it
        accepts), or a value beyond the limits of the module docstring (each message names
        the value and the limit).

    Notes
    -----
    A symbolic approximation whose amplitude equation is a polynomial of degree <= 2 in
    ``Omega**2`` is traced by amplitude parametrisation; any other (second-order modified
    L-P, for instance) by seeding and continuation of its residuals
    (:func:`perturb.numeric.residual.residual_response`) — ``"shb"`` over a harmonic set or
    with ``bias=True`` in all its unknowns (``a_n, b_n, c_0``), stability by Hill's method
    truncated at its highest harmonic.
    """
    if is_system(oscillator):
        return _system_response(oscillator, method, Omega, frequencies, output, options)
    check_oscillator_output(oscillator, output)
    spec = registry.spec("hb1" if method is None else method)
    if frequencies is not None:
        frequencies = checks.frequencies(frequencies, MAX_FREQUENCIES)
    if spec.kind == "symbolic":
        derive_options, solve_options = spec.split(options)
        approx = _derive(oscillator, spec, derive_options, use_cache=False)
        return trace_approximation(approx, Omega, frequencies=frequencies, **solve_options)
    options = spec.validate(options)
    if spec.kind == "auto":
        rtol = options.pop("rtol", 1e-3)
        if frequencies is not None:
            if "points" in options:
                raise ParameterError(
                    "points sets the resolution of a traced curve: give it without frequencies="
                )
            options["frequencies"] = frequencies
        return spec.resolve()(oscillator, Omega, rtol, **options)[0]
    if spec.kind == "reference":
        return _exact(oscillator, Omega, frequencies, options)
    return _harmonic_balance(oscillator, Omega, frequencies, options)


def derive(
    oscillator: Oscillator, method: str, *, use_cache: bool = False, **options: Any
) -> Approximation:
    """The approximation of ``oscillator`` by the symbolic ``method`` (a registry name).

    Parameters
    ----------
    use_cache
        Read and write the derivation cache (:func:`perturb.io.cache.cached_derivation`,
        which also honours ``PERTURB_CACHE=0``); the result is the same either way.
    options
        The method's derivation options (``order``, ``harmonics``, ``bias``, ...); ``None``
        values count as not given.

    Raises
    ------
    ParameterError
        For a method that is not symbolic, or an option it does not take.
    """
    spec = registry.spec(method)
    if spec.kind != "symbolic":
        raise ParameterError(
            f"method {spec.name!r} ({spec.title}) is a solver, not a derivation: expected one "
            f"of {', '.join(registry.symbolic_names())}"
        )
    derive_options = spec.validate(options, stage="derive")
    return _derive(oscillator, spec, derive_options, use_cache=use_cache)


def _derive(
    oscillator: Oscillator, spec: registry.MethodSpec, options: dict[str, Any], use_cache: bool
) -> Approximation:
    if use_cache:
        from perturb.io.cache import cached_derivation

        return cached_derivation(spec.name, spec.resolve(), oscillator, **options)
    return spec.resolve()(oscillator, **options)


def _residual_traced(approximation: Approximation) -> bool:
    """Whether an approximation is traced by residual continuation: its amplitude equation is
    not a polynomial of degree <= 2 in ``Omega**2``, or it has no slow flow."""
    poly = approximation.frequency_polynomial
    return poly is None or len(poly) > 3 or approximation.slow_flow is None


def trace_approximation(
    approximation: Approximation,
    Omega: Sequence[float] = (0.2, 2.0),
    *,
    frequencies: Sequence[float] | None = None,
    **options: Any,
) -> Response:
    """The frequency response of a derived approximation.

    Amplitude parametrisation (:func:`perturb.numeric.amplitude.approximation_response`, at
    listed frequencies :func:`~perturb.numeric.amplitude.solutions_at`) when the amplitude
    equation is a polynomial of degree <= 2 in ``Omega**2``; otherwise residual continuation
    (:func:`perturb.numeric.residual.residual_response`, at listed frequencies
    :func:`~perturb.numeric.residual.residual_solutions_at`).

    Parameters
    ----------
    options
        ``points`` (of an amplitude-parametrised curve; a residual-traced curve's resolution
        is set by its continuation step, so it is not needed there), ``stability``,
        ``amplitude_range`` and, for residual-traced approximations, the options of
        :func:`~perturb.numeric.residual.residual_response`.

    Raises
    ------
    ParameterError
        For an option that does not apply to how this approximation is traced.
    """
    allowed = {"points", "stability", "amplitude_range", *RESIDUAL_OPTIONS}
    unknown = sorted(set(options) - allowed)
    if unknown:
        raise ParameterError(
            f"{', '.join(unknown)}: not options of tracing an approximation (expected: "
            f"{', '.join(sorted(allowed))})"
        )
    if "points" in options:
        options["points"] = check_points(options["points"])
    if frequencies is not None:
        frequencies = checks.frequencies(frequencies, MAX_FREQUENCIES)
        if "points" in options:
            raise ParameterError(
                "points sets the resolution of a traced curve: give it without frequencies="
            )
    if _residual_traced(approximation):
        from perturb.numeric.residual import residual_response, residual_solutions_at

        if len(approximation.unknowns) == 1 or approximation.frequency in approximation.unknowns:
            # a free oscillation: no forcing, so no phase and no response to trace
            raise ParameterError(
                f"{approximation.method}: unknowns "
                f"({', '.join(str(u) for u in approximation.unknowns)}) of a free "
                "oscillation's frequency-amplitude relation (a backbone), not a forced "
                "response: the tracers need an amplitude and a phase. Draw it with a scene "
                "[ask] kind = 'backbone', or use 'mlp' for the forced response"
            )
        # a harmonic set or a mean term (symbolic 'shb'): residual continuation in all the
        # unknowns (perturb.numeric.residual), stability by Hill's method at its harmonics

        # the curve's resolution is set by the continuation step, not by a point count
        options.pop("points", None)
        if frequencies is not None:
            return residual_solutions_at(approximation, frequencies, **options)
        return residual_response(approximation, Omega, **options)
    given = sorted(set(options) & set(RESIDUAL_OPTIONS))
    if given:
        raise ParameterError(
            f"{', '.join(given)}: options of residual continuation; {approximation.method!r} "
            "is traced by amplitude parametrisation (its amplitude equation is a polynomial "
            "in Omega**2)"
        )
    from perturb.numeric.amplitude import approximation_response, solutions_at

    if frequencies is not None:
        return solutions_at(approximation, frequencies, **options)
    return approximation_response(approximation, Omega, **options)


def _harmonic_balance(
    oscillator: Oscillator,
    Omega: Sequence[float],
    frequencies: list[float] | None,
    options: dict[str, Any],
) -> Response:
    """Method ``"hb"``: numeric harmonic balance over a window or at listed frequencies."""
    from perturb import seeds
    from perturb.numeric.harmonic_balance import harmonic_balance_response

    options.setdefault("all_branches", True)
    # every branch: Newton started also from the single-harmonic balance branches
    options.setdefault("seeds", seeds.single_harmonic_seeds)
    H = options.pop("harmonics", DEFAULT_HARMONICS)
    if frequencies is not None:
        return _hb_solutions_at(oscillator, frequencies, H, options)
    return harmonic_balance_response(oscillator, Omega, harmonics=H, **options)


def periodic_orbits(
    oscillator: Oscillator,
    Omega: float | None = None,
    *,
    m: int = 1,
    guesses: Sequence[Sequence[float]] = (),
    grid: int = 3,
    transient_periods: int = 100,
    extent: float | None = None,
    output: str | None = None,
    invariants: Sequence[float] | None = None,
) -> tuple:
    """Every period-``m`` orbit found at forcing frequency ``Omega`` (the front door).

    A :class:`~perturb.model.system.System` (several coordinates) is answered by
    :func:`perturb.simulate.orbits.shooting.periodic_orbit` on its flow (exact when piecewise
    affine, else DOP853) started from the periodic solutions of its linear parts (one per
    region), from ``guesses`` (its ``n`` states each) and from the states reached after
    ``transient_periods`` forcing periods from the zero state, from ``+-extent`` times each
    coordinate's linear-response size (default 3) and from ``grid`` random states in that box
    (a fixed seed); duplicates (also the same period-``m`` orbit started at another forcing
    phase) and orbits of a shorter period are dropped. The orbits are sorted by ``max |.|`` of
    ``output`` (:func:`system_output`; default the first coordinate), whose numbers
    :func:`orbit_columns` gives.

    A system with conserved linear combinations (:meth:`System.invariants
    <perturb.model.system.System.invariants>`: ``c . y' = c . b(t)``, e.g. ``C1 p1 + C2 p2``
    of ``mount_linear``) has a continuous family of orbits, one per value of each invariant.
    The orbit returned is the one whose period-mean of ``c . y(t)`` equals ``invariants``
    (one number per row of ``system.invariants()``; default 0, the value of the rest state
    ``y = 0``: the mount's chambers hold their rest volume on average): the seeds are
    projected onto that level set and Newton runs on it (:func:`_pinned_orbit`), so one orbit
    per frequency is found. Its multipliers hold one exact 1 per invariant (the family's
    direction, trivial), left out of ``stability`` and ``max_multiplier``
    (:func:`invariant_note` says so in one line).

    A system without harmonic forcing (autonomous: ``belt``, ``drill_string``, a van der Pol
    written as equations) has limit cycles of their own period instead: ``Omega`` must be
    None (or only set a parameter), ``m`` 1, and the answer is :func:`limit_cycles`'s
    ``cycles`` (each ``orbit.period``, its multipliers with the trivial 1; a drill string's
    orbit is periodic up to a shift of its angles, gauge ``d . y0 = 0``). Its equilibria
    (stable ones, when no cycle is found) come from :func:`limit_cycles` itself.

    :func:`perturb.simulate.orbits.search.periodic_orbits` (attractors from a grid of
    initial conditions, closed-form segment orbits, ``guesses``), started also, for
    ``m = 1``, from the approximations' solutions of
    :func:`perturb.seeds.periodic_orbit_guesses` (single-harmonic balance and a multi-start
    numeric harmonic-balance search).  Those only start shooting: every orbit is accepted on
    the exact flow's residual.  The parameters are those of the search.

    Returns
    -------
    tuple of PeriodicOrbit
        Sorted by amplitude.
    """
    if is_system(oscillator):
        return _system_periodic_orbits(
            oscillator, Omega, m, guesses, grid, transient_periods, extent, output, invariants
        )
    if invariants is not None:
        raise ParameterError(
            f"invariants = {invariants!r}: an option of systems with conserved combinations; "
            f"{getattr(oscillator, 'name', 'the oscillator')!r} is one coordinate"
        )
    check_oscillator_output(oscillator, output)
    from perturb import seeds
    from perturb.simulate.orbits.search import periodic_orbits as search

    nodes = seeds.periodic_orbit_guesses(oscillator, Omega, extent=extent) if m == 1 else []
    return search(
        oscillator,
        Omega,
        m=m,
        guesses=guesses,
        node_guesses=nodes,
        grid=grid,
        transient_periods=transient_periods,
        extent=extent,
    )


def _exact(
    oscillator: Oscillator,
    Omega: Sequence[float],
    frequencies: list[float] | None,
    options: dict[str, Any],
) -> Response:
    """Method ``"exact"``: the exact solvers, started also from approximations' solutions.

    ``approximation`` (an :class:`~perturb.approximation.Approximation`, e.g.
    ``single_harmonic_balance(osc)``) adds ``approximation_seeds`` (default 16) points along
    each of its branches to the caller's ``seeds`` (:func:`perturb.seeds.approximation_seeds`);
    the search at single frequencies starts also from
    :func:`perturb.seeds.periodic_orbit_guesses`.
    """
    from perturb import seeds
    from perturb.simulate.exact_response import (
        ONE_FREQUENCY_WINDOW,
        exact_frequency_response,
        exact_solutions_at,
    )

    options = dict(options)
    approximation = options.pop("approximation", None)
    per_branch = options.pop("approximation_seeds", 16)
    if isinstance(per_branch, bool) or not isinstance(per_branch, int) or per_branch < 0:
        raise ParameterError(
            f"approximation_seeds = {per_branch!r}: expected a non-negative integer"
        )
    if frequencies is None:
        window: Sequence[float] = Omega
    else:
        targets = sorted(set(frequencies))
        if len(targets) == 1:
            window = (targets[0] / ONE_FREQUENCY_WINDOW, targets[0] * ONE_FREQUENCY_WINDOW)
        else:
            window = (targets[0], targets[-1])
    if approximation is not None:
        try:
            lo, hi = (float(w) for w in window)
        except (TypeError, ValueError):
            lo = hi = math.nan
        if math.isfinite(lo) and math.isfinite(hi) and 0 < lo < hi:
            extra = seeds.approximation_seeds(approximation, (lo, hi), per_branch)
            options["seeds"] = [*options.get("seeds", ()), *extra]
    if frequencies is not None:
        return exact_solutions_at(
            oscillator,
            frequencies,
            orbit_guesses=lambda w: seeds.periodic_orbit_guesses(oscillator, w),
            **options,
        )
    return exact_frequency_response(oscillator, Omega, **options)


def _hb_solutions_at(
    oscillator: Oscillator, targets: list[float], harmonics: int, options: dict[str, Any]
) -> Response:
    """Every numeric HB solution at exactly the frequencies ``targets``: the branches over a
    window covering them, each crossing solved again at its frequency by Newton
    (:func:`perturb.numeric.harmonic_balance.harmonic_balance_orbit`)."""
    import numpy as np

    from perturb.errors import PerturbError
    from perturb.numeric.harmonic_balance import (
        harmonic_balance_branch,
        harmonic_balance_branches,
        harmonic_balance_orbit,
    )
    from perturb.response import Branch, Response, covering_window, polyline_crossings

    opts = dict(options)
    all_branches = bool(opts.pop("all_branches", True))
    system_keys = ("m", "odd_only", "projection", "samples")
    orbit_opts = {k: opts[k] for k in (*system_keys, "stability", "tol") if k in opts}
    window = covering_window(targets)
    seeds = opts.pop("seeds", None)
    if all_branches:
        found = harmonic_balance_branches(
            oscillator, window, harmonics=harmonics, seeds=seeds, **opts
        )
    else:
        found = (harmonic_balance_branch(oscillator, window, harmonics=harmonics, **opts),)
    wanted = sorted(set(targets))
    branches, notes = [], []
    seen: dict[float, list[np.ndarray]] = {w: [] for w in wanted}
    for bi, br in enumerate(found):
        rows = []
        for w, j in polyline_crossings(br.omega, wanted):
            w0, w1 = float(br.omega[j]), float(br.omega[j + 1])
            t = 0.0 if w1 == w0 else (w - w0) / (w1 - w0)
            guess = (1 - t) * br.coefficients[j] + t * br.coefficients[j + 1]
            try:
                sol = harmonic_balance_orbit(
                    oscillator, w, harmonics=harmonics, guess=guess, **orbit_opts
                )
            except PerturbError:
                notes.append(f"branch {bi}: Newton at Omega = {w!r} failed; row left out")
                continue
            u = sol.coefficients
            scale = max(1e-12, float(np.abs(u).max()))
            if any(float(np.abs(u - v).max()) <= 1e-6 * scale for v in seen[w]):
                continue  # two crossings polished onto one solution
            seen[w].append(u)
            rows.append(sol)
        if rows:
            mm = [s.max_multiplier if math.isfinite(s.max_multiplier) else -1.0 for s in rows]
            branches.append(
                Branch(
                    omega=[s.Omega for s in rows],
                    amplitude=[s.amplitude for s in rows],
                    first_harmonic_amplitude=[s.first_harmonic_amplitude for s in rows],
                    mean=[s.mean for s in rows],
                    stable=[s.stable for s in rows],
                    max_multiplier=mm,
                )
            )
    first = found[0]
    total = sum(len(b) for b in branches)
    notes.insert(
        0,
        f"{total} solutions at {len(wanted)} frequencies on {len(found)} branches traced over "
        f"Omega = {window[0]:.6g}..{window[1]:.6g}, each solved again at its frequency",
    )
    if not branches:
        notes.append("no branch crosses the requested frequencies")
    return Response(
        tuple(branches),
        first.method,
        first.system.oscillator.name,
        dict(first.params),
        notes=tuple(notes),
    )


# ------------------------------------------------------------------------------------------
# Systems of several coordinates (issue 15): the front door for System models
# ------------------------------------------------------------------------------------------

#: Methods a :class:`~perturb.model.system.System` takes: the exact reference, numeric
#: multi-harmonic balance, the symbolic single-harmonic balance of systems
#: (:mod:`perturb.methods.system_harmonic_balance`: ``"hb1"`` with the bias its derivation
#: decides, ``"shb"`` with ``bias=`` and the harmonic set ``(1,)``) and the automatic choice.
SYSTEM_METHODS = ("exact", "hb", "hb1", "shb", "auto")
#: Methods of systems only (not in the registry of one-coordinate methods): the slow flow of
#: two coordinates with an internal resonance (:func:`_system_ms_ir`).
SYSTEM_ONLY_METHODS = ("ms-ir", "internal-resonance")
#: Options of ``"ms-ir"`` (:func:`_system_ms_ir`).
SYSTEM_MS_IR_OPTIONS = ("resonance", "near", "tolerance", "stability", "ds_max", "max_points")
#: Options of the symbolic single-harmonic balance of a system (:func:`_system_shb`).
SYSTEM_SHB_OPTIONS = ("bias", "harmonics", "stability", "all_branches", "ds_max", "max_points")
#: Options of ``method="auto"`` for a system (:func:`perturb.auto.auto_system_response`).
SYSTEM_AUTO_OPTIONS = ("rtol", "spots", "n_spots", "ladder", "log")
#: Options of method ``"hb"`` for a system (:func:`_system_hb`).
SYSTEM_HB_OPTIONS = (
    "harmonics",
    "m",
    "all_branches",
    "stability",
    "mirror",
    "ds_max",
    "max_points",
    "max_branches",
    "tol",
    "projection",
    "direction",
    "interior",
)
#: Integrators of :func:`system_time_history`.
SYSTEM_INTEGRATORS = ("auto", "exact", "ode", "events")
#: Samples per forcing period for the orbit statistics of a system (as the orbit solvers'
#: ``N_STATS``: uniform samples of a periodic signal give its mean and first harmonic).
_STATS_SAMPLES = 1024


def is_system(model: Any) -> bool:
    """Whether ``model`` is a :class:`~perturb.model.system.System` (several coordinates or
    first-order states), as opposed to an :class:`~perturb.model.oscillator.Oscillator`."""
    from perturb.model.system import System

    return isinstance(model, System)


def system_coordinates(system: Any) -> tuple[str, ...]:
    """The coordinates whose ``amplitude_<name>`` and ``mean_<name>`` a system's outputs
    report: the second-order coordinates, then the first-order states (velocities left out)."""
    return (*system.coordinates, *system.first_order)


def system_output(system: Any, output: str | None = None) -> tuple[Any, str]:
    """The combination ``c`` (over ``system.state_names``) that a system's ``amplitude``
    measures, and its text.

    Parameters
    ----------
    output
        A coordinate name or a linear combination (``"x2"``, ``"x1 - x2"``, ``"x1'"``);
        default: the first coordinate.

    Raises
    ------
    ModelError
        Naming the value and the system's states (not a state, not linear, zero).
    ParameterError
        Not a string.
    """
    from perturb.errors import ModelError

    text = system_coordinates(system)[0] if output is None else output
    if not isinstance(text, str) or not text.strip():
        raise ParameterError(
            f"output = {output!r}: expected a coordinate name or a linear combination such as "
            f"'x1 - x2' (states of {system.name!r}: {', '.join(system.state_names)})"
        )
    try:
        return system.output(text.strip()), text.strip()
    except (ModelError, ParameterError):
        raise
    except PerturbError as exc:  # a parse error of the text: say what was expected
        raise ModelError(
            f"output {text!r}: {exc}; expected a coordinate ({', '.join(system.state_names)}) "
            "or a linear combination of them such as 'x1 - x2'"
        ) from None


def check_oscillator_output(oscillator: Any, output: str | None) -> None:
    """An oscillator has one coordinate: ``output`` may only name it.

    Raises
    ------
    ParameterError
        Naming the value and the coordinate.
    """
    if output is None:
        return
    x = str(getattr(oscillator, "x", "x"))
    if not isinstance(output, str) or output.strip() != x:
        raise ParameterError(
            f"output {output!r}: model {getattr(oscillator, 'name', '?')!r} has the one "
            f"coordinate {x!r} (amplitude = max |{x}|); expected {x!r}, or a system of several "
            "coordinates for combinations"
        )


def _system_at(system: Any, Omega: float | None) -> Any:
    """``system`` with its parameter ``Omega`` set (when given)."""
    if Omega is None:
        return system
    if "Omega" not in system.params:
        raise ParameterError(
            f"Omega = {Omega!r}: system {system.name!r} has no forcing-frequency parameter "
            f"'Omega' (its parameters: {', '.join(system.params) or 'none'})"
        )
    return system.with_params(Omega=checks.finite(Omega, "Omega"))


def _system_flow(system: Any, method: str = "auto") -> Any:
    """The flow of a system without stops: exact when piecewise affine, else DOP853.

    Raises
    ------
    ModelError
        A system with stops (its impacts and resting phases need the event-driven solver).
    """
    from perturb.errors import ModelError
    from perturb.simulate.flows.factory import make_flow

    stops = [e.name for e in system.elements if e.kind == "stop"]
    if stops:
        raise ModelError(
            f"system {system.name!r} has the stop(s) {', '.join(stops)}: its motion needs the "
            "event-driven solver, which these front doors do not take yet (the mount's step "
            "response: a scene of kind 'step_response', e.g. perturb/scenes/mount_step.toml)"
        )
    return make_flow(system, method=method)


def _forcing_period(flow: Any, system: Any) -> float:
    from perturb.errors import ModelError

    if flow.period is None:
        raise ModelError(
            f"system {system.name!r} is autonomous (no harmonic forcing): its periodic orbits "
            "are limit cycles of unknown period (perturb.simulate.orbits.shooting."
            "limit_cycle), not orbits at a forcing frequency; expected a forced system (e.g. "
            "F*cos(Omega*t) on the right-hand side)"
        )
    return float(flow.period)


def orbit_columns(system: Any, orbit: Any, output: str | None = None) -> dict[str, float]:
    """The numbers of one periodic orbit of a system, by output column.

    ``amplitude``, ``first_harmonic_amplitude`` and ``mean`` of the ``output`` combination
    (:func:`system_output`), then ``amplitude_<name>`` (``max |.|``) and ``mean_<name>`` of
    every coordinate (:func:`system_coordinates`). Maxima are refined on the orbit itself
    (:meth:`PeriodicOrbit.max_abs <perturb.simulate.orbits.shooting.PeriodicOrbit.max_abs>`);
    the mean and first harmonic come from ``1024 m`` uniform samples (their Fourier
    coefficients).
    """
    import numpy as np

    c, _ = system_output(system, output)
    harmonic = 1 if orbit.autonomous else orbit.m
    n = _STATS_SAMPLES * harmonic
    _, Y = orbit.sample_states(n)
    z = np.fft.rfft(c @ Y) / n
    out = {
        "amplitude": float(orbit.max_abs(c)),
        "first_harmonic_amplitude": float(2.0 * abs(z[harmonic])) if harmonic < z.size else 0.0,
        "mean": float(z[0].real),
    }
    names = system.state_names
    coords = system_coordinates(system)
    eye = np.eye(len(names))
    for name in coords:
        out[f"amplitude_{name}"] = float(orbit.max_abs(eye[names.index(name)]))
    for name in coords:
        out[f"mean_{name}"] = float(np.mean(Y[names.index(name)]))
    return out


def _linear_guesses(system: Any, flow: Any) -> list:
    """Period-``T`` solutions of the linear parts, at ``t = 0``: for a piecewise-affine system
    one per region (``y = -A^-1 b + Re (i w I - A)^-1 (u - i v)`` for each input
    ``u cos wt + v sin wt``), else of the linearisation about the zero state (its harmonics
    sampled over a period). Starting guesses only: shooting decides."""
    import numpy as np

    from perturb.errors import ModelError

    guesses = []
    try:
        pa = system.piecewise_affine({})
    except (ModelError, ParameterError):
        pa = None
    if pa is not None:
        for region in pa.regions.values():
            A, b = np.asarray(region.A, float), np.asarray(region.b, float)
            try:
                y = -np.linalg.solve(A, b)
                for h in pa.inputs:
                    I = np.eye(A.shape[0])
                    y = y + np.linalg.solve(1j * h.omega * I - A, h.u - 1j * h.v).real
            except np.linalg.LinAlgError:
                continue
            if np.all(np.isfinite(y)):
                guesses.append(y)
        return guesses
    n = system.n
    zero = np.zeros(n)
    try:
        A = np.asarray(flow.jacobian(0.0, zero), dtype=float)
    except (AttributeError, PerturbError):
        return guesses
    T = float(flow.period)
    N = 64
    g = np.array([flow.vector_field(T * j / N, zero) for j in range(N)])
    G = np.fft.rfft(g, axis=0) / N
    try:
        y = -np.linalg.solve(A, G[0].real)
        for k in range(1, G.shape[0] - 1):
            w = 2.0 * math.pi * k / T
            y = y + (2.0 * np.linalg.solve(1j * w * np.eye(n) - A, G[k])).real
    except np.linalg.LinAlgError:
        return guesses
    if np.all(np.isfinite(y)):
        guesses.append(y)
    return guesses


def _system_periodic_orbits(
    system: Any,
    Omega: float | None,
    m: int,
    guesses: Sequence[Sequence[float]],
    grid: int,
    transient_periods: int,
    extent: float | None,
    output: str | None,
    invariants: Sequence[float] | None = None,
) -> tuple:
    """:func:`periodic_orbits` for a :class:`~perturb.model.system.System`."""
    import numpy as np

    system = _system_at(system, Omega)
    if not is_forced(system):
        if m != 1:
            raise ParameterError(
                f"m = {m!r}: system {system.name!r} is autonomous (no forcing), so there are no "
                "forcing periods to count; its limit cycles have their own period (m = 1)"
            )
        if invariants is not None:
            _invariant_pin(system, invariants)  # names the invariants, or says there are none
        return limit_cycles(
            system,
            guesses=guesses,
            grid=grid,
            transient_periods=transient_periods,
            extent=extent,
            output=output,
        ).cycles
    m = checks.whole(m, "m", 1, 64, "forcing periods per orbit")
    grid = checks.whole(grid, "grid", 0, 100, "random starting states")
    transient_periods = checks.whole(transient_periods, "transient_periods", 0, 100_000)
    factor = 3.0 if extent is None else checks.finite(extent, "extent")
    if not factor > 0:
        raise ParameterError(f"extent = {extent!r}: expected a positive number")
    c, _ = system_output(system, output)
    pin = _invariant_pin(system, invariants)
    _check_no_free_family(system)
    flow = _system_flow(system)
    T = _forcing_period(flow, system)
    n = system.n
    given = _state_guesses(guesses, system)
    linear = _linear_guesses(system, flow)
    # the start box: each state's size in the linear responses (1 where they all vanish)
    size = np.max(np.abs(np.array(linear)), axis=0) if linear else np.ones(n)
    size = np.where(size > 1e-12 * max(1.0, float(size.max())), size, max(float(size.max()), 1.0))
    starts = [np.zeros(n), *linear]
    for name in system_coordinates(system):
        i = system.state_names.index(name)
        for sign in (1.0, -1.0):
            y = np.zeros(n)
            y[i] = sign * factor * size[i]
            starts.append(y)
    rng = np.random.default_rng(0)  # reproducible starts
    starts += [factor * size * rng.uniform(-1.0, 1.0, n) for _ in range(grid)]
    if pin is not None:  # on the pinned level set: seeds projected, no family to drift along
        starts = [_project_on(pin[0], pin[1], y) for y in starts]
    candidates = [*given, *linear]
    for y in starts:  # settled long runs: the attractors
        try:
            end = flow(y, 0.0, max(transient_periods, 1) * T).y
        except PerturbError:
            continue  # escaped or the integrator gave up: no attractor from here
        if np.all(np.isfinite(end)) and float(np.abs(end).max()) < 1e8 * float(size.max()):
            candidates.append(np.asarray(end, dtype=float))
    found: list = []
    sections: list = []  # each orbit's states at its m forcing phases (one orbit, m starts)

    def known(y: np.ndarray, tol: float) -> bool:
        scale = max(1.0, float(np.abs(y).max()))
        return any(float(np.abs(S - y[:, None]).max(axis=0).min()) <= tol * scale for S in sections)

    for y in candidates:  # bounded: one Newton solve per candidate
        if known(y, 1e-5):
            continue
        orbit = _shoot(flow, y, m, T) if pin is None else _pinned_orbit(flow, y, m, T, pin, size)
        if orbit is None:
            continue
        _, S = orbit.sample_states(m)  # y(jT), j = 0..m-1
        if known(orbit.y0, 1e-7):
            continue
        scale = max(1.0, float(np.abs(orbit.y0).max()))
        if any(
            m % d == 0 and float(np.abs(S[:, d] - orbit.y0).max()) <= 1e-7 * scale
            for d in range(1, m)
        ):
            continue  # its period is a divisor of m forcing periods: not a period-m orbit
        found.append(orbit)
        sections.append(S)
    return tuple(sorted(found, key=lambda o: float(o.max_abs(c))))


#: Growth of a perturbation allowed over one shooting interval (as the exact response's
#: NODE_GROWTH): a strongly unstable orbit is solved again on nodes that each grow it by at
#: most this, so its statistics do not come from one propagation amplifying its rounding.
_NODE_GROWTH = 100.0
#: Most shooting nodes per forcing period.
_MAX_NODES = 64


def _shoot(flow: Any, y: Any, m: int, T: float) -> Any:
    """The period-``m`` orbit from the guess ``y``: single shooting; multiple shooting on
    nodes sampled from the guess's trajectory when that fails, and again on nodes of the
    orbit when it is strongly unstable. None when neither converges."""
    import numpy as np

    from perturb.simulate.orbits.shooting import multiple_shooting, periodic_orbit

    def nodes_for(mu: float) -> int:
        k = math.ceil(math.log(min(max(mu, 1.0), 1e300)) / math.log(_NODE_GROWTH))
        return int(min(max(k, 2 * m, 8), _MAX_NODES * m))

    try:
        orbit = periodic_orbit(flow, y, m=m, max_iter=40)
    except PerturbError:
        try:  # the guess's own trajectory as nodes: sub-intervals keep the growth bounded
            n = nodes_for(1.0)
            t = m * T * np.arange(n) / n
            ys = flow(y, 0.0, m * T, t_eval=t).ys
            return multiple_shooting(flow, np.asarray(ys, dtype=float), m=m, max_iter=40)
        except PerturbError:
            return None
    if orbit.max_multiplier <= _NODE_GROWTH:
        return orbit
    try:
        _, Y = orbit.sample_states(nodes_for(orbit.max_multiplier))
        return multiple_shooting(flow, Y.T.copy(), m=m, max_iter=40)
    except PerturbError:
        return orbit  # the single-shooting orbit (converged; its rounding amplified)


# ------------------------------------------------------------------------------------------
# conserved linear combinations (System.invariants): orbits pinned on one member of a family
# ------------------------------------------------------------------------------------------
def is_forced(system: Any) -> bool:
    """Whether a system has a harmonic forcing (a term ``a cos(w t)`` / ``a sin(w t)``, ``w >
    0``); without one it is autonomous: its periodic orbits are limit cycles of their own
    period (:func:`limit_cycles`)."""
    if not system.F.has(system.t):
        return False
    if tuple(system.free_parameters) == ("Omega",):  # its value does not decide (F = 0 does)
        return is_forced(system.with_params(Omega=1.0))
    if system.free_parameters:  # amplitudes still to be set: the time dependence decides
        return True
    return any(om > 0.0 for om, _, _ in system.numeric_form()["harmonics"])


def combination_text(c: Any, names: Sequence[str]) -> str:
    """``c`` over ``names`` as text, ``"p1 + 100*p2"`` (12 significant digits)."""
    parts = []
    for ci, nm in zip(c, names, strict=True):
        if ci == 0:
            continue
        mag = abs(float(ci))
        term = nm if mag == 1.0 else f"{mag:.12g}*{nm}"
        parts.append((" - " if ci < 0 else " + ") + term)
    text = "".join(parts)
    return text[3:] if text.startswith(" + ") else "-" + text[3:]


def _invariant_pin(
    system: Any, values: Sequence[float] | None
) -> tuple[Any, Any, list[str]] | None:
    """``(C, target, labels)``: the invariants ``C`` of ``system`` (rows) and the values
    ``C y0`` of the orbit whose period-mean of ``C y(t)`` is ``values`` (default 0, the rest
    state's), or None without invariants.

    ``C y(t) = C y(0) + int_0^t C b``; for ``C b = sum alpha_k cos w_k t + beta_k sin w_k t``
    the mean of the integral over a common period is ``sum beta_k / w_k``.

    Raises
    ------
    ModelError
        A constant part of ``C b`` (the combination drifts: no periodic orbit at all).
    ParameterError
        ``values`` not ``r`` finite numbers.
    """
    import numpy as np

    from perturb.errors import ModelError

    C = system.invariants()
    r = C.shape[0]
    labels = [combination_text(c, system.state_names) for c in C]
    if r == 0:
        if values is not None and len(list(values)) != 0:
            raise ParameterError(
                f"invariants = {values!r}: system {system.name!r} has no conserved linear "
                "combination (System.invariants() is empty); expected none"
            )
        return None
    if values is None:
        vals = np.zeros(r)
    else:
        try:
            vals = np.array([checks.finite(v, "invariants") for v in values], dtype=float)
        except TypeError:
            vals = np.array([])
        if vals.size != r:
            raise ParameterError(
                f"invariants = {values!r}: expected {r} number(s), the period-mean value(s) of "
                f"{'; '.join(labels)}"
            )
    num = system.numeric_form()
    n2 = num["n2"]
    Cb = C[:, n2:] @ num["Binv"]  # c . b(t) = c[n2:] . Binv F(t)
    offset = np.zeros(r)
    for om, cu, cv in num["harmonics"]:
        if om == 0.0:
            rate = Cb @ cu
            size = np.abs(Cb) @ np.abs(cu)
            if np.any(np.abs(rate) > 1e-12 * np.maximum(size, 1e-300)):
                raise ModelError(
                    f"system {system.name!r}: the conserved combination(s) "
                    f"{'; '.join(labels)} change at the constant rate(s) {rate.tolist()} "
                    "(a constant forcing part along them): no periodic orbit exists"
                )
            continue
        offset += (Cb @ cv) / om
    return C, vals - offset, labels


def _project_on(C: Any, target: Any, y: Any) -> Any:
    """``y`` moved along the rows of ``C`` onto ``C y = target`` (least change)."""
    import numpy as np

    return y - C.T @ np.linalg.solve(C @ C.T, C @ y - target)


def _pinned_orbit(flow: Any, y: Any, m: int, T: float, pin: tuple, size: Any) -> Any:
    """The period-``m`` orbit from the guess ``y`` with ``C y0 = target`` (``pin``): Newton
    on ``y0 = y_p + S Q z`` (``S = diag(size)``, the states' scales; ``Q`` an orthonormal basis
    of the scaled invariants' null space), whose ``n - r`` periodicity equations ``Q^T S^-1
    (phi(y0) - y0) = 0`` are the whole condition (``C (phi(y0) - y0) = int C b = 0`` holds on
    its own), with the square Jacobian ``Q^T (S^-1 M S - I) Q``. The orbit's trivial
    multipliers (``C M = C``: one 1 per invariant) are set to exactly 1 and left out of its
    stability, which the restriction ``Q^T S^-1 M S Q`` decides. None when Newton fails."""
    import dataclasses

    import numpy as np

    from perturb.simulate.orbits.shooting import (
        UNIT_TOL,
        classify_multipliers,
        periodic_orbit,
        shooting_newton,
    )

    C, target, _ = pin
    r, n = C.shape
    Cs = C * size[None, :]
    Q = np.linalg.svd(Cs)[2][r:].T  # orthonormal basis of {w : Cs w = 0}
    y_p = _project_on(C, target, np.asarray(y, dtype=float))
    P = m * T

    def state(z: Any) -> Any:
        return y_p + size * (Q @ z)

    def evaluate(z: Any) -> tuple:
        y0 = state(z)
        res = flow(y0, 0.0, P, sensitivity=True)
        M = np.asarray(res.sensitivity, dtype=float)
        Ms = M * size[None, :] / size[:, None]
        return Q.T @ ((np.asarray(res.y) - y0) / size), Q.T @ (Ms - np.eye(n)) @ Q, M

    try:
        out = shooting_newton(
            evaluate,
            np.zeros(n - r),
            tol=1e-13,
            max_iter=40,
            scale=lambda z: 1.0,  # the residual is in units of each state's own scale
            what="shooting on the invariants' level set",
        )
        y0 = state(out.z)
        # the orbit object (dense output, statistics) of the converged state: no Newton step
        orbit = periodic_orbit(flow, y0, m=m, max_iter=0, tol=1e-6)
    except PerturbError:
        return None
    Ms = np.asarray(orbit.monodromy) * size[None, :] / size[:, None]
    inner = np.linalg.eigvals(Q.T @ Ms @ Q)
    mu = np.concatenate([np.ones(r, dtype=complex), inner.astype(complex)])
    mu = mu[np.argsort(-np.abs(mu), kind="stable")]
    mu.setflags(write=False)
    stability, max_mu = classify_multipliers(inner, autonomous=False, unit_tol=UNIT_TOL)
    return dataclasses.replace(orbit, multipliers=mu, stability=stability, max_multiplier=max_mu)


def invariant_note(system: Any, values: Sequence[float] | None = None) -> str | None:
    """One line on a system's conserved combinations and the value its orbits are pinned at
    (None without invariants)."""
    C = system.invariants()
    if C.shape[0] == 0:
        return None
    labels = [combination_text(c, system.state_names) for c in C]
    vals = [0.0] * len(labels) if values is None else [float(v) for v in values]
    pinned = "; ".join(f"mean of {lab} = {v:g}" for lab, v in zip(labels, vals, strict=True))
    return (
        f"conserved combination(s) of {system.name!r}: {'; '.join(labels)} (its rate depends "
        f"on the time only, so periodic orbits form a family along it); the orbit with "
        f"{pinned} over the period is reported (default 0: the rest state y = 0; other "
        f"values: invariants= / --invariants); {len(labels)} multiplier(s) 1 trivial, left out "
        "of the stability"
    )


# ------------------------------------------------------------------------------------------
# autonomous systems: limit cycles and equilibria
# ------------------------------------------------------------------------------------------
class Equilibrium:
    """An equilibrium of an autonomous system (or, for a system with a drift direction ``d``
    such as the drill string's angles, a steady drift ``y' = rate * d``).

    Attributes
    ----------
    y : ndarray, shape (n,)
        The state (drift systems: with ``d . y = 0``).
    eigenvalues : ndarray of complex
        Of the Jacobian there, by decreasing real part (a drift system's trivial 0 included).
    stable : bool
        Every non-trivial eigenvalue has a negative real part.
    drift_rate : float or None
        ``rate`` of a steady drift; None for a true equilibrium.
    stability : str
        ``"stable"``, ``"unstable"``, or ``"marginal"`` when the largest non-trivial real part
        is within ``1e-9 max(1, max |lambda|)`` of 0 (a centre, or one of a continuum of
        sticking equilibria: the linearisation does not decide).
    """

    def __init__(self, y, eigenvalues, stable, drift_rate=None, stability=None) -> None:
        self.y, self.eigenvalues, self.stable = y, eigenvalues, bool(stable)
        self.drift_rate = drift_rate
        self.stability = stability or ("stable" if stable else "unstable")

    def __repr__(self) -> str:
        kind = "equilibrium" if self.drift_rate is None else f"steady drift {self.drift_rate:.6g}"
        return f"Equilibrium({kind}, {self.stability}, y = {[float(v) for v in self.y]})"


class LimitCycles:
    """What :func:`limit_cycles` found: ``cycles`` (tuple of
    :class:`~perturb.simulate.orbits.shooting.PeriodicOrbit`, by amplitude), ``equilibria``
    (tuple of :class:`Equilibrium`), ``drift`` (the direction ``d`` or None: orbits periodic up
    to a shift along it, gauge ``d . y0 = 0``), ``shifts`` (per cycle, the shift along ``d``
    over one period; 0 without drift) and ``notes`` (one line each: what was tried, what
    failed)."""

    def __init__(self, cycles, equilibria, drift, shifts, notes) -> None:
        self.cycles, self.equilibria, self.drift = tuple(cycles), tuple(equilibria), drift
        self.shifts, self.notes = tuple(shifts), tuple(notes)

    def __repr__(self) -> str:
        return (
            f"LimitCycles({len(self.cycles)} cycle(s), periods "
            f"{[round(o.period, 10) for o in self.cycles]}, {len(self.equilibria)} "
            "equilibri(um/a))"
        )


#: Time scales (2 pi / the fastest oscillation of the linearisation) per settling chunk, and
#: the window sampled for crossings after settling.
_SETTLE_CHUNK = 10
_WINDOW = 20
_SAMPLES_PER_SCALE = 64


def _autonomous_flow(system: Any) -> Any:
    """The flow for limit cycles: event-driven when the system has stops or friction contacts
    (sticking phases), else :func:`make_flow` (exact when piecewise affine, else DOP853), all
    at ``rtol = 1e-12`` with ``atol`` ``1e-12`` scaled down to small states (as
    :func:`_event_flow`)."""
    from perturb.simulate.flows.factory import make_flow
    from perturb.simulate.flows.system_events import SystemEventFlow

    contacts = [e.name for e in system.elements if e.kind in ("stop", "friction")]
    atol = float(_event_flow(system, [0.0] * system.n).atol)
    if contacts:
        return SystemEventFlow(system, rtol=1e-12, atol=atol)
    return make_flow(system, rtol=1e-12, atol=atol)


def _drift_direction(system: Any, A: Any) -> Any:
    """The one direction ``d`` with ``f(y + s d) = f(y)`` (``A d = 0`` and every element's
    combination blind to it: a free rotation angle), unit max-norm; None when there is none or
    more than one, or an element depends on the whole state."""
    import numpy as np

    rows = [A]
    for e in system.elements:
        c = system.numeric_form()["comb"][e.name][0]
        if c is None:
            return None
        rows.append(np.asarray(c, dtype=float)[None, :])
    mat = np.vstack(rows)
    scale = np.abs(mat).max(axis=1, keepdims=True)
    mat = mat / np.where(scale > 0, scale, 1.0)
    _, sv, Vt = np.linalg.svd(mat)
    n = A.shape[0]
    sv = np.concatenate([sv, np.zeros(max(0, n - sv.size))])
    null = Vt[sv <= 1e-10 * max(float(sv.max()), 1e-300)]
    if null.shape[0] != 1:
        return None
    d = null[0] / null[0][np.argmax(np.abs(null[0]))]
    d[np.abs(d) < 1e-12] = 0.0
    return d


def _linear_part(system: Any) -> Any:
    """The linear part ``A`` of ``y' = A y + g(y) + b(t)`` (elements left out)."""
    import numpy as np

    num = system.numeric_form()
    n, n2 = system.n, num["n2"]
    A = np.zeros((n, n))
    A[:n2, n2 : 2 * n2] = np.eye(n2)
    A[n2:, :] = -num["Binv"] @ num["L"]
    return A


def _check_no_free_family(system: Any) -> None:
    """A forced system whose field is blind to shifts along a direction ``d`` (a free
    translation or rotation) that no invariant pins has no isolated periodic orbit: each orbit
    ``y(t)`` comes with ``y(t) + s d`` for every ``s`` (or drifts along ``d``).

    Raises
    ------
    ModelError
        Naming ``d``.
    """
    import numpy as np

    from perturb.errors import ModelError

    d = _drift_direction(system, _linear_part(system))
    if d is None:
        return
    C = system.invariants()
    if C.shape[0] and float(np.abs(C @ d).max()) > 1e-9 * float(np.abs(C).max()):
        return  # pinning the invariant pins the shift too (mount_linear: equal pressures)
    text = combination_text(d, system.state_names)
    raise ModelError(
        f"system {system.name!r} is unchanged by a shift of its state along d = {text} (a free "
        "translation or rotation) that no conserved combination pins: its forced orbits are "
        "not isolated (each comes with every shifted copy) or drift along d; expected a "
        "restoring element on that direction (e.g. a spring to the ground)"
    )


def _equilibrium(flow: Any, jac: Any, y: Any, d: Any, scale: float) -> Any:
    """Newton on ``f(y) = 0`` (with a drift ``d``: ``f(y) = s d``, ``d . y = 0``) from ``y``,
    40 steps at most; ``(y, s)`` or None."""
    import numpy as np

    n = y.size
    z = np.append(np.array(y, dtype=float), 0.0) if d is not None else np.array(y, dtype=float)
    if d is not None:
        z[:n] -= d * float(d @ z[:n]) / float(d @ d)
    for _ in range(40):
        yy = z[:n]
        try:
            f = np.asarray(flow.vector_field(0.0, yy), dtype=float)
            J = np.asarray(jac(0.0, yy), dtype=float)
        except (PerturbError, ArithmeticError, ValueError):
            return None
        if d is not None:
            r = np.append(f - z[n] * d, d @ yy)
            K = np.zeros((n + 1, n + 1))
            K[:n, :n], K[:n, n], K[n, :n] = J, -d, d
        else:
            r, K = f, J
        if not np.all(np.isfinite(r)):
            return None
        if float(np.abs(r).max()) <= 1e-12 * max(scale, 1.0) * max(1.0, float(np.abs(J).max())):
            return z[:n].copy(), (float(z[n]) if d is not None else None)
        try:
            step = np.linalg.solve(K, -r)
        except np.linalg.LinAlgError:
            return None
        if not np.all(np.isfinite(step)):
            return None
        z = z + step
        if float(np.abs(z[:n]).max()) > 1e8 * max(scale, 1.0):
            return None
    return None


def _crossings(t: Any, s: Any, value: float) -> list:
    """Times and sample indices where ``s`` crosses ``value`` upwards (linear interpolation)."""
    import numpy as np

    j = np.flatnonzero((s[:-1] < value) & (s[1:] >= value))
    return [
        (float(t[i] + (value - s[i]) / (s[i + 1] - s[i]) * (t[i + 1] - t[i])), int(i)) for i in j
    ]


class BalanceCycle:
    """A limit cycle of autonomous harmonic balance (:func:`perturb.numeric.autonomous_balance.
    autonomous_balance_orbit`) read like a :class:`~perturb.simulate.orbits.shooting.
    PeriodicOrbit` by the front doors (:func:`orbit_columns`, ``perturb periodic``): ``period``,
    ``y0``, ``multipliers``, ``max_multiplier`` (the largest non-trivial one), ``stability``,
    ``sample_states``, ``max_abs`` (on ``2^14`` samples of the series); ``solution`` is the
    balance's own result."""

    autonomous = True
    m = 1
    _SAMPLES = 2**14

    def __init__(self, solution: Any, system: Any) -> None:
        import numpy as np

        self.solution = solution
        self.n2 = len(system.coordinates)
        self.period = float(solution.period)
        self.multipliers = np.asarray(solution.multipliers)
        self.max_multiplier = float(solution.max_multiplier)
        self.stability = "stable" if solution.stable else "unstable"
        self.t0 = 0.0
        self.y0 = self._states(np.zeros(1))[:, 0]
        self._dense: Any = None

    def _states(self, t: Any) -> Any:
        import numpy as np

        U = np.asarray(self.solution.coefficients, dtype=float)
        w = float(self.solution.frequency)
        H = (U.shape[1] - 1) // 2
        th = w * np.asarray(t, dtype=float)
        k = np.arange(1, H + 1)
        c, s = np.cos(np.outer(k, th)), np.sin(np.outer(k, th))
        val = U[:, :1] + U[:, 1::2] @ c + U[:, 2::2] @ s
        der = w * (k * U[: self.n2, 2::2] @ c - k * U[: self.n2, 1::2] @ s)
        return np.vstack([val[: self.n2], der, val[self.n2 :]])

    def sample_states(self, n: int = 256) -> tuple[Any, Any]:
        """``n`` equally spaced samples of every state over one period: ``(t, Y)``."""
        import numpy as np

        t = self.period * np.arange(int(n)) / int(n)
        return t, self._states(t)

    def max_abs(self, output: Any = None) -> Any:
        """``max_t |c . y(t)|`` (every state's without ``output``) on ``2^14`` samples."""
        import numpy as np

        if self._dense is None:
            self._dense = self.sample_states(self._SAMPLES)[1]
        if output is None:
            return np.array([self._peak(row) for row in self._dense])
        return self._peak(np.asarray(output, dtype=float) @ self._dense)

    @staticmethod
    def _peak(values: Any) -> float:
        """``max |v|`` of periodic samples, the largest refined by the parabola through it and
        its neighbours (the sampled maximum alone is off by ~(pi/N)^2 of the curvature)."""
        import numpy as np

        a = np.abs(values)
        i = int(np.argmax(a))
        y0, y1, y2 = a[i - 1], a[i], a[(i + 1) % a.size]
        den = y0 - 2 * y1 + y2
        if den >= 0:  # a kink or a flat top: the sample is the best there is
            return float(y1)
        return float(y1 - 0.125 * (y2 - y0) ** 2 / den)

    def __repr__(self) -> str:
        return f"BalanceCycle(period {self.period:.10g}, {self.stability})"


#: Methods of :func:`limit_cycles`.
LIMIT_CYCLE_METHODS = ("exact", "hb")


def _balance_limit_cycles(system: Any, harmonics: int, output: str | None) -> LimitCycles:
    """:func:`limit_cycles` with ``method="hb"``: autonomous harmonic balance from its own
    automatic start (one cycle, no equilibria searched)."""
    from perturb.numeric.autonomous_balance import autonomous_balance_orbit

    H = registry.check_harmonics(harmonics)
    system_output(system, output)  # a bad output is refused before any work
    try:
        sol = autonomous_balance_orbit(system, H)
    except PerturbError as exc:
        if isinstance(exc, ParameterError):
            raise
        from perturb.errors import ModelError

        if isinstance(exc, ModelError):
            raise
        return LimitCycles((), (), None, (), (f"harmonic balance, H = {H}: {exc}",))
    note = (
        f"harmonic balance of the autonomous system, H = {H} (frequency an unknown, phase "
        f"condition): one cycle from its automatic start, residual {sol.residual_norm:.1e}"
        + (f", friction jumps smoothed over {sol.jump_width:.3g}" if sol.jump_width else "")
        + "; no equilibria searched (method 'exact' finds them)"
    )
    return LimitCycles((BalanceCycle(sol, system),), (), None, (0.0,), (note,))


def limit_cycles(
    system: Any,
    *,
    guesses: Sequence[Sequence[float]] = (),
    grid: int = 3,
    transient_periods: int = 100,
    extent: float | None = None,
    output: str | None = None,
    method: str = "exact",
    harmonics: int | None = None,
) -> LimitCycles:
    """Every limit cycle (and equilibrium) found of an autonomous system (no harmonic forcing).

    ``method="hb"`` answers by autonomous harmonic balance instead
    (:func:`perturb.numeric.autonomous_balance.autonomous_balance_orbit`, ``harmonics``
    harmonics, default 7; the frequency an unknown, Floquet multipliers of the linearisation):
    one cycle from its automatic start, as a :class:`BalanceCycle`, no equilibria; ``guesses``,
    ``grid``, ``transient_periods`` and ``extent`` belong to the default ``"exact"`` search.

    The equilibria come from Newton on ``f(y) = 0`` from the zero state and from where the
    settled runs come to rest (a system with a drift direction ``d``, ``f(y + s d) = f(y)``
    such as a freely turning angle: steady drifts ``f(y) = s d``). The time scale ``tau`` is
    ``2 pi`` over the fastest oscillation of the Jacobian at the first equilibrium (or of the
    linear part). Runs start from each equilibrium nudged by ``1e-3`` of its scale, from the
    zero state, from ``+-extent`` (default 3) times each coordinate's scale about the first
    equilibrium, from ``guesses`` and from ``grid`` random states in that box (a fixed seed);
    each settles for up to ``transient_periods * tau`` (in chunks of ``10 tau``, stopped as
    soon as it comes near a cycle already found), then ``20 tau`` are sampled: a run that
    still oscillates gives the phase state (the velocity, else first-order state, of the
    largest relative range), its mid-range value as the phase, the period between upward
    crossings and the state there; :func:`perturb.simulate.orbits.shooting.limit_cycle`
    (with ``drift=d`` when there is one) polishes the cycle. Cycles equal in period, and in the
    ``max |.|`` and mean of every state not along ``d``, are one.

    Flows: :class:`~perturb.simulate.flows.system_events.SystemEventFlow` when the system has
    friction contacts or stops, else :func:`~perturb.simulate.flows.factory.make_flow` (exact
    piecewise-affine or DOP853), ``rtol = 1e-12``.

    Returns
    -------
    LimitCycles
        Cycles sorted by ``max |.|`` of ``output``, equilibria, notes.

    Raises
    ------
    ModelError
        A forced system, or one with conserved combinations (:meth:`System.invariants
        <perturb.model.system.System.invariants>`; not searched yet).
    ParameterError
        Bad ``guesses``, ``grid``, ``transient_periods`` or ``extent``; a ``method`` other
        than ``"exact"`` or ``"hb"``; ``harmonics`` without ``method="hb"``.
    """
    import numpy as np

    from perturb.errors import ModelError

    if method not in LIMIT_CYCLE_METHODS:
        raise ParameterError(
            f"method = {method!r}: expected 'exact' (shooting from settled runs) or 'hb' "
            "(autonomous harmonic balance, harmonics=H)"
        )
    if method == "hb":
        if guesses or grid != 3 or transient_periods != 100 or extent is not None:
            raise ParameterError(
                "guesses, grid, transient_periods and extent belong to the exact search "
                "(method='exact'); method 'hb' takes harmonics"
            )
        if not is_system(system):
            raise ParameterError(f"system = {system!r}: expected a perturb System")
        if is_forced(system):
            raise ModelError(
                f"system {system.name!r} is forced: its periodic orbits are at the forcing "
                "frequency (frequency_response / periodic_orbits), not limit cycles"
            )
        return _balance_limit_cycles(system, 7 if harmonics is None else harmonics, output)
    if harmonics is not None:
        raise ParameterError(
            f"harmonics = {harmonics!r}: an option of method 'hb' (the exact search has none)"
        )
    from perturb.simulate.orbits.shooting import limit_cycle

    if is_forced(system):
        raise ModelError(
            f"system {system.name!r} is forced (harmonic terms in its equations): its orbits are "
            "at the forcing frequency (periodic_orbits with Omega), not limit cycles"
        )
    C = system.invariants()
    if C.shape[0]:
        labels = "; ".join(combination_text(c, system.state_names) for c in C)
        raise ModelError(
            f"system {system.name!r} is autonomous with the conserved combination(s) {labels}: "
            "its limit cycles come in families along them, which this search does not pin yet"
        )
    grid = checks.whole(grid, "grid", 0, 100, "random starting states")
    transient_periods = checks.whole(transient_periods, "transient_periods", 0, 100_000)
    factor = 3.0 if extent is None else checks.finite(extent, "extent")
    if not factor > 0:
        raise ParameterError(f"extent = {extent!r}: expected a positive number")
    c_out, _ = system_output(system, output)
    n = system.n
    given = _state_guesses(guesses, system)
    flow = _autonomous_flow(system)
    if not hasattr(flow, "jacobian"):  # the exact piecewise-affine flow: DOP853's field has it
        from perturb.simulate.flows.factory import make_flow

        jac = make_flow(system, method="ode").jacobian
    else:
        jac = flow.jacobian
    notes: list[str] = []
    n2 = system.numeric_form()["n2"]
    A = _linear_part(system)
    d = _drift_direction(system, A)
    free = np.ones(n, dtype=bool) if d is None else d == 0  # states not along the drift

    def gauge(y: Any) -> Any:
        return y if d is None else y - d * float(d @ y) / float(d @ d)

    # equilibria from the zero state (and the linear part's)
    equilibria: list = []

    def add_equilibrium(y: Any) -> None:
        scale = max(1.0, float(np.abs(y).max()))
        found = _equilibrium(flow, jac, y, d, scale)
        if found is None:
            return
        ye, rate = found
        for e in equilibria:
            if float(np.abs(gauge(e.y) - gauge(ye)).max()) <= 1e-8 * scale:
                return
        J = np.asarray(jac(0.0, ye), dtype=float)
        lam = np.linalg.eigvals(J)
        lam = lam[np.argsort(-lam.real, kind="stable")]
        nontrivial = lam if d is None else np.delete(lam, int(np.argmin(np.abs(lam))))
        top = float(nontrivial.real.max()) if nontrivial.size else -1.0
        margin = 1e-9 * max(1.0, float(np.abs(lam).max()))
        label = "stable" if top < -margin else ("unstable" if top > margin else "marginal")
        equilibria.append(Equilibrium(ye, lam, label == "stable", rate, label))

    add_equilibrium(np.zeros(n))
    try:
        b0 = flow.vector_field(0.0, np.zeros(n))
        add_equilibrium(gauge(-np.linalg.lstsq(A, b0, rcond=None)[0]))
    except (np.linalg.LinAlgError, PerturbError, ValueError):
        pass
    ref = equilibria[0].y if equilibria else np.zeros(n)
    try:
        J0 = np.asarray(jac(0.0, ref), dtype=float)
    except (PerturbError, ValueError):
        J0 = A
    lam = np.linalg.eigvals(J0)
    fast = float(np.abs(lam.imag).max()) if lam.size else 0.0
    if not fast > 0:
        nonzero = np.abs(lam[np.abs(lam) > 1e-12 * max(1.0, float(np.abs(lam).max()))])
        fast = float(nonzero.min()) if nonzero.size else 1.0
    tau = 2.0 * math.pi / fast
    size = np.abs(ref).copy()
    size = np.where(size > 1e-12 * max(1.0, float(size.max())), size, max(1.0, float(size.max())))
    size = np.where(free, size, 0.0) if d is not None else size
    starts = [*given]
    rng = np.random.default_rng(0)  # reproducible starts
    for e in equilibria:
        starts.append(e.y + 1e-3 * np.maximum(np.abs(e.y), 1.0) * rng.uniform(-1.0, 1.0, n))
    starts.append(np.zeros(n))
    for name in system_coordinates(system):
        i = system.state_names.index(name)
        if d is not None and d[i] != 0:
            continue  # a drifting angle: a shift along d is the same motion
        for sign in (1.0, -1.0):
            y = ref.copy()
            y[i] += sign * factor * max(size[i], 1e-300)
            starts.append(y)
    starts += [ref + factor * size * rng.uniform(-1.0, 1.0, n) for _ in range(grid)]

    cycles: list = []
    shifts: list = []
    samples: list = []  # each cycle's sampled states (gauged, drift-free states), for "near"
    keys: list = []

    def near_known(y: Any) -> bool:
        yy = gauge(y)[free]
        scale = max(1.0, float(np.abs(yy).max()))
        return any(
            float(np.abs(S - yy[:, None]).max(axis=0).min()) <= 1e-3 * scale for S in samples
        )

    bound = 1e8 * max(1.0, float(np.abs(size).max()), float(np.abs(ref).max()))
    for y in starts:  # bounded: a fixed number of starts, each a bounded run and one Newton
        z = np.asarray(y, dtype=float)
        t = 0.0
        try:
            for _ in range(max(1, math.ceil(transient_periods / _SETTLE_CHUNK))):
                z = gauge(np.asarray(flow(z, t, t + _SETTLE_CHUNK * tau).y, dtype=float))
                t += _SETTLE_CHUNK * tau
                if not np.all(np.isfinite(z)) or float(np.abs(z).max()) > bound:
                    raise ArithmeticError("escaped")
                if near_known(z):
                    break
            if near_known(z):
                continue
            tw = np.linspace(t, t + _WINDOW * tau, _WINDOW * _SAMPLES_PER_SCALE + 1)
            ys = np.asarray(flow(z, t, tw[-1], t_eval=tw).ys, dtype=float).T
        except (PerturbError, ArithmeticError, ValueError) as exc:
            notes.append(f"a run from {np.round(y, 6).tolist()} gave up: {exc}")
            continue
        rng_state = ys.max(axis=1) - ys.min(axis=1)
        mag = np.maximum(np.abs(ys).max(axis=1), 1e-300)
        rel = np.where(free, rng_state / mag, 0.0)
        half = ys.shape[1] // 2
        first = np.where(free, np.ptp(ys[:, :half], axis=1), 0.0)
        second = np.where(free, np.ptp(ys[:, half:], axis=1), 0.0)
        if float(rel.max()) <= 1e-7 or float(second.max()) <= 0.5 * float(first.max()):
            add_equilibrium(ys[:, -1])  # came to rest, or still decaying towards it
            continue
        cand = [i for i in range(n2, n) if free[i]] or [i for i in range(n) if free[i]]
        k = max(cand, key=lambda i: (rel[i], -i))
        value = 0.5 * float(ys[k].max() + ys[k].min())
        cross = _crossings(tw, ys[k], value)
        if len(cross) < 3:
            notes.append(
                f"a run from {np.round(y, 6).tolist()} settled on no oscillation of "
                f"{system.state_names[k]} with three crossings in {_WINDOW} time scales"
            )
            continue
        (t1, _), (t2, i2) = cross[-2], cross[-1]
        f = (value - ys[k, i2]) / (ys[k, i2 + 1] - ys[k, i2])
        guess = gauge(ys[:, i2] + f * (ys[:, i2 + 1] - ys[:, i2]))
        guess[k] = value
        try:
            orbit = limit_cycle(
                flow, guess, t2 - t1, phase_state=k, phase_value=value, drift=d, max_iter=40
            )
        except PerturbError as exc:
            notes.append(f"limit_cycle from a settled run failed: {exc}")
            add_equilibrium(ys[:, -1])  # a slowly decaying oscillation: its equilibrium
            continue
        _, Y = orbit.sample_states(_STATS_SAMPLES)
        Yf = Y[free]  # states not along the drift (the gauge leaves them unchanged)
        eye = np.eye(n)
        # phase-independent numbers: refined maxima; the sampled means agree to ~1e-6 (a
        # stick-slip signal's kinks) whichever crossing the phase condition picked
        key = np.concatenate(
            [
                [orbit.period],
                [float(orbit.max_abs(eye[i])) for i in range(n) if free[i]],
                Yf.mean(axis=1),
            ]
        )
        if any(
            float(np.abs(key - other).max()) <= 1e-5 * max(1.0, float(np.abs(other).max()))
            for other in keys
        ):
            continue
        keys.append(key)
        cycles.append(orbit)
        samples.append(Yf)
        end = np.asarray(flow(orbit.y0, 0.0, orbit.period).y, dtype=float)
        shifts.append(0.0 if d is None else float(d @ (end - orbit.y0)) / float(d @ d))
    family = [o for o in cycles if np.all(np.abs(np.abs(o.multipliers) - 1.0) <= 1e-6)]
    if family:
        notes.append(
            f"{len(family)} of the cycles have every multiplier on the unit circle at 1: they "
            "are members of a continuous family (a conservative system), not isolated limit "
            "cycles; the ones listed are those the runs happened to settle near"
        )
    order = sorted(range(len(cycles)), key=lambda i: float(cycles[i].max_abs(c_out)))
    return LimitCycles(
        [cycles[i] for i in order],
        equilibria,
        d,
        [shifts[i] for i in order],
        notes,
    )


class SystemHistory:
    """A sampled time history of a system: ``t``, every state ``y`` (``samples x n``) and the
    ``output`` combination.

    Attributes
    ----------
    t : ndarray
    y : ndarray, shape (samples, n)
        In the order of ``state_names``.
    state_names : tuple of str
    output : ndarray
        The output combination at each sample.
    output_name : str
    method : str
        ``"exact"`` (closed-form piecewise-affine flow) or ``"ode"`` (DOP853).
    name : str
        The system's name.
    """

    def __init__(self, t, y, state_names, output, output_name, method, name) -> None:
        self.t, self.y, self.output = t, y, output
        self.state_names = tuple(state_names)
        self.output_name, self.method, self.name = output_name, method, name

    def __repr__(self) -> str:
        import numpy as np

        return (
            f"SystemHistory({self.name}, {self.t.size} samples on [{self.t[0]:g}, "
            f"{self.t[-1]:g}], {self.method}; output {self.output_name}: max |.| = "
            f"{float(np.abs(self.output).max()):.6g})"
        )

    @property
    def columns(self) -> tuple[str, ...]:
        """The CSV columns: ``t``, the states, ``output``."""
        return ("t", *self.state_names, "output")

    def to_csv(self, path: Any = None) -> str:
        """The CSV text (:attr:`columns`); with ``path`` also written there (complete or
        absent: a temporary file renamed)."""
        rows = [",".join(self.columns)]
        for k in range(self.t.size):
            vals = [float(self.t[k]), *map(float, self.y[k]), float(self.output[k])]
            rows.append(",".join(repr(v) for v in vals))
        text = "\n".join(rows) + "\n"
        if path is not None:
            from perturb.atomic import write_text

            write_text(path, text)
        return text


def system_time_history(
    system: Any,
    y0: Sequence[float] | None,
    t_span: Sequence[float],
    *,
    method: str = "auto",
    samples: int = 2001,
    output: str | None = None,
    Omega: float | None = None,
) -> SystemHistory:
    """Integrate a system of several coordinates from ``y0`` over ``t_span``.

    Parameters
    ----------
    system
        A :class:`~perturb.model.system.System` with its parameter values (no stops).
    y0
        The ``n`` states in the order of ``system.state_names`` (default: zero).
    method
        ``"auto"``: the event-driven flow
        (:class:`~perturb.simulate.flows.system_events.SystemEventFlow`) when the system has
        stops or friction contacts, else the exact closed-form flow when piecewise affine,
        else DOP853 (:func:`perturb.simulate.flows.factory.make_flow`); ``"exact"``,
        ``"ode"`` or ``"events"`` to choose. The oscillators' ``"event"`` and ``"lcp"``
        integrators take one coordinate.
    samples
        Equally spaced output instants, 2 to 10**7.
    output
        What the ``output`` column holds (:func:`system_output`).
    Omega
        Sets the system's parameter ``Omega``.

    Raises
    ------
    ParameterError
        Bad method, ``y0``, span or sample count.
    ModelError
        A system with stops; ``method="exact"`` on a system that is not piecewise affine.
    """
    import numpy as np

    from perturb.simulate.flows.affine_exact import AffineExactFlow

    if method not in SYSTEM_INTEGRATORS:
        raise ParameterError(
            f"method = {method!r}: a system of several coordinates takes 'auto', 'exact' "
            "(piecewise affine), 'ode' or 'events' (the 'event' and 'lcp' integrators of "
            "an oscillator take one coordinate)"
        )
    samples = checks.whole(samples, "samples", 2, 10**7, "rows of the output")
    try:
        t0, t1 = (checks.finite(t, "t_span") for t in t_span)
    except (TypeError, ValueError):
        raise ParameterError(f"t_span = {t_span!r}: expected (t0, t1)") from None
    if not t1 > t0:
        raise ParameterError(f"t_span = {t_span!r}: expected t0 < t1")
    system = _system_at(system, Omega)
    c, name = system_output(system, output)
    n = system.n
    y = np.zeros(n) if y0 is None else np.array(y0, dtype=float).reshape(-1)
    if y.size != n or not np.all(np.isfinite(y)):
        raise ParameterError(
            f"y0 = {y0!r}: expected {n} finite numbers, the states {', '.join(system.state_names)}"
        )
    t = np.linspace(t0, t1, samples)
    contacts = [e.name for e in system.elements if e.kind in ("stop", "friction")]
    if method == "events" or (method == "auto" and contacts):
        # stops (impacts, a resting plate) and friction contacts (sticking) need the
        # event-driven solver: DOP853 alone would step across them
        flow = _event_flow(system, y)
        label = "events"
    else:
        flow = _system_flow(system, method)
        label = "exact" if isinstance(flow, AffineExactFlow) else "ode"
    ys = np.array(flow(y, t0, t1, t_eval=t).ys, dtype=float)
    ys[0] = y  # the initial state as given (a dense output rounds it)
    return SystemHistory(t, ys, system.state_names, ys @ c, name, label, system.name)


def _state_guesses(guesses: Any, system: Any) -> list:
    """The user's starting states of a system, each checked: ``n`` finite numbers."""
    import numpy as np

    n = system.n
    out = []
    for g in guesses:
        try:
            y = np.array(g, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            y = np.array([])
        if y.size != n or not np.all(np.isfinite(y)):
            raise ParameterError(
                f"guess {g!r}: expected {n} finite numbers ({', '.join(system.state_names)})"
            )
        out.append(y)
    return out


def _event_flow(system: Any, y0: Any) -> Any:
    """The event-driven flow of a system, its absolute tolerance ``1e-12`` scaled down to the
    states' size when they are small (``max |.|`` of ``y0`` and of the equilibrium of the
    linearisation at the zero state: the mount's volumes are 1e-6 m^3)."""
    import numpy as np

    from perturb.simulate.flows.system_events import SystemEventFlow

    flow = SystemEventFlow(system)
    zero = np.zeros(system.n)
    size = float(np.abs(y0).max())
    try:
        eq = -np.linalg.solve(flow.jacobian(0.0, zero), flow.vector_field(0.0, zero))
        if np.all(np.isfinite(eq)):
            size = max(size, float(np.abs(eq).max()))
    except (np.linalg.LinAlgError, PerturbError, ValueError):
        pass  # a singular linear part (a free rigid-body mode): the states' own size
    # only ever smaller than 1e-12: large states are held by rtol, and a drifting rigid-body
    # mode (the drill string's rotation) has no equilibrium to size anything
    scale = min(size, 1.0) if size > 0 else 1.0
    return SystemEventFlow(system, rtol=1e-11, atol=1e-12 * scale)


@functools.cache
def _response_class() -> type:
    """:class:`SystemResponse`, defined on first use: the response module loads NumPy, which
    importing this module does not."""
    from dataclasses import dataclass, field

    from perturb.response import Response

    @dataclass(frozen=True, eq=False, repr=False)  # Response's short repr
    class SystemResponse(Response):
        """A system's frequency response: the :class:`~perturb.response.Response` columns
        measure ``output``; ``columns`` holds, per branch, ``amplitude_<name>`` and
        ``mean_<name>`` of every coordinate (arrays), which :meth:`to_csv` appends."""

        output: str = ""
        coordinates: tuple[str, ...] = ()
        columns: tuple[Any, ...] = field(default=())

        def extra_columns(self) -> dict[str, list[float]]:
            """The per-coordinate columns, one value per CSV row."""
            names = [f"amplitude_{c}" for c in self.coordinates]
            names += [f"mean_{c}" for c in self.coordinates]
            return {n: [float(v) for cols in self.columns for v in cols[n]] for n in names}

        def to_csv(self, path: Any = None, extra: Any = None) -> str:
            """The CSV of :class:`~perturb.response.Response`, then ``amplitude_<name>``,
            ``mean_<name>`` of every coordinate, then ``extra``."""
            return super().to_csv(path, extra={**self.extra_columns(), **dict(extra or {})})

    SystemResponse.__module__ = __name__
    SystemResponse.__qualname__ = "SystemResponse"
    return SystemResponse


def __getattr__(name: str) -> Any:
    # SystemResponse is built on first access (see _response_class)
    if name == "SystemResponse":
        return _response_class()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _system_response(
    system: Any,
    method: str | None,
    Omega: Sequence[float],
    frequencies: Sequence[float] | None,
    output: str | None,
    options: dict[str, Any],
) -> Any:
    """:func:`frequency_response` of a :class:`~perturb.model.system.System`: the exact
    branches (:func:`perturb.simulate.exact_response.exact_branches` with ``output``) as a
    :class:`SystemResponse`; at listed ``frequencies``, every orbit found there
    (:func:`periodic_orbits` and the crossings of the branches traced over a covering
    window, polished by shooting at each frequency), each its own one-point branch.

    Raises
    ------
    ParameterError
        A method other than ``"exact"`` (the approximations take one coordinate), or an
        option ``"exact"`` does not take.
    """
    if method in SYSTEM_ONLY_METHODS:
        return _system_ms_ir(system, Omega, frequencies, output, dict(options))
    spec = registry.spec("exact" if method is None else method)
    if spec.name not in SYSTEM_METHODS:
        raise ParameterError(
            f"method {spec.name!r} ({spec.title}) is for one coordinate (an Oscillator); a "
            f"system of several coordinates ({system.name!r}) takes one of "
            f"{', '.join(SYSTEM_METHODS)} ({system_method_text()})"
        )
    if spec.name == "hb":
        return _system_hb(system, Omega, frequencies, output, dict(options))
    if spec.name in ("hb1", "shb"):
        return _system_shb(system, spec.name, Omega, frequencies, output, dict(options))
    if spec.name == "auto":
        return _system_auto(system, Omega, frequencies, output, dict(options))
    options = spec.validate(dict(options))
    for key in ("approximation", "approximation_seeds"):
        if key in options:
            raise ParameterError(
                f"{key}: approximations start the exact solver of one coordinate; a system "
                "takes seeds=[(Omega, y0), ...] with its n states"
            )
    system_output(system, output)  # a bad output is refused before any work
    _check_frequency_response(system, frequencies is not None)
    if frequencies is not None:
        return _system_solutions_at(
            system, checks.frequencies(frequencies, MAX_FREQUENCIES), output, options
        )
    from perturb.simulate.exact_response import exact_branches

    found = exact_branches(system, Omega, output=output, **options)
    resp = found.to_response()
    cls = _response_class()
    return cls(
        resp.branches,
        resp.method,
        resp.model,
        resp.params,
        resp.folds,
        resp.notes,
        output=system_output(system, output)[1],
        coordinates=system_coordinates(system),
        columns=found.columns(),
    )


def _system_hb(
    system: Any,
    Omega: Sequence[float],
    frequencies: Sequence[float] | None,
    output: str | None,
    options: dict[str, Any],
) -> Any:
    """Method ``"hb"`` for a :class:`~perturb.model.system.System`: numeric multi-harmonic
    balance (:mod:`perturb.numeric.system_balance`), every branch in the window
    (:func:`~perturb.numeric.system_balance.system_balance_response`; one branch from the
    high end with ``all_branches=False``), or one orbit per listed frequency (automatic
    start), as a :class:`SystemResponse` with ``amplitude_<name>`` / ``mean_<name>`` per
    coordinate (method ``"hb-system"``).

    Raises
    ------
    ParameterError
        An option the system's HB does not take (the message lists those it does), bad
        values (``harmonics``, window, ``stability``).
    """
    from perturb.numeric.system_balance import SystemBalance

    unknown = sorted(set(options) - set(SYSTEM_HB_OPTIONS))
    if unknown:
        raise ParameterError(
            f"{', '.join(unknown)}: not options of harmonic balance for a system (expected: "
            f"{', '.join(SYSTEM_HB_OPTIONS)})"
        )
    H = registry.check_harmonics(options.pop("harmonics", DEFAULT_HARMONICS))
    m = options.pop("m", 1)
    stability = _check_stability_flag(options.pop("stability", True))
    projection = options.pop("projection", "exact")
    all_branches = options.pop("all_branches", True)
    system_output(system, output)  # a bad output is refused before any work
    _check_frequency_response(system, frequencies is not None)
    sb = SystemBalance(system, H, m=m, projection=projection)
    branches, resp = _balance_branches(
        system, sb, Omega, frequencies, output, stability, all_branches, options
    )
    if resp is None:
        notes: tuple[str, ...] = (
            f"harmonic balance of a system, H = {H}, m = {m}: every solution found at "
            "each frequency",
        )
        return _balance_response(system, branches, "hb-system", output, notes)
    return _balance_response(system, branches, resp.method, output, resp.notes, resp)


def _balance_branches(
    system: Any,
    sb: Any,
    Omega: Sequence[float],
    frequencies: Sequence[float] | None,
    output: str | None,
    stability: bool,
    all_branches: bool,
    options: dict[str, Any],
) -> tuple[list, Any]:
    """The branches of the balance ``sb`` (a :class:`~perturb.numeric.system_balance.
    SystemBalance`) over ``Omega`` (every branch, or one with ``all_branches=False``), or its
    solutions at listed ``frequencies``; and the traced response (None at listed
    frequencies)."""
    from perturb.numeric.system_balance import (
        system_balance_branch,
        system_balance_response,
        system_balance_solutions_at,
    )

    if frequencies is not None:
        for key in ("mirror", "ds_max", "max_points", "max_branches", "direction", "interior"):
            if key in options:
                raise ParameterError(f"{key}: an option of a traced window, not of frequencies=")
        options.pop("tol", None)
        found = system_balance_solutions_at(
            system,
            checks.frequencies(frequencies, MAX_FREQUENCIES),
            output=output,
            stability=stability,
            balance=sb,
        )
        return list(found.branches), None
    window = checks.window(Omega)
    if all_branches:
        options.pop("direction", None)
        found = system_balance_response(
            system, window, output=output, stability=stability, balance=sb, **options
        )
        return list(found.branches), found.to_response()
    options.pop("interior", None)
    options.pop("mirror", None)
    options.pop("max_branches", None)
    br = system_balance_branch(
        system, window, output=output, stability=stability, balance=sb, **options
    )
    return [br], br.to_response()


def _balance_response(
    system: Any,
    branches: Sequence[Any],
    method: str,
    output: str | None,
    notes: Sequence[str],
    traced: Any = None,
) -> Any:
    """A :class:`SystemResponse` of balance branches; ``traced`` (a Response of the same
    branches, or None for listed points) gives the folds and parameters."""
    # each branch's columns also hold "states" (P, n): the HB orbits' states at t = 0, which
    # system_errors shoots the exact orbits from (not written to the CSV)
    cols = tuple({**b.columns(), "states": b.states()} for b in branches)
    cls = _response_class()
    if traced is None:
        return cls(
            tuple(b.to_branch() for b in branches),
            method,
            system.name,
            notes=tuple(notes),
            output=system_output(system, output)[1],
            coordinates=system_coordinates(system),
            columns=cols,
        )
    return cls(
        tuple(b.to_branch() for b in branches),
        method,
        traced.model,
        traced.params,
        traced.folds,
        tuple(notes),
        output=system_output(system, output)[1],
        coordinates=system_coordinates(system),
        columns=cols,
    )


def system_method_text() -> str:
    """One line naming what each method of :data:`SYSTEM_METHODS` does for a system."""
    return (
        "exact: continuation of exact orbits; hb: numeric multi-harmonic balance, harmonics=H; "
        "hb1 / shb: symbolic single-harmonic balance (describing functions; shb takes bias=); "
        "ms-ir: slow flow of two coordinates with a 1:1 or 1:3 internal resonance; "
        "auto: the cheapest of those meeting rtol at exact spot checks"
    )


def _check_stability_flag(stability: Any) -> bool:
    if stability in ("none", False, None):
        return False
    if stability in (True, "hill", "floquet"):
        return True
    raise ParameterError(
        f"stability = {stability!r}: expected True/'floquet' (Floquet multipliers of the "
        "linearisation about the HB orbit) or False/'none'"
    )


def _parameter_values(derivation: Any, system_name: str, what: str) -> list[float]:
    """The numbers of a system derivation's ``parameters`` (in their order), or a
    ParameterError naming the one without a value."""
    values = []
    for p in derivation.parameters:
        v = derivation.values.get(str(p))
        if v is None:
            raise ParameterError(
                f"parameter {p} of system {system_name!r} has no value: {what} needs numbers "
                "to be solved"
            )
        values.append(float(v))
    return values


def system_single_harmonic_residuals(derivation: Any) -> Any:
    """The residuals of a system's symbolic single-harmonic balance as a numeric function.

    Parameters
    ----------
    derivation
        A :class:`~perturb.methods.system_harmonic_balance.SystemHarmonicBalance`.

    Returns
    -------
    callable
        ``f(U, Omega) -> R``: ``U`` of shape ``(P, n, 3)`` (per point and coordinate the
        coefficients ``[mean, cos, sin]`` as numeric balance lays them out), ``Omega`` of
        shape ``(P,)``; ``R`` of shape ``(P, len(residuals))``, the system's parameter values
        bound. Without a bias in the derivation the means are not arguments (they must be 0).
    """
    import numpy as np

    from perturb.numeric.compile import lambdify

    fn = lambdify(derivation.arguments, derivation.residuals)
    values = _parameter_values(derivation, derivation.system.name, "the single-harmonic balance")
    biased = bool(derivation.biases)

    def residuals(U: Any, Omega: Any) -> Any:
        U = np.asarray(U, dtype=float)
        W = np.asarray(Omega, dtype=float)
        args = ([*U[:, :, 0].T] if biased else []) + [*U[:, :, 1].T] + [*U[:, :, 2].T]
        out = fn(*args, W, *(np.full(W.shape, v) for v in values))
        return np.stack([np.broadcast_to(o, W.shape) for o in out], axis=1)

    return residuals


def _system_shb(
    system: Any,
    name: str,
    Omega: Sequence[float],
    frequencies: Sequence[float] | None,
    output: str | None,
    options: dict[str, Any],
) -> Any:
    """Methods ``"hb1"`` and ``"shb"`` for a :class:`~perturb.model.system.System`: the
    symbolic single-harmonic balance (:func:`perturb.methods.system_harmonic_balance.
    system_single_harmonic_balance`, describing functions of each element's combination).

    Its equations are those of numeric harmonic balance with ``H = 1`` and the exact Galerkin
    projection (the projection of a PWL force on one harmonic is its closed-form describing
    function and mean), so the numeric layer traces them there (every branch, Floquet
    multipliers of the linearisation about each orbit), and every point found is then checked
    on the symbolic residuals themselves (lambdified): a point where they do not vanish (to
    ``1e-7`` of the orbit's size) is dropped with a note. Without a bias (an odd system without
    static load, ``bias=None``/``False``) the ansatz has zero means: branches of numeric
    solutions with a mean are outside it and left out (the note says how many).

    Raises
    ------
    ParameterError
        An option neither method takes (listing those they do), ``bias`` with ``"hb1"``, a
        harmonic set other than ``(1,)``.
    ModelError
        What the derivation refuses (a stop, a zero combination, several forcing frequencies).
    """
    import numpy as np

    from perturb.methods.system_harmonic_balance import system_single_harmonic_balance
    from perturb.numeric.system_balance import SystemBalance

    unknown = sorted(set(options) - set(SYSTEM_SHB_OPTIONS))
    if unknown:
        raise ParameterError(
            f"{', '.join(unknown)}: not options of the single-harmonic balance of a system "
            f"(expected: {', '.join(SYSTEM_SHB_OPTIONS)})"
        )
    bias = options.pop("bias", None)
    harmonics = options.pop("harmonics", None)
    if name == "hb1" and (bias is not None or harmonics is not None):
        given = "bias" if bias is not None else "harmonics"
        raise ParameterError(
            f"{given}: 'hb1' is the single-harmonic balance with the bias its derivation "
            "decides (a mean where an element is not odd or a load acts); method 'shb' takes "
            "bias=True/False, numeric 'hb' takes harmonics=H"
        )
    if harmonics is not None and tuple(harmonics) not in ((1,), (1.0,)):
        raise ParameterError(
            f"harmonics = {harmonics!r}: the symbolic balance of a system has the one harmonic "
            "set (1,); numeric 'hb' takes harmonics=H for more"
        )
    if bias is not None and not isinstance(bias, bool):
        raise ParameterError(f"bias = {bias!r}: expected True, False or None (automatic)")
    stability = _check_stability_flag(options.pop("stability", True))
    all_branches = options.pop("all_branches", True)
    system_output(system, output)  # a bad output is refused before any work
    _check_frequency_response(system, frequencies is not None)
    derivation = system_single_harmonic_balance(system, bias=bias)
    sb = SystemBalance(system, 1)
    branches, traced = _balance_branches(
        system, sb, Omega, frequencies, output, stability, all_branches, options
    )
    residuals = system_single_harmonic_residuals(derivation)
    kept, off_ansatz, off_residual, worst = [], 0, 0, 0.0
    for br in branches:
        U = np.asarray(br.U, dtype=float)
        size = np.maximum(1.0, np.abs(U).max(axis=(1, 2)))
        ok = np.ones(len(br), dtype=bool)
        if not derivation.biases:
            ok &= np.abs(U[:, :, 0]).max(axis=1) <= 1e-7 * size
        R = np.abs(residuals(U, br.Omega)).max(axis=1)
        good = ok & (R <= 1e-7 * size)
        off_residual += int(np.sum(ok & ~good))
        if np.any(good):
            worst = max(worst, float(np.max(R[good] / size[good])))
        if good.all():
            kept.append(br)
            continue
        if not ok.any():
            off_ansatz += 1
            continue
        kept += _runs_of(br, good, frequencies is not None)
    notes = [
        f"symbolic single-harmonic balance of {len(derivation.coordinates)} coordinates "
        f"({derivation.label}: unknowns {', '.join(map(str, derivation.unknowns))}), solved "
        "as numeric balance with H = 1 and the exact projection (the same equations); its "
        f"symbolic residuals at the solutions: max {worst:.1e} relative to the orbit's size",
        *derivation.notes,
    ]
    if off_ansatz:
        notes.append(
            f"{off_ansatz} branches with a mean left out: the zero-mean ansatz (no bias in the "
            "derivation) does not hold them; method 'shb' with bias=True keeps them"
        )
    if off_residual:
        notes.append(f"{off_residual} points dropped: the symbolic residuals did not vanish there")
    label = f"{name}-system"
    if traced is None:
        return _balance_response(system, kept, label, output, notes)
    folds = tuple(
        (float(f), float(b.output_amplitude[int(np.argmin(np.abs(b.Omega - f)))]))
        for b in kept
        for f in b.folds
    )
    return _balance_response(
        system,
        kept,
        label,
        output,
        notes,
        _Traced(traced.model, dict(traced.params), tuple(dict.fromkeys(folds))),
    )


class _Traced:
    """The model, parameters and folds of a traced response (what :func:`_balance_response`
    reads from it)."""

    def __init__(self, model: str, params: dict, folds: tuple) -> None:
        self.model, self.params, self.folds = model, params, folds


def _runs_of(br: Any, good: Any, listed: bool) -> list:
    """The runs of consecutive ``good`` points of a balance branch, each a branch of its own
    (at least two points; one for listed frequencies)."""
    import dataclasses

    import numpy as np

    out = []
    idx = np.flatnonzero(good)
    if idx.size == 0:
        return out
    cuts = np.flatnonzero(np.diff(idx) > 1) + 1
    for run in np.split(idx, cuts):
        if run.size < (1 if listed else 2):
            continue
        sl = slice(int(run[0]), int(run[-1]) + 1)
        lo, hi = float(br.Omega[sl].min()), float(br.Omega[sl].max())
        out.append(
            dataclasses.replace(
                br,
                Omega=br.Omega[sl],
                U=br.U[sl],
                amplitudes={k: v[sl] for k, v in br.amplitudes.items()},
                output_amplitude=br.output_amplitude[sl],
                max_multiplier=None if br.max_multiplier is None else br.max_multiplier[sl],
                stable=None if br.stable is None else br.stable[sl],
                folds=tuple(f for f in br.folds if lo <= f <= hi),
                curve=None,
                output_coefficients=br.output_coefficients[sl],
            )
        )
    return out


def _system_auto(
    system: Any,
    Omega: Sequence[float],
    frequencies: Sequence[float] | None,
    output: str | None,
    options: dict[str, Any],
) -> Any:
    """Method ``"auto"`` for a system: :func:`perturb.auto.auto_system_response` (the ladder
    hb1 -> HB H = 3 ... 63 -> exact with exact spot checks in n dimensions).

    Raises
    ------
    ParameterError
        An option it does not take (listing those it does), a bad ``rtol``.
    """
    unknown = sorted(set(options) - set(SYSTEM_AUTO_OPTIONS))
    if unknown:
        raise ParameterError(
            f"{', '.join(unknown)}: not options of method 'auto' for a system (expected: "
            f"{', '.join(SYSTEM_AUTO_OPTIONS)})"
        )
    rtol = registry.check_rtol(options.pop("rtol", 1e-3))
    system_output(system, output)  # a bad output is refused before any work
    _check_frequency_response(system, frequencies is not None)
    if frequencies is not None:
        frequencies = checks.frequencies(frequencies, MAX_FREQUENCIES)
    # the registry's target (perturb.auto.auto_frequency_response) hands a system to its
    # ladder of system methods; resolved by name: auto imports solve, never the reverse
    resp, _ = registry.spec("auto").resolve()(
        system, Omega, rtol, output=output, frequencies=frequencies, **options
    )
    return resp


class SlowFlowSolver:
    """The fixed points of an internal-resonance slow flow
    (:class:`~perturb.methods.system_averaging.InternalResonanceSlowFlow`) as numbers: the slow
    flow ``F(x, Omega)`` in the Cartesian amplitudes ``x = (p_1, q_1, p_2, q_2)``, its Jacobian,
    ``dF/dOmega``, and the waveforms ``q_i(t)`` they stand for, the parameter values bound.

    Parameters
    ----------
    flow
        The derivation (:func:`derive_system` with ``"ms-ir"``).
    system
        The system it was derived from (state names, output combinations).
    """

    _SAMPLES = 512

    def __init__(self, flow: Any, system: Any) -> None:
        import sympy as sp

        from perturb.numeric.compile import lambdify

        self.flow, self.system = flow, system
        args = tuple(flow.arguments)
        W = args[len(flow.cartesian)]
        self._values = _parameter_values(flow, system.name, "the slow flow")
        self._F = lambdify(args, list(flow.slow_flow))
        self._J = lambdify(args, list(sp.ImmutableMatrix(flow.jacobian)))
        self._dW = lambdify(args, [sp.diff(e, W) for e in flow.slow_flow])
        t = next(
            (s for w in flow.waveforms for s in w.free_symbols if s.name == "t"), sp.Symbol("t")
        )
        self._wave = lambdify((*args, t), list(flow.waveforms))
        self._period = lambdify((W, *flow.parameters), flow.period)
        self.n = len(flow.cartesian)

    def residual(self, x: Any, W: float) -> Any:
        import numpy as np

        return np.array([float(v) for v in self._F(*x, W, *self._values)])

    def jacobians(self, x: Any, W: float) -> tuple[Any, Any]:
        import numpy as np

        J = np.array([float(v) for v in self._J(*x, W, *self._values)]).reshape(self.n, self.n)
        return J, np.array([float(v) for v in self._dW(*x, W, *self._values)])

    def newton(self, x: Any, W: float, iterations: int = 40) -> Any:
        """A fixed point from ``x`` (damped Newton); None without convergence."""
        import numpy as np

        x = np.asarray(x, dtype=float).copy()
        for _ in range(iterations):
            F = self.residual(x, W)
            J, _ = self.jacobians(x, W)
            try:
                dx = np.linalg.solve(J, -F)
            except np.linalg.LinAlgError:
                return None
            step = 1.0
            for _ in range(8):  # halvings: the slow flow is polynomial, steps may overshoot
                if np.linalg.norm(self.residual(x + step * dx, W)) < np.linalg.norm(F) or (
                    np.linalg.norm(F) < 1e-13
                ):
                    break
                step *= 0.5
            x = x + step * dx
            if np.abs(step * dx).max() <= 1e-12 * max(1.0, np.abs(x).max()):
                return x if np.linalg.norm(self.residual(x, W)) <= 1e-9 else None
        return None

    def states(self, x: Any, W: float, samples: int | None = None) -> tuple[Any, Any]:
        """``(t, Y)``: the states ``(q, q')`` of the waveform over one period (velocities by
        FFT differentiation of the periodic samples)."""
        import numpy as np

        n = samples or self._SAMPLES
        T = float(self._period(W, *self._values))
        t = T * np.arange(n) / n
        q = np.array([np.broadcast_to(v, t.shape) for v in self._wave(*x, W, *self._values, t)])
        k = np.fft.rfftfreq(n, d=T / n) * 2 * np.pi
        v = np.fft.irfft(1j * k * np.fft.rfft(q, axis=1), n=n, axis=1)
        return t, np.vstack([q, v])

    def measures(self, x: Any, W: float, c: Any) -> tuple[float, dict[str, float], Any, float]:
        """``max |c . y|``, every coordinate's ``max |.|`` (parabola-refined samples), the
        state at ``t = 0`` and the output's amplitude at the forcing frequency."""
        import numpy as np

        _, Y = self.states(x, W)
        coords = {name: BalanceCycle._peak(Y[j]) for j, name in enumerate(self.system.coordinates)}
        s = c @ Y
        # the period spans m forcing periods (m = 3 when the forcing is near the upper mode
        # of a 1:3 resonance): the forcing frequency is harmonic m of the samples
        m = max(1, round(float(self._period(W, *self._values)) * W / (2 * np.pi)))
        z = np.fft.rfft(s) / s.size
        first = float(2 * abs(z[m])) if m < z.size else 0.0
        return BalanceCycle._peak(s), coords, Y[:, 0].copy(), first

    def stable(self, x: Any, W: float) -> tuple[bool, float]:
        """Stable when every eigenvalue of the slow flow's Jacobian has a negative real part;
        the Floquet multiplier estimate ``max |exp(lambda T)|``."""
        import numpy as np

        J, _ = self.jacobians(x, W)
        lam = np.linalg.eigvals(J)
        T = float(self._period(W, *self._values))
        return bool(np.max(lam.real) < 0), float(np.max(np.abs(np.exp(lam * T))))


def _system_ms_ir(
    system: Any,
    Omega: Sequence[float],
    frequencies: Sequence[float] | None,
    output: str | None,
    options: dict[str, Any],
    seeds: Sequence[tuple[float, Any]] = (),
) -> Any:
    """Method ``"ms-ir"`` for a system of two coordinates with a 1:1 or 1:3 internal
    resonance: the fixed points of the first-order slow flow
    (:func:`perturb.methods.system_averaging.internal_resonance_slow_flow`) traced over the
    window by the continuation core (seeds: Newton from the rest state and from scaled copies of
    the first fixed point at both edges and three interior frequencies, and ``seeds``), or
    solved at listed frequencies; stability from the slow flow's Jacobian. Amplitudes are
    ``max |.|`` of the waveforms ``q = Phi eta`` the fixed points stand for.

    Raises
    ------
    ParameterError
        An option it does not take (listing those it does).
    ModelError
        What the derivation refuses (not two coordinates, no internal resonance within
        ``tolerance``, PWL under 1:3, stops, ...).
    """
    import numpy as np

    from perturb.numeric.continuation import ContinuationError, continue_curve
    from perturb.response import Branch

    unknown = sorted(set(options) - set(SYSTEM_MS_IR_OPTIONS))
    if unknown:
        raise ParameterError(
            f"{', '.join(unknown)}: not options of 'ms-ir' (expected: "
            f"{', '.join(SYSTEM_MS_IR_OPTIONS)})"
        )
    stability = _check_stability_flag(options.pop("stability", True))
    ds_max = options.pop("ds_max", 0.05)
    max_points = options.pop("max_points", 2000)
    c, out_text = system_output(system, output)
    _check_frequency_response(system, frequencies is not None)
    flow = derive_system(system, "ms-ir", **options)
    solver = SlowFlowSolver(flow, system)
    coords = system_coordinates(system)

    def branch_of(xs: Any, ws: Any) -> tuple[Any, dict]:
        rows = [solver.measures(x, float(w), c) for x, w in zip(xs, ws, strict=True)]
        st = [
            solver.stable(x, float(w)) if stability else (False, np.nan)
            for x, w in zip(xs, ws, strict=True)
        ]
        amp = np.array([r[0] for r in rows])
        br = Branch(
            np.asarray(ws, dtype=float),
            amp,
            np.array([r[3] for r in rows]),
            np.zeros(len(rows)),
            np.array([s[0] for s in st]),
            np.array([s[1] for s in st]),
        )
        cols = {f"amplitude_{n}": np.array([r[1].get(n, np.nan) for r in rows]) for n in coords}
        cols.update({f"mean_{n}": np.zeros(len(rows)) for n in coords})
        cols["states"] = np.array([r[2] for r in rows])
        return br, cols

    branches, columns, folds = [], [], []
    if frequencies is not None:
        for w in checks.frequencies(frequencies, MAX_FREQUENCIES):
            found = _slow_flow_solutions(solver, w, [x for ws, x in seeds if ws == w])
            for x in found:
                br, cols = branch_of([x], [w])
                branches.append(br)
                columns.append(cols)
    else:
        lo, hi = checks.window(Omega)
        traced: list[tuple[Any, Any]] = []

        def on_traced(x: Any, w: float) -> bool:
            for U, L in traced:
                j = int(np.argmin(np.abs(L - w)))
                if abs(L[j] - w) <= 0.02 * (hi - lo) and np.abs(U[j] - x).max() <= 0.02 * max(
                    1e-9, np.abs(x).max()
                ):
                    return True
            return False

        starts = [(w, x) for w, x in seeds]
        for w in [hi, lo, *np.linspace(lo, hi, 5)[1:-1]]:
            starts += [(float(w), x) for x in _slow_flow_solutions(solver, float(w), [])]
        for w, x in starts[:24]:
            if on_traced(x, w):
                continue
            parts = []
            for direction in (-1, 1):
                try:
                    curve = continue_curve(
                        solver.residual,
                        solver.jacobians,
                        x,
                        w,
                        (lo, hi),
                        direction=direction,
                        ds_max=ds_max,
                        max_points=max_points,
                        u_scale=max(1e-6, float(np.abs(x).max())),
                        lam_scale=hi - lo,
                    )
                except (ContinuationError, PerturbError):
                    continue
                parts.append((np.asarray(curve.u), np.asarray(curve.lam, dtype=float), curve))
            if not parts:
                continue
            if len(parts) == 2:
                U = np.concatenate([parts[0][0][::-1], parts[1][0][1:]])
                L = np.concatenate([parts[0][1][::-1], parts[1][1][1:]])
            else:
                U, L = parts[0][0], parts[0][1]
            traced.append((U, L))
            br, cols = branch_of(U, L)
            branches.append(br)
            columns.append(cols)
            for _, _, curve in parts:
                for f in curve.folds:
                    j = int(np.argmin(np.abs(L - f.lam)))
                    folds.append((float(f.lam), float(br.amplitude[j])))
    notes = (
        f"{flow.method}: fixed points of the slow flow in "
        f"{', '.join(map(str, flow.cartesian))} ({len(branches)} branches); amplitudes max |.| "
        "of the waveforms q = Phi eta, stability from the slow flow's Jacobian",
        *flow.notes,
    )
    cls = _response_class()
    return cls(
        tuple(branches),
        "ms-ir-system",
        system.name,
        {k: v for k, v in system.params.items() if k != "Omega" and v is not None},
        tuple(dict.fromkeys(folds)),
        tuple(notes),
        output=out_text,
        coordinates=coords,
        columns=tuple(columns),
    )


def _slow_flow_solutions(solver: SlowFlowSolver, W: float, guesses: Sequence[Any]) -> list:
    """Distinct fixed points of the slow flow at ``W``: Newton from ``guesses``, the rest
    state and scaled copies of the first fixed point found (at most 12 runs)."""
    import numpy as np

    out: list = []
    starts = [np.asarray(g, dtype=float) for g in guesses] + [np.zeros(solver.n)]
    rng = np.random.default_rng(0)
    tried = 0
    while starts and tried < 12:
        g = starts.pop(0)
        tried += 1
        x = solver.newton(g, W)
        if x is None:
            continue
        if any(np.abs(x - y).max() <= 1e-7 * max(1.0, np.abs(y).max()) for y in out):
            continue
        out.append(x)
        if len(out) == 1:
            size = max(1e-3, float(np.abs(x).max()))
            starts += [size * f * rng.standard_normal(solver.n) for f in (0.5, 2.0, 4.0, 8.0)]
    return out


#: The symbolic derivations of a system (:func:`derive_system`): name -> (target, what,
#: options).
SYSTEM_DERIVATIONS: dict[str, tuple[str, str, tuple[str, ...]]] = {
    "hb1": (
        "perturb.methods.system_harmonic_balance:system_single_harmonic_balance",
        "single-harmonic balance / describing functions of n coordinates",
        ("bias",),
    ),
    "ms-ir": (
        "perturb.methods.system_averaging:internal_resonance_slow_flow",
        "first-order multiple scales / averaging of two coordinates with a 1:1 or 1:3 "
        "internal resonance (slow flow)",
        ("resonance", "near", "tolerance"),
    ),
    "nnm": (
        "perturb.methods.system_lindstedt:nnm_backbone",
        "Lindstedt-Poincare / modified L-P backbone of a nonlinear normal mode of a "
        "conservative two-coordinate system",
        ("mode", "order", "method", "harmonics"),
    ),
}
#: Other names of :data:`SYSTEM_DERIVATIONS` entries.
SYSTEM_DERIVATION_ALIASES = {
    "shb": "hb1",
    "internal-resonance": "ms-ir",
    "nnm-lp": "nnm",
    "nnm-mlp": "nnm",
}
#: Options an alias sets (``nnm-mlp`` is the modified L-P backbone).
SYSTEM_DERIVATION_PRESETS: dict[str, dict[str, Any]] = {
    "nnm-lp": {"method": "lp"},
    "nnm-mlp": {"method": "mlp"},
}


def derive_system(system: Any, method: str, /, **options: Any) -> Any:
    """The symbolic derivation ``method`` of a system of several coordinates.

    Parameters
    ----------
    system
        A :class:`~perturb.model.system.System`.
    method
        ``"hb1"`` (alias ``"shb"``): :func:`perturb.methods.system_harmonic_balance.
        system_single_harmonic_balance` (option ``bias``); ``"ms-ir"`` (alias
        ``"internal-resonance"``): :func:`perturb.methods.system_averaging.
        internal_resonance_slow_flow` (``resonance`` ``"1:1"``/``"1:3"``, ``near``,
        ``tolerance``); ``"nnm"``: :func:`perturb.methods.system_lindstedt.nnm_backbone`
        (``mode``, ``order``, ``method`` ``"lp"``/``"mlp"``, ``harmonics``; the aliases
        ``"nnm-lp"`` and ``"nnm-mlp"`` set ``method``). ``method`` is positional only, so
        ``derive_system(system, "nnm", method="mlp")`` passes the backbone's own ``method``.

    Returns
    -------
    The method's result (``SystemHarmonicBalance``, ``InternalResonanceSlowFlow`` or
    ``NNMBackbone``): printable, with ``steps`` (``perturb.report.latex.derivation_body``).

    Raises
    ------
    ParameterError
        An unknown method (listing those there are) or an option it does not take.
    ModelError
        What the method refuses (its message names the reason).
    """
    import importlib

    if not is_system(system):
        raise ParameterError(
            f"system = {system!r:.80}: expected a perturb System (an oscillator takes "
            "perturb.solve.derive)"
        )
    name = SYSTEM_DERIVATION_ALIASES.get(method, method) if isinstance(method, str) else method
    if name not in SYSTEM_DERIVATIONS:
        aliases = ", ".join(f"{a} = {n}" for a, n in SYSTEM_DERIVATION_ALIASES.items())
        raise ParameterError(
            f"method {method!r}: the derivations of a system are "
            f"{', '.join(SYSTEM_DERIVATIONS)} (aliases {aliases})"
        )
    target, _, takes = SYSTEM_DERIVATIONS[name]
    for key, value in SYSTEM_DERIVATION_PRESETS.get(method, {}).items():
        if options.get(key) not in (None, value):
            raise ParameterError(
                f"{key} = {options[key]!r}: {method!r} is the derivation with {key} = {value!r}"
            )
        options[key] = value
    unknown = sorted(k for k, v in options.items() if k not in takes and v is not None)
    if unknown:
        raise ParameterError(
            f"{', '.join(unknown)}: not options of {name!r} (it takes: {', '.join(takes)})"
        )
    module, _, attr = target.partition(":")
    fn = getattr(importlib.import_module(module), attr)
    return fn(system, **{k: v for k, v in options.items() if v is not None})


#: At most this many HB points of a response are checked against exact orbits
#: (:func:`system_errors`; evenly spread, the others NaN).
MAX_ERROR_POINTS = 200


def system_errors(
    system: Any, response: Any, output: str | None = None, *, max_points: int = MAX_ERROR_POINTS
) -> tuple[dict[str, Any], str]:
    """Errors of a system's HB response (``method="hb"``) against the exact orbits at its
    points' frequencies.

    At each point (at most ``max_points``, evenly spread; the others NaN) the exact periodic
    orbit is shot (:func:`perturb.simulate.orbits.shooting.periodic_orbit` on the system's
    exact piecewise-affine flow, or DOP853 for a smooth system) from the HB orbit's state at
    ``t = 0``, and ``max |.|`` of the output and of every coordinate compared:
    ``|A_hb - A_exact| / A_exact``. A point whose shooting fails (or lands on an orbit of a
    different amplitude by more than half: another branch) is NaN.

    Returns
    -------
    (dict, str)
        The CSV columns ``rel_error`` (output) and ``rel_error_<name>`` per coordinate, one
        value per row, and a one-line summary of the largest errors per coordinate.

    Raises
    ------
    ParameterError
        A response without the HB orbits' states (not from ``method="hb"``).
    """
    import numpy as np

    from perturb.errors import ModelError
    from perturb.simulate.orbits.shooting import periodic_orbit

    cols = getattr(response, "columns", ())
    if not cols or any("states" not in c for c in cols):
        raise ParameterError(
            "the errors against exact orbits need a system's HB response "
            "(frequency_response(system, method='hb')), whose points carry their orbits"
        )
    c, _ = system_output(system, output)
    names = system.state_names
    coords = system_coordinates(system)
    eye = np.eye(len(names))
    rows = [(b, j) for b, br in enumerate(response.branches) for j in range(len(br))]
    pick = set(np.unique(np.linspace(0, len(rows) - 1, min(len(rows), max_points)).round()))
    keys = ["rel_error", *(f"rel_error_{n}" for n in coords)]
    out = {k: np.full(len(rows), np.nan) for k in keys}
    for r, (b, j) in enumerate(rows):
        if r not in pick:
            continue
        W = float(response.branches[b].omega[j])
        try:
            flow = _system_flow(_system_at(system, W))
            orbit = periodic_orbit(flow, cols[b]["states"][j])
        except (PerturbError, ModelError, np.linalg.LinAlgError):
            continue
        hb = [float(response.branches[b].amplitude[j])]
        hb += [float(cols[b][f"amplitude_{n}"][j]) for n in coords]
        ex = [float(orbit.max_abs(c))]
        ex += [float(orbit.max_abs(eye[names.index(n)])) for n in coords]
        if abs(hb[0] - ex[0]) > 0.5 * max(abs(ex[0]), 1e-300):
            continue  # shooting fell onto another orbit
        for k, a, e in zip(keys, hb, ex, strict=True):
            # a coordinate at rest in both (not excited): no error
            out[k][r] = abs(a - e) / e if e != 0 else (0.0 if a == 0 else np.inf)
    done = int(np.sum(np.isfinite(out["rel_error"])))
    parts = [
        f"{k.removeprefix('rel_error_') if k != 'rel_error' else 'output'} {np.nanmax(out[k]):.3g}"
        if np.any(np.isfinite(out[k]))
        else f"{k} -"
        for k in keys
    ]
    summary = ", ".join(parts) + f" ({done} of {len(rows)} points checked)"
    return out, summary


def _check_frequency_response(system: Any, listed: bool) -> None:
    """Refuse what has no frequency response, or would return a family of orbits.

    Raises
    ------
    ModelError
        An autonomous system (no forcing frequency to vary); a system with conserved
        combinations (:meth:`System.invariants <perturb.model.system.System.invariants>`) over
        a traced window: the continuation (:mod:`perturb.simulate.exact_response`) does not pin
        them, so it would follow a family of orbits. At listed frequencies the pinned orbits of
        :func:`periodic_orbits` answer instead.
    """
    from perturb.errors import ModelError

    if not is_forced(system):
        from perturb.model.system_builtins import BUILTIN_SYSTEMS

        model = system.name if system.name in BUILTIN_SYSTEMS else "MODEL"
        raise ModelError(
            f"system {system.name!r} is autonomous (no harmonic forcing): there is no forcing "
            "frequency to vary, so no frequency response; its periodic orbits are limit cycles "
            f"of their own period: perturb periodic {model} (without --omega), or "
            "perturb.solve.periodic_orbits(system) / limit_cycles(system)"
        )
    C = system.invariants()
    if C.shape[0] and not listed:
        labels = "; ".join(combination_text(c, system.state_names) for c in C)
        raise ModelError(
            f"system {system.name!r} conserves {labels} (its rate depends on the time only), so "
            "its periodic orbits form a family along it; the traced exact response does not "
            "pin it yet. Listed frequencies work (frc --omega w1,w2 / frequencies=[...]: one "
            f"orbit each, the mean of {labels} pinned at 0), as does perturb periodic "
            f"{system.name} --omega W / periodic_orbits(system, W, invariants=...)"
        )


def _traced_crossings(
    system: Any,
    targets: list[float],
    window: tuple,
    found_at: dict,
    output: str | None,
    options: dict[str, Any],
    notes: list[str],
) -> Any:
    """The exact branches traced over ``window`` from the orbits ``found_at`` each target
    frequency (and ``options["seeds"]``), each crossing of a target polished by shooting and
    added to ``found_at`` when new; the traced result (None when the continuation failed)."""
    import numpy as np

    from perturb.simulate.exact_response import exact_branches
    from perturb.simulate.exact_response.results import polish_at

    seeds = list(options.pop("seeds", ())) + [
        (w, o.y0) for w, orbits in found_at.items() for o in orbits
    ]
    if "options" not in options:
        options.setdefault("max_seconds", 120.0)  # a bounded tracing, as for one oscillator
    try:
        traced = exact_branches(system, window, seeds=seeds, output=output, **options)
    except PerturbError as exc:
        traced = None
        notes.append(f"continuation over [{window[0]:.6g}, {window[1]:.6g}] failed: {exc}")
    if traced is not None:
        for bi, br in enumerate(traced.branches):
            p = br.parameters
            for j in range(len(p) - 1):
                lo, hi = sorted((p[j], p[j + 1]))
                for w in targets:
                    if not lo <= w <= hi or (w == p[j + 1] and j + 1 < len(p) - 1):
                        continue
                    orbit = polish_at(br, j, w)
                    if orbit is None:
                        notes.append(f"branch {bi}: shooting at Omega = {w!r} failed")
                        continue
                    scale = max(1.0, float(np.abs(orbit.y0).max()))
                    if not any(
                        o.m == orbit.m and float(np.abs(o.y0 - orbit.y0).max()) <= 1e-6 * scale
                        for o in found_at[w]
                    ):
                        found_at[w].append(orbit)
    return traced


def _system_solutions_at(
    system: Any, frequencies: list[float], output: str | None, options: dict[str, Any]
) -> Any:
    """Every orbit of a system found at exactly ``frequencies`` (see :func:`_system_response`)."""
    import numpy as np

    from perturb.response import Branch
    from perturb.simulate.exact_response.api import ONE_FREQUENCY_WINDOW

    targets = sorted(set(frequencies))
    if len(targets) == 1:
        window = (targets[0] / ONE_FREQUENCY_WINDOW, targets[0] * ONE_FREQUENCY_WINDOW)
    else:
        window = (targets[0], targets[-1])
    notes: list[str] = []
    found_at = {
        w: list(_system_periodic_orbits(system, w, 1, (), 3, 100, None, output)) for w in targets
    }
    pinned = invariant_note(system)
    if pinned is not None:
        # the continuation does not pin the invariants (it would trace a family): the pinned
        # orbits of periodic_orbits at each frequency are the answer
        notes.append(pinned)
        traced = None
    else:
        traced = _traced_crossings(system, targets, window, found_at, output, options, notes)
    branches, columns = [], []
    coords = system_coordinates(system)
    for w in targets:
        at_w = system.with_params(Omega=w) if "Omega" in system.params else system
        rows = [(orbit_columns(at_w, o, output), o) for o in found_at[w]]
        rows.sort(key=lambda r: (r[0]["amplitude"], r[0]["mean"]))
        for num, o in rows:
            branches.append(
                Branch(
                    omega=[w],
                    amplitude=[num["amplitude"]],
                    first_harmonic_amplitude=[num["first_harmonic_amplitude"]],
                    mean=[num["mean"]],
                    stable=[o.max_multiplier < 1.0],
                    max_multiplier=[o.max_multiplier],
                )
            )
            columns.append(
                {k: np.array([num[k]]) for k in num if k.startswith(("amplitude_", "mean_"))}
            )
        notes.append(f"{len(rows)} orbits at Omega = {w!r} (one per branch)")
    method = traced.method if traced is not None else "exact"
    params = {k: v for k, v in system.params.items() if k != "Omega"}
    cls = _response_class()
    return cls(
        tuple(branches),
        "exact" if method is None else str(method),
        system.name,
        params,
        notes=tuple(notes),
        output=system_output(system, output)[1],
        coordinates=coords,
        columns=tuple(columns),
    )
