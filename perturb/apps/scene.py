"""Scenes: one question about one system, read from a TOML file.

A scene names the model (a builtin ``name`` or an ``equation`` string, parsed safely), its
parameter values, what is asked (``[ask] kind``), the method and where to write results::

    [model]
    name = "nsd"            # or: equation = "x'' + mu*x' + x + x**3 = F*cos(Omega*t)"
    [params]
    k = -2.0
    [ask]
    kind = "frequency_response"
    omega = [0.2, 2.0]
    points = 2000
    [method]
    name = "hb"             # numeric harmonic balance; every branch it finds
    harmonics = 15
    [compare]
    reference = "exact"     # also every exact periodic orbit: drawn, and errors measured
    methods = ["hb1"]       # further methods drawn and measured against the reference
    [output]
    csv = "frc.csv"
    png = "frc.png"
    latex = "derivation.tex"

``[ask] kind`` is one of

``frequency_response``
    ``omega = [lo, hi]``, ``points``; any method of :func:`perturb.frequency_response`,
    including ``name = "auto"`` with ``[accuracy] rtol`` (the cheapest method that meets it at
    exact spot checks, :mod:`perturb.auto`; the choice goes to ``report.json``).
    ``name = "hb"`` traces every branch numeric harmonic balance finds (``all_branches =
    false`` for the connected one only). An optional ``[compare]`` table adds a ``reference``
    (``"exact"``: continuation of the exact periodic orbits) and further ``methods``; all are
    drawn in one figure and written to one CSV (branches numbered through, the ``method``
    column telling them apart, a last column ``rel_error`` against the reference), and each
    method's measured error against the reference (branches found, max relative error of
    ``max |x|``) goes into the legend and ``report.json``. An optional ``[plot]`` table:
    ``zoom = [omega_lo, omega_hi, amplitude_lo, amplitude_hi]`` (a panel enlarging where
    branches crowd), ``mean = true`` (a panel of the orbits' means, which separates
    asymmetric orbits from symmetric ones of equal amplitude), ``log_amplitude`` (default:
    logarithmic when the amplitudes span more than a factor 30).
``backbone``
    ``amplitude = [lo, hi]``, ``points``: the frequency of the free undamped oscillation
    (forcing and damping set to zero) against its amplitude, from the energy integral.
``time_history``
    ``y0 = [x0, v0]``, ``t = [t0, t1]``, ``samples``; ``[method] name`` is the integrator
    (``auto``, ``exact``, ``event``, ``lcp``, ``ode``).
``step_response``
    As ``time_history`` from rest by default, with the forcing held at its value at ``t = 0``
    (``F`` for ``F cos(Omega t)``): the response to a suddenly applied load.
``bifurcation_diagram``
    ``parameter``, ``values = [lo, hi]``, ``points``, optional ``y0``, ``transient_periods``,
    ``record_periods``: stroboscopic ``x`` of the attractors against the parameter.

Each writes a CSV and a PNG into the output directory (``[output] csv`` / ``png``) and a JSON
``report`` of what was computed, every file complete or absent (:mod:`perturb.atomic`; two
outputs with the same name are refused). What a run should not pass over in silence — no
branch found, seeds that did not converge — is printed as a ``note:`` line and listed under
``notes`` in the report. Peak maps are scenes with a ``[sweep]`` table
(:mod:`perturb.apps.grid_cli`). Unknown sections or keys, and keys of another kind, are errors (a
typo must not be silently ignored).
"""

from __future__ import annotations

import json
import sys
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from types import MappingProxyType

from perturb import checks
from perturb.atomic import check_distinct, write_text
from perturb.errors import ParameterError, PerturbError
from perturb.model.builtins import builtin_model
from perturb.model.oscillator import Oscillator, validate_parameter_value

__all__ = [
    "Scene",
    "load_scene",
    "default_scene",
    "run_scene",
    "backbone",
    "step_oscillator",
]

_KEYS: dict[str, set[str]] = {
    "model": {"name", "equation", "system", "equations", "output"},
    "params": set(),  # any parameter name
    "ask": {
        "kind",
        "omega",
        "points",
        "amplitude",
        "y0",
        "t",
        "samples",
        "parameter",
        "values",
        "transient_periods",
        "record_periods",
        "times",
        "outputs",
        "crossings",
        "active",
        "method",
    },
    "method": {"name", "order", "harmonics", "all_branches"},
    "compare": {"reference", "methods"},
    "plot": {"zoom", "mean", "log_amplitude"},
    "output": {"csv", "png", "latex", "report"},
    "accuracy": {"rtol", "spots"},
}
#: The ``[ask]`` keys each kind accepts (besides ``kind``).
_KIND_KEYS: dict[str, set[str]] = {
    "frequency_response": {"omega", "points"},
    "backbone": {"amplitude", "points"},
    "time_history": {"y0", "t", "samples"},
    "step_response": {"y0", "t", "samples"},
    "bifurcation_diagram": {
        "parameter",
        "values",
        "points",
        "y0",
        "transient_periods",
        "record_periods",
    },
}
_KINDS = tuple(_KIND_KEYS)
#: Integrators of the time-history kinds.
_INTEGRATORS = ("auto", "exact", "event", "lcp", "ode")
#: File names when ``[output]`` does not give them.
_DEFAULT_NAMES = {
    "frequency_response": ("frc.csv", "frc.png"),
    "backbone": ("backbone.csv", "backbone.png"),
    "time_history": ("time_history.csv", "time_history.png"),
    "step_response": ("step_response.csv", "step_response.png"),
    "bifurcation_diagram": ("bifurcation.csv", "bifurcation.png"),
}


@dataclass(frozen=True)
class Scene:
    """A parsed scene; build with :func:`load_scene` or :func:`default_scene`."""

    model: str
    equation: str | None
    params: Mapping[str, float]
    kind: str = "frequency_response"
    omega: tuple[float, float] = (0.2, 2.0)
    points: int = 2000
    method: str = "hb1"
    rtol: float | None = None
    order: int | None = None
    harmonics: int | None = None
    spots: tuple[float, ...] | None = None
    amplitude: tuple[float, float] = (0.1, 10.0)
    y0: tuple[float, float] = (0.0, 0.0)
    t: tuple[float, float] = (0.0, 100.0)
    samples: int = 4001
    parameter: str | None = None
    values: tuple[float, float] | None = None
    transient_periods: int = 200
    record_periods: int = 16
    all_branches: bool = True
    reference: str | None = None
    compare_methods: tuple[str, ...] = ()
    plot: Mapping[str, object] = field(default_factory=lambda: MappingProxyType({}))
    outputs: Mapping[str, str] = field(
        default_factory=lambda: MappingProxyType(
            {"csv": "frc.csv", "png": "frc.png", "latex": "derivation.tex"}
        )
    )
    source: str = "<scene>"
    #: A system of several coordinates (``[model] system``, ``equations`` or the ``name`` of
    #: a builtin system) instead of an oscillator.
    is_system: bool = False
    equations: tuple[str, ...] | None = None
    #: ``[model] output``: what a system's ``amplitude`` measures.
    output: str | None = None
    #: A system's initial state: ``n`` numbers, or ``{state: value}`` (others 0).
    state0: tuple[float, ...] | Mapping[str, float] | None = None
    #: ``[ask] outputs`` / ``crossings`` / ``active`` of a system's step response.
    step_outputs: tuple[str, ...] | Mapping[str, str] | None = None
    crossings: tuple[str, ...] = ()
    active: Mapping[str, int | None] | None = None
    #: ``[method] bias`` of a system scene with ``name = "shb"`` (None: automatic).
    bias: bool | None = None

    def model_object(self):
        """The scene's model with its parameter values: an
        :class:`~perturb.model.oscillator.Oscillator`, or a
        :class:`~perturb.model.system.System` for a system scene."""
        if not self.is_system:
            return self.oscillator()
        if self.equations is not None:
            from perturb.model.system import System

            return System.parse(list(self.equations), dict(self.params), name=self.model)
        from perturb.model.system_builtins import builtin_system

        return builtin_system(self.model, **self.params)

    def oscillator(self) -> Oscillator:
        """The model with the scene's parameter values (an oscillator scene)."""
        if self.is_system:
            raise PerturbError(
                f"scene {self.source}: the model {self.model!r} is a system of several "
                "coordinates, not an oscillator: use Scene.model_object()"
            )
        if self.equation is not None:
            return Oscillator.parse(self.equation, dict(self.params), name=self.model)
        return builtin_model(self.model, **self.params)


def _scene_error(source: str, msg: str) -> PerturbError:
    return PerturbError(f"scene {source}: {msg}")


