r"""The builtin multi-coordinate models as data (name, equations, stops, defaults, description).

No SymPy here, so a listing stays fast; :meth:`SystemSpec.build` parses the equations into a
:class:`~perturb.model.system.System`. State order: second-order coordinates, their
velocities, then first-order states (``y = (q, q', p)``).

Models
------
``nsd2``
    Two-storey structure with the Zou–Nagarajaiah negative-stiffness device between ground and
    the first mass (non-dimensional, as the SDOF ``nsd`` builtin, eq. 6):

    .. math::

        x_1'' + \mu_1 x_1' + \mu_2 (x_1' - x_2') + k x_1
            + (1 - k)[(x_1 - 1)H(x_1 - 1) + (x_1 + 1)H(-x_1 - 1)]
            + k_2 (x_1 - x_2) = F \cos\Omega t,\qquad
        m_2 x_2'' + \mu_2 (x_2' - x_1') + k_2 (x_2 - x_1) = 0 .

``impact_pair``
    Primary oscillator ``x1`` with a second mass ``x2`` moving in a two-sided clearance
    ``|x1 - x2| <= d`` and contact springs of stiffness ``r`` (an impact damper; the same
    equations are a gear pair with backlash in relative coordinates):

    .. math::

        x_1'' + \mu x_1' + x_1 + r\,b(x_1 - x_2) = F \cos\Omega t,\quad
        m_2 x_2'' + \mu_2 (x_2' - x_1') - r\,b(x_1 - x_2) = 0,

    :math:`b(s) = (s - d)H(s - d) + (s + d)H(-s - d)`.

``mount``
    He–Singh hydraulic mount with free decoupler and top-chamber vacuum after an ideal step
    ``x = X`` (``derivations/hydraulic_mount.py``: ``Mount`` values, ``simulate_mount`` states).
    Track and decoupler volumes ``V_i``, ``V_d`` (``V_d`` = volume passed since the plate left
    the top stop): ``I_i V_i'' + R_i V_i' = p_1 - p_2``, ``I_d V_d'' + R_d V_d' = p_1 - p_2``,
    ``p_2 = (V_i + V_d)/C_2``, and with the top chamber's compression ``u = A_r X - V_i - V_d``
    the PWL pressure (continuous knee at ``u_k = -p_v C_1``, compliance ``C_1`` above, ``C_{1v}``
    below): ``p_1 = u/C_1 + (1/C_{1v} - 1/C_1)(u - u_k)H(u_k - u)``. The decoupler is the stop
    ``0 <= V_d <= 2 V_gap`` (plastic, restitution 0): while it rests the flow is held (the
    script's modes ``dec = +-1``). A harmonic displacement would move the vacuum surface in
    time, which the piecewise-affine data cannot hold; the model is the step response.
``mount_fixed``
    The same mount with the decoupler fixed (``V_d = 0``): the track volume ``V_i`` alone,
    ``I_i V_i'' + R_i V_i' + V_i/C_2 = p_1(A_r X - V_i)`` with the vacuum knee; step
    ``X = -3.7e-3``. Piecewise linear (exact propagation).
``mount_fixed_linear``
    ``mount_fixed`` without vacuum (``p_1 = (A_r X - V_i)/C_1``): linear, its step response has
    a closed form. :func:`mount_system` builds every member of the family (free or fixed
    decoupler, with or without vacuum, ideal or ramped step) and :func:`mount_outputs` names
    their outputs (``p1``, ``p2``, ``flow``, ``plate``).
``mount_linear``
    The floating-decoupler linear mount in first-order form (``integrate_full``), pressures and
    flows ``(p1, p2, q_i, q_d)``, with a harmonic displacement ``x = Xa cos(Omega t)``:
    ``C_1 p_1' = A_r x' - q_i - q_d``, ``C_2 p_2' = q_i + q_d``,
    ``I_i q_i' = p_1 - p_2 - R_i q_i``, ``I_d q_d' = p_1 - p_2 - R_d q_d``.
``belt``
    Mass on a belt moving at ``v_b`` with Stribeck friction (self-excited stick–slip; the
    standard form, e.g. Popp & Stelter 1990):
    ``m x'' + c x' + k x + N [mu_k + (mu_s - mu_k) exp(-|x' - v_b|/v_s)] sign(x' - v_b) = 0``.
    ``mu_s = mu_k`` gives Coulomb friction.
``drill_string``
    Two-degree-of-freedom torsional drill string (rotary table ``phi_r`` driven by a constant
    motor torque ``T_m``, bit ``phi_b``), the standard lumped form of Navarro-López & Cortés
    (2007) with their bit friction law
    ``T_b = W_ob R_b [mu_c + (mu_s - mu_c) exp(-gamma_b |phi_b'| / nu_f)] sign(phi_b')``;
    parameter values of the order used there (representative, not a specific rig).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

from perturb import checks
from perturb.errors import ModelError, ParameterError

if TYPE_CHECKING:
    from perturb.model.system import System

__all__ = [
    "SystemSpec",
    "BUILTIN_SYSTEMS",
    "builtin_system",
    "builtin_outputs",
    "mount_system",
    "mount_outputs",
]


@dataclass(frozen=True)
class SystemSpec:
    """A named builtin system: equations (one per coordinate / first-order state), stops as
    ``(name, combination, lower, upper)`` text, default parameter values, a description, and
    named outputs (expression text in the states and parameters, e.g. the mount's chamber
    pressures, for :func:`perturb.simulate.step_response.step_response`)."""

    name: str
    equations: tuple[str, ...]
    defaults: Mapping[str, float]
    description: str
    stops: tuple[tuple[str, str, str, str], ...] = ()
    outputs: Mapping[str, str] = field(default_factory=lambda: MappingProxyType({}))

    def build(self, **params: Any) -> System:
        """The model as a :class:`~perturb.model.system.System` (defaults overridden)."""
        from perturb.model.system import System, stop  # SymPy only when a model is built

        values = dict(self.defaults, **params)
        elements = [stop(on, lo, hi, name=nm) for nm, on, lo, hi in self.stops]
        return System.parse(self.equations, values, name=self.name, elements=elements)


def _spec(name, equations, defaults, description, stops=(), outputs=None) -> SystemSpec:
    return SystemSpec(
        name,
        tuple(equations),
        MappingProxyType(defaults),
        description,
        stops,
        MappingProxyType(dict(outputs or {})),
    )


_B = "((x1 - x2 - d)*Heaviside(x1 - x2 - d) + (x1 - x2 + d)*Heaviside(-x1 + x2 - d))"
# top-chamber compression u = A_r X - V_i - V_d and its vacuum knee u_k = -p_vac C1
_U = "(A_r*X - V_i - V_d)"
_P1 = f"({_U}/C1 + (1/C1_vac - 1/C1)*({_U} + p_vac*C1)*Heaviside(-p_vac*C1 - {_U}))"
_P2 = "(V_i + V_d)/C2"
# Mount() of derivations/hydraulic_mount.py (SI units), step X = X_free
_MOUNT = {
    "A_r": 3.0e-3,
    "C1": 4.0e-11,
    "C2": 4.0e-9,
    "I_i": 6.0e6,
    "R_i": 9.0e7,
    "p_vac": 9.0e4,
    "C1_vac": 2.0e-9,
    "I_d": 1.5e5,
    "R_d": 1.5e7,
    "V_gap": 7.5e-7,
    "X": -2.4e-3,
}


def _mount_spec(name: str, decoupler: str, vacuum: bool, ramp: bool) -> SystemSpec:
    """The He-Singh mount family as text: fixed or free decoupler, with or without vacuum, an
    ideal step or a ramp (see :func:`mount_system`)."""
    free = decoupler == "free"
    disp = "x" if ramp else "X"
    vol = "(V_i + V_d)" if free else "V_i"
    u = f"(A_r*{disp} - {vol})"
    p1 = (
        f"({u}/C1 + (1/C1_vac - 1/C1)*({u} + p_vac*C1)*Heaviside(-p_vac*C1 - {u}))"
        if vacuum
        else f"{u}/C1"
    )
    p2 = f"{vol}/C2"
    eqs = [f"I_i*V_i'' + R_i*V_i' + {p2} - {p1} = 0"]
    if free:
        eqs.append(f"I_d*V_d'' + R_d*V_d' + {p2} - {p1} = 0")
    if ramp:
        # the displacement as a first-order state x, driven by the clock state: the ramp is
        # then a step element on the clock, and the vacuum knee (which moves with x during the
        # ramp) stays a fixed surface of the state
        eqs += ["clock' = 1", "x' = X/rise*Heaviside(rise - clock)"]
    text = " ".join(eqs)
    defaults = {
        k: v
        for k, v in {**_MOUNT, "X": _MOUNT["X"] if free else -3.7e-3, "rise": 8.0e-3}.items()
        if re.search(rf"\b{k}\b", text)
    }
    outputs = {"p1": p1, "p2": p2, "flow": "V_i' + V_d'" if free else "V_i'"}
    if free:
        outputs["plate"] = "V_d - V_gap"
        defaults["V_gap"] = _MOUNT["V_gap"]
    stops = (("decoupler", "V_d", "0", "2*V_gap"),) if free else ()
    what = (
        ("free decoupler V_d on stops 0..2 V_gap" if free else "fixed decoupler")
        + (", top-chamber vacuum below -p_vac" if vacuum else ", no vacuum (linear)")
        + (", displacement ramped to X in rise seconds" if ramp else ", ideal step X")
    )
    return _spec(name, eqs, defaults, f"He-Singh hydraulic mount: {what}", stops, outputs)


def mount_system(
    *, decoupler: str = "free", vacuum: bool = True, rise: float = 0.0, **params: Any
) -> System:
    r"""The He–Singh hydraulic mount after a step of the displacement to ``X``.

    The lumped equations of ``derivations/hydraulic_mount.py`` (``simulate_mount``), in the
    track and decoupler volumes ``V_i``, ``V_d`` (SI units):
    ``I_i V_i'' + R_i V_i' = p_1 - p_2``, with a free decoupler also
    ``I_d V_d'' + R_d V_d' = p_1 - p_2`` and the stop ``0 <= V_d <= 2 V_gap`` (plastic; the
    plate starts on the top stop, ``V_d = 0``), with a fixed one ``V_d = 0``;
    ``p_2 = (V_i + V_d)/C_2`` and, with the top chamber's compression
    ``u = A_r x - V_i - V_d``, ``p_1 = u/C_1`` or, with ``vacuum``, the PWL pressure with the
    knee ``u_k = -p_v C_1`` of the builtin ``mount``.

    Parameters
    ----------
    decoupler : {"free", "fixed"}
    vacuum : bool
        Top-chamber vacuum (compliance ``C_1v`` below ``p_1 = -p_v``); without it the fixed
        decoupler model is linear (its step response has a closed form).
    rise : float
        ``0``: ideal step ``x = X`` (states ``V``, ``V'``). ``> 0``: the displacement ramps from
        0 to ``X`` in ``rise`` seconds; two first-order states are added, the clock ``clock``
        (``clock' = 1``) and the displacement ``x`` (``x' = (X/rise) H(rise - clock)``), so the
        ramped system is still autonomous and piecewise affine. Start from ``clock = x = 0``.
    **params
        Parameter values overriding the defaults (``Mount()`` of the script; ``X`` is
        ``-3.7e-3`` for the fixed and ``-2.4e-3`` for the free decoupler).

    Returns
    -------
    System
        Named ``mount``, ``mount_fixed``, ``mount_fixed_linear`` (ideal steps; the builtins of
        those names) or ``mount_free_linear`` / ``..._ramp``. Named outputs (``p1``, ``p2``,
        ``flow``, ``plate``): ``mount_outputs(...)``.

    Raises
    ------
    ParameterError
        For a decoupler other than "free"/"fixed", a non-boolean ``vacuum`` or a ``rise`` that
        is not a finite number ``>= 0``.
    """
    return _mount_family(decoupler, vacuum, rise).build(
        **({"rise": rise} if rise > 0 else {}), **params
    )


def mount_outputs(*, decoupler: str = "free", vacuum: bool = True, rise: float = 0.0):
    """The named outputs of :func:`mount_system` (name -> expression text): ``p1``, ``p2``
    (chamber pressures), ``flow`` (total flow out of the top chamber, zero at the extrema of
    ``p_1``) and, with a free decoupler, ``plate`` (plate position as a volume, ``-V_gap``
    on the top stop)."""
    return _mount_family(decoupler, vacuum, rise).outputs


def _mount_family(decoupler: Any, vacuum: Any, rise: Any) -> SystemSpec:
    if decoupler not in ("free", "fixed"):
        raise ParameterError(f"decoupler = {decoupler!r}: expected 'free' or 'fixed'")
    checks.flag(vacuum, "vacuum")
    if (
        isinstance(rise, bool)
        or not isinstance(rise, int | float)
        or not math.isfinite(rise)
        or rise < 0
    ):
        raise ParameterError(f"rise = {rise!r}: expected a finite number >= 0 (seconds)")
    name = {
        ("free", True): "mount",
        ("free", False): "mount_free_linear",
        ("fixed", True): "mount_fixed",
        ("fixed", False): "mount_fixed_linear",
    }[decoupler, vacuum] + ("_ramp" if rise > 0 else "")
    return _mount_spec(name, decoupler, vacuum, rise > 0)


#: The builtin multi-coordinate systems, by name.
BUILTIN_SYSTEMS: Mapping[str, SystemSpec] = MappingProxyType(
    {
        s.name: s
        for s in (
            _spec(
                "nsd2",
                (
                    "x1'' + mu1*x1' + mu2*(x1' - x2') + k*x1 + (1 - k)*((x1 - 1)*Heaviside(x1 - 1)"
                    " + (x1 + 1)*Heaviside(-x1 - 1)) + k2*(x1 - x2) = F*cos(Omega*t)",
                    "m2*x2'' + mu2*(x2' - x1') + k2*(x2 - x1) = 0",
                ),
                {"k": -0.5, "mu1": 0.05, "mu2": 0.02, "k2": 1.0, "m2": 1.0, "F": 2.0, "Omega": 1.0},
                "2-DOF structure with the nsd device (stiffness k for |x1| < 1, 1 outside) "
                "between ground and the first mass",
            ),
            _spec(
                "impact_pair",
                (
                    f"x1'' + mu*x1' + x1 + r*{_B} = F*cos(Omega*t)",
                    f"m2*x2'' + mu2*(x2' - x1') - r*{_B} = 0",
                ),
                {"mu": 0.05, "mu2": 0.01, "r": 20.0, "d": 0.5, "m2": 0.2, "F": 0.5, "Omega": 1.0},
                "impact damper / backlash pair: mass m2 in a two-sided clearance d of the "
                "primary mass, contact stiffness r",
            ),
            _spec(
                "mount",
                (
                    f"I_i*V_i'' + R_i*V_i' + {_P2} - {_P1} = 0",
                    f"I_d*V_d'' + R_d*V_d' + {_P2} - {_P1} = 0",
                ),
                dict(_MOUNT),
                "He-Singh hydraulic mount after a step X: inertia track V_i, free decoupler "
                "V_d on stops 0..2 V_gap, top-chamber vacuum below -p_vac",
                (("decoupler", "V_d", "0", "2*V_gap"),),
                {"p1": _P1, "p2": _P2, "flow": "V_i' + V_d'", "plate": "V_d - V_gap"},
            ),
            _mount_spec("mount_fixed", "fixed", vacuum=True, ramp=False),
            _mount_spec("mount_fixed_linear", "fixed", vacuum=False, ramp=False),
            _spec(
                "mount_linear",
                (
                    "C1*p1' + q_i + q_d = -A_r*Xa*Omega*sin(Omega*t)",
                    "C2*p2' - q_i - q_d = 0",
                    "I_i*q_i' + R_i*q_i - p1 + p2 = 0",
                    "I_d*q_d' + R_d*q_d - p1 + p2 = 0",
                ),
                {
                    **{k: _MOUNT[k] for k in ("A_r", "C1", "C2", "I_i", "R_i", "I_d", "R_d")},
                    "Xa": 1.0e-4,
                    "Omega": 60.0,
                },
                "He-Singh mount, floating decoupler, first-order pressures/flows, harmonic "
                "displacement Xa cos(Omega t)",
            ),
            _spec(
                "belt",
                (
                    "m*x'' + c*x' + k*x + N*(mu_k + (mu_s - mu_k)*exp(-Abs(x' - v_b)/v_s))"
                    "*sign(x' - v_b) = 0",
                ),
                {
                    "m": 1.0,
                    "c": 0.0,
                    "k": 1.0,
                    "N": 1.0,
                    "mu_s": 0.4,
                    "mu_k": 0.25,
                    "v_s": 0.5,
                    "v_b": 0.2,
                },
                "mass on a moving belt with Stribeck friction (stick-slip limit cycle)",
            ),
            _spec(
                "drill_string",
                (
                    "J_r*phi_r'' + c_t*(phi_r' - phi_b') + k_t*(phi_r - phi_b) + c_r*phi_r' = T_m",
                    "J_b*phi_b'' + c_t*(phi_b' - phi_r') + k_t*(phi_b - phi_r) + c_b*phi_b'"
                    " + W_ob*R_b*(mu_c + (mu_s - mu_c)*exp(-gamma_b*Abs(phi_b')/nu_f))"
                    "*sign(phi_b') = 0",
                ),
                {
                    "J_r": 2122.0,
                    "J_b": 374.0,
                    "k_t": 473.0,
                    "c_t": 23.2,
                    "c_r": 425.0,
                    "c_b": 50.0,
                    "W_ob": 5.0e4,
                    "R_b": 0.155575,
                    "mu_c": 0.5,
                    "mu_s": 0.8,
                    "gamma_b": 0.9,
                    "nu_f": 1.0,
                    "T_m": 6000.0,
                },
                "2-DOF torsional drill string with Stribeck bit friction (stick-slip)",
            ),
        )
    }
)


def builtin_outputs(name: str) -> Mapping[str, str]:
    """The named outputs of a builtin system (name -> expression text; may be empty).

    Raises
    ------
    ModelError
        For an unknown name (the message lists the known ones).
    """
    return _builtin_spec(name).outputs


def _builtin_spec(name: str) -> SystemSpec:
    try:
        return BUILTIN_SYSTEMS[name]
    except KeyError:
        raise ModelError(
            f"unknown system {name!r}: expected one of {', '.join(BUILTIN_SYSTEMS)}"
        ) from None


def builtin_system(name: str, **params: Any) -> System:
    """A builtin system by name, defaults overridden by ``params``.

    Raises
    ------
    ModelError
        For an unknown name (the message lists the known ones).
    """
    return _builtin_spec(name).build(**params)
