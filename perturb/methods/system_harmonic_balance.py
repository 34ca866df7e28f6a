r"""Single-harmonic balance (describing functions) for systems of several coordinates.

The system (:class:`~perturb.model.system.System`)

.. math::

    M q'' + D p' + C q' + K q + E p + \sum_e w_e\, f_e(s_e) = F_0 + F_c \cos\Omega t
        + F_s \sin\Omega t, \qquad s_e = c_e\cdot y,\quad y = (q, q', p),

is balanced on the ansatz of one harmonic per coordinate and first-order state (and a bias
where the forces are not odd):

.. math::

    z_k(\tau) = \bar a_k + a_k \cos\tau + b_k \sin\tau, \qquad \tau = \Omega t .

Each element's signal is then itself one harmonic,
:math:`s_e = \sigma_e + S_c \cos\tau + S_s\sin\tau = \sigma_e + S_e\cos(\tau - \varphi_e)`, with

.. math::

    S_c = \alpha\cdot a + \Omega\,\beta\cdot b,\quad S_s = \alpha\cdot b - \Omega\,\beta\cdot a,
    \quad \sigma_e = \alpha\cdot\bar a,\quad S_e = \sqrt{S_c^2 + S_s^2},
    \quad \tan\varphi_e = S_s/S_c,

(``alpha`` the position and state part of ``c_e``, ``beta`` its velocity part). With
:math:`\psi = \tau - \varphi_e` the element's force is the SDOF case,
:math:`f_e(\sigma + S\cos\psi) = m_e(S, \sigma) + N_e(S, \sigma)\, S\cos\psi + \ldots`, where
:math:`N_e = a_1/S` is the describing function (``a_1`` the first Fourier coefficient in closed
form from :mod:`perturb.fourier.symbols`, ``theta = arccos((d - sigma)/S)`` for a switching
point ``d``) and :math:`m_e = a_0/2` its mean. Rotating back by :math:`\varphi_e`,
:math:`S\cos\psi = S_c\cos\tau + S_s\sin\tau`, so the first harmonic of the force is
:math:`N_e (S_c \cos\tau + S_s\sin\tau)`: a memoryless element is a real gain on its own
signal. Distributed by :math:`w_e`, the balance of the mean, cosine and sine terms reads

.. math::

    (K - \Omega^2 M) a + \Omega C b + E a_p + \Omega D b_p + \textstyle\sum_e w_e N_e S_{c,e}
        &= F_c,\\
    (K - \Omega^2 M) b - \Omega C a + E b_p - \Omega D a_p + \textstyle\sum_e w_e N_e S_{s,e}
        &= F_s,\\
    K \bar a + E \bar a_p + \textstyle\sum_e w_e m_e &= F_0 .

:func:`system_single_harmonic_balance` returns these residuals (SymPy, the coefficient
functions by name so that the numeric layer evaluates them with the stable forms of
:data:`perturb.fourier.symbols.NUMERIC_IMPLEMENTATIONS`), the describing functions used (also
in their textbook closed forms), and a LaTeX derivation. Solving the residuals is the numeric
layer's work; this module never imports it.

Why not :class:`~perturb.approximation.Approximation`: that contract holds one
:class:`~perturb.model.oscillator.Oscillator`, one scalar ``waveform`` and one ``amplitude``
symbol (the amplitude parametrisation, ``frequency_polynomial`` and ``phase_from`` of the
numeric layer are all SDOF). An n-coordinate result needs the system, one waveform per
coordinate, the unknowns grouped by coordinate and harmonic, and (unforced) a phase
condition; :class:`SystemHarmonicBalance` holds those.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import sympy as sp

from perturb.approximation import Step
from perturb.errors import FourierError, ModelError, NonsmoothError, PerturbError
from perturb.fourier.symbols import closed_form, series_coefficient
from perturb.fourier.trig import fold_mirror_angles
from perturb.fourier.trig import harmonics as trig_harmonics
from perturb.methods.applicability import is_odd
from perturb.model.oscillator import Oscillator
from perturb.model.parsing import real_symbol
from perturb.model.pwl import to_pwl
from perturb.model.system import S as ELEMENT_SYMBOL
from perturb.model.system import System
from perturb.printing import latex

__all__ = [
    "SystemDescribingFunction",
    "SystemHarmonicBalance",
    "system_single_harmonic_balance",
]

_SWITCHES = (sp.Heaviside, sp.Max, sp.Min, sp.Abs, sp.sign, sp.Piecewise)


@dataclass(frozen=True)
class SystemDescribingFunction:
    """The describing function of one element under the single-harmonic ansatz.

    Attributes
    ----------
    element
        The element's name in the system.
    function
        ``f(s)`` in the symbol :data:`perturb.model.system.S`.
    signal
        ``c . y`` in the state symbols.
    distribution
        ``w``: one entry per equation.
    amplitude_symbol, mean_symbol, phase_symbol
        ``S_e``, ``sigma_e``, ``phi_e`` as the derivation writes them.
    cos_part, sin_part, mean
        ``S_c``, ``S_s`` and ``sigma`` of the signal in the unknowns and the frequency.
    amplitude
        ``S_e = sqrt(S_c**2 + S_s**2)`` in the unknowns.
    gain
        ``N_e(S_e, sigma_e) = a_1 / S_e``, Fourier coefficient functions by name.
    gain_closed, definitions, domains
        ``N_e`` in its textbook theta-form, the angles' definitions and where that form holds.
    mean_force
        ``m_e(S_e, sigma_e) = a_0 / 2`` (zero when the balance has no bias).
    first_harmonic
        ``(N_e S_c, N_e S_s)``: the cosine and sine coefficients of the force in the unknowns.
    odd
        Whether ``f(-s) = -f(s)``.
    gain_at_rest
        ``lim N_e`` as ``S_e -> 0``: the slope ``f'(sigma_e)`` (in ``sigma_e``; jumps of ``f``
        dropped, they matter only when ``sigma_e`` sits on a jump). ``N_e = a_1/S_e`` is 0/0
        there, so a numeric layer that starts from rest uses this value.
    """

    element: str
    function: sp.Expr
    signal: sp.Expr
    distribution: tuple[sp.Expr, ...]
    amplitude_symbol: sp.Symbol
    mean_symbol: sp.Symbol
    phase_symbol: sp.Symbol
    cos_part: sp.Expr
    sin_part: sp.Expr
    mean: sp.Expr
    amplitude: sp.Expr
    gain: sp.Expr
    gain_closed: sp.Expr
    definitions: tuple[tuple[sp.Symbol, sp.Expr], ...]
    domains: tuple[sp.Basic, ...]
    mean_force: sp.Expr
    first_harmonic: tuple[sp.Expr, sp.Expr]
    odd: bool
    gain_at_rest: sp.Expr = sp.S.Zero

    def __str__(self) -> str:
        S, sig = self.amplitude_symbol, self.mean_symbol
        return (
            f"{self.element}: f(s) = {sp.sstr(self.function)}, s = {sp.sstr(self.signal)}; "
            f"N({S}, {sig}) = {sp.sstr(self.gain)}"
        )


@dataclass(frozen=True)
class SystemHarmonicBalance:
    """Single-harmonic balance of a :class:`~perturb.model.system.System` (immutable).

    Attributes
    ----------
    system
        The system balanced.
    method
        ``"hb1-system"``.
    coordinates
        Names of the balanced coordinates: second-order ones, then first-order states.
    biases, cosines, sines
        ``abar_k``, ``a_k``, ``b_k`` per coordinate (``biases`` empty without a bias).
    unknowns
        ``biases + cosines + sines``: the order of ``residuals``' blocks.
    frequency
        ``Omega`` (forced; a parameter to sweep) or ``omega`` (unforced: an unknown, with
        ``phase_condition``).
    residuals
        ``(mean equations, cosine equations, sine equations)`` flattened, one per coordinate in
        each block; ``residual == 0`` at a solution.
    labels
        What each residual balances (``"cos x1"``).
    parameters
        The other symbols of the residuals (system parameters); ``values`` their values.
    describing_functions
        One :class:`SystemDescribingFunction` per element.
    waveforms
        ``z_k(tau)`` per coordinate; ``tau = frequency * t``.
    forcing
        ``(F_0, F_c, F_s)``: the forcing's mean, cosine and sine vectors (equations order).
    phase_condition
        Unforced systems only: ``b_1`` (set it to zero: the time origin); else ``None``.
    steps, notes
        The derivation (titles, text, mathematics) and caveats.
    """

    system: System
    method: str
    options: Mapping[str, Any]
    coordinates: tuple[str, ...]
    biases: tuple[sp.Symbol, ...]
    cosines: tuple[sp.Symbol, ...]
    sines: tuple[sp.Symbol, ...]
    frequency: sp.Symbol
    residuals: tuple[sp.Expr, ...]
    labels: tuple[str, ...]
    parameters: tuple[sp.Symbol, ...]
    values: Mapping[str, float | None]
    describing_functions: tuple[SystemDescribingFunction, ...]
    waveforms: tuple[sp.Expr, ...]
    tau: sp.Symbol
    forcing: tuple[tuple[sp.Expr, ...], tuple[sp.Expr, ...], tuple[sp.Expr, ...]]
    phase_condition: sp.Expr | None = None
    steps: tuple[Step, ...] = ()
    notes: tuple[str, ...] = ()
    _latex: str = field(default="", repr=False, compare=False)

    @property
    def unknowns(self) -> tuple[sp.Symbol, ...]:
        return self.biases + self.cosines + self.sines

    @property
    def autonomous(self) -> bool:
        """True for an unforced system (the frequency is an unknown)."""
        return self.phase_condition is not None

    @property
    def arguments(self) -> tuple[sp.Symbol, ...]:
        """``unknowns + (frequency,) + parameters``: every symbol of the residuals, in the order
        a numeric layer passes them to ``sympy.lambdify`` (with
        :data:`perturb.fourier.symbols.NUMERIC_IMPLEMENTATIONS` first among its modules)."""
        return self.unknowns + (self.frequency,) + self.parameters

    @property
    def label(self) -> str:
        opts = ", ".join(f"{k}={v}" for k, v in self.options.items())
        return f"{self.method}({opts})"

    def jacobian(self, frequency: bool = False) -> sp.ImmutableMatrix:
        """``d residuals / d unknowns`` (and a last column ``d / d frequency`` when
        ``frequency``), exact: the coefficient functions differentiate in closed form (a ramp
        coefficient's derivative is a step coefficient, a step's a Dirac coefficient)."""
        wrt = self.unknowns + ((self.frequency,) if frequency else ())
        return sp.ImmutableMatrix(
            len(self.residuals), len(wrt), lambda i, j: sp.diff(self.residuals[i], wrt[j])
        )

    def latex(self) -> str:
        """The derivation as a LaTeX body (sections and displayed equations)."""
        return self._latex

    def latex_document(self) -> str:
        """A complete LaTeX document of the derivation (``pdflatex`` compiles it)."""
        return (
            "\\documentclass[11pt]{article}\n\\usepackage[margin=2cm]{geometry}\n"
            "\\usepackage{amsmath,amssymb}\n\\allowdisplaybreaks\n\\begin{document}\n"
            f"\\section*{{Single-harmonic balance of the system {_tex_text(self.system.name)}}}\n"
            f"{self._latex}\n\\end{{document}}\n"
        )

    def __str__(self) -> str:
        lines = [f"Single-harmonic balance ({self.label}) of system {self.system.name!r}"]
        lines.append("  unknowns: " + ", ".join(map(str, self.unknowns)))
        lines.append(f"  frequency: {self.frequency}" + (" (unknown)" if self.autonomous else ""))
        for name, wave in zip(self.coordinates, self.waveforms, strict=True):
            lines.append(f"  {name}({self.tau}) = {sp.sstr(wave)}")
        for df in self.describing_functions:
            lines.append("  " + str(df))
        for lab, r in zip(self.labels, self.residuals, strict=True):
            text = sp.sstr(r)
            if len(text) > 300:
                text = text[:297] + "..."
            lines.append(f"  [{lab}] 0 = {text}")
        if self.phase_condition is not None:
            lines.append(f"  phase condition: {self.phase_condition} = 0")
        lines += [f"  note: {n}" for n in self.notes]
        return "\n".join(lines)


# ----------------------------------------------------------------------------- helpers --
def _tex_text(text: str) -> str:
    out = []
    for ch in str(text):
        if ch in "&%$#_{}":
            out.append("\\" + ch)
        elif ch == "~":
            out.append("\\textasciitilde{}")
        elif ch == "^":
            out.append("\\textasciicircum{}")
        elif ch == "\\":
            out.append("\\textbackslash{}")
        else:
            out.append(ch)
    return "".join(out)


def _coordinate_tex(name: str, primes: int = 0) -> str:
    return latex(real_symbol(name)) + "'" * primes


def _column(entries: list[str]) -> str:
    return "\\begin{bmatrix}" + " \\\\ ".join(entries) + "\\end{bmatrix}"


def _sub(idx: int, count: int) -> str:
    """The subscript of element ``idx``: none when the system has one element."""
    return "" if count == 1 else f"_{{{idx}}}"


def _times(w: sp.Expr, text: str) -> str:
    """``w text`` in LaTeX without a factor 1 (and ``-text`` for -1)."""
    w = sp.sympify(w)
    if w == 1:
        return text
    if w == -1:
        return "-" + text
    tex = latex(w)
    return (f"\\left({tex}\\right)" if isinstance(w, sp.Add) else tex) + "\\, " + text


def _sum(terms: list[str]) -> str:
    out = ""
    for t in terms:
        out += t if not out else (" " + t if t.startswith("-") else " + " + t)
    return out.replace(" -", " - ") if out else "0"


def _function_tex(f: sp.Expr) -> str:
    """A piecewise-linear ``f(s)`` as cases on intervals (the form a paper prints); any other
    function as it is."""
    try:
        pwl = to_pwl(f, ELEMENT_SYMBOL)
    except (PerturbError, TypeError, ValueError):  # symbolic breakpoints: print f as it is
        return latex(f)
    s = latex(ELEMENT_SYMBOL)
    bps = list(pwl.breakpoints)
    rows = []
    for i, (k, c) in enumerate(zip(pwl.slopes, pwl.offsets, strict=True)):
        piece = latex(sp.expand(k * ELEMENT_SYMBOL + c))
        lo = latex(bps[i - 1]) + " \\le " if i > 0 else ""
        hi = " < " + latex(bps[i]) if i < len(bps) else ""
        rows.append(f"{piece} & {lo}{s}{hi}" if (lo or hi) else piece)
    return "\\begin{cases}" + " \\\\ ".join(rows) + "\\end{cases}"


def _slope(f: sp.Expr, at: sp.Expr) -> sp.Expr:
    """``f'(at)`` away from jumps: the derivative with its Dirac terms dropped."""
    d = sp.diff(f, ELEMENT_SYMBOL)
    d = d.replace(lambda e: isinstance(e, sp.DiracDelta), lambda e: sp.S.Zero)
    return (
        sp.simplify(d.xreplace({ELEMENT_SYMBOL: at}))
        if d.is_polynomial()
        else d.xreplace({ELEMENT_SYMBOL: at})
    )