def parse_scene(text: str, source: str = "<scene>") -> Scene:
    """Read a scene from TOML text (no code is evaluated).

    The tables are read in a fixed order, one stage each: the TOML and its section/key names
    (:func:`_scene_tables`), ``[model]``, ``[params]``, ``[ask]``, ``[method]``,
    ``[compare]``, ``[plot]``, ``[output]``, ``[accuracy]``. A scene with several mistakes
    reports the first in that order; every message names the table, the key and the bad value.

    Parameters
    ----------
    text
        The scene file's text.
    source
        How messages name the scene (its path, or ``"<default scene>"``).

    Raises
    ------
    PerturbError
        ``"scene <source>: ..."`` naming the first bad table, key or value.
    """
    data = _scene_tables(text, source)
    system = _system_model_table(source, data.get("model", {}))
    if system is not None:
        return _parse_system_scene(source, data, system)
    name, equation = _model_table(source, data.get("model", {}))
    params = _params_table(source, data.get("params", {}))
    kind, points, fields = _ask_table(source, data.get("ask", {}))
    method, method_fields = _method_table(source, data.get("method", {}), kind)
    fields.update(method_fields)
    fields.update(_compare_table(source, data.get("compare", {}), kind, method))
    fields.update(_plot_table(source, data.get("plot", {}), kind))
    outputs = _output_table(source, data.get("output", {}), kind)
    rtol, accuracy_fields = _accuracy_table(source, data.get("accuracy", {}), kind, method)
    fields.update(accuracy_fields)
    return Scene(
        model=str(name),
        equation=equation,
        params=MappingProxyType(params),
        kind=kind,
        points=points,
        method=method,
        rtol=rtol,
        outputs=MappingProxyType(outputs),
        source=source,
        **fields,
    )


def _scene_tables(text: str, source: str) -> dict:
    """The TOML document, after checking that every section is a known table and every key
    one of its section's (``[params]`` takes any name: the model checks them).

    Raises
    ------
    PerturbError
        Invalid TOML, an unknown section, a section that is not a table, or an unknown key.
    """
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise _scene_error(source, f"invalid TOML: {exc}") from None
    for section, body in data.items():
        if section not in _KEYS:
            raise _scene_error(
                source, f"unknown section [{section}]: expected one of {', '.join(_KEYS)}"
            )
        if not isinstance(body, dict):
            raise _scene_error(source, f"[{section}] must be a table")
        allowed = _KEYS[section]
        if allowed:
            for key in body:
                if key not in allowed:
                    raise _scene_error(
                        source,
                        f"unknown key {key!r} in [{section}]: expected one of "
                        + ", ".join(sorted(allowed)),
                    )
    return data


def _model_table(source: str, model: dict) -> tuple[str, str | None]:
    """``[model]``: ``(name, equation)`` -- a builtin ``name``, or an ``equation`` string
    (named ``"custom"`` unless a name is given). The equation is only parsed (safely) when
    the scene's oscillator is built.

    Raises
    ------
    PerturbError
        Neither key given, or an equation that is not a string.
    """
    name = model.get("name", "custom" if "equation" in model else None)
    if name is None:
        raise _scene_error(source, "[model] needs a builtin 'name' or an 'equation'")
    equation = model.get("equation")
    if equation is not None and not isinstance(equation, str):
        raise _scene_error(source, f"[model] equation = {equation!r}: expected a string")
    return name, equation


def _params_table(source: str, table: dict) -> dict[str, float]:
    """``[params]``: every value checked by the model layer's
    :func:`~perturb.model.oscillator.validate_parameter_value` (a finite real number; its
    message, prefixed with the scene)."""
    params = {}
    for key, value in table.items():
        try:
            params[key] = validate_parameter_value(key, value)
        except ParameterError as exc:
            raise _scene_error(source, str(exc)) from None
    return params


#: ``[ask] points`` when not given, by kind (others: 2000).
_DEFAULT_POINTS = {"frequency_response": 2000, "backbone": 200, "bifurcation_diagram": 60}
#: Whole-number ``[ask]`` keys besides ``points``, with their limits (bounded work).
_ASK_COUNTS = (
    ("samples", 2, 10**7),
    ("transient_periods", 0, 10**6),
    ("record_periods", 1, 10**4),
)


def _ask_table(source: str, ask: dict) -> tuple[str, int, dict]:
    """``[ask]``: ``(kind, points, fields)``, ``fields`` holding the :class:`Scene` fields the
    table sets (``omega``, ``amplitude``, ``t``, ``values``, ``y0``, ``samples``,
    ``transient_periods``, ``record_periods``, ``parameter``).

    Raises
    ------
    PerturbError
        An unknown kind, a key of another kind, a bad interval, ``y0`` or count, or a
        bifurcation diagram without its ``parameter`` or ``values``.
    """
    kind = ask.get("kind", "frequency_response")
    if kind not in _KINDS:
        raise _scene_error(source, f"[ask] kind = {kind!r}: expected one of {', '.join(_KINDS)}")
    for key in ask:
        if key != "kind" and key not in _KIND_KEYS[kind]:
            raise _scene_error(
                source,
                f"[ask] {key!r} does not apply to kind {kind!r}: expected one of "
                + ", ".join(sorted(_KIND_KEYS[kind])),
            )
    fields: dict = {}
    if "omega" in ask or kind == "frequency_response":
        fields["omega"] = _interval(source, "omega", ask.get("omega", [0.2, 2.0]), positive=True)
    if "amplitude" in ask:
        fields["amplitude"] = _interval(source, "amplitude", ask["amplitude"], positive=True)
    if "t" in ask:
        fields["t"] = _interval(source, "t", ask["t"], positive=False)
    if "values" in ask:
        fields["values"] = _interval(source, "values", ask["values"], positive=False)
    if "y0" in ask:
        y0 = ask["y0"]
        if not _finite_list(y0, 2):
            raise _scene_error(source, f"[ask] y0 = {y0!r}: expected [x0, v0]")
        fields["y0"] = (float(y0[0]), float(y0[1]))
    points = ask.get("points", _DEFAULT_POINTS.get(kind, 2000))
    if not _is_count(points, 10, 10**6):
        raise _scene_error(source, f"[ask] points = {points!r}: expected an integer in [10, 1e6]")
    for key, lo, hi in _ASK_COUNTS:
        if key in ask:
            value = ask[key]
            if not _is_count(value, lo, hi):
                raise _scene_error(
                    source, f"[ask] {key} = {value!r}: expected an integer in [{lo}, {hi}]"
                )
            fields[key] = value
    if kind == "bifurcation_diagram":
        parameter = ask.get("parameter")
        if not isinstance(parameter, str) or not parameter.isidentifier():
            raise _scene_error(
                source, f"[ask] parameter = {parameter!r}: expected the name of a parameter"
            )
        if "values" not in fields:
            raise _scene_error(source, "[ask] values = [lo, hi] is needed for the diagram")
        fields["parameter"] = parameter
    return kind, points, fields


#: Kinds whose ``[method] name`` is an integrator, not a method of the registry.
_INTEGRATOR_KINDS = ("time_history", "step_response", "bifurcation_diagram")


def _method_table(source: str, table: dict, kind: str) -> tuple[str, dict]:
    """``[method]``: ``(method, fields)`` -- the canonical method name (aliases resolved by
    the registry) or the integrator, and the options the registry validated (``order``,
    ``harmonics``, ``all_branches``).

    Raises
    ------
    PerturbError
        An unknown method or integrator, an option of the wrong type, options given to an
        integrator, or an option the method refuses (the registry's message).
    """
    method = table.get("name", "auto" if kind in ("time_history", "step_response") else "hb1")
    if kind in _INTEGRATOR_KINDS:
        if method not in _INTEGRATORS:
            raise _scene_error(
                source,
                f"[method] name = {method!r}: kind {kind!r} expects an integrator, one of "
                + ", ".join(_INTEGRATORS),
            )
    else:
        spec = _method_spec(source, "[method] name =", method)
        method = spec.name
    for key in ("order", "harmonics"):
        if key in table:
            value = table[key]
            if not isinstance(value, int) or isinstance(value, bool):
                raise _scene_error(
                    source, f"[method] {key} = {value!r}: expected a positive integer"
                )
    if "all_branches" in table:
        value = table["all_branches"]
        if not isinstance(value, bool):
            raise _scene_error(source, f"[method] all_branches = {value!r}: expected true or false")
    given = {k: table[k] for k in ("order", "harmonics", "all_branches") if k in table}
    if given and kind in _INTEGRATOR_KINDS:
        raise _scene_error(
            source, f"[method] {', '.join(given)}: not options of the integrator {method!r}"
        )
    if not given:
        return method, {}
    # the method's own options and limits (the registry's), before any work
    try:
        return method, dict(spec.validate(given, prefix="[method] "))
    except ParameterError as exc:
        raise _scene_error(source, str(exc)) from None


def _compare_table(source: str, table: dict, kind: str, method: str) -> dict:
    """``[compare]`` (frequency responses only): the ``reference`` (``"exact"``) and the
    further ``methods`` (``compare_methods``), as :class:`Scene` fields.

    Raises
    ------
    PerturbError
        The table under another kind, a reference other than exact (or exact against
        itself), a method that is not in the registry (or ``auto``), a method twice (the
        scene's own included), or ``exact`` both as reference and among the methods.
    """
    if table and kind != "frequency_response":
        raise _scene_error(source, f"[compare] does not apply to kind {kind!r}")
    fields: dict = {}
    if "reference" in table:
        ref = table["reference"]
        if ref != "exact":
            raise _scene_error(source, f"[compare] reference = {ref!r}: expected 'exact'")
        if method == "exact":
            raise _scene_error(
                source,
                "[compare] reference = 'exact' with [method] name = 'exact': compare "
                "the exact response with what? Give another method or drop the reference",
            )
        fields["reference"] = ref
    if "methods" in table:
        names = table["methods"]
        if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
            raise _scene_error(
                source, f"[compare] methods = {names!r}: expected a list of method names"
            )
        from perturb.methods.registry import names as method_names

        for n in names:
            if n == "auto" or n not in method_names():
                raise _scene_error(
                    source,
                    f"[compare] methods: {n!r} is not a method: expected one of "
                    + ", ".join(x for x in method_names() if x != "auto"),
                )
        if len(set(names)) != len(names) or method in names:
            raise _scene_error(source, f"[compare] methods = {names!r}: a method twice")
        if "reference" in fields and "exact" in names:
            raise _scene_error(source, "[compare] 'exact' is already the reference")
        fields["compare_methods"] = tuple(names)
    return fields


