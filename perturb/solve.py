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
:class:`~perturb.model.system.System` (method ``"exact"`` only for now: the approximations
take one coordinate and refuse a system by name). ``output=`` (a coordinate or a linear
combination such as ``"x1 - x2"``, default the first coordinate) is what the ``amplitude``,
``first_harmonic_amplitude`` and ``mean`` columns measure; every coordinate's ``max |.|`` and
mean come as ``amplitude_<name>`` / ``mean_<name>`` (:class:`SystemResponse`,
:func:`orbit_columns`). :func:`system_time_history` integrates a system (exact piecewise-affine
flow, DOP853, or event-driven with stops and friction contacts).

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
    "SystemResponse",  # noqa: F822 - built on first access (module __getattr__)
    "SYSTEM_INTEGRATORS",
    "orbit_columns",
    "system_time_history",
    "SystemHistory",
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
        :class:`~perturb.model.system.System` of several coordinates (method ``"exact"``
        only, for now: the answer is a :class:`SystemResponse`, see :func:`_system_response`).
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
            oscillator, Omega, m, guesses, grid, transient_periods, extent, output
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

#: Methods a :class:`~perturb.model.system.System` takes (the approximations of several
#: coordinates are the next issue's).
SYSTEM_METHODS = ("exact",)
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
) -> tuple:
    """:func:`periodic_orbits` for a :class:`~perturb.model.system.System`."""
    import numpy as np

    m = checks.whole(m, "m", 1, 64, "forcing periods per orbit")
    grid = checks.whole(grid, "grid", 0, 100, "random starting states")
    transient_periods = checks.whole(transient_periods, "transient_periods", 0, 100_000)
    factor = 3.0 if extent is None else checks.finite(extent, "extent")
    if not factor > 0:
        raise ParameterError(f"extent = {extent!r}: expected a positive number")
    system = _system_at(system, Omega)
    c, _ = system_output(system, output)
    flow = _system_flow(system)
    T = _forcing_period(flow, system)
    n = system.n
    given = []
    for g in guesses:
        try:
            y = np.array(g, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            y = np.array([])
        if y.size != n or not np.all(np.isfinite(y)):
            raise ParameterError(
                f"guess {g!r}: expected {n} finite numbers ({', '.join(system.state_names)})"
            )
        given.append(y)
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
        orbit = _shoot(flow, y, m, T)
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
    spec = registry.spec("exact" if method is None else method)
    if spec.name not in SYSTEM_METHODS:
        raise ParameterError(
            f"method {spec.name!r} ({spec.title}) is for one coordinate (an Oscillator); a "
            f"system of several coordinates ({system.name!r}) takes method 'exact' for now"
        )
    options = spec.validate(dict(options))
    for key in ("approximation", "approximation_seeds"):
        if key in options:
            raise ParameterError(
                f"{key}: approximations start the exact solver of one coordinate; a system "
                "takes seeds=[(Omega, y0), ...] with its n states"
            )
    system_output(system, output)  # a bad output is refused before any work
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


def _system_solutions_at(
    system: Any, frequencies: list[float], output: str | None, options: dict[str, Any]
) -> Any:
    """Every orbit of a system found at exactly ``frequencies`` (see :func:`_system_response`)."""
    import numpy as np

    from perturb.response import Branch
    from perturb.simulate.exact_response import exact_branches
    from perturb.simulate.exact_response.api import ONE_FREQUENCY_WINDOW
    from perturb.simulate.exact_response.results import polish_at

    targets = sorted(set(frequencies))
    if len(targets) == 1:
        window = (targets[0] / ONE_FREQUENCY_WINDOW, targets[0] * ONE_FREQUENCY_WINDOW)
    else:
        window = (targets[0], targets[-1])
    notes: list[str] = []
    found_at = {
        w: list(_system_periodic_orbits(system, w, 1, (), 3, 100, None, output)) for w in targets
    }
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