def _matrix(mat: sp.MatrixBase) -> str:
    rows = [" & ".join(latex(v) for v in mat.row(i)) for i in range(mat.rows)]
    return "\\begin{bmatrix}" + " \\\\ ".join(rows) + "\\end{bmatrix}"


def _forcing(system: System) -> tuple[sp.Symbol | None, list[tuple[sp.Expr, sp.Expr, sp.Expr]]]:
    """The forcing frequency (a parameter symbol, or None when there is no forcing in time)
    and ``(F_0, F_c, F_s)`` per equation."""
    t = system.t
    rates: set[sp.Expr] = set()
    for entry in system.F:
        entry = sp.sympify(entry)
        for f in entry.atoms(sp.cos, sp.sin):
            if f.has(t):
                rates.add(sp.expand(f.args[0]).coeff(t))
        if entry.has(t) and not entry.atoms(sp.cos, sp.sin):
            raise ModelError(
                f"forcing {entry} of system {system.name!r}: expected constant and "
                f"cos/sin(Omega*{t}) terms"
            )
    if len(rates) > 1:
        raise ModelError(
            f"the forcing of system {system.name!r} has the frequencies "
            f"{sorted(map(str, rates))}: single-harmonic balance takes one forcing frequency; "
            "use numeric harmonic balance (perturb.numeric.system_balance)"
        )
    if not rates:
        parts = []
        for entry in system.F:
            entry = sp.sympify(entry)
            if entry.has(t):  # pragma: no cover - caught above
                raise ModelError(f"forcing {entry}: expected constant or harmonic terms")
            parts.append((entry, sp.S.Zero, sp.S.Zero))
        return None, parts
    (Omega,) = rates
    if not isinstance(Omega, sp.Symbol):
        raise ModelError(
            f"the forcing frequency of system {system.name!r} is {Omega}: expected a single "
            "parameter symbol (e.g. Omega) to sweep"
        )
    tau = real_symbol("tau")
    parts = []
    for i, entry in enumerate(system.F):
        comps = trig_harmonics(sp.expand(sp.sympify(entry).xreplace({t: tau / Omega})), tau)
        others = sorted(n for n in comps if n not in (0, 1))
        if others:
            raise ModelError(
                f"forcing {entry} in equation {i + 1} of system {system.name!r} has harmonics "
                f"{others} of {Omega}: single-harmonic balance takes the first harmonic only"
            )
        zero = (sp.S.Zero, sp.S.Zero)
        parts.append((comps.get(0, zero)[0], *comps.get(1, zero)))
    return Omega, parts