def _plot_table(source: str, table: dict, kind: str) -> dict:
    """``[plot]`` (frequency responses only): ``{"plot": options}`` when any is given --
    ``mean`` and ``log_amplitude`` (booleans), ``zoom`` (four finite numbers, lo < hi)."""
    if table and kind != "frequency_response":
        raise _scene_error(source, f"[plot] does not apply to kind {kind!r}")
    plot_opts: dict = {}
    for key in ("mean", "log_amplitude"):
        if key in table:
            if not isinstance(table[key], bool):
                raise _scene_error(source, f"[plot] {key} = {table[key]!r}: expected true or false")
            plot_opts[key] = table[key]
    if "zoom" in table:
        z = table["zoom"]
        if not (_finite_list(z, 4) and z[0] < z[1] and z[2] < z[3]):
            raise _scene_error(
                source,
                f"[plot] zoom = {z!r}: expected [omega_lo, omega_hi, amplitude_lo, "
                "amplitude_hi] with lo < hi",
            )
        plot_opts["zoom"] = tuple(float(v) for v in z)
    return {"plot": MappingProxyType(plot_opts)} if plot_opts else {}


def _output_table(source: str, table: dict, kind: str) -> dict[str, str]:
    """``[output]``: the file name of each output, defaults filled in by kind (``latex`` for
    frequency responses only).

    Raises
    ------
    PerturbError
        A name that is not a plain file name (directories would let a scene write anywhere).
    ParameterError
        Two outputs with the same name.
    """
    csv_name, png_name = _DEFAULT_NAMES[kind]
    outputs = {"csv": csv_name, "png": png_name, "report": "report.json"}
    if kind == "frequency_response":
        outputs["latex"] = "derivation.tex"
    for key, value in table.items():
        if not isinstance(value, str) or not value or Path(value).name != value:
            raise _scene_error(
                source, f"[output] {key} = {value!r}: expected a plain file name (no directories)"
            )
        outputs[key] = value
    try:
        check_distinct(outputs.values())
    except ParameterError as exc:
        raise ParameterError(f"scene {source}: [output] {exc}") from None
    return outputs


def _accuracy_table(source: str, table: dict, kind: str, method: str) -> tuple[float | None, dict]:
    """``[accuracy]``: ``(rtol, fields)`` -- the tolerance of ``method = "auto"`` (checked by
    :func:`perturb.auto.check_rtol`, required for an auto frequency response) and its spot
    frequencies (``spots``, positive and finite).

    Raises
    ------
    PerturbError
        A bad ``rtol`` or ``spots``, or an auto frequency response without ``rtol``.
    """
    rtol = table.get("rtol")
    if rtol is not None:
        from perturb.auto import check_rtol

        try:
            rtol = check_rtol(rtol)
        except ParameterError as exc:
            raise _scene_error(source, f"[accuracy] {exc}") from None
    if method == "auto" and kind == "frequency_response" and rtol is None:
        raise _scene_error(source, "[method] name = 'auto' needs [accuracy] rtol = ...")
    if "spots" not in table:
        return rtol, {}
    spots = table["spots"]
    if not isinstance(spots, list) or not spots or not all(_is_positive(w) for w in spots):
        raise _scene_error(
            source, f"[accuracy] spots = {spots!r}: expected a list of positive frequencies"
        )
    return rtol, {"spots": tuple(float(w) for w in spots)}


def _method_spec(source: str, what: str, name: object):
    """The registry's spec of a scene's method name (aliases accepted), or a scene error."""
    from perturb.methods.registry import spec

    try:
        return spec(name, what=what)
    except ParameterError as exc:
        raise _scene_error(source, str(exc)) from None


def _is_number(v: object) -> bool:
    """A TOML integer or float (TOML booleans are Python bools, refused)."""
    return isinstance(v, int | float) and not isinstance(v, bool)


def _is_finite(v: object) -> bool:
    """A finite TOML number (:func:`perturb.checks.finite` also refuses bools and strings)."""
    try:
        checks.finite(v, "value")
    except ParameterError:
        return False
    return _is_number(v)


def _is_positive(v: object) -> bool:
    """A finite TOML number > 0 (a frequency)."""
    return _is_finite(v) and v > 0  # type: ignore[operator]


def _finite_list(value: object, n: int) -> bool:
    """A TOML array of ``n`` finite numbers."""
    return isinstance(value, list) and len(value) == n and all(_is_finite(v) for v in value)


def _is_count(value: object, low: int, high: int) -> bool:
    """A TOML integer (not a float: TOML tells them apart, and ``points = 100.0`` is refused)
    within ``[low, high]`` (:func:`perturb.checks.whole`)."""
    if not isinstance(value, int) or isinstance(value, bool):
        return False
    try:
        checks.whole(value, "value", low, high)
    except ParameterError:
        return False
    return True


def _interval(source: str, key: str, value: object, *, positive: bool) -> tuple[float, float]:
    """``[ask] key = [low, high]``: two finite numbers, ``low < high`` (and ``low > 0`` when
    ``positive``) -- the scene's own message, naming the key and the value."""
    ok = (
        _finite_list(value, 2)
        and value[0] < value[1]  # type: ignore[index]
        and (not positive or value[0] > 0)  # type: ignore[index]
    )
    if not ok:
        cond = "0 < low < high" if positive else "low < high"
        raise _scene_error(source, f"[ask] {key} = {value!r}: expected [low, high] with {cond}")
    return (float(value[0]), float(value[1]))  # type: ignore[index]


def load_scene(path: str | Path) -> Scene:
    """Read a scene file."""
    p = Path(path)
    try:
        text = p.read_text()
    except OSError as exc:
        raise PerturbError(f"cannot read scene file {str(p)!r}: {exc.strerror}") from None
    return parse_scene(text, str(p))


def default_scene() -> Scene:
    """The scene embedded in the package: the Zou–Nagarajaiah frequency response, k = -2."""
    text = resources.files("perturb").joinpath("scenes/default.toml").read_text()
    return parse_scene(text, "<default scene>")


def run_scene(scene: Scene, out_dir: str | Path = "out", *, log=None) -> dict[str, Path]:
    """Answer ``scene`` and write its outputs into ``out_dir``.

    Parameters
    ----------
    scene : Scene
    out_dir : str or Path
        Created if missing.
    log : file, optional
        Where progress lines go (default standard error).

    Returns
    -------
    dict
        The written paths by kind (``csv``, ``png``, ``report``, and ``latex`` for a
        frequency response with a symbolic method among its methods). Every file is written
        to a temporary file beside it and renamed (complete or absent).

    Raises
    ------
    ParameterError
        Before any work, when two outputs would be written to the same file.
    """

    def say(msg: str) -> None:
        print(msg, file=log or sys.stderr, flush=True)

    out = Path(out_dir)
    names = {"csv": scene.outputs["csv"], "png": scene.outputs["png"]}
    names["report"] = scene.outputs.get("report", "report.json")
    if scene.kind == "frequency_response" and "latex" in scene.outputs:
        names["latex"] = scene.outputs["latex"]
    check_distinct(out / n for n in names.values())
    out.mkdir(parents=True, exist_ok=True)
    osc = scene.model_object()
    say(f"[perturb] scene {scene.source}: {osc}")
    paths = {"csv": out / names["csv"], "png": out / names["png"]}
    if scene.is_system:
        runner = {
            "frequency_response": _run_system_frequency_response,
            "time_history": _run_system_time_history,
            "step_response": _run_system_step_response,
        }[scene.kind]
    else:
        runner = {
            "frequency_response": _run_frequency_response,
            "backbone": _run_backbone,
            "time_history": _run_time_history,
            "step_response": _run_time_history,
            "bifurcation_diagram": _run_bifurcation,
        }[scene.kind]
    report = {
        "scene": scene.source,
        "kind": scene.kind,
        "model": str(osc),
        "params": dict(scene.params),
    }
    report.update(runner(scene, osc, out, paths, say))
    notes = list(report.get("notes", ()))
    for note in notes:
        if not _routine_note(note):
            say(f"[perturb] note: {note}")
    report["notes"] = notes
    paths["report"] = out / names["report"]
    write_text(paths["report"], json.dumps(report, indent=1, default=str) + "\n")
    for kind, p in paths.items():
        say(f"[perturb] wrote {kind}: {p}")
    return paths


def _routine_note(note: str) -> bool:
    """Notes kept in report.json but not printed: how each exact branch ended, workers."""
    import re

    return bool(re.search(r"(^|: )(branch \d+: |traced with \d+ worker)", note))


