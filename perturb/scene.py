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
    name = "hb1"
    [output]
    csv = "frc.csv"
    png = "frc.png"
    latex = "derivation.tex"

Unknown sections or keys are errors (a typo must not be silently ignored).
"""

from __future__ import annotations

import sys
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from types import MappingProxyType

from .errors import ParameterError, PerturbError
from .methods import METHODS
from .model import Oscillator, builtin_model, validate_parameter_value

__all__ = ["Scene", "load_scene", "default_scene", "run_scene", "METHODS"]

_KEYS: dict[str, set[str]] = {
    "model": {"name", "equation"},
    "params": set(),  # any parameter name
    "ask": {"kind", "omega", "points"},
    "method": {"name"},
    "output": {"csv", "png", "latex"},
    "accuracy": {"rtol"},
}
_KINDS = ("frequency_response",)


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
    outputs: Mapping[str, str] = field(
        default_factory=lambda: MappingProxyType(
            {"csv": "frc.csv", "png": "frc.png", "latex": "derivation.tex"}
        )
    )
    source: str = "<scene>"

    def oscillator(self) -> Oscillator:
        if self.equation is not None:
            return Oscillator.parse(self.equation, dict(self.params), name=self.model)
        return builtin_model(self.model, **self.params)


def _scene_error(source: str, msg: str) -> PerturbError:
    return PerturbError(f"scene {source}: {msg}")


def parse_scene(text: str, source: str = "<scene>") -> Scene:
    """Read a scene from TOML text (no code is evaluated)."""
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
    model = data.get("model", {})
    name = model.get("name", "custom" if "equation" in model else None)
    if name is None:
        raise _scene_error(source, "[model] needs a builtin 'name' or an 'equation'")
    equation = model.get("equation")
    if equation is not None and not isinstance(equation, str):
        raise _scene_error(source, f"[model] equation = {equation!r}: expected a string")
    params = {}
    for key, value in data.get("params", {}).items():
        try:
            params[key] = validate_parameter_value(key, value)
        except ParameterError as exc:
            raise _scene_error(source, str(exc)) from None
    ask = data.get("ask", {})
    kind = ask.get("kind", "frequency_response")
    if kind not in _KINDS:
        raise _scene_error(source, f"[ask] kind = {kind!r}: expected one of {', '.join(_KINDS)}")
    omega = ask.get("omega", [0.2, 2.0])
    if (
        not isinstance(omega, list)
        or len(omega) != 2
        or not all(isinstance(w, int | float) and not isinstance(w, bool) for w in omega)
        or not 0 < omega[0] < omega[1]
    ):
        raise _scene_error(
            source, f"[ask] omega = {omega!r}: expected [low, high] with 0 < low < high"
        )
    points = ask.get("points", 2000)
    if not isinstance(points, int) or isinstance(points, bool) or not 10 <= points <= 10**6:
        raise _scene_error(source, f"[ask] points = {points!r}: expected an integer in [10, 1e6]")
    method = data.get("method", {}).get("name", "hb1")
    if method not in METHODS:
        raise _scene_error(
            source, f"[method] name = {method!r}: expected one of {', '.join(METHODS)}"
        )
    outputs = dict(Scene.__dataclass_fields__["outputs"].default_factory())  # type: ignore[misc]
    for key, value in data.get("output", {}).items():
        if not isinstance(value, str) or not value or Path(value).name != value:
            raise _scene_error(
                source, f"[output] {key} = {value!r}: expected a plain file name (no directories)"
            )
        outputs[key] = value
    rtol = data.get("accuracy", {}).get("rtol")
    return Scene(
        model=str(name),
        equation=equation,
        params=MappingProxyType(params),
        kind=kind,
        omega=(float(omega[0]), float(omega[1])),
        points=points,
        method=method,
        rtol=None if rtol is None else float(rtol),
        outputs=MappingProxyType(outputs),
        source=source,
    )


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
    """Answer ``scene`` and write its outputs into ``out_dir``; returns the written paths."""
    from .cache import cached_derivation
    from .numeric.frequency_response import frequency_response
    from .report.figures import plot_frequency_response
    from .report.latex import latex_document

    def say(msg: str) -> None:
        print(msg, file=log or sys.stderr, flush=True)

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    osc = scene.oscillator()
    say(f"[perturb] scene {scene.source}: {osc}")
    say(f"[perturb] deriving {scene.method} ...")
    approx = cached_derivation(scene.method, METHODS[scene.method], osc)
    say(f"[perturb] tracing the frequency response over Omega in {scene.omega} ...")
    resp = frequency_response(approx, scene.omega, points=scene.points)
    say(f"[perturb] {resp!r}".replace("\n", "\n[perturb] "))
    paths = {
        "csv": out / scene.outputs["csv"],
        "png": out / scene.outputs["png"],
        "latex": out / scene.outputs["latex"],
    }
    resp.to_csv(paths["csv"])
    plot_frequency_response(resp, paths["png"])
    latex_document(approx, paths["latex"])
    for kind, p in paths.items():
        say(f"[perturb] wrote {kind}: {p}")
    return paths