def _check_element(system: System, e, vals: Mapping[sp.Symbol, Any]) -> None:
    if e.kind == "stop":
        raise ModelError(
            f"element {e.name!r} of system {system.name!r} is a rigid stop: its impacts are no "
            "force, so it has no describing function; use the exact solvers (perturb.simulate)"
        )
    if e.combination is None:
        raise ModelError(
            f"element {e.name!r} of system {system.name!r} is a smooth term of several states "
            f"({e.function}): single-harmonic balance takes elements on one combination s = c.y; "
            "use numeric harmonic balance (AFT)"
        )
    comb = [sp.sympify(c) for c in e.combination]
    zero_sym = all(sp.simplify(c) == 0 for c in comb)
    zero_num = (
        not zero_sym
        and vals
        and all(sp.simplify(c.xreplace(vals)) == 0 for c in comb if not c.free_symbols - set(vals))
        and all(not (c.free_symbols - set(vals)) for c in comb)
    )
    if zero_sym or zero_num:
        raise ModelError(
            f"element {e.name!r} of system {system.name!r}: its combination "
            f"{tuple(e.combination)} is identically zero"
            + (" for the parameter values" if zero_num else "")
            + ", so its signal never changes; expected a nonzero combination of "
            f"{', '.join(system.state_names)}"
        )
    if vals:
        for atom in e.function.atoms(*_SWITCHES):
            if atom.has(ELEMENT_SYMBOL) and not atom.xreplace(vals).has(ELEMENT_SYMBOL):
                raise ModelError(
                    f"element {e.name!r} of system {system.name!r}: the switch {atom} is "
                    f"{atom.xreplace(vals)} for the parameter values, so its combination is "
                    "identically zero there and it never switches; expected a switch of a "
                    "nonzero combination of the states"
                )