def _trace(
    scene: Scene, osc: Oscillator, method: str, say, *, primary: bool
) -> tuple[object, object, dict]:
    """One method's response over the scene's window: (response, approximation or None, info)."""
    from perturb.methods.registry import spec

    info: dict = {"method": method}
    approx = None
    harmonics = scene.harmonics if primary else None
    order = scene.order if primary else None
    if method == "auto":
        from perturb.auto import auto_frequency_response

        say(f"[perturb] choosing a method for rtol = {scene.rtol:g} (spot checks) ...")
        resp, choice = auto_frequency_response(
            osc,
            scene.omega,
            scene.rtol,
            spots=scene.spots,
            points=scene.points,
            log=lambda line: say(f"[perturb]   {line}"),
        )
        say("[perturb] " + choice.summary().replace("\n", "\n[perturb] "))
        info["auto"] = choice.to_dict()
        info["auto"]["summary"] = choice.summary()
        cand = choice.chosen.candidate
        if cand.method not in ("hb", "exact"):
            from perturb.auto import derive_candidate

            approx = derive_candidate(cand, osc)
    elif spec(method).kind != "symbolic":
        from perturb.solve import frequency_response

        extra: dict = {}
        if method == "hb":
            extra = {"harmonics": 15 if harmonics is None else harmonics}
            extra["all_branches"] = scene.all_branches
            info["harmonics"] = extra["harmonics"]
            info["all_branches"] = scene.all_branches
        say(f"[perturb] tracing the {method} frequency response over Omega in {scene.omega} ...")
        resp = frequency_response(osc, method, scene.omega, **extra)
    else:
        from perturb.solve import derive, trace_approximation

        say(f"[perturb] deriving {method} ...")
        opts = {"order": order, "harmonics": harmonics}
        approx = derive(osc, method, use_cache=True, **opts)
        say(f"[perturb] tracing the {method} frequency response over Omega in {scene.omega} ...")
        resp = trace_approximation(approx, scene.omega, points=scene.points)
    info["response"] = resp.method
    info["branches"] = len(resp.branches)
    info["points"] = int(sum(len(b) for b in resp.branches))
    # the auto choice's summary heads the notes; it is printed above and in the report
    printed = set(info["auto"]["summary"].splitlines()) if "auto" in info else set()
    notes = [f"{resp.method}: {n}" for n in resp.notes if n not in printed]
    if not resp.branches:
        notes.append(
            f"{resp.method}: no periodic solution found for Omega in "
            f"[{scene.omega[0]:g}, {scene.omega[1]:g}] (an empty answer, not a proof that none "
            "exists): check the damping and forcing, widen the window, or try method 'exact'"
        )
    info["notes"] = notes
    return resp, approx, info


def _errors_against(resp, ref, tolerance: float = 0.02) -> dict:
    """Branches of ``ref`` that ``resp`` finds, and its errors on them (:func:`compare`)."""
    import numpy as np

    from perturb.comparison import compare

    if not resp.branches or not ref.branches:
        return {
            "reference_branches": len(ref.branches),
            "branches": len(resp.branches),
            "found": 0,
            "missed": list(range(len(ref.branches))),
            "spurious": list(range(len(resp.branches))),
            "max_error": None,
            "rms_error": None,
            "stability_disagreements": 0,
            "tolerance": tolerance,
        }
    c = compare(resp, ref, tolerance=tolerance)
    found = [r.branch for r in c.reference_branches if r.matched_by]
    errs = [b.max_error for b in c.branches if b.matched is not None and np.isfinite(b.max_error)]
    return {
        "reference_branches": len(ref.branches),
        "branches": len(resp.branches),
        "found": len(found),
        "not_found": [r.branch for r in c.reference_branches if not r.matched_by],
        "missed": list(c.missed),
        "spurious": list(c.spurious),
        "max_error": float(max(errs)) if errs else None,
        "rms_error": float(c.rms_error) if np.isfinite(c.rms_error) else None,
        # stability against the nearest exact orbit within compare's default 20 %: an
        # approximation a few percent off must not escape the check by being off
        "stability_disagreements": len(compare(resp, ref).stability_disagreements),
        "tolerance": tolerance,
    }


def _legend_label(resp, errors: dict | None) -> str:
    from perturb.report.figures import method_label

    label = method_label(resp.method)
    if errors is None:
        return f"{label}: {len(resp.branches)} branches"
    n = errors["reference_branches"]
    if errors["max_error"] is None:
        return f"{label}: none of the {n} exact branches"
    found = "all" if errors["found"] == n else f"{errors['found']} of"
    text = f"{label}:\n  {found} {n} exact branches, max error {errors['max_error']:.1e} on them"
    if errors["spurious"]:
        text += f", {len(errors['spurious'])} spurious"
    if errors["stability_disagreements"]:
        text += f",\n  stability differs from exact at {errors['stability_disagreements']} points"
    return text


def _run_frequency_response(scene: Scene, osc: Oscillator, out: Path, paths: dict, say) -> dict:
    """Answer a frequency-response scene: trace its method (and the ``[compare]`` methods and
    reference), measure them against the exact reference, write the CSV, the figure and the
    derivation; returns the report's fields.

    The stages: :func:`_trace_scene_methods`, then :func:`_measure_against_exact` (with a
    reference) or :func:`_auto_labels` (without), the CSV, :func:`_draw_frequency_response`,
    :func:`_write_derivation`.
    """
    from perturb.response import responses_to_csv

    info: dict = {"omega": list(scene.omega), "method": scene.method}
    responses, runs, ref, approx, notes = _trace_scene_methods(scene, osc, say, info)
    for r in responses:
        say(f"[perturb] {r!r}".replace("\n", "\n[perturb] "))
    if ref is not None:
        labels, extra = _measure_against_exact(responses, runs, ref, say)
        drawn = [*responses, ref]
    else:
        labels, extra = _auto_labels(info, responses), None
        drawn = responses
    info["responses"] = runs
    responses_to_csv(drawn, paths["csv"], extra=extra)
    info["legend"] = None if labels is None else list(labels)
    _draw_frequency_response(scene, osc, responses, ref, labels, paths["png"])
    info.update(_write_derivation(scene, approx, out, paths))
    info["notes"] = notes
    return info


def _trace_scene_methods(scene: Scene, osc: Oscillator, say, info: dict) -> tuple:
    """Stage 1: trace the scene's method, each ``[compare]`` method and the exact reference.

    ``info`` (the report) gets the primary response's name and branch count, and the auto
    choice when the method is ``auto``.

    Returns
    -------
    (responses, runs, ref, approx, notes)
        The traced responses (primary first), one report entry per trace (the reference's
        last, with ``role = "reference"``), the exact reference or None, the first symbolic
        approximation (for the derivation) or None, and the notes of every trace.
    """
    notes: list[str] = []
    resp, approx, main = _trace(scene, osc, scene.method, say, primary=True)
    info["response"] = resp.method
    info["branches"] = len(resp.branches)
    if "auto" in main:
        info["auto"] = main.pop("auto")
    notes += main.pop("notes")
    responses = [resp]
    runs = [main]
    for name in scene.compare_methods:
        r, a, i = _trace(scene, osc, name, say, primary=False)
        notes += i.pop("notes")
        responses.append(r)
        runs.append(i)
        approx = approx if approx is not None else a
    ref = None
    if scene.reference == "exact":
        ref, _, i = _trace(scene, osc, "exact", say, primary=False)
        notes += i.pop("notes")
        i["role"] = "reference"
        runs.append(i)
    return responses, runs, ref, approx, notes


def _measure_against_exact(responses: list, runs: list, ref, say) -> tuple[list[str], dict]:
    """Stage 2 (with a reference): each response's errors against the exact orbits, into its
    report entry (``against_exact``), a printed line and its legend label.

    Returns
    -------
    (labels, extra)
        Legend labels (the reference's last) and the CSV's extra ``rel_error`` column (0 on
        the reference's own rows).
    """
    from perturb.comparison import relative_errors

    say(f"[perturb] {ref!r}".replace("\n", "\n[perturb] "))
    errors = [_errors_against(r, ref) for r in responses]
    labels = [_legend_label(r, e) for r, e in zip(responses, errors, strict=True)]
    labels.append(f"exact periodic orbits: {len(ref.branches)} branches (the reference)")
    for run, e in zip(runs, errors, strict=False):
        run["against_exact"] = e
        found = "all" if e["found"] == e["reference_branches"] else f"{e['found']} of"
        err = "-" if e["max_error"] is None else f"{e['max_error']:.2e}"
        say(
            f"[perturb] {run['response']} against exact: finds {found} "
            f"{e['reference_branches']} exact branches, max relative error {err} on them, "
            f"{len(e['spurious'])} spurious branches"
        )
    rel = []
    for r in responses:
        rel += [float(v) for v in relative_errors(r, ref)] if r.branches else []
    rel += [0.0] * sum(len(b) for b in ref.branches)
    return labels, {"rel_error": rel}


