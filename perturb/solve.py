"""The front doors of the pipeline for an :class:`~perturb.model.oscillator.Oscillator`.

``frequency_response(osc, method=..., Omega=...)`` answers with any approximation method
(``"hb1"``, ...) or with ``"exact"`` (shooting + continuation on the exact flow); the other
functions are re-exported from the layers that own them.

Limits
------
Requests whose cost grows without bound are refused before any work starts, with a message
that names the value and the limit. The limits live here, in one place, for the Python API,
the command line and the scenes:

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
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Sequence
from typing import Any

from perturb.errors import ParameterError
from perturb.methods import METHODS
from perturb.methods.applicability import ORDER_LIMITS
from perturb.model.oscillator import Oscillator
from perturb.response import Branch, Response

__all__ = [
    "frequency_response",
    "periodic_orbits",
    "ALIASES",
    "MAX_HARMONICS",
    "MAX_ORDER",
    "MAX_POINTS",
    "MAX_FREQUENCIES",
    "check_harmonics",
    "check_order",
    "check_points",
]


#: Names the command line also accepts (issue 5 spells them this way).
ALIASES = {"mms": "ms", "avg": "kb"}

#: Largest number of harmonics of numeric harmonic balance (see the module docstring).
MAX_HARMONICS = 255
#: Largest expansion order of any symbolic method; each method's own limit is
#: :data:`perturb.methods.applicability.ORDER_LIMITS` (the one table of measured limits).
_EXPANSION_METHODS = ("lp", "mlp", "ms")  # ORDER_LIMITS["hb"] counts harmonics, not an order
MAX_ORDER = max(ORDER_LIMITS[m] for m in _EXPANSION_METHODS)
#: Largest number of points of a traced curve.
MAX_POINTS = 100_000
#: Largest number of listed frequencies (``frequencies=``; each one is a solve).
MAX_FREQUENCIES = 10_000


def _integer(name: str, value: Any, low: int, high: int, why: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int | float) or value != int(value):
        raise ParameterError(f"{name} = {value!r}: expected a whole number from {low} to {high}")
    value = int(value)
    if value < low:
        raise ParameterError(f"{name} = {value}: expected at least {low}")
    if value > high:
        raise ParameterError(f"{name} = {value}: expected at most {high} ({why})")
    return value


def check_harmonics(harmonics: Any, name: str = "harmonics") -> int:
    """``harmonics`` as an int in ``1..MAX_HARMONICS``.

    Raises
    ------
    ParameterError
        Naming the value and the limit.
    """
    return _integer(
        name, harmonics, 1, MAX_HARMONICS, "time grows as harmonics**3: 50 s for one branch at 255"
    )


def check_order(order: Any, name: str = "order", method: str | None = None) -> int:
    """``order`` as an int from 1 to the method's limit.

    The limit is ``ORDER_LIMITS[method]`` (:mod:`perturb.methods.applicability`) for a method
    that has one, else :data:`MAX_ORDER`.

    Raises
    ------
    ParameterError
        Naming the value and the limit.
    """
    method = ALIASES.get(method, method) if method is not None else None
    expansion = method in _EXPANSION_METHODS
    limit = ORDER_LIMITS[method] if expansion else MAX_ORDER
    what = f"the largest order of {method!r}" if expansion else "symbolic work"
    return _integer(name, order, 1, limit, f"{what}: symbolic work grows ~4x per order")


def check_points(points: Any, name: str = "points") -> int:
    """``points`` as an int in ``2..MAX_POINTS``.

    Raises
    ------
    ParameterError
        Naming the value and the limit.
    """
    return _integer(name, points, 2, MAX_POINTS, "curve resolution")


def _check_frequencies(frequencies: Any) -> list[float]:
    try:
        values = [float(w) for w in frequencies]
    except (TypeError, ValueError):
        raise ParameterError(
            f"frequencies = {frequencies!r}: expected a sequence of positive numbers"
        ) from None
    if not values or not all(math.isfinite(w) and w > 0 for w in values):
        raise ParameterError(
            f"frequencies = {values!r}: expected positive finite forcing frequencies"
        )
    if len(values) > MAX_FREQUENCIES:
        raise ParameterError(
            f"frequencies: {len(values)} values, expected at most {MAX_FREQUENCIES}"
        )
    return values


def frequency_response(
    oscillator: Oscillator,
    method: str = "hb1",
    Omega: Sequence[float] = (0.2, 2.0),
    *,
    frequencies: Sequence[float] | None = None,
    order: int | None = None,
    harmonics: int | None = None,
    **options: Any,
) -> Response:
    """The frequency response of ``oscillator`` by ``method``.

    Parameters
    ----------
    method
        ``"exact"`` (continuation of exact periodic orbits), ``"hb"`` (numeric multi-harmonic
        balance, ``harmonics`` harmonics, exact Galerkin projection for PWL forces, every
        branch by default), ``"auto"`` (the cheapest method that meets ``rtol`` at exact spot
        checks, :func:`perturb.auto.auto_frequency_response`; the choice, its estimate
        and the spot-check errors are the first ``notes`` of the response) or a
        symbolic method of :data:`perturb.methods.METHODS` (``"mms"`` and ``"avg"`` are
        accepted for ``"ms"`` and ``"kb"``).
    Omega
        ``(low, high)``.
    frequencies
        Exact frequencies to report instead of a traced curve: every solution found at
        each of them, and no other frequency. With ``"hb"`` and residual-traced
        approximations the branches are traced over a window covering the frequencies and
        each crossing of a branch with a requested frequency is solved again at exactly
        that frequency.
    order
        Expansion order of the symbolic method (``mlp``, ``ms``, ``lp``), at most
        :data:`MAX_ORDER`.
    harmonics
        Harmonics of ``"hb"`` (default 15; at most :data:`MAX_HARMONICS`), or of the Fourier
        series of ``lp`` / ``mlp``. Any other method refuses it.
    options
        Passed to the solver. With ``"hb"``: ``all_branches`` (default ``True``; ``False``
        traces only the branch connected to the window's high end) and the options of
        :func:`perturb.numeric.harmonic_balance.harmonic_balance_response` (``seeds``
        defaults to :func:`perturb.seeds.single_harmonic_seeds`). With ``"exact"``:
        ``approximation`` and ``approximation_seeds`` (see :func:`_exact`) and the options of
        :func:`perturb.simulate.exact_response.exact_branches`. With ``"auto"``:
        ``rtol`` (relative amplitude tolerance in ``(0, 1)``, default ``1e-3``), ``spots`` /
        ``n_spots`` (spot-check frequencies), ``points``.

    Raises
    ------
    ParameterError
        Unknown method, an option the method does not take, or a value beyond the limits
        of the module docstring (each message names the value and the limit).

    Notes
    -----
    A symbolic approximation whose amplitude equation is a polynomial of degree <= 2 in
    ``Omega**2`` is traced by amplitude parametrisation; any other (second-order modified
    L-P, for instance) by seeding and continuation of its residuals
    (:func:`perturb.numeric.residual.residual_response`).
    """
    if not isinstance(method, str):
        raise ParameterError(f"method = {method!r}: expected a method name")
    method = ALIASES.get(method, method)
    if harmonics is not None:
        harmonics = check_harmonics(harmonics)
    if order is not None:
        order = check_order(order, method=method)
    if "points" in options:
        options["points"] = check_points(options["points"])
    if frequencies is not None:
        frequencies = _check_frequencies(frequencies)
    known = ("auto", "exact", *METHODS)
    if method not in known:
        raise ParameterError(
            f"method = {method!r}: expected 'auto', 'exact', 'hb' or one of "
            f"{', '.join(METHODS)} (aliases {', '.join(ALIASES)})"
        )
    if method == "auto":
        from perturb.auto import auto_frequency_response, check_rtol

        rtol = check_rtol(options.pop("rtol", 1e-3))
        if frequencies is not None or order is not None or harmonics is not None:
            raise ParameterError(
                "method 'auto' chooses order and harmonics itself over a window Omega=(lo, hi): "
                "give neither frequencies=, order= nor harmonics="
            )
        return auto_frequency_response(oscillator, Omega, rtol, **options)[0]
    if method == "exact":
        _refuse(method, order=order, harmonics=harmonics)
        return _exact(oscillator, Omega, frequencies, options)
    if method == "hb" and order is None:
        from perturb import seeds
        from perturb.numeric.harmonic_balance import harmonic_balance_response

        options.setdefault("all_branches", True)
        # every branch: Newton started also from the single-harmonic balance branches
        options.setdefault("seeds", seeds.single_harmonic_seeds)
        H = 15 if harmonics is None else harmonics
        if frequencies is not None:
            return _hb_solutions_at(oscillator, frequencies, H, options)
        return harmonic_balance_response(oscillator, Omega, harmonics=H, **options)
    from perturb.numeric.amplitude import approximation_response as traced
    from perturb.numeric.amplitude import solutions_at
    from perturb.numeric.residual import residual_response

    fn = METHODS[method]
    takes = inspect.signature(fn).parameters
    method_options: dict[str, Any] = {}
    if order is not None:
        if "order" not in takes:
            raise ParameterError(f"order = {order!r}: method {method!r} has no expansion order")
        method_options["order"] = order
    if harmonics is not None:
        if "harmonics" not in takes or method == "hb":
            raise ParameterError(
                f"harmonics = {harmonics!r}: method {method!r} takes no number of harmonics "
                "(numeric harmonic balance does: method='hb')"
            )
        method_options["harmonics"] = harmonics
    approx = fn(oscillator, **method_options)
    poly = approx.frequency_polynomial
    if poly is None or len(poly) > 3 or approx.slow_flow is None:
        # the curve's resolution is set by the continuation step, not by a point count
        options.pop("points", None)
        if frequencies is not None:
            return _residual_solutions_at(approx, frequencies, options)
        return residual_response(approx, Omega, **options)
    if frequencies is not None:
        return solutions_at(approx, frequencies, **options)
    return traced(approx, Omega, **options)


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


def _refuse(method: str, **given: Any) -> None:
    for name, value in given.items():
        if value is not None:
            raise ParameterError(f"{name} = {value!r}: method {method!r} takes no {name}")


def _covering_window(targets: Sequence[float]) -> tuple[float, float]:
    """A window a little wider than the requested frequencies, so that a branch crossing
    the extreme ones is traced through them, not stopped on them."""
    lo, hi = min(targets), max(targets)
    return lo * (1 - 0.02), hi * (1 + 0.02)


def _crossings(omega: Any, targets: Sequence[float]) -> list[tuple[float, int]]:
    """``(target, j)`` for every segment ``j`` of a polyline in Omega that a target lies on
    (a frequency hit exactly by a point counts once)."""
    out = []
    n = len(omega)
    for j in range(max(n - 1, 0)):
        lo, hi = sorted((float(omega[j]), float(omega[j + 1])))
        for w in targets:
            if lo <= w <= hi and not (w == float(omega[j + 1]) and j + 1 < n - 1):
                out.append((w, j))
    return out


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

    opts = dict(options)
    all_branches = bool(opts.pop("all_branches", True))
    system_keys = ("m", "odd_only", "projection", "samples")
    orbit_opts = {k: opts[k] for k in (*system_keys, "stability", "tol") if k in opts}
    window = _covering_window(targets)
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
        for w, j in _crossings(br.omega, wanted):
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


def _residual_solutions_at(approx, targets: list[float], options: dict[str, Any]) -> Response:
    """Every solution of a residual-traced approximation at exactly ``targets``: the
    branches over a window covering them
    (:func:`perturb.numeric.residual.residual_response`), each crossing solved
    again at its frequency by Newton on the residuals.

    The residuals' unknowns along a traced branch are not kept by the tracer, so Newton
    starts at each frequency from the tracer's own seeding grid (amplitudes times phases,
    denser than the tracer's); every crossing of a traced branch with a requested frequency
    must then be matched by one of the solutions (within 2 % in ``amplitude``), else a note
    says which was missed.
    """
    import numpy as np

    from perturb.numeric.residual import (
        ResidualSystem,
        _branch,
        _newton_many,
        _phase_and_freq,
        _polar,
        _unique,
        _Waveform,
        residual_response,
    )

    window = _covering_window(targets)
    traced = residual_response(approx, window, **options)
    stability = options.get("stability", "hill")
    max_correction = float(options.get("max_correction", 1.0))
    a_lo, a_hi = (float(a) for a in options.get("amplitude_range", (1e-2, 1e2)))
    polar = _polar(approx)
    sys_ = ResidualSystem(polar)
    n, amp = sys_.n, sys_.amplitude_index
    wanted = np.array(sorted(set(targets)))
    axes = [
        np.geomspace(a_lo, a_hi, 48) if i == amp else np.linspace(-np.pi, np.pi, 12, endpoint=False)
        for i in range(n)
    ]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, n)
    U, W = _newton_many(sys_, np.tile(grid, (wanted.size, 1)), np.repeat(wanted, grid.shape[0]))
    pos = U[:, amp] > 0
    U, W = U[pos], W[pos]
    if n > 1:
        other = [i for i in range(n) if i != amp]
        U[:, other] = np.angle(np.exp(1j * U[:, other]))
    U, W = _unique(U, W, amp)
    order = np.lexsort((U[:, amp], W))
    U, W = U[order], W[order]
    notes = [
        f"{W.size} solutions at {wanted.size} frequencies by Newton from a grid at each, "
        f"checked against the branches traced over Omega = {window[0]:.6g}..{window[1]:.6g}"
    ]
    branches: list[Branch] = []
    if W.size:
        wave = _Waveform(polar, polar.amplitude or sys_.unknowns[amp], *_phase_and_freq(polar))
        b = _branch(polar, sys_, wave, U, W, stability)
        ok = b.amplitude <= (1.0 + max_correction) * b.first_harmonic_amplitude
        if not np.all(ok):
            notes.append(
                f"{int(np.count_nonzero(~ok))} solutions left out where the waveform's "
                f"correction exceeds {max_correction:g} times its first harmonic"
            )
        # one branch per frequency rank: the k-th smallest amplitude at each frequency
        rank = np.zeros(W.size, int)
        keep = np.nonzero(ok)[0]
        for w in wanted:
            idx = keep[W[keep] == w]
            rank[idx] = np.arange(idx.size)
        for r in range(int(rank[keep].max()) + 1 if keep.size else 0):
            sel = keep[rank[keep] == r]
            branches.append(
                Branch(
                    omega=b.omega[sel],
                    amplitude=b.amplitude[sel],
                    first_harmonic_amplitude=b.first_harmonic_amplitude[sel],
                    mean=b.mean[sel],
                    stable=b.stable[sel],
                    max_multiplier=b.max_multiplier[sel],
                )
            )
    got: dict[float, list[float]] = {float(w): [] for w in wanted}
    for br in branches:
        for ww, a in zip(br.omega, br.amplitude, strict=True):
            got[float(ww)].append(float(a))
    for bi, br in enumerate(traced.branches):
        for w, j in _crossings(br.omega, list(wanted)):
            w0, w1 = float(br.omega[j]), float(br.omega[j + 1])
            t = 0.0 if w1 == w0 else (w - w0) / (w1 - w0)
            a = (1 - t) * float(br.amplitude[j]) + t * float(br.amplitude[j + 1])
            if not any(abs(v - a) <= 0.02 * abs(a) for v in got[float(w)]):
                notes.append(
                    f"traced branch {bi} crosses Omega = {w!r} near amplitude {a:.6g}, but "
                    "Newton from the grid found no solution there"
                )
    return Response(
        tuple(branches),
        traced.method,
        traced.model,
        dict(traced.params),
        notes=tuple(notes),
    )
