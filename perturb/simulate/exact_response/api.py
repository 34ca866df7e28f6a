"""Public front functions of the exact frequency response: ``continue_orbits`` (one
branch from a seed), ``exact_frequency_response`` (a :class:`~perturb.response.Response`)
and ``exact_solutions_at`` (every traced orbit at given frequencies).

Part of :mod:`perturb.simulate.exact_response` (the method is described there).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike

from perturb import checks
from perturb.errors import ParameterError, PerturbError
from perturb.model.oscillator import Oscillator
from perturb.model.system import System
from perturb.response import Branch, Response
from perturb.simulate.exact_response.base import STAT_SAMPLES
from perturb.simulate.exact_response.branches import exact_branches, output_of, undamped_note
from perturb.simulate.exact_response.march import Tracer
from perturb.simulate.exact_response.options import (
    ORBIT_FIELDS,
    ExactResponseOptions,
    exact_options,
    flow_family,
    parameter_window,
    settings,
)
from perturb.simulate.exact_response.results import ContinuationBranch, polish_at
from perturb.simulate.flows.factory import FlowFamily
from perturb.simulate.orbits.shooting import (
    PeriodicOrbit,
)


def continue_orbits(
    oscillator: Oscillator | System | FlowFamily,
    start: float,
    y_guess: ArrayLike,
    window: Sequence[float],
    *,
    parameter: str | None = None,
    m: int = 1,
    t0: float = 0.0,
    directions: Literal["both", "forward"] = "both",
    output: str | ArrayLike | None = None,
    options: ExactResponseOptions | None = None,
    **knobs: Any,
) -> ContinuationBranch:
    r"""Trace the branch of period-``m`` orbits through ``(start, y_guess)``.

    Parameters
    ----------
    oscillator
        The oscillator or :class:`~perturb.model.system.System`, or a
        :class:`~perturb.simulate.flows.factory.FlowFamily` built from it (exact flow for PWL
        models, ``solve_ivp`` otherwise).
    start
        Parameter value of the seed (inside ``window``).
    y_guess
        ``(x, v)`` at ``t0`` near an orbit (a system's ``n`` states); polished by Newton at
        ``start`` first.
    window
        ``(low, high)``: the branch stops at the edges, with a point exactly on them.
    parameter
        Name of the continuation parameter (default: the forcing frequency).
    m
        Forcing periods per orbit period.
    t0
        Phase of the section.
    directions
        ``'both'`` (default) or ``'forward'`` (increasing parameter at the seed).
    output
        Systems: what the amplitude measures (see :func:`exact_branches`).
    options : ExactResponseOptions, optional
        The tuning knobs: ``ds_max`` (output spacing, default 0.005), ``ds_min``, ``tol``,
        ``max_points`` and ``max_periods`` (budgets per direction; default 20000 points and
        1e6 forcing periods), ``closed_form``; see :class:`ExactResponseOptions`.
    **knobs
        Those fields as keywords, replacing those of ``options``.

    Returns
    -------
    ContinuationBranch

    Raises
    ------
    ParameterError
        Bad arguments (also a keyword that is not one of the fields above).
    ShootingError
        The seed does not converge to an orbit.

    Examples
    --------
    >>> from perturb.model.builtins import builtin_model
    >>> br = continue_orbits(builtin_model("nsd", k=-2, mu=0.05, F=2), 1.6, [5.0, 0.0],
    ...                      (1.5, 2.0))
    >>> br.closed, br.points[0].parameter, br.points[-1].parameter
    (False, 1.5, 2.0)
    """
    o = exact_options(options, knobs, ORBIT_FIELDS, "continue_orbits")
    max_periods = 1e6 if o.max_periods is None else o.max_periods
    family = flow_family(oscillator, parameter)
    lo, hi = parameter_window(window)
    start = checks.finite(start, "start")
    if not lo <= start <= hi:
        raise ParameterError(f"start = {start} is outside the window ({lo}, {hi})")
    if isinstance(m, bool) or not isinstance(m, int) or m < 1:
        raise ParameterError(f"m = {m!r}: expected a positive integer")
    if directions not in ("both", "forward"):
        raise ParameterError(f"directions = {directions!r}: expected 'both' or 'forward'")
    st = settings(o.ds_max, o.ds_min, o.tol, o.max_points, max_periods)
    system = getattr(family, "system", None)
    out_vec, out_label = None, ""
    if system is not None:
        out_vec, out_label = output_of(system, output)
    elif output is not None:
        raise ParameterError(
            f"output = {output!r}: an oscillator's amplitude is max |x|; output is for systems"
        )
    names = system.state_names if system is not None else ("x", "v")
    try:
        guess = np.asarray(y_guess, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        guess = np.array([])
    if guess.size != len(names) or not np.all(np.isfinite(guess)):
        raise ParameterError(
            f"y_guess = {y_guess!r}: expected {len(names)} finite numbers ({', '.join(names)})"
        )
    t0 = checks.finite(t0, "t0")
    tracer = Tracer(family, m, t0, (lo, hi), st, closed_form=o.closed_form, output=out_vec)
    tracer.output_label = out_label
    pt = tracer.start_point(start, guess)
    return tracer.trace(pt, directions)[0]


def exact_frequency_response(
    oscillator: Oscillator | System,
    window: Sequence[float] = (0.2, 2.0),
    **options: Any,
) -> Response:
    """Every branch found by :func:`exact_branches` as a :class:`~perturb.response.Response`
    (method ``'exact'`` for PWL models, ``'shooting'`` for the ODE flow of smooth ones); the
    options are those of :func:`exact_branches` (``output=`` for a
    :class:`~perturb.model.system.System`: what the ``amplitude`` column measures; the
    per-coordinate columns are in :meth:`ExactBranches.columns` of :func:`exact_branches`).
    ``notes`` say which branches are closed loops and which are mirror images."""
    return exact_branches(oscillator, window, **options).to_response()


#: the window traced around a single requested frequency: [w / f, w * f]
ONE_FREQUENCY_WINDOW = 1.25


#: wall-clock budget of that tracing (seconds) unless the caller gives max_seconds
_ONE_SECONDS = 120.0


def _same_orbit(a: PeriodicOrbit, b: PeriodicOrbit) -> bool:
    if a.m != b.m:
        return False
    scale = max(1.0, float(np.max(np.abs(a.y0))), float(np.max(np.abs(b.y0))))
    return float(np.max(np.abs(np.asarray(a.y0) - np.asarray(b.y0)))) <= 1e-6 * scale


def _output_row(o: PeriodicOrbit, c: np.ndarray | None) -> tuple[float, float, float]:
    """(amplitude, first harmonic, mean) of an orbit: of ``x`` (``c`` None), else of the
    output ``c . y`` of a system (max by :meth:`PeriodicOrbit.max_abs`, the rest from
    ``STAT_SAMPLES`` samples per forcing period)."""
    if c is None:
        return o.amplitude, o.first_harmonic_amplitude, o.mean
    ns = STAT_SAMPLES * o.m
    _, Y = o.sample_states(ns)
    g = np.fft.rfft(c @ Y) / ns
    first = float(2.0 * abs(g[o.m])) if o.m < g.size else 0.0
    return float(o.max_abs(c)), first, float(g[0].real)


def _search(model: Oscillator | System, w: float, nodes: Any) -> list[PeriodicOrbit]:
    """The brute-force orbit search at ``w`` (oscillators; a system has none yet: its
    tracing is seeded by its region steady states and sweeps)."""
    if isinstance(model, System):
        return []
    from perturb.simulate.orbits.search import periodic_orbits

    return list(periodic_orbits(model, w, node_guesses=nodes))


def _solutions_at_one(
    oscillator: Oscillator | System,
    w: float,
    options: dict[str, Any],
    orbit_guesses: Callable[[float], Sequence[np.ndarray]] | None = None,
) -> Response:
    """Every orbit at the single frequency ``w``: the brute-force search of
    :func:`~perturb.simulate.orbits.search.periodic_orbits` (started also from
    ``orbit_guesses(w)``), and every crossing of ``w`` by the branches that
    :func:`exact_branches` traces over ``[w / 1.25, w * 1.25]`` (seeded with the orbits
    found), polished by shooting at exactly ``w``; duplicates removed."""
    family = FlowFamily(oscillator)
    notes: list[str] = []
    nodes = orbit_guesses(w) if orbit_guesses is not None else ()
    orbits: list[PeriodicOrbit] = _search(oscillator, w, nodes)
    c = _output_vector(oscillator, options)
    n_search = len(orbits)
    undamped = undamped_note(family, (w, w))
    if undamped is not None:
        notes.append(undamped.replace("no branches traced", "no continuation"))
    else:
        opts = dict(options)
        seeds = list(opts.pop("seeds", ()))
        seeds += [(w, o.y0) for o in orbits if o.m == 1]
        if opts.get("options") is None:  # else the options object's max_seconds holds
            opts.setdefault("max_seconds", _ONE_SECONDS)
        lo, hi = w / ONE_FREQUENCY_WINDOW, w * ONE_FREQUENCY_WINDOW
        try:
            found = exact_branches(oscillator, (lo, hi), seeds=seeds, **opts)
        except PerturbError as exc:
            found = None
            notes.append(f"continuation over [{lo:.6g}, {hi:.6g}] failed: {exc}")
        added = 0
        if found is not None:
            notes += [n for n in found.notes if not n.startswith("traced with")]
            for bi, br in enumerate(found.branches):
                p = br.parameters
                for j in range(len(p) - 1):
                    a, b = sorted((p[j], p[j + 1]))
                    if not a <= w <= b or (w == p[j + 1] and j + 1 < len(p) - 1):
                        continue
                    orbit = polish_at(br, j, w)
                    if orbit is None:
                        notes.append(f"branch {bi}: shooting at Omega = {w!r} failed")
                        continue
                    if not any(_same_orbit(orbit, o) for o in orbits):
                        orbits.append(orbit)
                        added += 1
        notes.append(
            f"{n_search} orbits from periodic_orbits, {added} more where the branches traced "
            f"over [{lo:.6g}, {hi:.6g}] cross Omega = {w!r}"
        )
    stats = [_output_row(o, c) for o in orbits]
    order = sorted(range(len(orbits)), key=lambda i: (stats[i][0], stats[i][2]))
    params = {k: v for k, v in oscillator.params.items() if k != family.parameter}
    branches = tuple(
        Branch(
            omega=[w],
            amplitude=[stats[i][0]],
            first_harmonic_amplitude=[stats[i][1]],
            mean=[stats[i][2]],
            # max |mu| < 1, as on traced branches: is_stable is False within unit_tol of
            # the unit circle, which every lightly damped orbit is (mu -> 0)
            stable=[orbits[i].max_multiplier < 1.0],
            max_multiplier=[orbits[i].max_multiplier],
        )
        for i in order
    )
    method = "exact" if family.exact else "shooting"
    notes.insert(0, f"{len(orbits)} orbits at Omega = {w!r} (one per branch)")
    return Response(branches, method, oscillator.name, params, notes=tuple(notes))


def _output_vector(model: Oscillator | System, options: dict[str, Any]) -> np.ndarray | None:
    """The output combination of a system (``options['output']``, default its first
    coordinate); None for an oscillator."""
    if not isinstance(model, System):
        return None
    return output_of(model, options.get("output"))[0]


def exact_solutions_at(
    oscillator: Oscillator | System,
    frequencies: Sequence[float],
    *,
    orbit_guesses: Callable[[float], Sequence[np.ndarray]] | None = None,
    **options: Any,
) -> Response:
    """Every exact periodic orbit at exactly the forcing frequencies ``frequencies``.

    With two or more distinct frequencies the branches are traced by :func:`exact_branches`
    over ``[min, max]`` (``options`` are its options) and every crossing of a branch with a
    requested frequency is polished by shooting at that frequency, so the output holds the
    requested values exactly and keeps the branch structure (a branch that folds back meets a
    frequency more than once).  A single frequency is answered by
    :func:`~perturb.simulate.orbits.search.periodic_orbits` together with the crossings of the
    branches traced over ``[w / 1.25, w * 1.25]`` (each orbit its own branch; the tracing
    has a wall-clock budget of 120 s unless ``max_seconds`` is given, as a keyword or by an
    ``options=`` :class:`ExactResponseOptions`).

    ``orbit_guesses(Omega)``, when given, returns node guesses (arrays of states over one
    forcing period) that :func:`~perturb.simulate.orbits.search.periodic_orbits` also shoots
    from (``node_guesses``); the front door :func:`perturb.solve.frequency_response` passes
    :func:`perturb.seeds.periodic_orbit_guesses` (approximations' solutions).  They only start
    shooting on the exact flow.

    Raises
    ------
    ParameterError
        Empty, non-finite or non-positive frequencies.
    """
    try:
        w_all = np.asarray(frequencies, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ParameterError(
            f"frequencies = {frequencies!r}: expected a sequence of positive numbers"
        ) from None
    if w_all.size == 0 or not np.all(np.isfinite(w_all)) or np.any(w_all <= 0.0):
        raise ParameterError(
            f"frequencies = {w_all.tolist()!r}: expected positive finite forcing frequencies"
        )
    targets = np.unique(w_all)
    if targets.size == 1:
        return _solutions_at_one(oscillator, float(targets[0]), options, orbit_guesses)

    # a short window gives the sweeps and closed-form seeds few chances to meet every branch,
    # so the orbits found at the middle frequency (brute force over initial conditions plus
    # the caller's orbit guesses) seed the tracing as well
    w_mid = float(targets[targets.size // 2])
    seeds = list(options.pop("seeds", ()))
    nodes = orbit_guesses(w_mid) if orbit_guesses is not None else ()
    seeds += [(w_mid, o.y0) for o in _search(oscillator, w_mid, nodes) if o.m == 1]
    c = _output_vector(oscillator, options)
    found = exact_branches(
        oscillator, (float(targets[0]), float(targets[-1])), seeds=seeds, **options
    )
    branches = []
    notes = list(found.to_response().notes)
    for bi, br in enumerate(found.branches):
        p = br.parameters
        rows: list[tuple[float, PeriodicOrbit]] = []
        for j in range(len(p) - 1):
            lo, hi = sorted((p[j], p[j + 1]))
            # half-open on the far end so a frequency hit exactly by a point is polished once
            inside = targets[(targets >= lo) & (targets <= hi)]
            for w in inside:
                if w == p[j + 1] and j + 1 < len(p) - 1:
                    continue
                orbit = polish_at(br, j, float(w))
                if orbit is None:
                    notes.append(f"branch {bi}: shooting at Omega = {w!r} failed; row left out")
                    continue
                rows.append((float(w), orbit))
        if rows:
            st = [_output_row(o, c) for _, o in rows]
            branches.append(
                Branch(
                    omega=[w for w, _ in rows],
                    amplitude=[a for a, _, _ in st],
                    first_harmonic_amplitude=[f for _, f, _ in st],
                    mean=[m for _, _, m in st],
                    stable=[o.max_multiplier < 1.0 for _, o in rows],
                    max_multiplier=[o.max_multiplier for _, o in rows],
                )
            )
    return Response(
        tuple(branches),
        found.method,
        found.model,
        dict(found.params),
        notes=tuple(notes),
    )