def _auto_labels(info: dict, responses: list) -> list[str] | None:
    """Stage 2 (without a reference): legend labels telling an ``auto`` choice's rtol and
    spot-check error (None when the method is not auto: the figure's own labels)."""
    if "auto" not in info:
        return None
    from perturb.report.figures import method_label

    ch = info["auto"]
    spot = ch["chosen"]["max_spot_error"]
    spot_text = f"{spot:.1e}" if isinstance(spot, float) else str(spot)
    return [
        f"{method_label(responses[0].method)}:\n  chosen for rtol {ch['rtol']:g}, max error "
        f"{spot_text} at {len(ch['spot_frequencies'])} exact spot checks"
    ] + [method_label(r.method) for r in responses[1:]]


def _draw_frequency_response(
    scene: Scene, osc: Oscillator, responses: list, ref, labels: list[str] | None, png: Path
) -> None:
    """Stage 3: the figure -- the reference (if any) underneath, thick and dark, the
    responses on top; a logarithmic amplitude axis when amplitudes span decades (unless
    ``[plot] log_amplitude`` says otherwise)."""
    from perturb.report.figures import equation_title, frequency_response_figure

    drawn = responses if ref is None else [*responses, ref]
    title = equation_title(osc, dict(scene.params))
    if ref is not None:
        title += "\nerrors: relative, of the amplitude $\\max\\,|x|$, against the exact orbits"
    # the reference underneath (thick, dark), the approximations on top
    order = list(range(len(drawn)))
    if ref is not None:
        order = [len(drawn) - 1, *range(len(drawn) - 1)]
    palette = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd"]
    colors = [palette[k % len(palette)] for k in range(len(responses))]
    widths = [1.3 if k == 0 else 1.0 for k in range(len(responses))]
    if ref is not None:
        colors.append("0.15")
        widths.append(2.8)
    amps = [float(a) for r in drawn for b in r.branches for a in b.amplitude if a > 0]
    # amplitudes spanning decades (a resonance peak over small in-well orbits): log axis
    log_axis = bool(amps) and max(amps) > 30 * max(min(amps), 1e-12)
    fig = frequency_response_figure(
        [drawn[k] for k in order],
        png,
        title=title,
        zoom=scene.plot.get("zoom"),
        mean=bool(scene.plot.get("mean", False)),
        labels=None if labels is None else [labels[k] for k in order],
        colors=[colors[k] for k in order],
        linewidths=[widths[k] for k in order],
        log_amplitude=scene.plot.get("log_amplitude", log_axis),
        legend_kw={"fontsize": 7, "loc": "upper right" if ref is not None else "best"},
    )
    _close(fig)


def _write_derivation(scene: Scene, approx, out: Path, paths: dict) -> dict:
    """Stage 4: the LaTeX derivation of the first symbolic approximation, when the scene
    asks for one (``paths["latex"]`` set); the report's ``derivation`` field, or a ``latex``
    field saying why none was written."""
    if approx is not None and "latex" in scene.outputs:
        from perturb.report.latex import latex_document

        paths["latex"] = out / scene.outputs["latex"]
        write_text(paths["latex"], latex_document(approx))
        return {"derivation": approx.label}
    if "latex" in scene.outputs:
        return {
            "latex": "not written: none of the scene's methods is symbolic (add one, 'hb1' say, "
            "to [compare] methods for its derivation)"
        }
    return {}


def _numeric_force(osc: Oscillator):
    """``f(x)`` of the free undamped oscillator as a numpy function (parameters substituted)."""
    import numpy as np
    import sympy as sp

    x = osc.x
    f = osc.restoring_force.xreplace(osc.substitutions())
    free = f.free_symbols - {x}
    if free:
        raise ParameterError(
            "backbone: the restoring force needs values for "
            + ", ".join(sorted(str(s) for s in free))
        )
    fn = sp.lambdify(x, f, modules=[{"Heaviside": lambda z, h0=0.5: np.heaviside(z, h0)}, "numpy"])
    return lambda z: np.asarray(fn(z), dtype=float) * np.ones_like(np.asarray(z, dtype=float))


def backbone(osc: Oscillator, amplitudes) -> dict[str, list[float]]:
    """Period and frequency of the free undamped oscillation from each turning point.

    From rest at ``x0`` the motion runs to the other turning point ``x1`` (the nearest point
    beyond which the potential ``G(x) = int_0^x f`` exceeds ``G(x0)``) and back, so
    ``T = 2 |int_{x0}^{x1} dx / sqrt(2 (G(x0) - G(x)))|``, evaluated by adaptive quadrature
    after ``x = c + h sin(theta)``, which removes the inverse square-root end singularities.

    Parameters
    ----------
    osc : Oscillator
        Damping and forcing are ignored; the restoring force needs parameter values.
    amplitudes : array_like
        Starting turning points ``x0 > 0``.

    Returns
    -------
    dict
        Lists ``x0``, ``x1``, ``amplitude`` (``max(|x0|, |x1|)``), ``period``, ``omega``
        (``2 pi / period``); turning points without a bounded orbit are left out.
    """
    import numpy as np
    from scipy.integrate import quad
    from scipy.optimize import brentq

    f = _numeric_force(osc)
    try:
        kinks = sorted(float(b) for b in osc.piecewise_linear().breakpoints)
    except Exception:  # a smooth force has no canonical PWL form; nothing to split at
        kinks = []

    def G(z: float) -> float:
        pts = [b for b in kinks if min(0.0, z) < b < max(0.0, z)]
        return float(quad(lambda s: float(f(s)), 0.0, z, points=pts or None, limit=200)[0])

    out: dict[str, list[float]] = {k: [] for k in ("x0", "x1", "amplitude", "period", "omega")}
    for x0 in np.asarray(amplitudes, dtype=float):
        f0 = float(f(x0))
        if f0 == 0.0:
            continue
        d = -1.0 if f0 > 0 else 1.0  # the force pushes the mass this way
        g0 = G(x0)
        # march until the potential climbs back to G(x0): the other turning point
        step, z, x1, gz = 0.01 * max(1.0, abs(x0)), x0, None, g0
        for i in range(20000):
            z_next = z + d * step
            # the potential step by step: short integrals instead of one from 0 each time
            pts = [b for b in kinks if min(z, z_next) < b < max(z, z_next)]
            g_next = gz + quad(lambda q: float(f(q)), z, z_next, points=pts or None)[0]
            if g_next >= g0:
                if i == 0:
                    break  # at (numerically) an equilibrium: no oscillation to time
                fa, fb = G(z) - g0, G(z_next) - g0
                if fa * fb <= 0:
                    x1 = brentq(lambda q, g0=g0: G(q) - g0, z, z_next, xtol=1e-14, rtol=1e-14)
                else:
                    # the step-by-step sum crossed G(x0) and the direct integral, rounded
                    # differently, did not (a turning point at a hilltop of the potential,
                    # where G touches G(x0)): the end nearer to it
                    x1 = z if abs(fa) <= abs(fb) else z_next
                break
            z, gz = z_next, g_next
        if x1 is None:
            continue
        c, h = 0.5 * (x0 + x1), 0.5 * (x1 - x0)
        ths = sorted(float(np.arcsin((b - c) / h)) for b in kinks if min(x0, x1) < b < max(x0, x1))

        def integrand(th: float, c=c, h=h, g0=g0) -> float:
            gap = 2.0 * (g0 - G(c + h * np.sin(th)))
            return abs(h) * np.cos(th) / np.sqrt(max(gap, 1e-300))

        half = quad(integrand, -np.pi / 2, np.pi / 2, points=ths or None, limit=200)[0]
        T = 2.0 * half
        out["x0"].append(float(x0))
        out["x1"].append(float(x1))
        out["amplitude"].append(max(abs(float(x0)), abs(float(x1))))
        out["period"].append(T)
        out["omega"].append(2.0 * np.pi / T)
    return out


def _run_backbone(scene: Scene, osc: Oscillator, out: Path, paths: dict, say) -> dict:
    import numpy as np

    lo, hi = scene.amplitude
    say(f"[perturb] backbone (free undamped) for turning points {lo:g}..{hi:g} ...")
    bb = backbone(osc, np.linspace(lo, hi, scene.points))
    cols = ("x0", "x1", "amplitude", "period", "omega")
    lines = [",".join(cols)] + [
        ",".join(repr(bb[c][i]) for c in cols) for i in range(len(bb["x0"]))
    ]
    write_text(paths["csv"], "\n".join(lines) + "\n")
    from perturb.report.figures import equation_title, save_figure

    fig, ax = _figure()
    ax.plot(bb["omega"], bb["amplitude"], "o", ms=2, mew=0)
    ax.set_xlabel(r"free-vibration frequency $\omega$")
    ax.set_ylabel(r"amplitude $\max\,|x|$")
    ax.set_title("backbone (free, undamped) of\n" + equation_title(osc), fontsize=8)
    save_figure(fig, paths["png"])
    _close(fig)
    info = {"amplitude": [lo, hi], "points": len(bb["x0"]), "method": "energy quadrature"}
    if not bb["x0"]:
        info["notes"] = [
            f"no bounded free oscillation from any turning point in [{lo:g}, {hi:g}]: the "
            "backbone is empty (is the restoring force confining there?)"
        ]
    return info


def _figure():
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.8), dpi=110, layout="constrained")
    ax.grid(alpha=0.3)
    return fig, ax


def _close(fig) -> None:
    """Release a saved figure (pyplot keeps every open figure alive)."""
    import matplotlib.pyplot as plt

    plt.close(fig)