# ------------------------------------------------------------------------------ method --
def system_single_harmonic_balance(
    system: System, *, bias: bool | None = None
) -> SystemHarmonicBalance:
    r"""Derive the single-harmonic balance equations of a system of several coordinates.

    Parameters
    ----------
    system
        ``M q'' + D p' + C q' + K q + E p + sum_e w_e f_e(c_e . y) = F(t)`` with ``F`` a
        constant plus one harmonic of a parameter frequency (``Omega``), or constant (unforced:
        the frequency becomes the unknown ``omega`` and ``b_1 = 0`` fixes the time origin).
        Elements: piecewise-linear (Heaviside, Max, Min, Abs, sign, Piecewise, friction laws
        such as ``sign(s - v_b)``) and polynomial functions of one combination ``s = c . y``,
        positions, velocities or first-order states.
    bias
        Add a constant ``abar_k`` to every coordinate and the mean balance. ``None``
        (default): exactly when an element is not odd or the forcing has a constant part.

    Returns
    -------
    SystemHarmonicBalance
        Residuals in the unknowns ``abar_k, a_k, b_k``, the frequency and the parameters;
        describing functions; derivation (``latex()``, ``latex_document()``).

    Raises
    ------
    ModelError
        For a rigid stop, a smooth element of several states, an element whose combination is
        identically zero (symbolically or for the parameter values), a force without
        closed-form Fourier coefficients (``exp``), a forcing with several frequencies or
        higher harmonics, or ``bias=False`` where an element is not odd or there is a static
        load.
    """
    if isinstance(system, Oscillator):
        system = System.from_oscillator(system)
    if not isinstance(system, System):
        raise ModelError(
            f"system = {system!r}: expected a perturb.model.system.System (or an Oscillator)"
        )
    n2, n1 = len(system.coordinates), len(system.first_order)
    names = (*system.coordinates, *system.first_order)
    m = n2 + n1
    values = {k: v for k, v in system.params.items() if v is not None}
    vals = {real_symbol(k): sp.Float(v) for k, v in values.items()}
    for e in system.elements:
        _check_element(system, e, vals)
    Omega, forcing = _forcing(system)
    autonomous = Omega is None
    if autonomous:
        Omega = real_symbol("omega" if "omega" not in system.params else "omega_r")
    F0 = [p[0] for p in forcing]
    Fc = [p[1] for p in forcing]
    Fs = [p[2] for p in forcing]
    odd = []
    for e in system.elements:
        try:
            odd.append(is_odd(e.function, (ELEMENT_SYMBOL,), vals))
        except (TypeError, ValueError):  # pragma: no cover - undecidable: be safe, use a bias
            odd.append(False)
    load = any(sp.simplify(f) != 0 for f in F0)
    need = load or not all(odd)
    if bias is None:
        bias = need
    elif not isinstance(bias, bool):
        raise ModelError(f"bias = {bias!r}: expected True, False or None (automatic)")
    elif not bias and need:
        reasons = []
        if load:
            reasons.append(f"a static load {[sp.sstr(f) for f in F0]}")
        if not all(odd):
            bad = [e.name for e, o in zip(system.elements, odd, strict=True) if not o]
            reasons.append(f"elements that are not odd ({', '.join(bad)})")
        why = " and ".join(reasons)
        raise ModelError(
            f"system {system.name!r} has {why}: its orbits have a mean; pass bias=True "
            "(or bias=None)"
        )
    tau = real_symbol("tau")
    a = tuple(real_symbol(f"a_{k + 1}") for k in range(m))
    b = tuple(real_symbol(f"b_{k + 1}") for k in range(m))
    abar = tuple(real_symbol(f"abar_{k + 1}") for k in range(m)) if bias else ()
    zero_bias = abar or tuple(sp.S.Zero for _ in range(m))

    # ---- describing functions, one per element
    single = len(system.elements) == 1
    dfs: list[SystemDescribingFunction] = []
    states = system.states
    for idx, e in enumerate(system.elements, 1):
        suffix = "" if single else f"_{idx}"
        S_sym = sp.Symbol(f"S{suffix}", positive=True)
        sig_sym = real_symbol(f"sigma{suffix}")
        phi_sym = real_symbol(f"varphi{suffix}")
        c = [sp.sympify(ci) for ci in e.combination]
        alpha = c[:n2] + c[2 * n2 :]  # positions and first-order states: z = (q, p)
        beta = c[n2 : 2 * n2]  # velocities of q
        Sc = sp.Add(*(al * ak for al, ak in zip(alpha, a, strict=True))) + Omega * sp.Add(
            *(be * bk for be, bk in zip(beta, b[:n2], strict=True))
        )
        Ss = sp.Add(*(al * bk for al, bk in zip(alpha, b, strict=True))) - Omega * sp.Add(
            *(be * ak for be, ak in zip(beta, a[:n2], strict=True))
        )
        sigma = sp.Add(*(al * ck for al, ck in zip(alpha, zero_bias, strict=True)))
        centre = sig_sym if bias else sp.S.Zero
        try:
            a1 = series_coefficient(e.function, ELEMENT_SYMBOL, 1, S_sym, centre, values=values)
            a0 = series_coefficient(e.function, ELEMENT_SYMBOL, 0, S_sym, centre, values=values)
        except (FourierError, NonsmoothError) as exc:
            raise ModelError(
                f"element {e.name!r} of system {system.name!r}: f(s) = {e.function} has no "
                f"closed-form describing function ({exc}); use numeric harmonic balance (AFT)"
            ) from None
        gain = sp.expand(a1 / S_sym)
        closed, definitions, domains = closed_form(gain, theta=f"theta{suffix}")
        # a symmetric force's two angles fold into one (theta_1 = pi - theta_2), as in hb1
        (closed,), definitions = fold_mirror_angles((closed,), definitions)
        if definitions and suffix and definitions[0][0].name == "theta":
            theta_e = sp.Symbol(f"theta{suffix}", positive=True)
            closed = closed.xreplace({definitions[0][0]: theta_e})
            definitions = ((theta_e, definitions[0][1]),)
        mean_force = sp.expand(a0 / 2) if bias else sp.S.Zero
        amp = sp.sqrt(Sc**2 + Ss**2)
        reps = {S_sym: amp, sig_sym: sigma}
        g = gain.xreplace(reps)
        dfs.append(
            SystemDescribingFunction(
                element=e.name,
                function=e.function,
                signal=sp.Add(*(ci * y for ci, y in zip(c, states, strict=True))),
                distribution=tuple(sp.sympify(w) for w in e.distribution),
                amplitude_symbol=S_sym,
                mean_symbol=sig_sym,
                phase_symbol=phi_sym,
                cos_part=Sc,
                sin_part=Ss,
                mean=sigma,
                amplitude=amp,
                gain=gain,
                gain_closed=closed,
                definitions=tuple(definitions),
                domains=tuple(domains),
                mean_force=mean_force,
                first_harmonic=(g * Sc, g * Ss),
                odd=odd[idx - 1],
                gain_at_rest=_slope(e.function, sig_sym if bias else sp.S.Zero),
            )
        )

    # ---- the balance
    M, C, K, D, E = system.M, system.C, system.K, system.D, system.E
    cos_eq, sin_eq, mean_eq = [], [], []
    shown_c, shown_s, shown_0 = [], [], []
    shown_syms = [_shown_symbols(k, len(dfs)) for k in range(1, len(dfs) + 1)]
    aq, ap, bq, bp = a[:n2], a[n2:], b[:n2], b[n2:]
    for i in range(m):
        lin_c = sp.Add(
            *((K[i, j] - Omega**2 * M[i, j]) * aq[j] + Omega * C[i, j] * bq[j] for j in range(n2)),
            *(E[i, j] * ap[j] + Omega * D[i, j] * bp[j] for j in range(n1)),
        )
        lin_s = sp.Add(
            *((K[i, j] - Omega**2 * M[i, j]) * bq[j] - Omega * C[i, j] * aq[j] for j in range(n2)),
            *(E[i, j] * bp[j] - Omega * D[i, j] * ap[j] for j in range(n1)),
        )
        nl_c = sp.Add(*(df.distribution[i] * df.first_harmonic[0] for df in dfs))
        nl_s = sp.Add(*(df.distribution[i] * df.first_harmonic[1] for df in dfs))
        cos_eq.append(lin_c + nl_c - Fc[i])
        ws = [df.distribution[i] for df in dfs]
        shown_c.append(
            (
                lin_c,
                sp.Add(*(w * N * Sc for w, (N, Sc, _, _) in zip(ws, shown_syms, strict=True))),
                Fc[i],
            )
        )
        shown_s.append(
            (
                lin_s,
                sp.Add(*(w * N * Ss for w, (N, _, Ss, _) in zip(ws, shown_syms, strict=True))),
                Fs[i],
            )
        )
        sin_eq.append(lin_s + nl_s - Fs[i])
        if bias:
            lin_0 = sp.Add(
                *(K[i, j] * abar[j] for j in range(n2)),
                *(E[i, j] * abar[n2 + j] for j in range(n1)),
            )
            nl_0 = sp.Add(
                *(
                    df.distribution[i]
                    * df.mean_force.xreplace(
                        {df.amplitude_symbol: df.amplitude, df.mean_symbol: df.mean}
                    )
                    for df in dfs
                )
            )
            mean_eq.append(lin_0 + nl_0 - F0[i])
            shown_0.append(
                (
                    lin_0,
                    sp.Add(*(w * mm for w, (_, _, _, mm) in zip(ws, shown_syms, strict=True))),
                    F0[i],
                )
            )
    residuals = tuple(mean_eq + cos_eq + sin_eq)
    labels = tuple(
        [f"mean {nm}" for nm in names] * bool(bias)
        + [f"cos {nm}" for nm in names]
        + [f"sin {nm}" for nm in names]
    )
    unknown_set = set(a) | set(b) | set(abar) | {Omega}
    params = sorted(
        set().union(*(r.free_symbols for r in residuals)) - unknown_set, key=sp.default_sort_key
    )
    stray = [p for p in params if p.name not in system.params]
    if stray:  # pragma: no cover - every symbol of a System is a parameter
        raise PerturbError(f"residual symbols {stray} are neither unknowns nor parameters")
    waveforms = tuple(
        zb + ak * sp.cos(tau) + bk * sp.sin(tau) for zb, ak, bk in zip(zero_bias, a, b, strict=True)
    )
    notes = []
    if dfs:
        notes.append(
            "the describing functions N_e = a_1(S_e)/S_e are written for S_e > 0; at S_e = 0 "
            "(an element at rest) the first harmonic N_e S_c, N_e S_s is zero and N_e tends "
            "to the slope f'(sigma_e) (gain_at_rest)"
        )
    if any(e.kind == "friction" for e in system.elements):
        notes.append(
            "friction elements enter through their describing function on slip; sticking "
            "phases (s = 0 held) are not represented by a single harmonic"
        )
    options = {"harmonics": 1, "bias": bool(bias)}
    order = [*abar, *a, *b]
    shown = [
        (lab, sp.collect(sp.expand(lin), order) + nl - f)
        for lab, (lin, nl, f) in zip(labels, shown_0 + shown_c + shown_s, strict=True)
    ]
    steps = _steps(system, Omega, dfs, a, b, abar, tau, shown)
    result = SystemHarmonicBalance(
        system=system,
        method="hb1-system",
        options=MappingProxyType(options),
        coordinates=names,
        biases=abar,
        cosines=a,
        sines=b,
        frequency=Omega,
        residuals=residuals,
        labels=labels,
        parameters=tuple(params),
        values=MappingProxyType(dict(system.params)),
        describing_functions=tuple(dfs),
        waveforms=waveforms,
        tau=tau,
        forcing=(tuple(F0), tuple(Fc), tuple(Fs)),
        phase_condition=b[0] if autonomous else None,
        steps=steps,
        notes=tuple(notes),
        _latex=_latex_body(system, Omega, autonomous, dfs, a, b, abar, forcing, bool(bias), shown),
    )
    return result


