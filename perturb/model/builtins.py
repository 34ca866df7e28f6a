"""The builtin models as data (name, equation text, default parameters, description).

No SymPy here, so ``perturb models`` lists them without loading it; :meth:`ModelSpec.build`
parses the equation into an :class:`~perturb.model.oscillator.Oscillator`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

from perturb.errors import ModelError

if TYPE_CHECKING:
    from perturb.model.oscillator import Oscillator

__all__ = ["ModelSpec", "BUILTIN_MODELS", "builtin_model"]


# ------------------------------------------------------------------------- builtins --
@dataclass(frozen=True)
class ModelSpec:
    """A named builtin model: its equation, default parameter values and a description."""

    name: str
    equation: str
    defaults: Mapping[str, float]
    description: str

    def build(self, **params: Any) -> Oscillator:
        """The model as an :class:`~perturb.model.oscillator.Oscillator` (defaults overridden
        by ``params``)."""
        from perturb.model.oscillator import Oscillator  # SymPy only when a model is built

        values = dict(self.defaults, **params)
        return Oscillator.parse(self.equation, values, name=self.name)


def _spec(name: str, equation: str, defaults: dict[str, float], description: str) -> ModelSpec:
    return ModelSpec(name, equation, MappingProxyType(defaults), description)


_FORCE = "F*cos(Omega*t)"

#: The named models shipped with perturb, by name.
BUILTIN_MODELS: Mapping[str, ModelSpec] = MappingProxyType(
    {
        spec.name: spec
        for spec in (
            _spec(
                "nsd",
                "x'' + mu*x' + k*x + (1 - k)*((x - 1)*Heaviside(x - 1) + (x + 1)*Heaviside(-x - 1))"
                f" = {_FORCE}",
                {"k": -2.0, "mu": 0.05, "F": 2.0, "Omega": 1.0},
                "Zou-Nagarajaiah negative-stiffness device (eq. 6): stiffness k < 0 for |x| < 1, "
                "1 outside",
            ),
            _spec(
                "duffing",
                f"x'' + mu*x' + omega0**2*x + alpha*x**3 = {_FORCE}",
                {"mu": 0.1, "omega0": 1.0, "alpha": 1.0, "F": 0.5, "Omega": 1.0},
                "forced, damped Duffing oscillator",
            ),
            _spec(
                "quadratic_cubic",
                "x'' + omega0**2*x + alpha2*x**2 + alpha3*x**3 = 0",
                {"omega0": 1.0, "alpha2": 0.5, "alpha3": 1.0},
                "free conservative oscillator with quadratic and cubic stiffness",
            ),
            _spec(
                "vanderpol",
                "x'' - eps*(1 - x**2)*x' + x = 0",
                {"eps": 0.1},
                "autonomous van der Pol oscillator (limit cycle of amplitude ~2)",
            ),
            _spec(
                "mathieu",
                "x'' + (delta + eps*cos(2*t))*x = 0",
                {"delta": 1.0, "eps": 0.1},
                "Mathieu equation (parametric excitation)",
            ),
            _spec(
                "pendulum",
                f"x'' + mu*x' + omega0**2*sin(x) = {_FORCE}",
                {"mu": 0.0, "omega0": 1.0, "F": 0.0, "Omega": 1.0},
                "pendulum, optionally damped and forced",
            ),
            _spec(
                "clearance",
                f"x'' + mu*x' + x + r*(x - d)*Heaviside(x - d) = {_FORCE}",
                {"mu": 0.02, "r": 10.0, "d": 0.5, "F": 0.3, "Omega": 0.9},
                "one-sided spring of stiffness ratio r engaged beyond the gap d",
            ),
            _spec(
                "deadzone",
                f"x'' + mu*x' + k1*x + k2*(x - Max(-d, Min(d, x))) = {_FORCE}",
                {"mu": 0.05, "k1": 0.1, "k2": 1.0, "d": 1.0, "F": 0.5, "Omega": 1.0},
                "weak spring k1 plus a spring k2 acting only outside the dead zone |x| < d",
            ),
            _spec(
                "saturation",
                f"x'' + mu*x' + k1*x + k2*Max(-d, Min(d, x)) = {_FORCE}",
                {"mu": 0.05, "k1": 0.1, "k2": 1.0, "d": 1.0, "F": 0.5, "Omega": 1.0},
                "spring k2 whose force saturates at |x| = d, in parallel with k1",
            ),
            _spec(
                "bilinear",
                f"x'' + mu*x' + x + (r - 1)*x*Heaviside(x) = {_FORCE}",
                {"mu": 0.05, "r": 4.0, "F": 1.0, "Omega": 1.0},
                "bilinear spring: stiffness 1 for x < 0 and r for x > 0",
            ),
        )
    }
)


def builtin_model(name: str, **params: Any) -> Oscillator:
    """A builtin model by name, with its default parameter values overridden by ``params``.

    Raises
    ------
    ModelError
        For an unknown name (the message lists the known ones).
    """
    try:
        spec = BUILTIN_MODELS[name]
    except KeyError:
        raise ModelError(
            f"unknown model {name!r}: expected one of {', '.join(BUILTIN_MODELS)}"
        ) from None
    return spec.build(**params)