def step_oscillator(osc: Oscillator) -> Oscillator:
    """``osc`` with its forcing held at the value it has at ``t = 0`` (a suddenly applied
    constant load: ``F`` for ``F cos(Omega t)``)."""
    import sympy as sp

    eq = osc.equation
    t = next((s for s in eq.rhs.free_symbols if s.name == "t"), sp.Symbol("t"))
    rhs = eq.rhs.subs(t, 0)
    params = {k: v for k, v in osc.params.items() if v is not None and k != "Omega"}
    return Oscillator.parse(f"{eq.lhs} = {rhs}", params, name=f"{osc.name} step")


def _run_time_history(scene: Scene, osc: Oscillator, out: Path, paths: dict, say) -> dict:
    from perturb.report.figures import plot_time_history
    from perturb.simulate.time_history import time_history

    if scene.kind == "step_response":
        osc = step_oscillator(osc)
        say(f"[perturb] step load: {osc}")
    say(f"[perturb] integrating over t in {scene.t} from y0 = {scene.y0} ({scene.method}) ...")
    hist = time_history(osc, scene.y0, scene.t, method=scene.method, samples=scene.samples)
    say(f"[perturb] {hist!r}")
    from perturb.atomic import atomic_path
    from perturb.report.figures import equation_title

    with atomic_path(paths["csv"]) as tmp:
        hist.to_csv(tmp)
    _close(plot_time_history(hist, paths["png"], title=equation_title(osc)))
    return {"t": list(scene.t), "y0": list(scene.y0), "integrator": hist.method}


def _run_bifurcation(scene: Scene, osc: Oscillator, out: Path, paths: dict, say) -> dict:
    import numpy as np

    from perturb.simulate.studies import bifurcation_diagram

    assert scene.values is not None and scene.parameter is not None
    values = np.linspace(*scene.values, scene.points)
    say(
        f"[perturb] bifurcation diagram over {scene.parameter} in {scene.values} "
        f"({scene.points} values) ..."
    )
    diag = bifurcation_diagram(
        osc,
        scene.parameter,
        values,
        y0=scene.y0,
        transient_periods=scene.transient_periods,
        record_periods=scene.record_periods,
        method=scene.method,
        progress=False,
    )
    say(f"[perturb] {diag!r}")
    lines = [f"{scene.parameter},run,x,v,period"]
    for i in range(diag.x.shape[0]):
        for j, p in enumerate(diag.values):
            for x, v in zip(diag.x[i, j], diag.v[i, j], strict=True):
                lines.append(f"{float(p)!r},{i},{float(x)!r},{float(v)!r},{int(diag.period[i, j])}")
    write_text(paths["csv"], "\n".join(lines) + "\n")
    from perturb.report.figures import equation_title, param_tex, save_figure

    fig, ax = _figure()
    p, x = diag.points()
    ax.plot(p, x, "o", color="k", ms=2.5, mew=0, alpha=0.7)
    ax.set_xlabel(f"${param_tex(scene.parameter)}$")
    ax.set_ylabel(f"$x$ at phase {diag.phase:g} of each forcing period")
    ax.set_title(
        f"bifurcation diagram over ${param_tex(scene.parameter)}$ of\n"
        + equation_title(osc, skip=(scene.parameter,)),
        fontsize=8,
    )
    save_figure(fig, paths["png"])
    _close(fig)
    notes = []
    if not len(p):
        notes.append("no attractor recorded at any parameter value: the diagram is empty")
    return {
        "notes": notes,
        "parameter": scene.parameter,
        "values": list(scene.values),
        "points": scene.points,
        "period_1": int(np.sum(diag.period == 1)),
        "subharmonic": int(np.sum(diag.period > 1)),
        "not_periodic": int(np.sum(diag.period == 0)),
    }


def plot_system_history(history, path=None, *, title: str | None = None):
    """A system's time history: every coordinate against ``t`` (velocities left out) above,
    the output combination below.

    Parameters
    ----------
    history : perturb.solve.SystemHistory
    path : str or Path, optional
        Where the figure is saved (complete or absent).
    title : str, optional
        Plain text (wrapped); default names the integrator.
    """
    import textwrap

    from perturb.report.figures import mathtext_safe, save_figure

    fig, (ax1, ax2) = _subplots(2)
    names = history.state_names
    shown = [k for k, name in enumerate(names) if not name.endswith("'")]
    for k in shown:
        ax1.plot(history.t, history.y[:, k], lw=0.8, label=names[k])
    ax1.set_ylabel("coordinates")
    ax1.legend(fontsize=7, loc="upper right")
    ax2.plot(history.t, history.output, lw=0.8, color="k")
    ax2.set_xlabel("$t$")
    ax2.set_ylabel(mathtext_safe(f"output {history.output_name}"))
    for ax in (ax1, ax2):
        ax.grid(alpha=0.3)
    text = title or f"time history ({history.method})"
    fig.suptitle("\n".join(textwrap.wrap(mathtext_safe(text), 130)), fontsize=8)
    if path is not None:
        save_figure(fig, path)
    _close(fig)
    return fig


def _subplots(rows: int):
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt.subplots(rows, 1, figsize=(8, 5.5), dpi=110, layout="constrained", sharex=True)


def system_title(system, skip: tuple[str, ...] = (), width: int = 110) -> str:
    """A figure title for a system: its name, its description (a builtin) or its equations as
    given, its parameter values (but ``skip``), wrapped to ``width`` characters."""
    import textwrap

    from perturb.model.system_builtins import BUILTIN_SYSTEMS

    params = ", ".join(
        f"{k}={v:g}" for k, v in system.params.items() if v is not None and k not in skip
    )
    spec = BUILTIN_SYSTEMS.get(system.name)
    what = system.source
    if spec is not None and system.source == "; ".join(spec.equations):
        what = spec.description
    return "\n".join(textwrap.wrap(f"{system.name}: {what}   [{params}]", width))


# ------------------------------------------------------------------------------------------
# Systems of several coordinates (issue 15)
# ------------------------------------------------------------------------------------------

#: The ``[ask]`` keys of each kind a system scene takes (besides ``kind``).
_SYSTEM_KIND_KEYS: dict[str, set[str]] = {
    "frequency_response": {"omega", "points"},
    "time_history": {"y0", "t", "samples"},
    "step_response": {
        "y0",
        "t",
        "times",
        "samples",
        "points",
        "outputs",
        "crossings",
        "active",
        "method",
    },
}
#: Most equations of a system scene (bounded parsing work).
_MAX_EQUATIONS = 64


def _system_model_table(source: str, model: dict) -> dict | None:
    """``[model]`` of a system scene: ``system = "nsd2"`` (or ``name`` = a builtin system), or
    ``equations = [...]`` (one per coordinate / first-order state, parsed safely when the
    scene runs; ``name`` labels them), and ``output``; None for an oscillator's scene.

    Raises
    ------
    PerturbError
        ``output`` for an oscillator, ``equation`` with a system, both ``system`` and
        ``equations``, an unknown builtin system, equations that are not a list of strings.
    """
    from perturb.model.system_builtins import BUILTIN_SYSTEMS

    name, system, equations = model.get("name"), model.get("system"), model.get("equations")
    if system is None and equations is None and name not in BUILTIN_SYSTEMS:
        if "output" in model:
            raise _scene_error(
                source,
                f"[model] output = {model['output']!r}: applies to systems of several "
                "coordinates ([model] system or equations); an oscillator's amplitude is "
                "max |x|",
            )
        return None
    if "equation" in model:
        raise _scene_error(
            source,
            "[model] equation is one oscillator's equation: a system takes "
            "equations = [...] (one per coordinate) or system = '<builtin>'",
        )
    if system is not None and equations is not None:
        raise _scene_error(source, "[model] give system = '<builtin>' or equations, not both")
    if system is not None:
        if not isinstance(system, str) or system not in BUILTIN_SYSTEMS:
            raise _scene_error(
                source,
                f"[model] system = {system!r}: expected one of {', '.join(BUILTIN_SYSTEMS)}",
            )
        if name is not None and name != system:
            raise _scene_error(
                source, f"[model] name = {name!r} and system = {system!r}: give one of them"
            )
    if equations is not None:
        ok = (
            isinstance(equations, list)
            and 1 <= len(equations) <= _MAX_EQUATIONS
            and all(isinstance(e, str) and e.strip() for e in equations)
        )
        if not ok:
            raise _scene_error(
                source,
                f"[model] equations = {equations!r}: expected a list of 1 to {_MAX_EQUATIONS} "
                "equation strings, one per coordinate",
            )
        if name is not None and not isinstance(name, str):
            raise _scene_error(source, f"[model] name = {name!r}: expected a string")
    output = model.get("output")
    if output is not None and (not isinstance(output, str) or not output.strip()):
        raise _scene_error(
            source,
            f"[model] output = {output!r}: expected a coordinate or a linear combination "
            "such as 'x1 - x2'",
        )
    return {
        "model": system or (name if equations is None else (name or "custom")),
        "equations": None if equations is None else tuple(equations),
        "output": None if output is None else output.strip(),
    }