# ---------------------------------------------------------------------------- derivation --
def _steps(system, Omega, dfs, a, b, abar, tau, shown) -> tuple[Step, ...]:
    """The derivation as :class:`~perturb.approximation.Step` objects (plain SymPy)."""
    names = (*system.coordinates, *system.first_order)
    z = [real_symbol(nm) for nm in names]
    waves = [
        sp.Eq(zk, (abar[k] if abar else 0) + a[k] * sp.cos(tau) + b[k] * sp.sin(tau))
        for k, zk in enumerate(z)
    ]
    out = [
        Step("Ansatz", (*waves, sp.Eq(tau, Omega * system.t))),
    ]
    for df in dfs:
        S_, sig, phi = df.amplitude_symbol, df.mean_symbol, df.phase_symbol
        out.append(
            Step(
                f"Signal and describing function of {df.element}",
                (
                    sp.Eq(real_symbol("s"), df.signal),
                    sp.Eq(S_ * sp.cos(phi), df.cos_part),
                    sp.Eq(S_ * sp.sin(phi), df.sin_part),
                    sp.Eq(sig, df.mean),
                    sp.Eq(sp.Function("N")(S_, sig), df.gain),
                    sp.Eq(sp.Function("N")(S_, sig), df.gain_closed),
                    *(sp.Eq(s, v) for s, v in df.definitions),
                ),
            )
        )
    out.append(
        Step(
            "Balance of the " + ("mean, " if abar else "") + "cosine and sine terms",
            tuple(sp.Eq(sp.S.Zero, e, evaluate=False) for _, e in shown),
            "; ".join(lab for lab, _ in shown),
        )
    )
    return tuple(out)


