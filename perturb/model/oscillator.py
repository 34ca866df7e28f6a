"""The :class:`Oscillator`: a single-degree-of-freedom equation of motion.

An oscillator is written ``x'' + g(x, x', t) = f(t)``. perturb reads it from a string (parsed
safely, see :mod:`perturb.model.parsing`) or from a SymPy expression, divides by the coefficient of
``x''`` and sorts the terms of ``g`` into the parts every later stage asks about:

========================  =========================================================
part                      example (Zou–Nagarajaiah, ``nsd``)
========================  =========================================================
``damping``               ``mu`` (the coefficient of terms exactly ``c*x'``)
``linear_stiffness``      ``k`` (the coefficient of ``x``)
``polynomial``            terms ``c*x**m`` with ``m = 0`` or ``m >= 2``
``nonsmooth``             ``(1-k)*((x-1)*Heaviside(x-1) + (x+1)*Heaviside(-x-1))``
``smooth``                other functions of ``x`` alone (``sin(x)`` of a pendulum)
``velocity``              other terms with ``x'`` (``-eps*(1-x**2)*x'``, ``sign(x')``)
``parametric``            terms with both ``t`` and ``x`` or ``x'`` (Mathieu)
========================  =========================================================

Terms with neither ``x`` nor ``x'`` are moved to the right-hand side and form the
:class:`Forcing`, which must be periodic: a constant plus harmonics ``F_j cos(w_j t + p_j)``
whose frequencies have rational ratios.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import sympy as sp

from perturb.errors import ModelError, ParameterError
from perturb.model.parsing import MAX_MAGNITUDE, MIN_MAGNITUDE, parse_equation, real_symbol
from perturb.model.pwl import PiecewiseLinear, is_nonsmooth, to_pwl
from perturb.printing import latex

__all__ = [
    "Harmonic",
    "Forcing",
    "Oscillator",
    "validate_parameter_value",
]

ParamValue = float | None


def validate_parameter_value(name: str, value: Any) -> float:
    """Return ``value`` as a float if it is a finite real number in range, else raise.

    The range is the parser's (:data:`perturb.model.parsing.MIN_MAGNITUDE` to
    :data:`perturb.model.parsing.MAX_MAGNITUDE`, or 0): a parameter of ``1e-320`` is a subnormal
    float
    that the numeric layer treats as 0, and one of ``1e308`` overflows as soon as it is squared.

    Raises
    ------
    ParameterError
        For booleans, strings, complex numbers, NaN and infinities, and magnitudes out of
        range; the message names the parameter and the value.
    """
    if isinstance(value, bool) or not isinstance(value, numbers.Real | sp.Basic):
        raise ParameterError(
            f"parameter {name!r} = {value!r} ({type(value).__name__}): "
            "expected a finite real number"
        )
    if isinstance(value, sp.Basic):
        if not value.is_number or value.is_real is False or value.has(sp.nan, sp.zoo):
            raise ParameterError(
                f"parameter {name!r} = {_short_repr(value)}: expected a finite real number"
            )
        value = complex(value)
        if value.imag != 0:
            raise ParameterError(f"parameter {name!r} = {value}: expected a real number")
        value = value.real
    try:
        value = float(value)
    except (OverflowError, TypeError, ValueError):  # a Python int beyond the float range
        raise ParameterError(
            f"parameter {name!r} = {_short_repr(value)}: expected a finite real number "
            f"of magnitude at most {MAX_MAGNITUDE:g}"
        ) from None
    if not math.isfinite(value):
        raise ParameterError(f"parameter {name!r} = {value}: expected a finite real number")
    if value != 0 and not MIN_MAGNITUDE <= abs(value) <= MAX_MAGNITUDE:
        raise ParameterError(
            f"parameter {name!r} = {value:g}: expected 0 or a magnitude from "
            f"{MIN_MAGNITUDE:g} to {MAX_MAGNITUDE:g}"
        )
    return value


def _short_repr(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


@dataclass(frozen=True)
class Harmonic:
    """One forcing term ``amplitude * cos(frequency * t + phase)``."""

    amplitude: sp.Expr
    frequency: sp.Expr
    phase: sp.Expr = sp.Integer(0)

    def expr(self, t: sp.Symbol) -> sp.Expr:
        return self.amplitude * sp.cos(self.frequency * t + self.phase)

    def __str__(self) -> str:
        return f"{self.amplitude}*cos({self.frequency}*t + {self.phase})"


@dataclass(frozen=True)
class Forcing:
    """A periodic forcing ``constant + sum_j harmonics[j]``."""

    harmonics: tuple[Harmonic, ...] = ()
    constant: sp.Expr = sp.Integer(0)

    @property
    def is_zero(self) -> bool:
        return not self.harmonics and self.constant == 0

    @property
    def frequencies(self) -> tuple[sp.Expr, ...]:
        return tuple(h.frequency for h in self.harmonics)

    @property
    def base_frequency(self) -> sp.Expr | None:
        """The fundamental frequency (the largest ``w`` with every frequency an integer
        multiple of it), or None for a constant forcing."""
        if not self.harmonics:
            return None
        ref = self.harmonics[0].frequency
        ratios = [sp.nsimplify(h.frequency / ref) for h in self.harmonics]
        dens = [sp.fraction(r)[1] for r in ratios]
        nums = [sp.fraction(r)[0] for r in ratios]
        lcm_den = sp.ilcm(*dens) if len(dens) > 1 else dens[0]
        gcd_num = sp.igcd(*nums) if len(nums) > 1 else nums[0]
        return sp.simplify(ref * gcd_num / lcm_den)

    def expr(self, t: sp.Symbol) -> sp.Expr:
        return self.constant + sp.Add(*(h.expr(t) for h in self.harmonics))


def _empty_params() -> Mapping[str, ParamValue]:
    return MappingProxyType({})


@dataclass(frozen=True)
class Oscillator:
    """A single-degree-of-freedom oscillator ``x'' + g(x, x', t) = f(t)``.

    Build one with :meth:`Oscillator.parse`, :meth:`Oscillator.from_sympy` or
    :func:`builtin_model`; change parameter values with :meth:`with_params`. Instances are
    immutable.

    Attributes
    ----------
    x, v, t
        The state symbol, its derivative (the symbol ``x'``) and time.
    g
        Everything but ``x''`` on the left, normalised so that ``x''`` has coefficient 1.
    forcing
        The periodic right-hand side.
    params
        Parameter name -> float value, or None for a parameter left free.
    damping, linear_stiffness, polynomial, nonsmooth, smooth, velocity, parametric
        The parts of ``g`` (see the module docstring); ``g`` is
        ``damping*v + linear_stiffness*x + polynomial + nonsmooth + smooth + velocity
        + parametric``.
    name
        A short label (the builtin model's name, or ``"custom"``).
    """

    x: sp.Symbol
    v: sp.Symbol
    t: sp.Symbol
    g: sp.Expr
    forcing: Forcing
    params: Mapping[str, ParamValue] = field(default_factory=_empty_params)
    damping: sp.Expr = sp.Integer(0)
    linear_stiffness: sp.Expr = sp.Integer(0)
    polynomial: sp.Expr = sp.Integer(0)
    nonsmooth: sp.Expr = sp.Integer(0)
    smooth: sp.Expr = sp.Integer(0)
    velocity: sp.Expr = sp.Integer(0)
    parametric: sp.Expr = sp.Integer(0)
    name: str = "custom"
    source: str = ""

    # ---------------------------------------------------------------- construction --
    @classmethod
    def parse(
        cls,
        text: str,
        params: Mapping[str, Any] | None = None,
        *,
        time: str = "t",
        name: str = "custom",
    ) -> Oscillator:
        """Read an equation of motion from text.

        Parameters
        ----------
        text
            For example ``"x'' + mu*x' + k*x + (1-k)*((x-1)*Heaviside(x-1)
            + (x+1)*Heaviside(-x-1)) = F*cos(Omega*t)"``. Primes mark derivatives of the
            state variable (any name); a missing ``=`` means ``= 0``.
        params
            Values for some or all parameters; the others stay free (symbolic).
        time
            The name of the time variable in the forcing.
        name
            A label.

        Raises
        ------
        ParseError
            Malformed text (see :func:`perturb.model.parsing.parse_equation`).
        ModelError
            Text that parses but is not an oscillator (no ``x''``, ``x''`` entering
            nonlinearly, a forcing that is not periodic, ...).
        ParameterError
            Bad parameter values or names.
        """
        _check_name(time, "time")
        parsed = parse_equation(text)
        if parsed.state is None or parsed.derivative_order < 2:
            raise ModelError(
                f"no second derivative in {text!r}: expected an equation of motion of the form "
                "x'' + g(x, x') = f(t), with the state's second derivative written x''"
            )
        x = real_symbol(parsed.state)
        v = real_symbol(parsed.state + "'")
        a = real_symbol(parsed.state + "''")
        t = real_symbol(time)
        return cls._build(parsed.lhs - parsed.rhs, x, v, a, t, params, name, text)

    @classmethod
    def from_sympy(
        cls,
        equation: sp.Basic,
        x: sp.Basic | str = "x",
        t: sp.Basic | str = "t",
        params: Mapping[str, Any] | None = None,
        *,
        name: str = "custom",
    ) -> Oscillator:
        """Build an oscillator from a SymPy equation or expression (``expr = 0``).

        ``x`` may be an applied function ``x(t)`` (derivatives written with
        ``Derivative``/``.diff``) or a plain symbol, in which case the symbols named
        ``x'`` and ``x''`` stand for the derivatives.
        """
        if isinstance(equation, sp.Equality):
            expr = equation.lhs - equation.rhs
        elif isinstance(equation, sp.Expr):
            expr = equation
        else:
            raise ModelError(
                f"expected a SymPy Eq or Expr for the equation of motion, got "
                f"{type(equation).__name__}"
            )
        tname = t if isinstance(t, str) else str(t)
        _check_name(tname, "t")
        if isinstance(x, sp.core.function.AppliedUndef):
            xname = x.func.__name__
        elif isinstance(x, sp.core.function.UndefinedFunction):
            xname = x.__name__
        else:
            xname = str(x)
        _check_name(xname, "x")
        xs, vs, as_, ts = (
            real_symbol(xname),
            real_symbol(xname + "'"),
            real_symbol(xname + "''"),
            real_symbol(tname),
        )
        # Replace x(t) and its derivatives by the symbols perturb uses.
        reps: dict[sp.Basic, sp.Basic] = {}
        for d in expr.atoms(sp.Derivative):
            if d.expr.func.__name__ != xname:
                raise ModelError(f"derivative {d} is not of the state {xname!r}")
            order = sum(c for _, c in d.variable_count)
            if order > 2:
                raise ModelError(f"derivative {d} of order {order}: expected at most x''")
            reps[d] = vs if order == 1 else as_
        expr = expr.xreplace(reps)
        for f in expr.atoms(sp.core.function.AppliedUndef):
            if f.func.__name__ == xname:
                expr = expr.xreplace({f: xs})
            else:
                raise ModelError(f"unknown function {f} in the equation: expected only {xname}(t)")
        # Plain symbols of any assumptions are mapped onto perturb's real symbols, by name.
        expr = expr.xreplace({s: real_symbol(s.name) for s in expr.free_symbols})
        if not expr.has(as_):
            raise ModelError(
                f"no second derivative of {xname} in {equation}: expected x'' + g(x, x') = f(t)"
            )
        return cls._build(expr, xs, vs, as_, ts, params, name, str(equation))

    @classmethod
    def _build(
        cls,
        expr: sp.Expr,
        x: sp.Symbol,
        v: sp.Symbol,
        a: sp.Symbol,
        t: sp.Symbol,
        params: Mapping[str, Any] | None,
        name: str,
        source: str,
    ) -> Oscillator:
        # Only terms holding x'' are expanded (m*(x'' + x) must give its mass); the others
        # keep the grouping the user wrote.
        expr = sp.Add(
            *(sp.expand(term) if term.has(a) else term for term in sp.Add.make_args(expr))
        )
        inertia = expr.coeff(a)
        rest = expr - inertia * a
        if rest.has(a) or inertia.has(a):
            raise ModelError(
                f"x'' enters {source!r} nonlinearly: expected an equation linear in x''"
            )
        if inertia.has(x, v, t):
            raise ModelError(
                f"the coefficient of x'' is {inertia}, which depends on the state or time: "
                "expected a constant mass"
            )
        if inertia == 0:
            raise ModelError(f"the coefficient of x'' in {source!r} is zero")
        g_terms: list[sp.Expr] = []
        f_terms: list[sp.Expr] = []
        for term in sp.Add.make_args(_regroup(expr - inertia * a, x, v)):
            term = term / inertia
            (g_terms if term.has(x, v) else f_terms).append(term)
        forcing = _forcing(-sp.Add(*f_terms), t, source)
        parts = _split(g_terms, x, v, t, source)
        g = sp.Add(*g_terms)
        symbols = (g.free_symbols | forcing.expr(t).free_symbols) - {x, v, t}
        names = sorted(s.name for s in symbols)
        values: dict[str, ParamValue] = {n: None for n in names}
        osc = cls(
            x=x,
            v=v,
            t=t,
            g=g,
            forcing=forcing,
            params=MappingProxyType(values),
            name=name,
            source=source,
            **parts,
        )
        return osc.with_params(**dict(params or {})) if params else osc

    # ----------------------------------------------------------------- parameters --
    def with_params(self, values: Mapping[str, Any] | None = None, **kw: Any) -> Oscillator:
        """A copy with some parameter values set (None frees a parameter again).

        Raises
        ------
        ParameterError
            For an unknown parameter name or a value that is not a finite real number.
        """
        updates = dict(values or {}, **kw)
        new = dict(self.params)
        for key, value in updates.items():
            key = str(key)
            if key not in new:
                known = ", ".join(new) or "none"
                raise ParameterError(
                    f"unknown parameter {key!r} for model {self.name!r}: expected one of {known}"
                )
            new[key] = None if value is None else validate_parameter_value(key, value)
        return _replace(self, params=MappingProxyType(new))

    @property
    def parameters(self) -> tuple[sp.Symbol, ...]:
        """All parameter symbols, sorted by name."""
        return tuple(real_symbol(n) for n in self.params)

    @property
    def free_parameters(self) -> tuple[str, ...]:
        """Names of the parameters that have no value."""
        return tuple(n for n, val in self.params.items() if val is None)

    def substitutions(self) -> dict[sp.Symbol, sp.Float]:
        """Parameter symbol -> value, for the parameters that have one."""
        return {real_symbol(n): sp.Float(val) for n, val in self.params.items() if val is not None}

    def require_values(self, *names: str) -> dict[str, float]:
        """The values of ``names`` (all parameters when none given); raise if any is free."""
        names = names or tuple(self.params)
        missing = [n for n in names if self.params.get(n) is None]
        if missing:
            raise ParameterError(
                f"model {self.name!r} needs values for {', '.join(missing)}: pass them as "
                "params or --param NAME=VALUE"
            )
        return {n: float(self.params[n]) for n in names}  # type: ignore[arg-type]

    # ---------------------------------------------------------------- properties --
    @property
    def equation(self) -> sp.Equality:
        """``x'' + g = f(t)`` as a SymPy equation (unevaluated)."""
        a = real_symbol(self.x.name + "''")
        return sp.Eq(a + self.g, self.forcing.expr(self.t), evaluate=False)

    @property
    def restoring_force(self) -> sp.Expr:
        """The part of ``g`` that depends on ``x`` alone."""
        return self.linear_stiffness * self.x + self.polynomial + self.nonsmooth + self.smooth

    @property
    def is_autonomous(self) -> bool:
        return not self.forcing.harmonics and self.parametric == 0

    @property
    def is_piecewise_linear(self) -> bool:
        """True when the restoring force is piecewise linear in ``x`` (the nonsmooth part
        plus at most linear polynomial terms) and nothing else is nonlinear."""
        if self.smooth != 0 or self.velocity != 0 or self.parametric != 0:
            return False
        if self.polynomial != 0 and sp.Poly(self.polynomial, self.x).degree() > 0:
            return False
        return True

    @property
    def is_smooth(self) -> bool:
        return not is_nonsmooth(self.g)

    def piecewise_linear(self) -> PiecewiseLinear:
        """The restoring force in canonical piecewise-linear form.

        Parameter values set on the oscillator are substituted first, so breakpoints that
        depend on parameters are ordered by their values.

        Raises
        ------
        ModelError
            If the restoring force is not piecewise linear (or other nonlinear parts exist).
        """
        if not self.is_piecewise_linear:
            raise ModelError(
                f"model {self.name!r} is not piecewise linear: its equation has "
                + ", ".join(
                    f"{label} terms {val}"
                    for label, val in (
                        ("polynomial", self.polynomial),
                        ("smooth", self.smooth),
                        ("velocity", self.velocity),
                        ("parametric", self.parametric),
                    )
                    if val != 0
                )
            )
        values = {n: val for n, val in self.params.items() if val is not None}
        return to_pwl(self.restoring_force, self.x, values=values or None)

    def __str__(self) -> str:
        lhs = f"{self.x.name}'' + {sp.sstr(self.g)}"
        rhs = sp.sstr(self.forcing.expr(self.t))
        vals = ", ".join(
            f"{n}={'free' if val is None else f'{val:g}'}" for n, val in self.params.items()
        )
        return f"{self.name}: {lhs} = {rhs}" + (f"  [{vals}]" if vals else "")

    def _repr_latex_(self) -> str:
        return f"$\\displaystyle {latex(self.equation)}$"


def _check_name(name: str, what: str) -> None:
    """Names of the state and of time end up in generated code (``lambdify``): plain names
    only."""
    if not isinstance(name, str) or len(name) > 100 or not name.isidentifier():
        raise ModelError(
            f"{what} = {str(name)[:40]!r}: expected a plain name (letters, digits, _) for the "
            "variable"
        )


def _replace(obj: Oscillator, **changes: Any) -> Oscillator:
    from dataclasses import replace

    return replace(obj, **changes)


def _regroup(expr: sp.Expr, x: sp.Symbol, v: sp.Symbol) -> sp.Expr:
    """Split top-level products that mix state-free and state-dependent terms.

    ``c*(x + 1)`` has a forcing part ``c`` hidden in it; it is expanded. A product whose every
    expanded term depends on the state (``(1-k)*((x-1)*H(x-1) + ...)``) is kept as written,
    so the parts read the way the user wrote them.
    """
    out = []
    for term in sp.Add.make_args(expr):
        if term.has(x, v):
            pieces = sp.Add.make_args(sp.expand(term))
            if all(p.has(x, v) for p in pieces) and _one_kind(pieces, x, v):
                out.append(term)
            else:
                out.extend(pieces)
        else:
            out.append(term)
    return sp.Add(*out)


def _one_kind(pieces: tuple[sp.Expr, ...], x: sp.Symbol, v: sp.Symbol) -> bool:
    kinds = {_kind(p, x, v, None) for p in pieces}
    return len(kinds) == 1 and "linear" not in kinds and "damping" not in kinds


def _kind(term: sp.Expr, x: sp.Symbol, v: sp.Symbol, t: sp.Symbol | None) -> str:
    if t is not None and term.has(t):
        return "parametric"
    if term.has(v):
        coeff = sp.diff(term, v)
        if not coeff.has(x, v) and not is_nonsmooth(term):
            return "damping"
        return "velocity"
    if is_nonsmooth(term):
        return "nonsmooth"
    if term.is_polynomial(x):
        deg = sp.Poly(term, x).degree()
        return "linear" if deg == 1 else "polynomial"
    return "smooth"


def _split(
    terms: list[sp.Expr], x: sp.Symbol, v: sp.Symbol, t: sp.Symbol, source: str
) -> dict[str, sp.Expr]:
    parts: dict[str, list[sp.Expr]] = {
        k: []
        for k in (
            "damping",
            "linear",
            "polynomial",
            "nonsmooth",
            "smooth",
            "velocity",
            "parametric",
        )
    }
    for term in terms:
        kind = _kind(term, x, v, t)
        if kind == "polynomial" or kind == "linear":
            # A polynomial term may mix degrees, c*(x + x**3): split by degree.
            for (deg,), coeff in sp.Poly(term, x).terms():
                parts["linear" if deg == 1 else "polynomial"].append(coeff * x**deg)
            continue
        if kind == "parametric":
            _check_parametric(term, t, source)
        parts[kind].append(term)
    damping = sp.Add(*parts["damping"])
    linear = sp.Add(*parts["linear"])
    return {
        "damping": sp.simplify(sp.diff(damping, v)) if damping != 0 else sp.Integer(0),
        "linear_stiffness": sp.simplify(sp.diff(linear, x)) if linear != 0 else sp.Integer(0),
        "polynomial": sp.Add(*parts["polynomial"]),
        "nonsmooth": sp.Add(*parts["nonsmooth"]),
        "smooth": sp.Add(*parts["smooth"]),
        "velocity": sp.Add(*parts["velocity"]),
        "parametric": sp.Add(*parts["parametric"]),
    }


def _periodic_product(expr: sp.Expr, t: sp.Symbol) -> bool:
    """True when ``expr`` is a product of positive integer powers of ``cos(w*t + p)`` and
    ``sin(w*t + p)`` (and factors free of ``t``) with commensurate frequencies: periodic,
    decided without multiplying the product out. False means "not shown", not "not periodic"."""
    freqs: list[sp.Expr] = []
    for factor in sp.Mul.make_args(expr):
        base, exponent = factor.as_base_exp()
        if not base.has(t):
            continue
        if not (isinstance(base, sp.sin | sp.cos) and exponent.is_Integer and exponent > 0):
            return False
        arg = sp.expand(base.args[0])
        w = arg.coeff(t)
        if w == 0 or w.has(t) or sp.expand(arg - w * t).has(t):
            return False
        freqs.append(w)
    for w in freqs[1:]:
        ratio = w / freqs[0]
        if not ratio.is_Rational and not sp.simplify(ratio).is_Rational:
            return False
    return True


def _check_parametric(term: sp.Expr, t: sp.Symbol, source: str) -> None:
    _, tpart = term.as_independent(t, as_Add=False)
    if _periodic_product(tpart, t):  # the common case, without expanding the product
        return
    try:
        _forcing(tpart, t, source)
    except ModelError:
        raise ModelError(
            f"the time-dependent coefficient {tpart} in {source!r} is not periodic: expected "
            "sums of cos(w*t + p) and sin(w*t + p)"
        ) from None


def _harmonic_of(term: sp.Expr, t: sp.Symbol, source: str) -> Harmonic | None:
    """``term`` as ``c*cos(w*t + p)``, or None if it is free of ``t``."""
    if not term.has(t):
        return None
    coeff, trig = term.as_independent(t, as_Add=False)
    if isinstance(trig, sp.cos | sp.sin):
        arg = sp.expand(trig.args[0])
        w = arg.coeff(t)
        p = sp.expand(arg - w * t)
        if w != 0 and not w.has(t) and not p.has(t):
            if w.is_number and w < 0:  # cos(-w t + p) = cos(w t - p)
                w, p = -w, -p
                if isinstance(trig, sp.sin):
                    coeff = -coeff
            shift = sp.Integer(0) if isinstance(trig, sp.cos) else -sp.pi / 2
            phase = p + shift
            # numbers need no simplification (and it costs milliseconds per harmonic)
            return Harmonic(coeff, w, phase if phase.is_number else sp.simplify(phase))
    raise ModelError(
        f"forcing term {term} in {source!r} is not periodic: expected a constant plus terms "
        f"F*cos(w*{t} + p) or F*sin(w*{t} + p) with w, p free of {t}"
    )


#: Most terms a product of sines and cosines in the forcing (or in a parametric coefficient)
#: may expand to. Products are multiplied out as complex exponentials one factor at a time,
#: merging equal frequencies after each step (see ``_spectrum``), so commensurate forcings stay
#: small
#: (``cos(t)*cos(2*t)*...*cos(20*t)`` has 105 harmonics, found in 0.2 s); incommensurate ones
#: double with every factor and are refused here instead of expanding to 2**49 terms.
MAX_FORCING_TERMS = 200


_Spectrum = dict[sp.Expr, sp.Expr]  # angle -> coefficient of exp(i*angle)


def _too_many_harmonics(expr: sp.Expr) -> ModelError:
    shown = sp.sstr(expr)
    shown = shown if len(shown) <= 80 else shown[:77] + "..."
    return ModelError(
        f"the products of sines and cosines in {shown} expand to more than "
        f"{MAX_FORCING_TERMS} harmonics: expected a forcing with fewer, commensurate factors"
    )


def _times(p: _Spectrum, q: _Spectrum, whole: sp.Expr) -> _Spectrum:
    """The spectrum of a product: angles add, coefficients multiply; equal angles merge."""
    out: _Spectrum = {}
    for a, c in p.items():
        for b, d in q.items():
            key = a + b
            out[key] = out.get(key, 0) + c * d
    # expanded at every step: products of (p + q*I) would otherwise nest ever deeper
    out = {a: c if c.is_Rational else sp.expand(c) for a, c in out.items()}
    out = {a: c for a, c in out.items() if c != 0}
    if len(out) > 2 * MAX_FORCING_TERMS:
        raise _too_many_harmonics(whole)
    return out


def _spectrum(expr: sp.Expr, t: sp.Symbol, whole: sp.Expr) -> _Spectrum | None:
    """``expr`` as a sum of ``c * exp(i*angle)``, built along its tree (sums, products and
    powers of sines and cosines) without expanding it first: ``(cos(t) + sin(3*t) +
    cos(7*t))**20`` is 231 products of 20 factors once expanded, but its spectrum is 20
    multiplications of at most 141 angles. None when ``expr`` is not of that form (the caller
    then reports what is wrong with it)."""
    if not expr.has(t):
        return {sp.Integer(0): expr}
    if isinstance(expr, sp.cos | sp.sin):
        a = expr.args[0]
        if isinstance(expr, sp.cos):
            return {a: sp.Rational(1, 2), -a: sp.Rational(1, 2)}
        return {a: -sp.I / 2, -a: sp.I / 2}
    if expr.is_Add or expr.is_Mul:
        parts = [_spectrum(arg, t, whole) for arg in expr.args]
        if any(part is None for part in parts):
            return None
        out: _Spectrum = dict(parts[0])  # type: ignore[arg-type]
        for part in parts[1:]:
            if expr.is_Mul:
                out = _times(out, part, whole)  # type: ignore[arg-type]
            else:
                for a, c in part.items():  # type: ignore[union-attr]
                    out[a] = out.get(a, 0) + c
                if len(out) > 2 * MAX_FORCING_TERMS:
                    raise _too_many_harmonics(whole)
        return out
    if expr.is_Pow and expr.exp.is_Integer and 0 < expr.exp <= 2 * MAX_FORCING_TERMS:
        base = _spectrum(expr.base, t, whole)
        if base is None:
            return None
        out = base
        for _ in range(int(expr.exp) - 1):  # at most MAX_EXPONENT from the parser
            out = _times(out, base, whole)
        return out
    return None


def _real_form(spectrum: _Spectrum) -> sp.Expr:
    """Back from exponentials: ``c E(a) + c' E(-a) = (c + c') cos(a) + i (c - c') sin(a)``."""
    total: list[sp.Expr] = []
    done: set[sp.Expr] = set()
    for a, c in spectrum.items():
        if a in done:
            continue
        if a == 0:
            total.append(sp.expand(c))
            done.add(a)
            continue
        c2 = spectrum.get(-a, sp.Integer(0))
        done.update((a, -a))
        total.append(sp.expand(c + c2) * sp.cos(a) + sp.expand(sp.I * (c - c2)) * sp.sin(a))
    return sp.expand(sp.Add(*total))


def _forcing(expr: sp.Expr, t: sp.Symbol, source: str) -> Forcing:
    # Products and powers of harmonics (cos(t)*sin(2t), cos(t)**2) are periodic too:
    # turn them into sums first, as exponentials (no 2**factors blow-up, no expand first).
    spectrum = _spectrum(expr, t, expr) if expr.has(sp.sin, sp.cos) else None
    expr = _real_form(spectrum) if spectrum is not None else sp.expand(expr)
    harmonics: list[Harmonic] = []
    constant: sp.Expr = sp.Integer(0)
    for term in sp.Add.make_args(expr):
        h = _harmonic_of(term, t, source)
        if h is None:
            constant += term
        else:
            harmonics.append(h)
    if len(harmonics) > 1:
        ref = harmonics[0].frequency
        for h in harmonics[1:]:
            ratio = h.frequency / ref
            if not ratio.is_Rational:  # simplify only when the quotient is not plainly rational
                ratio = sp.simplify(ratio)
            if not ratio.is_Rational:
                raise ModelError(
                    f"forcing in {source!r} is not periodic: frequencies {ref} and "
                    f"{h.frequency} have ratio {ratio}, expected a rational number "
                    f"(write the second frequency as a multiple of the first)"
                )
    return Forcing(tuple(harmonics), constant)