def _parse_system_scene(source: str, data: dict, model: dict) -> Scene:
    """The rest of a system scene: ``[params]``, ``[ask]`` (kinds frequency_response,
    time_history, step_response), ``[method]``, ``[output]``; ``[compare]``, ``[plot]`` and
    ``[accuracy]`` are for oscillators (for now)."""
    params = _params_table(source, data.get("params", {}))
    ask = data.get("ask", {})
    kind = ask.get("kind", "frequency_response")
    if kind not in _KINDS:
        raise _scene_error(source, f"[ask] kind = {kind!r}: expected one of {', '.join(_KINDS)}")
    if kind not in _SYSTEM_KIND_KEYS:
        raise _scene_error(
            source,
            f"[ask] kind = {kind!r} takes one coordinate (an oscillator); a system of several "
            f"coordinates takes {', '.join(_SYSTEM_KIND_KEYS)}",
        )
    for key in ask:
        if key != "kind" and key not in _SYSTEM_KIND_KEYS[kind]:
            raise _scene_error(
                source,
                f"[ask] {key!r} does not apply to kind {kind!r} of a system: expected one of "
                + ", ".join(sorted(_SYSTEM_KIND_KEYS[kind])),
            )
    if data.get("plot"):
        raise _scene_error(
            source, "[plot] applies to oscillators; a system scene does not take it (yet)"
        )
    fields: dict = _system_ask_fields(source, ask, kind)
    fields["method"] = _system_method(source, data.get("method", {}), ask, kind)
    if fields["method"] == "auto" and kind == "frequency_response":
        rtol, accuracy_fields = _accuracy_table(source, data.get("accuracy", {}), kind, "auto")
        fields["rtol"] = rtol
        fields.update(accuracy_fields)
    elif data.get("accuracy"):
        raise _scene_error(
            source,
            "[accuracy] is the tolerance of [method] name = 'auto': a system scene takes it "
            "with that method only",
        )
    if "bias" in data.get("method", {}):
        bias = data["method"]["bias"]
        if not isinstance(bias, bool):
            raise _scene_error(source, f"[method] bias = {bias!r}: expected true or false")
        fields["bias"] = bias
    if fields["method"] == "hb" and "harmonics" in data.get("method", {}):
        from perturb.methods.registry import check_harmonics

        try:
            fields["harmonics"] = check_harmonics(data["method"]["harmonics"])
        except PerturbError as exc:
            raise _scene_error(source, f"[method] {exc}") from None
    compare = data.get("compare", {})
    if compare:
        # a system's HB against the exact orbits at its points (rel_error per coordinate)
        if set(compare) != {"reference"} or compare["reference"] != "exact":
            raise _scene_error(
                source,
                f"[compare] {compare!r}: a system scene takes reference = 'exact' only "
                "(with [method] name = 'hb', 'hb1', 'shb' or 'auto')",
            )
        if kind != "frequency_response" or fields["method"] not in _SYSTEM_COMPARED:
            raise _scene_error(
                source,
                "[compare] reference = 'exact' compares a system's balance response with exact "
                "orbits: it needs kind 'frequency_response' and [method] name = 'hb', 'hb1', "
                "'shb' or 'auto'",
            )
        fields["reference"] = "exact"
    outputs = _output_table(source, data.get("output", {}), kind)
    if "latex" in data.get("output", {}):
        raise _scene_error(
            source, "[output] latex: a system's exact response has no derivation to write"
        )
    outputs.pop("latex", None)
    return Scene(
        model=str(model["model"]),
        equation=None,
        params=MappingProxyType(params),
        kind=kind,
        outputs=MappingProxyType(outputs),
        source=source,
        is_system=True,
        equations=model["equations"],
        output=model["output"],
        **fields,
    )


def _system_ask_fields(source: str, ask: dict, kind: str) -> dict:
    """``[ask]`` of a system scene as :class:`Scene` fields."""
    fields: dict = {}
    if kind == "frequency_response":
        fields["omega"] = _interval(source, "omega", ask.get("omega", [0.2, 2.0]), positive=True)
        points = ask.get("points", 2000)
        if not _is_count(points, 10, 10**6):
            raise _scene_error(
                source, f"[ask] points = {points!r}: expected an integer in [10, 1e6]"
            )
        fields["points"] = points
        return fields
    for a, b in (("t", "times"), ("samples", "points")):
        if a in ask and b in ask:
            raise _scene_error(source, f"[ask] {a} and {b} are one setting: give one of them")
    span = ask.get("t", ask.get("times"))
    if span is not None:
        fields["t"] = _interval(source, "t" if "t" in ask else "times", span, positive=False)
    count_key = "samples" if "samples" in ask else "points"
    if count_key in ask:
        value = ask[count_key]
        if not _is_count(value, 2, 10**7):
            raise _scene_error(
                source, f"[ask] {count_key} = {value!r}: expected an integer in [2, 10000000]"
            )
        fields["samples"] = value
    if "y0" in ask:
        fields["state0"] = _state_table(source, ask["y0"])
    if "outputs" in ask:
        value = ask["outputs"]
        if isinstance(value, list) and value and all(isinstance(v, str) and v for v in value):
            fields["step_outputs"] = tuple(value)
        elif (
            isinstance(value, dict)
            and value
            and all(isinstance(v, str) and v for v in value.values())
        ):
            fields["step_outputs"] = MappingProxyType(dict(value))
        else:
            raise _scene_error(
                source,
                f"[ask] outputs = {value!r}: expected a list of output names or expressions, "
                "or a table name = expression",
            )
    if "crossings" in ask:
        value = ask["crossings"]
        if not isinstance(value, list) or not all(isinstance(v, str) and v for v in value):
            raise _scene_error(
                source, f"[ask] crossings = {value!r}: expected a list of output names"
            )
        fields["crossings"] = tuple(value)
    if "active" in ask:
        value = ask["active"]
        modes = {-1: -1, 0: None, 1: 1}
        if not isinstance(value, dict) or not all(
            isinstance(v, int) and not isinstance(v, bool) and v in modes for v in value.values()
        ):
            raise _scene_error(
                source,
                f"[ask] active = {value!r}: expected a table stop = -1 (resting on its lower "
                "limit), 1 (upper) or 0 (free)",
            )
        fields["active"] = MappingProxyType({k: modes[v] for k, v in value.items()})
    return fields


def _state_table(source: str, value: object) -> tuple[float, ...] | Mapping[str, float]:
    """``[ask] y0`` of a system: a list of the ``n`` states, or a table ``state = value``
    (the others 0); the count and names are checked against the model when it is built."""
    if isinstance(value, list) and value and all(_is_finite(v) for v in value):
        return tuple(float(v) for v in value)
    if isinstance(value, dict) and all(_is_finite(v) for v in value.values()):
        return MappingProxyType({str(k): float(v) for k, v in value.items()})
    raise _scene_error(
        source,
        f"[ask] y0 = {value!r}: expected the states as a list of finite numbers, or a table "
        "state = value (the others 0)",
    )


#: Methods of a system's frequency response whose points [compare] checks against exact
#: orbits.
_SYSTEM_COMPARED = ("hb", "hb1", "shb", "auto", "ms-ir")


def _system_method(source: str, table: dict, ask: dict, kind: str) -> str:
    """``[method] name`` of a system scene: for a frequency response one of
    :data:`perturb.solve.SYSTEM_METHODS` (``exact``, ``hb`` with ``harmonics``, ``hb1``,
    ``shb`` with ``bias``, ``auto`` with ``[accuracy] rtol``), an integrator for a time
    history, a step-response solver (also as ``[ask] method``) for a step response."""
    name0 = table.get("name")
    takes = {"name"}
    if kind == "frequency_response":
        takes |= {"hb": {"harmonics"}, "shb": {"bias"}}.get(name0, set())
    extra = sorted(set(table) - takes)
    if extra:
        raise _scene_error(
            source,
            f"[method] {', '.join(extra)}: not options of a system scene's method {name0!r}; "
            "a system scene takes [method] name (harmonics with name = 'hb', bias with "
            "name = 'shb')",
        )
    if "method" in ask and "name" in table:
        raise _scene_error(source, "[ask] method and [method] name are one setting: give one")
    if kind == "frequency_response":
        name = table.get("name", "exact")
        from perturb.solve import SYSTEM_METHODS, SYSTEM_ONLY_METHODS, system_method_text

        if name in SYSTEM_ONLY_METHODS:
            return "ms-ir"  # a method of systems only (not in the registry)
        spec = _method_spec(source, "[method] name =", name)

        if spec.name not in SYSTEM_METHODS:
            raise _scene_error(
                source,
                f"[method] name = {name!r} ({spec.title}) is a method for one coordinate; a "
                f"system of several coordinates takes one of {', '.join(SYSTEM_METHODS)} "
                f"({system_method_text()})",
            )
        return spec.name
    if kind == "time_history":
        from perturb.solve import SYSTEM_INTEGRATORS

        name = table.get("name", "auto")
        if name not in SYSTEM_INTEGRATORS:
            raise _scene_error(
                source,
                f"[method] name = {name!r}: a system's time history takes one of "
                + ", ".join(SYSTEM_INTEGRATORS),
            )
        return name
    from perturb.simulate.step_response import METHODS

    name = ask.get("method", table.get("name", "auto"))
    if name not in METHODS:
        raise _scene_error(
            source,
            f"method = {name!r}: a system's step response takes one of {', '.join(METHODS)}",
        )
    return name