def _latex_body(system, Omega, autonomous, dfs, a, b, abar, forcing, bias, shown) -> str:
    n2, n1 = len(system.coordinates), len(system.first_order)
    names = (*system.coordinates, *system.first_order)
    m = n2 + n1
    W = latex(Omega)
    t = latex(system.t)
    lines: list[str] = []
    add = lines.append
    q = [_coordinate_tex(c) for c in system.coordinates]
    p = [_coordinate_tex(c) for c in system.first_order]
    F0 = [f[0] for f in forcing]
    Fc = [f[1] for f in forcing]
    Fs = [f[2] for f in forcing]

    # 1. equations of motion
    add("\\subsection*{Equations of motion}")
    lhs = []
    if n2:
        lhs += [
            _matrix(system.M) + _column([x + "''" for x in q]),
            _matrix(system.C) + _column([x + "'" for x in q]),
            _matrix(system.K) + _column(q),
        ]
    if n1:
        lhs += [
            _matrix(system.D) + _column([x + "'" for x in p]),
            _matrix(system.E) + _column(p),
        ]
    nl = [
        f"{_column([latex(w) for w in df.distribution])} f{_sub(idx, len(dfs))}"
        f"\\!\\left(s{_sub(idx, len(dfs))}\\right)"
        for idx, df in enumerate(dfs, 1)
    ]
    rhs = _column([latex(sp.sympify(f)) for f in system.F])
    add("Written with matrices, the system reads")
    # three terms to a line: a 2x2 or 3x3 system fits the page width
    chunks = [lhs[i : i + 3] for i in range(0, len(lhs), 3)] + [
        nl[i : i + 3] for i in range(0, len(nl), 3)
    ]
    body = " \\\\\n&\\quad + ".join(" + ".join(c) for c in chunks if c)
    add(f"\\begin{{align*}}\n&{body} = {rhs},\n\\end{{align*}}")
    if dfs:
        add("with the nonlinear elements")
        for idx, df in enumerate(dfs, 1):
            sub = _sub(idx, len(dfs))
            add(
                f"\\[ s{sub} = {latex(df.signal)}, \\qquad f{sub}(s) = "
                f"{_function_tex(df.function)} \\]"
            )
        add(
            "(element "
            + ", ".join(f"{idx}: {_tex_text(df.element)}" for idx, df in enumerate(dfs, 1))
            + ")."
        )

    # 2. ansatz
    add("\\subsection*{Ansatz}")
    add(
        "One harmonic per coordinate"
        + (" and a bias" if bias else "")
        + (
            f"; the system is unforced, so the frequency ${W}$ is an unknown and $b_1 = 0$ "
            "fixes the time origin"
            if autonomous
            else f" at the forcing frequency ${W}$"
        )
        + ":"
    )
    add("\\begin{gather*}")
    rows = []
    for k, nm in enumerate(names):
        zb = f"{latex(abar[k])} + " if abar else ""
        rows.append(
            f"{_coordinate_tex(nm)} = {zb}{latex(a[k])}\\cos\\tau + {latex(b[k])}\\sin\\tau"
        )
    add(" \\\\\n".join(rows) + f", \\qquad \\tau = {W} {t}.")
    add("\\end{gather*}")

    # 3. describing functions
    names_of = [_display_names(idx, len(dfs)) for idx in range(1, len(dfs) + 1)]
    if dfs:
        add("\\subsection*{Describing functions}")
        add(
            "Under the ansatz each element's signal is one harmonic, "
            "$s = \\sigma + S_c\\cos\\tau + S_s\\sin\\tau = \\sigma + S\\cos(\\tau - \\varphi)$ "
            "with $S = \\sqrt{S_c^2 + S_s^2}$, $\\tan\\varphi = S_s/S_c$. With "
            "$\\psi = \\tau - \\varphi$ its force is the single-coordinate case, "
            "$f(\\sigma + S\\cos\\psi) = m(S, \\sigma) + N(S, \\sigma)\\, S\\cos\\psi + "
            "\\ldots$ (higher harmonics), where $N = a_1/S$ is the describing function and "
            "$m = a_0/2$ the mean; rotated back by $\\varphi$, "
            "$S\\cos\\psi = S_c\\cos\\tau + S_s\\sin\\tau$, so the first harmonic of the force "
            "is $N\\,(S_c\\cos\\tau + S_s\\sin\\tau)$: a real gain on the element's own signal."
            + (
                ""
                if bias
                else " The forces are odd and there is no static load: no bias, $\\sigma = 0$."
            )
        )
        for idx, df in enumerate(dfs, 1):
            nm = names_of[idx - 1]
            Sx, sx = latex(df.amplitude_symbol), latex(df.mean_symbol)
            if len(dfs) > 1:
                add(f"\\paragraph{{Element {idx} ({_tex_text(df.element)}).}}")
            add("\\begin{align*}")
            rows = [
                f"{nm['Sc']} &= {Sx}\\cos {latex(df.phase_symbol)} = {latex(df.cos_part)}",
                f"{nm['Ss']} &= {Sx}\\sin {latex(df.phase_symbol)} = {latex(df.sin_part)}",
            ]
            if bias:
                rows.append(f"{sx} &= {latex(df.mean)}")
            arg = f"{Sx}, {sx}" if bias else Sx
            rows.append(f"{nm['N']}({arg}) &= {latex(df.gain)}")
            if df.definitions or sp.expand(df.gain_closed - df.gain) != 0:
                rows.append(f"&= {latex(df.gain_closed)}")
            for s_, v in df.definitions:
                rows.append(f"{latex(s_)} &= {latex(v)}")
            if bias:
                rows.append(f"{nm['m']}({arg}) &= {latex(df.mean_force)}")
            add(" \\\\\n".join(rows))
            add("\\end{align*}")
            if df.domains:
                add(
                    "The closed form holds where the signal crosses every switching point ("
                    + ", ".join(f"${latex(d)}$" for d in df.domains)
                    + "); in the other regimes the coefficients are exactly zero or linear. "
                    "$a^H_n$ and $a^R_n$ are the Fourier coefficients of $H(s - d)$ and "
                    "$(s - d)H(s - d)$ along $s = S\\cos\\psi + \\sigma$ (evaluated in the "
                    "stable closed forms of the Fourier engine)."
                )

    # 4. balance in matrix form
    add("\\subsection*{Balance of the harmonics}")

    def nl(i: int, key: str) -> str:
        terms = [
            _times(df.distribution[i], nm[key])
            for df, nm in zip(dfs, names_of, strict=True)
            if df.distribution[i] != 0
        ]
        return _sum(terms)

    Nc = [nl(i, "NSc") for i in range(m)]
    Ns = [nl(i, "NSs") for i in range(m)]
    N0 = [nl(i, "m") for i in range(m)]
    vec = lambda xs: _column([latex(x) for x in xs])  # noqa: E731 - local shorthand
    add("Collecting the terms in $\\cos\\tau$ and $\\sin\\tau$" + (" and the mean" if bias else ""))
    eqs = [
        "\\left(K - \\Omega^{2} M\\right) a + \\Omega\\, C\\, b"
        + (" + E\\, a_p + \\Omega\\, D\\, b_p" if n1 else "")
        + " + N_c(a, b) = F_c",
        "\\left(K - \\Omega^{2} M\\right) b - \\Omega\\, C\\, a"
        + (" + E\\, b_p - \\Omega\\, D\\, a_p" if n1 else "")
        + " + N_s(a, b) = F_s",
    ]
    if bias:
        eqs.insert(0, "K \\bar a" + (" + E\\, \\bar a_p" if n1 else "") + " + N_0 = F_0")
    add("\\begin{gather*}\n" + " \\\\\n".join(eqs).replace("\\Omega", W) + "\n\\end{gather*}")
    add("reads")
    Zq = system.K - Omega**2 * system.M
    rows = []
    for label, first, second, sign, nlv, fv in (
        ("\\cos\\tau", a, b, "+", Nc, Fc),
        ("\\sin\\tau", b, a, "-", Ns, Fs),
    ):
        parts = []
        if n2:
            parts.append(f"{_matrix(Zq)}{vec(first[:n2])}")
            parts.append(f" {sign} {W}{_matrix(system.C)}{vec(second[:n2])}")
        if n1:
            parts.append(f" + {_matrix(system.E)}{vec(first[n2:])}")
            parts.append(f" {sign} {W}{_matrix(system.D)}{vec(second[n2:])}")
        if dfs:
            parts.append(f" + {_column(nlv)}")
        rows.append(f"{label}:&\\quad " + "".join(parts).lstrip(" +") + f" = {vec(fv)}")
    if bias:
        parts = []
        if n2:
            parts.append(f"{_matrix(system.K)}{vec(abar[:n2])}")
        if n1:
            parts.append(f" + {_matrix(system.E)}{vec(abar[n2:])}")
        if dfs:
            parts.append(f" + {_column(N0)}")
        rows.insert(0, "\\text{mean}:&\\quad " + "".join(parts).lstrip(" +") + f" = {vec(F0)}")
    add("\\begin{align*}\n" + " \\\\\n".join(rows) + "\n\\end{align*}")
    if dfs:
        add(
            "Each $N$ is evaluated at its element's own amplitude $S$"
            + (" and mean $\\sigma$" if bias else "")
            + ". Written out, coordinate by coordinate and harmonic by harmonic:"
        )
    else:
        add("Written out, coordinate by coordinate and harmonic by harmonic:")
    add("\\begin{align*}")
    add(" \\\\\n".join(f"0 &= {latex(e)} && \\text{{({_tex_text(lab)})}}" for lab, e in shown))
    add("\\end{align*}")
    count = (3 if bias else 2) * m
    if autonomous:
        add(
            f"With $b_1 = 0$ the {count} equations determine the {count - 1} remaining "
            f"amplitudes and the frequency ${W}$."
        )
    else:
        add(
            f"These are {count} equations in the {count} unknowns"
            + (" $\\bar a_k$," if bias else "")
            + f" $a_k$, $b_k$ at each frequency ${W}$."
        )
    return "\n".join(lines)


def _display_names(idx: int, count: int) -> dict[str, str]:
    """LaTeX names of element ``idx``'s quantities (no index when there is one element)."""
    sub = "" if count == 1 else str(idx)
    comma = "" if count == 1 else f",{idx}"
    n = f"N_{{{sub}}}" if sub else "N"
    return {
        "N": n,
        "Sc": f"S_{{c{comma}}}",
        "Ss": f"S_{{s{comma}}}",
        "NSc": f"{n} S_{{c{comma}}}",
        "NSs": f"{n} S_{{s{comma}}}",
        "m": f"m_{{{sub}}}" if sub else "m",
    }


def _shown_symbols(idx: int, count: int) -> tuple[sp.Symbol, sp.Symbol, sp.Symbol, sp.Symbol]:
    """``N``, ``S_c``, ``S_s``, ``m`` of element ``idx`` as symbols for the written-out
    equations."""
    nm = _display_names(idx, count)
    return tuple(sp.Symbol(nm[k]) for k in ("N", "Sc", "Ss", "m"))  # type: ignore[return-value]
