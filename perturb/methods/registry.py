"""The method registry: one :class:`MethodSpec` per method name, the one home of method choice.

Every front end asks this table — :func:`perturb.solve.frequency_response`, the command line
(``perturb frc`` / ``perturb derive``), scenes, grid sweeps, the benchmark and the automatic
choice (:mod:`perturb.auto`) — so a method is named, aliased, validated and dispatched the
same way everywhere. A spec holds:

- ``name``, ``aliases`` and a one-line ``title``;
- ``kind``: ``"symbolic"`` (an engine of :mod:`perturb.methods` derives an
  :class:`~perturb.approximation.Approximation`, which a numeric tracer then solves),
  ``"numeric"`` (a solver working on the oscillator directly: numeric harmonic balance),
  ``"reference"`` (exact periodic orbits) or ``"auto"`` (the cheapest-method ladder);
- ``target``: the function that does the work, as a ``"module:function"`` string resolved
  lazily by :meth:`MethodSpec.resolve` (with :mod:`importlib`), so that importing the registry
  imports neither SymPy nor SciPy, and the dispatcher can reach :mod:`perturb.auto` without
  importing it (auto imports solve, never the reverse);
- ``options``: every option the method accepts, each with its validator and where it goes
  (``"derive"``: the symbolic engine; ``"solve"``: the solver or tracer). An option not listed
  is refused by :meth:`MethodSpec.validate` with a message naming what the method accepts;
- ``capabilities``: ``"frequencies"`` (solutions at exactly listed frequencies),
  ``"all_branches"``, ``"stability"``, ``"latex"`` (a derivation with a LaTeX document);
- :meth:`MethodSpec.applies`: whether the method's ansatz fits a model
  (:mod:`perturb.methods.applicability`).

Names
-----
``"hb"`` is numeric multi-harmonic balance everywhere. The symbolic multi-harmonic engine
(:func:`perturb.methods.harmonic_balance.harmonic_balance`) is ``"shb"`` — *symbolic* harmonic
balance: it derives closed-form balance equations for a chosen harmonic set (``harmonics=(1,
3)``, ``bias=True``), a different product from the numeric solver's curve with ``harmonics=H``
harmonics, so it gets its own name rather than a meaning of ``"hb"`` that depends on the caller.

Limits
------
:data:`ORDER_LIMITS`, :data:`MAX_HARMONICS`, :data:`MAX_POINTS` and :data:`MAX_FREQUENCIES`
bound the work a request may ask for (measurements in :mod:`perturb.solve` and
:mod:`perturb.methods.applicability`); :func:`check_order`, :func:`check_harmonics` and
:func:`check_points` enforce them with messages naming the value and the limit.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

from perturb import checks
from perturb.errors import ModelError, ParameterError
from perturb.methods.limits import ORDER_LIMITS

__all__ = [
    "MethodSpec",
    "Option",
    "REGISTRY",
    "ALIASES",
    "KINDS",
    "CAPABILITIES",
    "ORDER_LIMITS",
    "MAX_HARMONICS",
    "MAX_ORDER",
    "MAX_POINTS",
    "MAX_FREQUENCIES",
    "spec",
    "names",
    "symbolic_names",
    "check_order",
    "check_harmonics",
    "check_points",
    "check_rtol",
]

#: Largest number of harmonics of numeric harmonic balance (time grows as ``H**3``; the
#: measurements are in :mod:`perturb.solve`).
MAX_HARMONICS = 255
#: Largest expansion order of any symbolic method.
MAX_ORDER = max(ORDER_LIMITS[m] for m in ("lp", "mlp", "ms"))
#: Largest number of points of a traced curve.
MAX_POINTS = 100_000
#: Largest number of listed frequencies (``frequencies=``; each one is a solve).
MAX_FREQUENCIES = 10_000

KINDS = ("symbolic", "numeric", "reference", "auto")
CAPABILITIES = ("frequencies", "all_branches", "stability", "latex")


# --------------------------------------------------------------------------------------------
# validators: (value, what) -> value
# --------------------------------------------------------------------------------------------
def check_harmonics(harmonics: Any, name: str = "harmonics") -> int:
    """``harmonics`` as an int in ``1..MAX_HARMONICS``.

    Raises
    ------
    ParameterError
        Naming the value and the limit.
    """
    why = "time grows as harmonics**3: 50 s for one branch at 255"
    return checks.whole(harmonics, name, 1, MAX_HARMONICS, why)


def check_order(order: Any, name: str = "order", method: str | None = None) -> int:
    """``order`` as an int from 1 to the method's limit (:data:`ORDER_LIMITS`), or to
    :data:`MAX_ORDER` for a method without one.

    Raises
    ------
    ParameterError
        Naming the value and the limit.
    """
    method = ALIASES.get(method, method) if method is not None else None
    expansion = method in ("lp", "mlp", "ms")
    limit = ORDER_LIMITS[method] if expansion else MAX_ORDER
    what = f"the largest order of {method!r}" if expansion else "symbolic work"
    return checks.whole(order, name, 1, limit, f"{what}: symbolic work grows ~4x per order")


def check_points(points: Any, name: str = "points") -> int:
    """``points`` as an int in ``2..MAX_POINTS``.

    Raises
    ------
    ParameterError
        Naming the value and the limit.
    """
    return checks.whole(points, name, 2, MAX_POINTS, "curve resolution")


def check_rtol(rtol: Any, name: str = "rtol") -> float:
    """``rtol`` as a float in the open interval ``(0, 1)``.

    Raises
    ------
    ParameterError
        Naming the bad value.
    """
    try:
        value = float(rtol)
    except (TypeError, ValueError):
        value = float("nan")
    if isinstance(rtol, bool) or not (0.0 < value < 1.0):
        raise ParameterError(f"{name} = {rtol!r}: expected a relative tolerance in (0, 1)")
    return value


def _flag(value: Any, name: str) -> bool:
    return checks.flag(value, name)


def _any(value: Any, name: str) -> Any:
    """Checked by the function that receives it (its own message names the value)."""
    return value


def _harmonic_set(value: Any, name: str) -> tuple:
    """The harmonic set of symbolic HB: a non-empty sequence (ints, fractions, strings like
    ``"1/3"``); the engine checks each member and :data:`ORDER_LIMITS` ``["hb"]``."""
    if isinstance(value, str | bytes) or not hasattr(value, "__len__") or len(value) == 0:
        raise ParameterError(
            f"{name} = {value!r}: expected a non-empty sequence of harmonics, e.g. (1, 3) "
            "(symbolic 'shb' takes a harmonic set; numeric 'hb' takes a count)"
        )
    if len(value) > ORDER_LIMITS["hb"]:
        raise ParameterError(
            f"{name}: {len(value)} harmonics, expected at most {ORDER_LIMITS['hb']} "
            "(the derivation grows too fast beyond it)"
        )
    return tuple(value)


# --------------------------------------------------------------------------------------------
# specs
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Option:
    """One option a method accepts.

    Attributes
    ----------
    name
        The keyword.
    check
        ``check(value, what) -> value``: the validated value, or :class:`ParameterError`.
    stage
        ``"derive"`` (passed to the symbolic engine) or ``"solve"`` (to the solver/tracer).
    help
        One line for messages and ``--help``.
    """

    name: str
    check: Callable[[Any, str], Any] = _any
    stage: str = "solve"
    help: str = ""


def _options(*opts: Option) -> Mapping[str, Option]:
    return MappingProxyType({o.name: o for o in opts})


@dataclass(frozen=True)
class MethodSpec:
    """One method: what it is called, what it takes, what it can do, where it lives.

    Attributes
    ----------
    name
        The one name (``"hb1"``, ``"hb"``, ``"exact"``, ...).
    kind
        One of :data:`KINDS`.
    target
        ``"module:function"``: the symbolic engine (kind ``"symbolic"``) or the solver that
        does the work (:mod:`perturb.solve` adds the seeds of :mod:`perturb.seeds` to the
        numeric and exact solvers, and answers at listed frequencies).
    title
        One line in words.
    aliases
        Other names accepted for it (``"mms"`` for ``"ms"``).
    options
        Name -> :class:`Option`, every option accepted.
    capabilities
        A subset of :data:`CAPABILITIES`.
    centred
        For a zero-mean ansatz, the keywords of
        :func:`perturb.methods.applicability.require_centred` (``polynomial``, ``load``);
        ``None`` when the method applies to off-centre orbits too.
    """

    name: str
    kind: str
    target: str
    title: str
    aliases: tuple[str, ...] = ()
    options: Mapping[str, Option] = field(default_factory=lambda: MappingProxyType({}))
    capabilities: frozenset[str] = frozenset()
    centred: Mapping[str, bool] | None = None

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"MethodSpec {self.name!r}: kind {self.kind!r} not in {KINDS}")
        unknown = set(self.capabilities) - set(CAPABILITIES)
        if unknown:
            raise ValueError(f"MethodSpec {self.name!r}: unknown capabilities {unknown}")

    @property
    def order_limit(self) -> int | None:
        """The largest ``order`` accepted, ``None`` without an order option."""
        if "order" not in self.options:
            return None
        return ORDER_LIMITS.get(self.name, MAX_ORDER)

    def resolve(self) -> Callable[..., Any]:
        """The function named by :attr:`target`, imported now."""
        module, _, attr = self.target.partition(":")
        return getattr(importlib.import_module(module), attr)

    def validate(
        self, options: Mapping[str, Any], prefix: str = "", stage: str | None = None
    ) -> dict[str, Any]:
        """``options`` checked: every name accepted by this method, every value within its
        limits.

        Parameters
        ----------
        options
            Name -> value; ``None`` values are left out (a front end's "not given").
        prefix
            Put before each name in messages (``"--"`` for the command line).
        stage
            Accept only the options of this stage (``"derive"``: a derivation alone).

        Raises
        ------
        ParameterError
            For an option the method does not take (naming it and listing what the method
            accepts) or a value beyond its limits.
        """
        out: dict[str, Any] = {}
        takes = {k: o for k, o in self.options.items() if stage is None or o.stage == stage}
        for key, value in options.items():
            if value is None:
                continue
            opt = takes.get(key)
            if opt is None:
                accepts = ", ".join(takes) or "no options"
                raise ParameterError(
                    f"{prefix}{key} = {value!r}: method {self.name!r} takes no {key} "
                    f"(it accepts: {accepts})" + _hint(self.name, key)
                )
            if key == "order":
                out[key] = check_order(value, f"{prefix}{key}", self.name)
            else:
                out[key] = opt.check(value, f"{prefix}{key}")
        return out

    def split(self, options: Mapping[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
        """Validated ``options`` split into (derive options, solve options)."""
        valid = self.validate(options)
        derive = {k: v for k, v in valid.items() if self.options[k].stage == "derive"}
        solve = {k: v for k, v in valid.items() if self.options[k].stage != "derive"}
        return derive, solve

    def applies(self, oscillator: Any) -> bool:
        """Whether the method's ansatz fits ``oscillator`` (a cheap check of the orbit's
        centring, :func:`perturb.methods.applicability.require_centred`; the engine may still
        refuse a model for a reason of its own, e.g. several forcing harmonics)."""
        if self.centred is None:
            return True
        from perturb.methods.applicability import require_centred

        try:
            require_centred(oscillator, self.name, **self.centred)
        except ModelError:
            return False
        return True


def _hint(method: str, key: str) -> str:
    if key == "harmonics" and method not in ("hb", "shb"):
        return " (numeric harmonic balance takes a number of harmonics: method 'hb')"
    if key == "order" and method in ("hb", "hb1", "shb"):
        return " (an expansion order belongs to 'mlp', 'ms' and 'lp')"
    return ""


# option groups -------------------------------------------------------------------------------
_POINTS = Option("points", check_points, help="points of an amplitude-parametrised curve")
_STABILITY = Option("stability", help="stability test ('hill', 'slow_flow', 'none', ...)")
_AMPLITUDE_RANGE = Option("amplitude_range", help="(low, high) amplitudes searched")
#: The tracers of approximations: amplitude parametrisation
#: (:func:`perturb.numeric.amplitude.approximation_response`) and residual continuation
#: (:func:`perturb.numeric.residual.residual_response`, options below).
RESIDUAL_OPTIONS = (
    "seed_frequencies",
    "seed_amplitudes",
    "seed_phases",
    "ds_max",
    "refine",
    "max_correction",
)
_TRACE = (_POINTS, _STABILITY, _AMPLITUDE_RANGE, *(Option(n) for n in RESIDUAL_OPTIONS))
_ORDER = Option("order", stage="derive", help="expansion order")
_SERIES = Option(
    "harmonics", check_harmonics, stage="derive", help="harmonics of the Fourier series"
)
_GEN = Option("generating_frequency", stage="derive", help="frequency of the generating solution")
_SYMBOLIC_CAPS = frozenset({"frequencies", "stability", "latex"})

_HB_OPTIONS = (
    Option("harmonics", check_harmonics, help="number of harmonics H (default 15)"),
    Option("all_branches", _flag, help="every branch (default True)"),
    *(
        Option(n)
        for n in (
            "m",
            "odd_only",
            "projection",
            "samples",
            "stability",
            "start",
            "direction",
            "ds_max",
            "max_points",
            "tol",
            "seeds",
            "seeds_per_branch",
            "branch_points",
            "mirror",
            "max_branches",
        )
    ),
)
_EXACT_OPTIONS = tuple(
    Option(n)
    for n in (
        "seeds",
        "approximation",
        "approximation_seeds",
        "sweep_points",
        "transient_periods",
        "options",
        "ds_max",
        "ds_min",
        "tol",
        "max_points",
        "branch_points",
        "period_doubling",
        "symmetry",
        "closed_form",
        "max_branches",
        "max_periods",
        "max_seconds",
        "progress",
        "workers",
    )
)
_AUTO_OPTIONS = (
    Option("rtol", check_rtol, help="relative amplitude tolerance in (0, 1), default 1e-3"),
    Option("spots", help="spot-check frequencies"),
    Option("n_spots", help="number of spot-check frequencies"),
    _POINTS,
    Option("ladder"),
    Option("log"),
    Option("max_extra_spots"),
)

_SPECS = (
    MethodSpec(
        "hb1",
        "symbolic",
        "perturb.methods.harmonic_balance:single_harmonic_balance",
        "single-harmonic balance (zero-mean, odd forces)",
        options=_options(*_TRACE),
        capabilities=_SYMBOLIC_CAPS,
        centred=MappingProxyType({"polynomial": False}),
    ),
    MethodSpec(
        "shb",
        "symbolic",
        "perturb.methods.harmonic_balance:harmonic_balance",
        "symbolic harmonic balance over a harmonic set, harmonics=(1, 3), bias=True",
        options=_options(
            Option("harmonics", _harmonic_set, stage="derive", help="harmonic set, e.g. (1, 3)"),
            Option("bias", _flag, stage="derive", help="a mean term (off-centre orbits)"),
            *_TRACE,
        ),
        capabilities=_SYMBOLIC_CAPS,
        centred=None,  # bias=True answers off-centre orbits
    ),
    MethodSpec(
        "kb",
        "symbolic",
        "perturb.methods.averaging:krylov_bogoliubov",
        "Krylov-Bogoliubov averaging with describing functions",
        aliases=("avg",),
        options=_options(_GEN, *_TRACE),
        capabilities=_SYMBOLIC_CAPS,
        centred=MappingProxyType({}),
    ),
    MethodSpec(
        "vdp",
        "symbolic",
        "perturb.methods.averaging:van_der_pol_averaging",
        "van der Pol averaging",
        options=_options(_GEN, *_TRACE),
        capabilities=_SYMBOLIC_CAPS,
        centred=MappingProxyType({}),
    ),
    MethodSpec(
        "ms",
        "symbolic",
        "perturb.methods.multiple_scales:multiple_scales",
        "multiple scales, order N",
        aliases=("mms",),
        options=_options(
            _ORDER,
            *(
                Option(n, stage="derive")
                for n in ("resonance", "epsilon", "detuning", "hard_forcing")
            ),
            *_TRACE,
        ),
        capabilities=_SYMBOLIC_CAPS,
        centred=MappingProxyType({}),
    ),
    MethodSpec(
        "lp",
        "symbolic",
        "perturb.methods.lindstedt:lindstedt_poincare",
        "Lindstedt-Poincare, order N (free conservative oscillators)",
        options=_options(
            _ORDER,
            *(Option(n, stage="derive") for n in ("amplitude", "scaling", "omega0")),
            _SERIES,
            *_TRACE,
        ),
        capabilities=_SYMBOLIC_CAPS,
        centred=MappingProxyType({"load": True}),
    ),
    MethodSpec(
        "mlp",
        "symbolic",
        "perturb.methods.modified_lindstedt:modified_lindstedt",
        "modified Lindstedt-Poincare, order N",
        options=_options(
            _ORDER,
            *(Option(n, stage="derive") for n in ("amplitude", "omega0")),
            _SERIES,
            *_TRACE,
        ),
        capabilities=_SYMBOLIC_CAPS,
        centred=MappingProxyType({}),
    ),
    MethodSpec(
        "hb",
        "numeric",
        "perturb.numeric.harmonic_balance:harmonic_balance_response",
        "numeric harmonic balance, --harmonics H (exact Galerkin projection for PWL forces)",
        options=_options(*_HB_OPTIONS),
        capabilities=frozenset({"frequencies", "all_branches", "stability"}),
    ),
    MethodSpec(
        "exact",
        "reference",
        "perturb.simulate.exact_response:exact_frequency_response",
        "continuation of exact periodic orbits (shooting)",
        options=_options(*_EXACT_OPTIONS),
        capabilities=frozenset({"frequencies", "all_branches", "stability"}),
    ),
    MethodSpec(
        "auto",
        "auto",
        "perturb.auto:auto_frequency_response",
        "the cheapest method that meets rtol (default 1e-3) at exact spot checks",
        options=_options(*_AUTO_OPTIONS),
        capabilities=frozenset({"frequencies", "stability"}),
    ),
)

#: Name -> spec, in the order of the command line's help (symbolic methods first).
REGISTRY: Mapping[str, MethodSpec] = MappingProxyType({s.name: s for s in _SPECS})
#: Alias -> name.
ALIASES: Mapping[str, str] = MappingProxyType({a: s.name for s in _SPECS for a in s.aliases})


def names(kind: str | None = None) -> tuple[str, ...]:
    """The method names (of one ``kind``), in registry order."""
    return tuple(n for n, s in REGISTRY.items() if kind is None or s.kind == kind)


def symbolic_names() -> tuple[str, ...]:
    """The names of the symbolic engines (those of :data:`perturb.methods.METHODS`)."""
    return names("symbolic")


def spec(method: Any, what: str = "method") -> MethodSpec:
    """The spec of ``method`` (a name or an alias).

    Raises
    ------
    ParameterError
        For anything else, listing the names and aliases.
    """
    if isinstance(method, str):
        found = REGISTRY.get(ALIASES.get(method, method))
        if found is not None:
            return found
    listed = ", ".join(REGISTRY)
    aliases = ", ".join(f"{a} = {n}" for a, n in ALIASES.items())
    hint = ""
    if isinstance(method, str) and method.startswith("hb"):
        hint = " ('hb' is numeric harmonic balance; symbolic harmonic balance is 'shb')"
    raise ParameterError(f"{what} {method!r}: expected one of {listed} (aliases {aliases}){hint}")