def _initial_state(scene: Scene, system):
    """The scene's initial state in the system's state order (zero by default)."""
    import numpy as np

    names = system.state_names
    y = np.zeros(len(names))
    if scene.state0 is None:
        return y
    if isinstance(scene.state0, Mapping):
        for key, value in scene.state0.items():
            if key not in names:
                raise _scene_error(
                    scene.source,
                    f"[ask] y0: {key!r} is not a state of {system.name!r}: expected one of "
                    + ", ".join(names),
                )
            y[names.index(key)] = value
        return y
    if len(scene.state0) != len(names):
        raise _scene_error(
            scene.source,
            f"[ask] y0 = {list(scene.state0)!r}: expected {len(names)} numbers, the states "
            + ", ".join(names),
        )
    return np.array(scene.state0, dtype=float)


def _run_system_time_history(scene: Scene, system, out: Path, paths: dict, say) -> dict:
    from perturb.solve import system_time_history

    y0 = _initial_state(scene, system)
    say(f"[perturb] integrating over t in {scene.t} from y0 = {list(y0)} ({scene.method}) ...")
    hist = system_time_history(
        system, y0, scene.t, method=scene.method, samples=scene.samples, output=scene.output
    )
    say(f"[perturb] {hist!r}")
    hist.to_csv(paths["csv"])
    plot_system_history(hist, paths["png"], title=system_title(system))
    return {
        "t": list(scene.t),
        "y0": [float(v) for v in y0],
        "states": list(system.state_names),
        "output": hist.output_name,
        "integrator": hist.method,
    }


def _step_outputs(scene: Scene, system) -> dict[str, str]:
    """The step response's named outputs: ``[ask] outputs`` (names of the builtin's outputs,
    state names or expressions), default the builtin's named outputs; the builtin's outputs
    named in ``[ask] crossings`` and ``[model] output`` (as ``output``) added."""
    from perturb.model.system_builtins import BUILTIN_SYSTEMS, builtin_outputs

    named = dict(builtin_outputs(scene.model)) if scene.model in BUILTIN_SYSTEMS else {}
    if scene.step_outputs is None:
        wanted = dict(named)
    elif isinstance(scene.step_outputs, Mapping):
        wanted = dict(scene.step_outputs)
    else:
        wanted = {item: named.get(item, item) for item in scene.step_outputs}
    for name in scene.crossings:  # a crossing of a builtin's named output needs it computed
        if name not in wanted and name in named:
            wanted[name] = named[name]
    if scene.output is not None:
        wanted.setdefault("output", scene.output)
    return wanted


def _run_system_step_response(scene: Scene, system, out: Path, paths: dict, say) -> dict:
    import numpy as np

    from perturb.simulate.step_response import step_response

    y0 = _initial_state(scene, system)
    outputs = _step_outputs(scene, system)
    times = np.linspace(scene.t[0], scene.t[1], scene.samples)
    say(
        f"[perturb] step response over t in {scene.t} ({scene.samples} samples, {scene.method}) ..."
    )
    r = step_response(
        system,
        times,
        y0=y0,
        method=scene.method,
        active=None if scene.active is None else dict(scene.active),
        outputs=outputs or None,
        crossings=scene.crossings,
    )
    say(f"[perturb] {r}".replace("\n", "\n[perturb] "))
    names = list(r.state_names) + list(r.outputs)
    cols = [np.asarray(r.times)] + [np.asarray(r.states)[:, k] for k in range(len(r.state_names))]
    cols += [np.asarray(r.outputs[k]) for k in r.outputs]
    lines = [",".join(["t", *names])]
    for j in range(len(r.times)):
        lines.append(",".join(repr(float(c[j])) for c in cols))
    write_text(paths["csv"], "\n".join(lines) + "\n")
    _plot_step_response(r, paths["png"], system_title(system))
    info: dict = {
        "t": list(scene.t),
        "samples": scene.samples,
        "y0": [float(v) for v in y0],
        "states": list(r.state_names),
        "outputs": outputs,
        "solver": r.method,
        "events": len(r.events),
        "crossings": {k: [float(t) for t in v] for k, v in r.crossings.items()},
    }
    if r.equilibrium is not None:
        info["equilibrium"] = [float(v) for v in r.equilibrium]
    return info


def _plot_step_response(r, png: Path, title: str) -> None:
    """Coordinates (velocities left out) in one panel, each output in its own (their units
    differ: a pressure, a flow)."""
    import textwrap

    import numpy as np

    from perturb.report.figures import mathtext_safe, save_figure

    outputs = list(r.outputs)[:5]  # a readable figure: at most five output panels
    fig, axes = _subplots(1 + len(outputs))
    axes = np.atleast_1d(axes)
    states = np.asarray(r.states)
    for k, name in enumerate(r.state_names):
        if not name.endswith("'"):
            axes[0].plot(r.times, states[:, k], lw=0.8, label=name)
    axes[0].set_ylabel("coordinates")
    axes[0].legend(fontsize=7, loc="best")
    for ax, name in zip(axes[1:], outputs, strict=True):
        ax.plot(r.times, r.outputs[name], lw=0.8, color="k")
        ax.set_ylabel(mathtext_safe(name))
    for ax in axes:
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("$t$")
    text = f"step response ({r.method}) of {title}"
    fig.suptitle("\n".join(textwrap.wrap(mathtext_safe(text), 130)), fontsize=8)
    save_figure(fig, png)
    _close(fig)


def label_errors(fig, summary: str) -> None:
    """Write a system's HB errors against exact orbits (:func:`perturb.solve.system_errors`'s
    summary) into the legend entry of the response (the first label), or under the title
    when the figure has no legend."""
    ax = fig.axes[0]
    legend = ax.get_legend()
    import textwrap

    text = "max rel. error vs exact: " + summary
    if legend is not None and legend.texts:
        first = legend.texts[0]
        first.set_text(first.get_text() + "\n" + textwrap.fill(text, 60))
    else:
        ax.set_title(ax.get_title() + "\n" + text, fontsize=8)


def _run_system_frequency_response(scene: Scene, system, out: Path, paths: dict, say) -> dict:
    """A system's frequency response (:func:`perturb.solve.frequency_response`, method
    ``exact`` or ``hb``): the CSV (the SDOF columns of ``[model] output``, then
    ``amplitude_<name>`` and ``mean_<name>`` of every coordinate; with ``[compare] reference
    = 'exact'`` also ``rel_error`` and ``rel_error_<name>`` against exact orbits at the HB
    points) and the figure of the output's amplitude, stable solid (the largest errors in
    its title)."""
    from perturb.solve import frequency_response, system_errors, system_output

    _, output = system_output(system, scene.output)
    method = scene.method
    what = {
        "exact": "exact frequency response",
        "hb": "harmonic-balance response",
        "hb1": "single-harmonic balance response",
        "shb": "single-harmonic balance response",
        "ms-ir": "internal-resonance slow-flow response",
        "auto": "response by the cheapest method meeting rtol",
    }[method]
    say(f"[perturb] tracing the {what} of {system.name} over Omega in {scene.omega} ...")
    options: dict = {}
    if method == "hb" and scene.harmonics:
        options["harmonics"] = scene.harmonics
    if method == "shb" and scene.bias is not None:
        options["bias"] = scene.bias
    if method == "auto":
        options["rtol"] = scene.rtol
        if scene.spots is not None:
            options["spots"] = scene.spots
        options["log"] = lambda line: say(f"[perturb]   {line}")
    resp = frequency_response(system, method, scene.omega, output=scene.output, **options)
    say(f"[perturb] {resp!r}".replace("\n", "\n[perturb] "))
    extra = summary = None
    has_states = bool(resp.columns) and "states" in resp.columns[0]
    if scene.reference == "exact" and method != "exact" and has_states:
        say("[perturb] shooting the exact orbits at the balance points ...")
        extra, summary = system_errors(system, resp, scene.output)
        say(f"[perturb] max relative error against exact orbits: {summary}")
    elif scene.reference == "exact" and method == "auto":
        say("[perturb] auto chose the exact solver: the response is its own reference")
    resp.to_csv(paths["csv"], extra=extra)  # the output's columns, then every coordinate's
    from perturb.report.figures import frequency_response_figure, save_figure

    fig = frequency_response_figure([resp], None, title=system_title(system, ("Omega",)))
    fig.axes[0].set_ylabel(f"amplitude max |{output}|")
    if summary is not None:
        label_errors(fig, summary)
    save_figure(fig, paths["png"])
    _close(fig)
    notes = [f"{resp.method}: {n}" for n in resp.notes]
    if not resp.branches:
        notes.append(
            f"{method}: no periodic solution found for Omega in [{scene.omega[0]:g}, "
            f"{scene.omega[1]:g}] (an empty answer, not a proof that none exists)"
        )
    report = {
        "omega": list(scene.omega),
        "method": method,
        "output": output,
        "branches": len(resp.branches),
        "points": int(sum(len(b) for b in resp.branches)),
        "columns": list(resp.extra_columns()) + (list(extra) if extra else []),
        "notes": notes,
    }
    if summary is not None:
        report["compare"] = f"exact orbits: {summary}"
    return report
