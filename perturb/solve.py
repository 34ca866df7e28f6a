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

Importing this module loads neither SymPy nor SciPy: each route imports its solver when
it runs.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from perturb import checks
from perturb.errors import ParameterError
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
    "derive",
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
    method: str = "hb1",
    Omega: Sequence[float] = (0.2, 2.0),
    *,
    frequencies: Sequence[float] | None = None,
    **options: Any,
) -> Response:
    """The frequency response of ``oscillator`` by ``method``.

    Parameters
    ----------
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
    spec = registry.spec(method)
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
) -> tuple:
    """Every period-``m`` orbit found at forcing frequency ``Omega`` (the front door).

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
