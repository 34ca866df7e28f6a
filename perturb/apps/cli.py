"""The ``perturb`` command.

Subcommands::

    perturb --version
    perturb models                                  list the builtin models
    perturb fourier "EXPR" --A 2 [--b 0] --n 15     Fourier coefficients of a force f(x)
    perturb frc MODEL [--method hb1] [--param k=-2 ...] [--omega 0.2:2.0[:N] | w1,w2]
                      [--harmonics H | 1,3 (shb)] [--out frc.csv] [--plot frc.png]
    perturb simulate MODEL [--param ...] --y0 x,v --t 0:100 [--method auto|exact|event|lcp|ode]
    perturb periodic MODEL [--param ...] --omega 0.6 [--m 1]   (autonomous system: no --omega)
    perturb derive METHOD MODEL [--order N] [--param ...] [--latex F.tex] [--json F.json]
    perturb run [SCENE.toml] [--out DIR] [--rtol R] answer a scene (default: the embedded one)

MODEL is a builtin oscillator, an equation string, a builtin system of several coordinates
(``nsd2``, ``impact_pair``, ``mount``, ...) or one equation per coordinate separated by
``;`` (parsed safely, :meth:`perturb.model.system.System.parse`). A system takes ``frc``
(``--method exact``, its only method for now), ``simulate`` (``--y0`` its states in the order
``perturb models`` lists) and ``periodic`` (an autonomous system, ``belt``, ``drill_string``:
its limit cycles and equilibria, without ``--omega``, which is refused there; ``frc`` refuses
it, there being no forcing frequency); ``--output`` names what ``amplitude`` measures (a
coordinate or a linear combination such as ``"x1 - x2"``), and every coordinate's ``max |.|``
and mean follow in the columns ``amplitude_<name>``, ``mean_<name>``.

Every error prints one line ``perturb: error: ...`` on standard error and exits with status
2: bad input (also what argparse rejects), values beyond the limits
(:data:`perturb.solve.MAX_HARMONICS`, :data:`~perturb.solve.MAX_ORDER`, :data:`MAX_SAMPLES`,
:data:`MAX_PERIODS`, :data:`OMEGA_RANGE`, ...), outputs that cannot be written (missing or
read-only folder, full disk) and unexpected internal errors (named, with a hint to rerun with
``PERTURB_DEBUG=1`` for the traceback). Ctrl-C exits with status 130 and SIGTERM with 143,
each with one line; every output is written to a temporary file beside it and renamed when
complete (:mod:`perturb.atomic`), so an interrupted run leaves each output complete or
absent. Nothing typed on the command line is evaluated as code.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import re
import signal
import sys
import threading
import warnings
from collections.abc import Iterator, Sequence
from pathlib import Path

from perturb import __version__
from perturb.checks import parse_number, whole
from perturb.errors import ParameterError, PerturbError

__all__ = [
    "main",
    "parse_param",
    "parse_omega",
    "MAX_SAMPLES",
    "MAX_PERIODS",
    "MAX_LCP_STEPS",
    "MAX_SUBHARMONIC",
    "MAX_FOURIER_N",
    "MAX_EQUATIONS",
    "OMEGA_RANGE",
]

_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]*")

#: Largest ``--samples`` of ``perturb simulate`` (a 1e6-row CSV is ~60 MB).
MAX_SAMPLES = 1_000_000
#: Longest ``--t`` span of ``perturb simulate``, in periods of ``max(Omega, 1)`` (so also in
#: natural periods of a unit-stiffness oscillator): 20 000 periods of ``nsd`` take ~2 s with
#: the exact propagator and up to minutes with the ODE and LCP integrators.
MAX_PERIODS = 20_000
#: Most fixed steps of ``perturb simulate --method lcp`` (span / h).
MAX_LCP_STEPS = 5_000_000
#: Largest ``--m`` (forcing periods per orbit) of ``perturb periodic``.
MAX_SUBHARMONIC = 16
#: Most equations of a MODEL given as equations separated by ``;`` (bounded parsing work).
MAX_EQUATIONS = 64
#: Largest ``--n`` of ``perturb fourier``.
MAX_FOURIER_N = 100_000  # = perturb.fourier.symbols.MAX_SERIES_ORDER (not imported: SymPy)
#: The names ``perturb derive`` takes for a system (= perturb.solve.SYSTEM_DERIVATIONS and its
#: aliases; not imported for the help text: solve imports SymPy; a test keeps them equal)
SYSTEM_DERIVATION_NAMES = ("hb1", "shb", "ms-ir", "internal-resonance", "nnm", "nnm-lp", "nnm-mlp")
#: Forcing frequencies the command accepts (``--omega`` of ``frc`` and ``periodic``): a period
#: a million times longer or shorter than a unit-stiffness oscillator's is beyond every
#: solver's resolution (``periodic nsd --omega 1e-300`` ran past 25 s; every step of a period
#: of 6e300 time units is numerically meaningless).
OMEGA_RANGE = (1e-6, 1e6)
#: Environment variable: when set to a non-empty value other than 0, an unexpected error
#: prints its full traceback.
DEBUG_ENV = "PERTURB_DEBUG"


class _UsageError(Exception):
    """An argparse error, reported by :func:`main` on one line."""


class _Terminated(BaseException):
    """SIGTERM, raised in the main thread so that ``finally`` blocks and the temporary files
    of :mod:`perturb.atomic` are cleaned up on the way out."""


class _Parser(argparse.ArgumentParser):
    """An argument parser whose errors are exceptions: :func:`main` prints them on one line
    (argparse's own prints the usage first, on several)."""

    def error(self, message: str):  # type: ignore[override]
        raise _UsageError(f"{message} (see: {self.prog} --help)")


def parse_param(text: str) -> tuple[str, float]:
    """``"k=-2"`` -> ``("k", -2.0)``; the value must be a finite number.

    Raises
    ------
    ParameterError
        Naming the bad text.
    """
    name, sep, value = text.partition("=")
    name, value = name.strip(), value.strip()
    if not sep or not _NAME.fullmatch(name):
        raise ParameterError(f"--param {text!r}: expected NAME=VALUE, e.g. k=-2")
    try:
        float(value)
    except ValueError:
        raise ParameterError(f"--param {text!r}: value {value!r} is not a number") from None
    return name, parse_number(value, f"--param {text!r}")


def _finite(flag: str):
    def convert(text: str) -> float:
        try:
            return parse_number(text, flag)
        except ParameterError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    return convert


def _harmonics_arg(text: str) -> int | str:
    """``--harmonics``: a whole number (numeric ``hb``'s count, the series of ``lp`` /
    ``mlp``) as before, or a comma list of harmonics such as ``1,3`` or ``1/3,1`` (the
    harmonic set of ``--method shb``; :func:`_harmonics_option` reads it once the method is
    known)."""
    try:
        return int(text)
    except ValueError:
        pass
    parts = [p.strip() for p in text.split(",")]
    ok = all(p and all(c.isdigit() or c == "/" for c in p) and p.count("/") <= 1 for p in parts)
    if "," not in text and "/" not in text or not ok:
        raise argparse.ArgumentTypeError(
            f"invalid value {text!r}: expected a whole number (hb) or a comma list of "
            "harmonics such as 1,3 (shb)"
        )
    return text


def _harmonics_option(method: str, value: int | str | None) -> int | tuple | None:
    """The ``harmonics`` option of ``method`` from ``--harmonics``: a set for ``shb`` (a
    comma list, or one harmonic), the whole number for every other method.

    Raises
    ------
    ParameterError
        For a comma list given to a method other than ``shb``.
    """
    if value is None:
        return None
    if method == "shb":
        items = str(value).split(",")
        return tuple(int(p) if "/" not in p else p.strip() for p in items)
    if isinstance(value, str):
        raise ParameterError(
            f"--harmonics {value}: a harmonic set (comma list) is for --method shb; "
            f"--method {method} takes a whole number"
        )
    return value


def _cmd_models(args: argparse.Namespace) -> int:
    from perturb.model.builtins import BUILTIN_MODELS

    for spec in BUILTIN_MODELS.values():
        defaults = ", ".join(f"{k}={v:g}" for k, v in spec.defaults.items())
        print(f"{spec.name}")
        print(f"    {spec.equation}")
        print(f"    {spec.description}")
        print(f"    defaults: {defaults}")
    from perturb.model.system_builtins import BUILTIN_SYSTEMS

    print()
    print("systems of several coordinates (MODEL as below, or equations separated by ';'):")
    for sys_spec in BUILTIN_SYSTEMS.values():
        defaults = ", ".join(f"{k}={v:g}" for k, v in sys_spec.defaults.items())
        print(f"{sys_spec.name}")
        for equation in sys_spec.equations:
            print(f"    {equation}")
        for stop_name, on, lower, upper in sys_spec.stops:
            print(f"    stop {stop_name}: {lower} <= {on} <= {upper}")
        print(f"    {sys_spec.description}")
        print(f"    states: {', '.join(_state_names(sys_spec.equations))}")
        print(f"    defaults: {defaults}")
    return 0


_PRIMED = re.compile(r"(?<![A-Za-z0-9_.])([A-Za-z][A-Za-z0-9_]*)\s*('+)")


def _state_names(equations: Sequence[str]) -> list[str]:
    """The state order of :meth:`System.parse <perturb.model.system.System.parse>` read from
    the equations' text (no SymPy, so ``perturb models`` stays fast): the second-order
    coordinates (a name with ``''``) in the order their derivatives first appear, their
    velocities, then the first-order states (a name with ``'`` only)."""
    order: dict[str, int] = {}
    for text in equations:
        for match in _PRIMED.finditer(text):
            name, primes = match.group(1), len(match.group(2))
            order[name] = max(order.get(name, 0), primes)
    second = [n for n, k in order.items() if k >= 2]
    return [*second, *(n + "'" for n in second), *(n for n, k in order.items() if k == 1)]


def _cmd_fourier(args: argparse.Namespace) -> int:
    import sympy as sp

    from perturb.fourier.symbols import series_coefficients
    from perturb.model.parsing import parse_expression, real_symbol

    expr = parse_expression(args.expr)
    x = real_symbol(args.var)
    from perturb.model.oscillator import validate_parameter_value

    values = dict(parse_param(p) for p in args.param or ())
    # the model's range for parameters (1e-300..1e300 or 0): 1e305 overflows once squared
    subs = {real_symbol(k): sp.Float(validate_parameter_value(k, v)) for k, v in values.items()}
    expr = expr.xreplace(subs)
    free = sorted(s.name for s in expr.free_symbols if s != x)
    if free:
        raise ParameterError(
            f"expression {args.expr!r} has parameters without values: {', '.join(free)}; "
            "give them with --param NAME=VALUE"
        )
    if args.A < 0:
        raise ParameterError(f"--A {args.A}: expected an amplitude >= 0")
    whole(args.n, "--n", 0, MAX_FOURIER_N)
    print(f"# Fourier coefficients of f({args.var}) = {args.expr}")
    print(f"# under {args.var} = A cos(psi) + b, A = {args.A:g}, b = {args.b:g}:")
    print("# f = a_0/2 + sum_n a_n cos(n psi)   (no sine terms: f depends on x alone)")
    print("n,a_n")
    for n, value in enumerate(series_coefficients(expr, x, args.n, args.A, args.b)):
        print(f"{n},{float(value):.17g}")
    return 0


def _check_omega_range(flag: str, text: str, values: Sequence[float]) -> None:
    lo, hi = OMEGA_RANGE
    bad = [w for w in values if not lo <= w <= hi]
    if bad:
        raise ParameterError(
            f"{flag} {text!r}: {bad[0]:g} is outside the forcing frequencies {lo:g} to {hi:g} "
            "that perturb resolves"
        )


def parse_omega(text: str) -> tuple[str, list[float]]:
    """``--omega`` forms: ``lo:hi`` (a traced curve), ``lo:hi:count`` (exactly ``count``
    equally spaced frequencies) or ``w1,w2,...`` (exactly those frequencies).

    Returns ``("range", [lo, hi])`` or ``("points", [...])``.

    Raises
    ------
    ParameterError
        Naming the bad text.
    """
    from perturb.methods.registry import MAX_FREQUENCIES

    text = text.strip()
    usage = f"--omega {text!r}: expected start:stop, start:stop:count or a list like 0.6,0.9"
    parts = text.split(":")
    try:
        [float(p) for p in parts] if ":" in text else [float(w) for w in text.split(",")]
    except ValueError:
        raise ParameterError(usage) from None
    numbers = [parse_number(p, "--omega") for p in parts] if ":" in text else []
    values = [parse_number(w, "--omega") for w in text.split(",")] if ":" not in text else []
    if ":" in text:
        if len(parts) not in (2, 3):
            raise ParameterError(usage)
        lo, hi = numbers[0], numbers[1]
        if not 0 < lo < hi:
            raise ParameterError(
                f"--omega {text!r}: expected 0 < start < stop"
                + (" (a window, not one frequency: give --omega W for that)" if lo == hi else "")
            )
        _check_omega_range("--omega", text, [lo, hi])
        if len(parts) == 2:
            return "range", [lo, hi]
        count = numbers[2]
        if count != int(count) or not 2 <= count <= MAX_FREQUENCIES:
            raise ParameterError(
                f"--omega {text!r}: expected a whole count from 2 to {MAX_FREQUENCIES}"
            )
        # decimal arithmetic on the typed numbers, so 0.5:0.7:5 gives 0.65, not
        # 0.6499999999999999: the values written are the values a reader expects
        from decimal import Decimal

        a, b, n = Decimal(parts[0].strip()), Decimal(parts[1].strip()), int(count)
        return "points", [float(a + (b - a) * i / (n - 1)) for i in range(n)]
    if not values:
        raise ParameterError(usage)
    if not all(w > 0 for w in values):
        raise ParameterError(f"--omega {text!r}: frequencies must be positive")
    _check_omega_range("--omega", text, values)
    if len(values) > MAX_FREQUENCIES:
        raise ParameterError(
            f"--omega: {len(values)} frequencies, expected at most {MAX_FREQUENCIES}"
        )
    return "points", values


def _names_system(text: str) -> bool:
    """Whether MODEL names a system of several coordinates: a builtin system or equations
    separated by ``;`` (decided on the text, before anything is parsed)."""
    from perturb.model.system_builtins import BUILTIN_SYSTEMS

    return text in BUILTIN_SYSTEMS or ";" in text


def _model_from_arg(text: str, params: dict[str, float]):
    """MODEL: a builtin oscillator, a builtin system, one equation (an oscillator) or several
    equations separated by ``;`` (a :class:`~perturb.model.system.System`, one equation per
    coordinate or first-order state, parsed safely)."""
    from perturb.model.builtins import BUILTIN_MODELS, builtin_model
    from perturb.model.oscillator import Oscillator
    from perturb.model.system_builtins import BUILTIN_SYSTEMS, builtin_system

    if text in BUILTIN_MODELS:
        return builtin_model(text, **params)
    if text in BUILTIN_SYSTEMS:
        return builtin_system(text, **params)
    if ";" in text:
        from perturb.model.system import System

        parts = [part.strip() for part in text.split(";") if part.strip()]
        if len(parts) > MAX_EQUATIONS:
            raise ParameterError(
                f"model: {len(parts)} equations separated by ';', expected at most "
                f"{MAX_EQUATIONS} (one per coordinate)"
            )
        return System.parse(parts, params)
    if "''" in text:
        return Oscillator.parse(text, params)
    raise PerturbError(
        f"model {text!r}: expected a builtin name ({', '.join(BUILTIN_MODELS)}), a builtin "
        f"system ({', '.join(BUILTIN_SYSTEMS)}), an equation such as "
        "\"x'' + mu*x' + x + x**3 = F*cos(Omega*t)\" or one equation per coordinate "
        "separated by ';'"
    )


def _oscillator_from_arg(text: str, params: dict[str, float], command: str):
    """MODEL for a command that takes one coordinate only."""
    if _names_system(text):
        raise PerturbError(
            f"model {text!r} is a system of several coordinates: perturb {command} takes "
            "one coordinate (an oscillator); systems take frc --method exact, simulate and "
            "periodic"
        )
    return _model_from_arg(text, params)


def _check_outputs(**outputs: str | None) -> None:
    """Refuse, before any work, outputs that cannot be written: two with one path, a missing
    or read-only folder, a folder given as a file name.

    Raises
    ------
    ParameterError
        Naming the flag and the path.
    """

    given = {flag: path for flag, path in outputs.items() if path}
    for flag, path in given.items():
        dest = Path(path)
        folder = dest.parent if str(dest.parent) else Path(".")
        if dest.is_dir():
            raise ParameterError(f"--{flag} {path!r} is a folder, expected a file name")
        if not folder.is_dir():
            raise ParameterError(f"--{flag} {path!r}: the folder {str(folder)!r} does not exist")
        if not os.access(folder, os.W_OK | os.X_OK):
            raise ParameterError(f"--{flag} {path!r}: the folder {str(folder)!r} is not writable")
    seen: dict[str, str] = {}
    for flag, path in given.items():
        key = os.path.realpath(path)
        if key in seen:
            raise ParameterError(
                f"--{seen[key]} and --{flag} are the same file {path!r}: "
                "give each output its own name"
            )
        seen[key] = flag


def _write_text(path: str, text: str) -> None:
    from perturb.atomic import write_text

    write_text(path, text)


@contextlib.contextmanager
def _atomic_figure(path: str) -> Iterator[Path]:
    """A temporary PNG path beside ``path``, renamed onto it when the figure is complete."""
    from perturb.atomic import atomic_path

    with atomic_path(path) as tmp:
        yield tmp


def _describe(resp, width: int = 400) -> str:
    """``repr(resp)`` with each line cut to ``width`` characters (a response near an exact
    resonance can list thousands of folds)."""
    lines = repr(resp).split("\n")
    return "\n".join(line if len(line) <= width else line[: width - 4] + " ..." for line in lines)


def _frc_summary(resp, kind: str) -> str:
    """A few lines about a response, for the terminal when the CSV is not wanted there."""
    lines = [_describe(resp)]
    n = sum(len(b) for b in resp.branches)
    lines.append(f"{len(resp.branches)} branches, {n} points")
    lines += [f"note: {note}" for note in resp.notes]
    if not resp.branches:
        lines.append("no solution in the window: see the notes above")
    return "\n".join(lines) + "\n"


def _cmd_frc(args: argparse.Namespace) -> int:
    from perturb.methods.registry import check_points, spec

    _check_outputs(out=args.out, plot=args.plot)
    if _names_system(args.model):
        return _frc_system(args)
    if args.method is None:
        args.method = "hb1"  # the default of an oscillator (a system's is exact)
    method = spec(args.method, what="--method")
    if args.compare not in (None, "exact"):
        raise PerturbError(f"--compare {args.compare!r}: expected exact")
    # the method's options and limits (the registry's) before the model: a refused request
    # costs nothing
    given = {"harmonics": _harmonics_option(method.name, args.harmonics), "order": args.order}
    if method.kind == "auto" and (args.order is not None or args.harmonics is not None):
        raise ParameterError(
            "--method auto chooses the order and the harmonics itself: "
            "give neither --order nor --harmonics"
        )
    options = method.validate(given, prefix="--")
    check_points(args.points, "--points")
    kind, omegas = parse_omega(args.omega)
    if args.one_branch:
        if "all_branches" not in method.options:
            raise ParameterError(
                f"--one-branch applies to --method hb (every other method returns what it "
                f"finds); got --method {args.method}"
            )
        options["all_branches"] = False
    elif "all_branches" in method.options:
        options["all_branches"] = True
    params = dict(parse_param(p) for p in args.param or ())
    osc = _model_from_arg(args.model, params)
    from perturb.solve import check_oscillator_output

    check_oscillator_output(osc, args.output)
    swept = str(getattr(osc.forcing, "base_frequency", ""))
    if swept in params:
        raise ParameterError(
            f"--param {swept}={params[swept]:g}: {swept} is the forcing frequency that frc "
            f"varies; give its values with --omega (e.g. --omega {params[swept]:g})"
        )
    from perturb.solve import frequency_response

    if method.kind == "auto":
        print("[perturb] choosing a method (exact spot checks) ...", file=sys.stderr)
    if kind == "range":
        # the curve's resolution, for the methods that trace by amplitude parametrisation
        if "points" in method.options:
            options["points"] = args.points
        resp = frequency_response(osc, method.name, omegas, **options)
    else:
        resp = frequency_response(osc, method.name, frequencies=omegas, **options)
    quiet_csv = args.out is None and args.plot
    rel = comparison = ref = None
    if args.compare == "exact":
        from perturb.comparison import compare, relative_errors

        if kind == "range":
            ref = frequency_response(osc, "exact", omegas)
        else:
            ref = frequency_response(osc, "exact", frequencies=omegas)
        rel = relative_errors(resp, ref)
        comparison = compare(resp, ref)
    text = resp.to_csv(None, extra=None if rel is None else {"rel_error": rel})
    # the files first, the report after: a run that fails while writing says only why
    if args.out is not None:
        _write_text(args.out, text)
    if args.plot:
        from perturb.report.figures import plot_frequency_response

        with _atomic_figure(args.plot) as tmp:
            # with --compare exact the reference is drawn too: the picture shows the error
            drawn = [resp] if ref is None else [resp, ref]
            plot_frequency_response(drawn, tmp, oscillator=osc)
    if not quiet_csv:
        print(_describe(resp), file=sys.stderr)
        for note in resp.notes:
            print(f"note: {note}", file=sys.stderr)
    if comparison is not None:
        print(str(comparison), file=sys.stderr)
    if quiet_csv:
        # the picture was asked for, not 3 000 CSV rows on the terminal
        sys.stdout.write(_frc_summary(resp, kind))
        print(f"wrote {args.plot} (add --out FILE.csv for the data)", file=sys.stdout)
    elif args.out is None:
        sys.stdout.write(text)
    return 0


def _frc_system(args: argparse.Namespace) -> int:
    """``perturb frc`` on a system of several coordinates: the exact response, or numeric
    multi-harmonic balance with ``--method hb`` (:func:`perturb.solve.frequency_response`),
    CSV with the SDOF columns of ``--output`` and ``amplitude_<name>``, ``mean_<name>`` of
    every coordinate; ``--compare exact`` (hb only) adds ``rel_error`` (of ``--output``'s
    max |.|) and ``rel_error_<name>`` per coordinate against the exact response."""
    from types import SimpleNamespace

    from perturb.methods.registry import check_points, spec
    from perturb.solve import SYSTEM_METHODS, SYSTEM_ONLY_METHODS

    if args.method in SYSTEM_ONLY_METHODS:
        # the slow flow of an internal resonance: a method of systems only (no registry entry)
        method = SimpleNamespace(name="ms-ir", kind="symbolic", title="internal resonance")
    else:
        method = spec("exact" if args.method is None else args.method, what="--method")
    if method.name not in (*SYSTEM_METHODS, "ms-ir"):
        raise ParameterError(
            f"--method {args.method}: {method.title} is a method for one coordinate; a system "
            f"of several coordinates ({args.model!r}) takes --method exact, hb, hb1, shb, "
            "ms-ir or auto (exact orbits; numeric multi-harmonic balance; symbolic "
            "single-harmonic balance; internal-resonance slow flow; the cheapest meeting "
            "rtol 1e-3)"
        )
    options: dict = {}
    if args.compare not in (None, "exact"):
        raise PerturbError(f"--compare {args.compare!r}: expected exact")
    if method.name in ("hb", "hb1", "shb", "auto", "ms-ir"):
        if args.order is not None:
            raise ParameterError(
                f"--order: not an option of --method {method.name} for a system (an "
                "expansion order belongs to the methods of one coordinate)"
            )
        if args.harmonics is not None:
            if method.name in ("hb1", "auto", "ms-ir"):
                raise ParameterError(
                    f"--harmonics: --method {method.name} chooses its harmonics itself (hb1: "
                    "one; auto: the ladder's); give --method hb --harmonics H"
                )
            options["harmonics"] = _harmonics_option(method.name, args.harmonics)
        if args.one_branch:
            if method.name in ("auto", "ms-ir"):
                raise ParameterError(
                    "--one-branch applies to --method hb, hb1 and shb; auto and ms-ir trace "
                    "every branch they find"
                )
            options["all_branches"] = False
    else:
        given = {
            "--harmonics": args.harmonics,
            "--order": args.order,
            "--one-branch": args.one_branch or None,
            "--compare": args.compare,
        }
        for flag, value in given.items():
            if value is not None:
                raise ParameterError(
                    f"{flag}: not an option of a system's exact response (the approximations "
                    "of one coordinate take it, and --method hb for a system); the exact "
                    "response takes --omega, --output, --param, --out and --plot"
                )
    check_points(args.points, "--points")
    kind, omegas = parse_omega(args.omega)
    params = dict(parse_param(p) for p in args.param or ())
    system = _model_from_arg(args.model, params)
    if "Omega" in params:
        raise ParameterError(
            f"--param Omega={params['Omega']:g}: Omega is the forcing frequency that frc "
            f"varies; give its values with --omega (e.g. --omega {params['Omega']:g})"
        )
    from perturb.solve import frequency_response, system_output

    _, output = system_output(system, args.output)  # refused before any work
    if method.kind == "auto":
        print("[perturb] choosing a method (exact spot checks) ...", file=sys.stderr)
    if kind == "range":
        resp = frequency_response(system, method.name, omegas, output=args.output, **options)
    else:
        resp = frequency_response(
            system, method.name, frequencies=omegas, output=args.output, **options
        )
    extra = ref = summary = None
    if args.compare == "exact" and resp.columns and "states" not in resp.columns[0]:
        # --method auto chose the exact solver: the response is its own reference
        summary = "none: the chosen method is the exact solver"
        ref = "exact orbits"
    elif args.compare == "exact":
        from perturb.solve import system_errors

        extra, summary = system_errors(system, resp, args.output)
        ref = "exact orbits"
    text = resp.to_csv(None, extra=extra)
    if args.out is not None:
        _write_text(args.out, text)
    if args.plot:
        from perturb.apps.scene import system_title
        from perturb.report.figures import plot_frequency_response, save_figure

        fig = plot_frequency_response([resp], None, title=system_title(system, ("Omega",)))
        fig.axes[0].set_ylabel(f"amplitude max |{output}|")
        if summary is not None:
            from perturb.apps.scene import label_errors

            label_errors(fig, summary)
        with _atomic_figure(args.plot) as tmp:
            save_figure(fig, tmp)
    quiet_csv = args.out is None and args.plot
    if not quiet_csv:
        print(_describe(resp), file=sys.stderr)
        for note in resp.notes:
            print(f"note: {note}", file=sys.stderr)
    if summary is not None:
        print(f"compare with {ref}: max relative error {summary}", file=sys.stderr)
    if quiet_csv:
        sys.stdout.write(_frc_summary(resp, kind))
        print(f"wrote {args.plot} (add --out FILE.csv for the data)", file=sys.stdout)
    elif args.out is None:
        sys.stdout.write(text)
    return 0


def _pair(flag: str, text: str) -> list[float]:
    parts = text.split(",")
    try:
        [float(p) for p in parts]
    except ValueError:
        raise ParameterError(f"{flag} {text!r}: expected two numbers like 0.3,0.1") from None
    if len(parts) != 2:
        raise ParameterError(f"{flag} {text!r}: expected two finite numbers like 0.3,0.1")
    return [parse_number(p, flag) for p in parts]


def _forcing_frequency(osc) -> float:
    """The value of the forcing frequency parameter, 1 when there is none."""
    for name in ("Omega", "omega", "w", "W"):
        value = osc.params.get(name)
        if value is not None and math.isfinite(float(value)) and float(value) > 0:
            return float(value)
    return 1.0


def _cmd_simulate(args: argparse.Namespace) -> int:
    from perturb.simulate.time_history import METHODS as INTEGRATORS
    from perturb.simulate.time_history import time_history

    _check_outputs(out=args.out, plot=args.plot)
    system = _names_system(args.model)
    if args.method not in INTEGRATORS and not (system and args.method == "events"):
        raise ParameterError(f"--method {args.method!r}: expected one of {', '.join(INTEGRATORS)}")
    whole(args.samples, "--samples", 2, MAX_SAMPLES, "rows of the output")
    t0, t1 = _pair("--t", args.t.replace(":", ","))
    if system:
        y0 = None if args.y0 is None else _numbers("--y0", args.y0)
    else:
        y0 = _pair("--y0", "0,0" if args.y0 is None else args.y0)
    if not t1 > t0:
        raise ParameterError(f"--t {args.t!r}: expected t0:t1 with t1 > t0")
    params = dict(parse_param(p) for p in args.param or ())
    osc = _model_from_arg(args.model, params)
    if not system:
        from perturb.solve import check_oscillator_output

        check_oscillator_output(osc, args.output)
    w = _forcing_frequency(osc)
    periods = (t1 - t0) * max(w, 1.0) / (2 * math.pi)
    if periods > MAX_PERIODS:
        raise ParameterError(
            f"--t {args.t!r}: spans {periods:.4g} periods of 2 pi/max(Omega, 1) = "
            f"{2 * math.pi / max(w, 1.0):.4g}; expected at most {MAX_PERIODS}"
        )
    if args.h is not None:
        if not args.h > 0:
            raise ParameterError(f"--h {args.h}: expected a step > 0")
        if (t1 - t0) / args.h > MAX_LCP_STEPS:
            raise ParameterError(
                f"--h {args.h}: {(t1 - t0) / args.h:.4g} steps over --t {args.t}; "
                f"expected at most {MAX_LCP_STEPS}"
            )
    if system:
        return _simulate_system(args, osc, y0, (t0, t1))
    hist = time_history(osc, y0, (t0, t1), method=args.method, samples=args.samples, h=args.h)
    text = hist.to_csv(args.out)
    if args.plot:
        from perturb.report.figures import plot_time_history

        with _atomic_figure(args.plot) as tmp:
            plot_time_history(hist, tmp, title=str(osc))
    print(repr(hist), file=sys.stderr)
    if args.out is None:
        sys.stdout.write(text)
    return 0


def _numbers(flag: str, text: str) -> list[float]:
    """``--y0`` of a system: a comma list of finite numbers (its count is checked against
    the model's states once the model is built)."""
    parts = text.split(",")
    try:
        [float(p) for p in parts]
    except ValueError:
        raise ParameterError(
            f"{flag} {text!r}: expected the states as numbers separated by commas, like 0.3,0,0,0"
        ) from None
    return [parse_number(p, flag) for p in parts]


def _simulate_system(args: argparse.Namespace, system, y0, t_span) -> int:
    """``perturb simulate`` on a system of several coordinates: CSV ``t``, every state,
    ``output``; the plot of every coordinate and the output."""
    from perturb.solve import system_time_history

    if args.method in ("event", "lcp"):
        raise ParameterError(
            f"--method {args.method}: the event-driven and LCP integrators take one "
            f"coordinate; a system ({system.name!r}) takes --method auto, exact, ode or events"
        )
    if args.h is not None:
        raise ParameterError(
            f"--h {args.h}: the step of --method lcp, which takes one coordinate; a system "
            "takes --method auto, exact or ode"
        )
    names = system.state_names
    if y0 is not None and len(y0) != len(names):
        raise ParameterError(
            f"--y0 {args.y0!r}: expected {len(names)} numbers, the states "
            f"{', '.join(names)} of {system.name!r}"
        )
    hist = system_time_history(
        system, y0, t_span, method=args.method, samples=args.samples, output=args.output
    )
    text = hist.to_csv(args.out)
    if args.plot:
        from perturb.apps.scene import plot_system_history, system_title

        with _atomic_figure(args.plot) as tmp:
            plot_system_history(hist, tmp, title=system_title(system))
    print(repr(hist), file=sys.stderr)
    if args.out is None:
        sys.stdout.write(text)
    return 0


def _multipliers_text(mu) -> str:
    """Floquet multipliers as one CSV field: ``re+imj`` numbers separated by spaces (each
    readable by Python's ``complex``)."""
    return " ".join(
        f"{float(z.real)!r}{'-' if z.imag < 0 else '+'}{abs(float(z.imag))!r}j" for z in mu
    )


def _periodic_system(args: argparse.Namespace, system) -> str:
    """The CSV of ``perturb periodic`` on a system: the SDOF columns (of ``--output``), each
    coordinate's ``amplitude_<name>`` and ``mean_<name>``, the multipliers and the initial
    state ``y0_<state>``."""
    from perturb.solve import invariant_note, orbit_columns, periodic_orbits, system_coordinates

    values = _invariant_values(args.invariants)
    orbits = periodic_orbits(system, args.omega, m=args.m, output=args.output, invariants=values)
    note = invariant_note(system, values)
    if note is not None:
        print(f"note: {note}", file=sys.stderr)
    coords = system_coordinates(system)
    cols = ["omega", "m", "amplitude", "first_harmonic_amplitude", "mean", "stable"]
    cols += ["max_multiplier", "stability"]
    cols += [f"amplitude_{c}" for c in coords] + [f"mean_{c}" for c in coords]
    cols += ["multipliers"] + [f"y0_{name}" for name in system.state_names]
    lines = [",".join(cols)]
    for o in orbits:
        num = orbit_columns(system, o, args.output)
        row = [repr(float(args.omega)), str(o.m)]
        row += [repr(num[k]) for k in ("amplitude", "first_harmonic_amplitude", "mean")]
        row += [str(int(o.max_multiplier < 1)), repr(float(o.max_multiplier)), o.stability]
        row += [repr(num[f"amplitude_{c}"]) for c in coords]
        row += [repr(num[f"mean_{c}"]) for c in coords]
        row += [_multipliers_text(o.multipliers)] + [repr(float(v)) for v in o.y0]
        lines.append(",".join(row))
    print(f"{len(orbits)} period-{args.m} orbits at Omega = {args.omega}", file=sys.stderr)
    return "\n".join(lines) + "\n"


def _invariant_values(text: str | None) -> list[float] | None:
    """``--invariants``: a comma list of finite numbers (its count is checked against the
    system's invariants by :func:`perturb.solve.periodic_orbits`)."""
    if text is None:
        return None
    return [parse_number(v.strip(), "--invariants") for v in text.split(",")]


def _periodic_autonomous(args: argparse.Namespace, system) -> str:
    """``perturb periodic`` on an autonomous system: its limit cycles
    (:func:`perturb.solve.limit_cycles`), one row each with the forced orbits' columns,
    ``period`` (and ``omega = 2 pi / period``), the multipliers (one trivial 1; a drifting
    system's drift direction's as 0), ``kind = limit_cycle``; then one row per equilibrium
    (``kind = equilibrium`` or ``steady_drift``: ``period`` inf, ``omega`` 0, no multipliers,
    its Jacobian's ``eigenvalues``), so the CSV is never silently empty."""
    from perturb.solve import limit_cycles, orbit_columns, system_coordinates

    if args.omega is not None:
        raise ParameterError(
            f"--omega {args.omega:g}: system {system.name!r} is autonomous (no forcing term, so "
            "no forcing frequency Omega): its limit cycles have their own period, which "
            "perturb periodic finds; leave --omega out"
        )
    if args.m != 1:
        raise ParameterError(
            f"--m {args.m}: system {system.name!r} is autonomous (no forcing periods to count); "
            "leave --m out"
        )
    if args.invariants is not None:
        _invariant_values(args.invariants)
        raise ParameterError(
            f"--invariants {args.invariants}: the limit-cycle search of an autonomous system "
            "takes no invariant values (it refuses systems with conserved combinations)"
        )
    method = getattr(args, "method", None) or "exact"
    harmonics = getattr(args, "harmonics", None)
    if harmonics is not None and method != "hb":
        raise ParameterError(
            f"--harmonics {harmonics}: an option of --method hb (the exact search has none)"
        )
    if method == "hb":
        found = limit_cycles(system, output=args.output, method="hb", harmonics=harmonics)
    else:
        found = limit_cycles(system, output=args.output)
    coords = system_coordinates(system)
    cols = ["omega", "m", "period", "amplitude", "first_harmonic_amplitude", "mean", "stable"]
    cols += ["max_multiplier", "stability"]
    cols += [f"amplitude_{c}" for c in coords] + [f"mean_{c}" for c in coords]
    cols += ["multipliers"] + [f"y0_{name}" for name in system.state_names]
    cols += ["kind", "eigenvalues"]
    lines = [",".join(cols)]
    for o in found.cycles:
        num = orbit_columns(system, o, args.output)
        row = [repr(2.0 * math.pi / o.period), "1", repr(float(o.period))]
        row += [repr(num[k]) for k in ("amplitude", "first_harmonic_amplitude", "mean")]
        row += [str(int(o.max_multiplier < 1)), repr(float(o.max_multiplier)), o.stability]
        row += [repr(num[f"amplitude_{c}"]) for c in coords]
        row += [repr(num[f"mean_{c}"]) for c in coords]
        row += [_multipliers_text(o.multipliers)] + [repr(float(v)) for v in o.y0]
        row += ["limit_cycle", ""]
        lines.append(",".join(row))
    from perturb.solve import system_output

    c, _ = system_output(system, args.output)
    names = system.state_names
    for e in found.equilibria:
        val = float(c @ e.y)
        row = ["0.0", "1", "inf", repr(abs(val)), "0.0", repr(val), str(int(e.stable)), ""]
        row += [e.stability]
        row += [repr(abs(float(e.y[names.index(n)]))) for n in coords]
        row += [repr(float(e.y[names.index(n)])) for n in coords]
        row += [""] + [repr(float(v)) for v in e.y]
        row += ["equilibrium" if e.drift_rate is None else "steady_drift"]
        row += [_multipliers_text(e.eigenvalues)]
        lines.append(",".join(row))
    what = f"system {system.name!r} is autonomous: "
    if found.cycles:
        periods = ", ".join(f"{o.period:.10g} ({o.stability})" for o in found.cycles)
        what += f"{len(found.cycles)} limit cycle(s), period {periods}"
    else:
        what += "no limit cycle found"
    if found.equilibria:
        what += "; " + "; ".join(
            ("equilibrium" if e.drift_rate is None else f"steady drift at rate {e.drift_rate:.6g}")
            + f" ({e.stability}, eigenvalues "
            + ", ".join(f"{complex(z):.6g}" for z in e.eigenvalues)
            + ")"
            for e in found.equilibria
        )
    elif not found.cycles:
        what += " and no equilibrium (every run escaped or failed; see the notes)"
    print(what, file=sys.stderr)
    if found.drift is not None:
        shifts = ", ".join(f"{s:.10g}" for s in found.shifts)
        print(
            f"note: the motion drifts along d = {found.drift.tolist()} ({system.name} turns): "
            f"each cycle is periodic up to a shift of {shifts} times d per period; y0 is given "
            "with d . y0 = 0, the multiplier of d taken out (0)",
            file=sys.stderr,
        )
    for note in found.notes:
        print(f"note: {note}", file=sys.stderr)
    return "\n".join(lines) + "\n"


def _cmd_periodic(args: argparse.Namespace) -> int:
    from perturb.solve import periodic_orbits

    _check_outputs(out=args.out)
    whole(args.m, "--m", 1, MAX_SUBHARMONIC, "forcing periods per orbit")
    if args.omega is not None:
        if not args.omega > 0:
            raise ParameterError(f"--omega {args.omega}: expected a forcing frequency > 0")
        _check_omega_range("--omega", str(args.omega), [args.omega])
    params = dict(parse_param(p) for p in args.param or ())
    osc = _model_from_arg(args.model, params)
    from perturb.solve import check_oscillator_output, is_forced, is_system

    if not is_system(osc) and args.omega is None and args.invariants is None:
        # an oscillator without forcing (x'' - eps (1 - x^2) x' + x = 0): its limit cycles,
        # as the one-coordinate system
        from perturb.model.system import System

        try:
            as_system = System.from_oscillator(osc)
            if not is_forced(as_system):
                check_oscillator_output(osc, args.output)
                osc = as_system
        except PerturbError:
            pass  # not expressible as a system: --omega is then required below
    # a forcing amplitude of 0 makes the system autonomous: decide with Omega set (to --omega,
    # or any value when it is left out: it then only multiplies the vanished forcing's time)
    at = osc
    if is_system(osc) and "Omega" in osc.free_parameters:
        at = osc.with_params(Omega=1.0 if args.omega is None else args.omega)
    autonomous = is_system(osc) and not is_forced(at)
    if args.invariants is not None and not is_system(osc):
        raise ParameterError(
            f"--invariants {args.invariants}: an option of systems with conserved "
            "combinations; an oscillator has one coordinate"
        )
    if args.omega is None and not autonomous:
        raise ParameterError(
            f"--omega: required for {args.model!r}, a forced model (its periodic orbits are at "
            "a forcing frequency, e.g. --omega 0.6); only an autonomous system (no forcing "
            "term, e.g. belt) goes without it"
        )
    if not autonomous and (args.method is not None or args.harmonics is not None):
        flag = "--method" if args.method is not None else "--harmonics"
        raise ParameterError(
            f"{flag}: applies to the limit cycles of an autonomous system (perturb periodic "
            "belt --method hb); the orbits at a forcing frequency are exact (frc --method hb "
            "for harmonic balance)"
        )
    if is_system(osc):
        text = _periodic_autonomous(args, at) if autonomous else _periodic_system(args, osc)
        if args.out:
            _write_text(args.out, text)
        else:
            sys.stdout.write(text)
        return 0
    check_oscillator_output(osc, args.output)
    orbits = periodic_orbits(osc, args.omega, m=args.m)
    cols = "omega,m,amplitude,first_harmonic_amplitude,mean,stable,max_multiplier,stability,x0,v0"
    lines = [cols]
    for o in orbits:
        nums = [o.amplitude, o.first_harmonic_amplitude, o.mean]
        lines.append(
            f"{float(args.omega)!r},{o.m},"
            + ",".join(repr(float(n)) for n in nums)
            + f",{int(o.max_multiplier < 1)},{float(o.max_multiplier)!r},{o.stability},"
            f"{float(o.y0[0])!r},{float(o.y0[1])!r}"
        )
    text = "\n".join(lines) + "\n"
    if args.out:
        _write_text(args.out, text)
    else:
        sys.stdout.write(text)
    print(f"{len(orbits)} period-{args.m} orbits at Omega = {args.omega}", file=sys.stderr)
    return 0


def _cmd_derive(args: argparse.Namespace) -> int:
    import json

    from perturb.io.serialize import approximation_to_dict
    from perturb.methods.registry import spec, symbolic_names
    from perturb.report.latex import latex_document
    from perturb.solve import derive

    _check_outputs(latex=args.latex, json=args.json)
    if _names_system(args.model):
        return _derive_system(args)
    method = spec(args.method, what="method")
    if method.kind != "symbolic":
        raise PerturbError(
            f"method {args.method!r} is a solver ({method.title}), not a derivation: expected "
            f"one of {', '.join(symbolic_names())}"
        )
    options = method.validate({"order": args.order}, prefix="--", stage="derive")
    params = dict(parse_param(p) for p in args.param or ())
    osc = _oscillator_from_arg(args.model, params, "derive")
    approx = derive(osc, method.name, use_cache=not args.no_cache, **options)
    # files first: the summary may go to a pipe that closes early
    if args.latex:
        latex_document(approx, args.latex)
    if args.json:
        _write_text(args.json, json.dumps(approximation_to_dict(approx), indent=1, sort_keys=True))
    # wrapped to the terminal (at most 100 columns); long equations as one summary line each,
    # the full text is in the --latex / --json files
    print(approx.summary())
    return 0


def _derive_system(args: argparse.Namespace) -> int:
    """``perturb derive METHOD SYSTEM``: a system's symbolic derivation
    (:func:`perturb.solve.derive_system`: hb1, ms-ir, nnm), printed; ``--latex`` writes the
    derivation as a LaTeX document, ``--order`` is the order of ``nnm``."""
    from perturb.solve import SYSTEM_DERIVATION_ALIASES, SYSTEM_DERIVATIONS, derive_system

    name = SYSTEM_DERIVATION_ALIASES.get(args.method, args.method)
    if name not in SYSTEM_DERIVATIONS:
        raise ParameterError(
            f"method {args.method!r}: {args.model!r} is a system of several coordinates; its "
            f"derivations are {', '.join(SYSTEM_DERIVATIONS)} ("
            + "; ".join(f"{k}: {v[1]}" for k, v in SYSTEM_DERIVATIONS.items())
            + ")"
        )
    if args.json:
        raise ParameterError(
            "--json: the JSON codec holds one-coordinate approximations; a system's derivation "
            "is written with --latex"
        )
    options = {}
    if args.order is not None:
        if name != "nnm":
            raise ParameterError(f"--order {args.order}: an option of nnm, not of {name}")
        options["order"] = args.order
    params = dict(parse_param(p) for p in args.param or ())
    system = _model_from_arg(args.model, params)
    result = derive_system(system, args.method, **options)
    if args.latex:
        if hasattr(result, "latex_document"):
            text = result.latex_document()
        else:
            from perturb.report.latex import derivation_body

            title = f"{name} of the system {system.name}".replace("_", r"\_")
            text = (
                "\\documentclass[11pt]{article}\n\\usepackage[margin=2cm]{geometry}\n"
                "\\usepackage{amsmath,amssymb}\n\\allowdisplaybreaks\n\\begin{document}\n"
                f"\\section*{{{title}}}\n{derivation_body(result.steps)}\n\\end{{document}}\n"
            )
        _write_text(args.latex, text)
    print(str(result))
    return 0


def _check_out_dir(out: str) -> None:
    """The output folder of ``perturb run``: it, or the nearest folder above it that exists,
    must be a writable folder.

    Raises
    ------
    ParameterError
        Naming the path.
    """
    path = Path(out)
    if path.exists() and not path.is_dir():
        raise ParameterError(f"--out {out!r} is a file, expected a folder")
    existing = path
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir() or not os.access(existing, os.W_OK | os.X_OK):
        raise ParameterError(f"--out {out!r}: the folder {str(existing)!r} is not writable")


def _cmd_run(args: argparse.Namespace) -> int:
    from perturb.apps.scene import default_scene, load_scene, run_scene

    _check_out_dir(args.out)
    if args.scene and _is_sweep_scene(args.scene):
        # a scene with a [sweep] table asks for a map: answer it as `perturb sweep` would,
        # into the output directory
        from perturb.apps.grid_cli import build_args, cmd_sweep

        Path(args.out).mkdir(parents=True, exist_ok=True)
        return cmd_sweep(build_args(args.scene, str(Path(args.out) / "map.nc")))
    # the scene's method options are checked against the method registry when it is read
    scene = load_scene(args.scene) if args.scene else default_scene()
    if args.rtol is not None:
        import dataclasses

        from perturb.auto import check_rtol

        if scene.method != "auto" or scene.kind != "frequency_response":
            raise PerturbError(
                f"--rtol {args.rtol}: applies to frequency-response scenes with "
                f"[method] name = 'auto' ({scene.source} asks for {scene.kind} by {scene.method})"
            )
        scene = dataclasses.replace(scene, rtol=check_rtol(args.rtol))
    run_scene(scene, args.out)
    return 0


def _is_sweep_scene(path: str) -> bool:
    import tomllib

    try:
        return "sweep" in tomllib.loads(Path(path).read_text())
    except (OSError, tomllib.TOMLDecodeError):
        return False  # load_scene reports the problem


def _method_help(kinds: tuple[str, ...]) -> dict[str, str]:
    """One line per method of the registry (of the given kinds), for ``--help``."""
    from perturb.methods.registry import REGISTRY

    rows = {}
    for name, spec in REGISTRY.items():
        if spec.kind in kinds:
            alias = f" (alias: {', '.join(spec.aliases)})" if spec.aliases else ""
            rows[name] = spec.title + alias
    return rows


def _methods_epilog(kinds: tuple[str, ...]) -> str:
    rows = _method_help(kinds)
    width = max(map(len, rows))
    return "methods:\n" + "\n".join(f"  {k:<{width}}  {v}" for k, v in rows.items())


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``perturb`` command (errors raise instead of exiting)."""
    from perturb.methods.registry import (
        MAX_FREQUENCIES,
        MAX_HARMONICS,
        MAX_ORDER,
        MAX_POINTS,
        names,
        symbolic_names,
    )

    parser = _Parser(
        prog="perturb",
        description="Periodic responses of nonlinear and piecewise-linear oscillators.",
        epilog=f"Errors: one line on stderr, exit status 2. {DEBUG_ENV}=1 shows tracebacks.",
    )
    parser.add_argument("--version", action="version", version=f"perturb {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    p = sub.add_parser("models", help="list the builtin models with their equations")
    p.set_defaults(func=_cmd_models)

    p = sub.add_parser(
        "fourier",
        help="closed-form Fourier coefficients of a force f(x) under x = A cos(psi) + b",
    )
    p.add_argument("expr", help='the force, e.g. "(x-1)*Heaviside(x-1)"')
    p.add_argument("--A", type=_finite("--A"), required=True, help="amplitude A >= 0")
    p.add_argument("--b", type=_finite("--b"), default=0.0, help="bias b (default 0)")
    p.add_argument(
        "--n", type=int, default=10, help=f"highest harmonic (default 10, at most {MAX_FOURIER_N})"
    )
    p.add_argument("--var", default="x", help="the variable (default x)")
    p.add_argument("--param", action="append", metavar="NAME=VALUE", help="parameter value")
    p.set_defaults(func=_cmd_fourier)

    p = sub.add_parser(
        "frc",
        help="frequency response of a model (CSV, optional PNG)",
        description="Frequency response of a model: every branch the method finds, with\n"
        "stability, as CSV (standard output unless --out) and an optional PNG. With --plot\n"
        "and no --out the terminal gets a short summary instead of the CSV.",
        epilog=_methods_epilog(("auto", "reference", "symbolic", "numeric")),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "model",
        help="builtin model or system name (perturb models), an equation string, or one "
        "equation per coordinate separated by ';'",
    )
    p.add_argument(
        "--method",
        help=f"{', '.join(names())} (default: hb1); a system of several coordinates takes "
        "exact (its default), hb, hb1, shb or auto; see the list below",
    )
    p.add_argument(
        "--param",
        action="append",
        metavar="NAME=VALUE",
        help="parameter value, repeatable (default: the model's defaults)",
    )
    p.add_argument(
        "--omega",
        default="0.2:2.0",
        help="start:stop (traced curve), start:stop:count or w1,w2,... (exactly these "
        f"frequencies, at most {MAX_FREQUENCIES}), within {OMEGA_RANGE[0]:g} to "
        f"{OMEGA_RANGE[1]:g} (default: 0.2:2.0)",
    )
    p.add_argument(
        "--points",
        type=int,
        default=2000,
        help=f"curve resolution for start:stop, at most {MAX_POINTS} (default: 2000)",
    )
    p.add_argument(
        "--order",
        type=int,
        help=f"expansion order of mlp, ms, lp, 1 to {MAX_ORDER} (default: the method's, 1 "
        "for mlp and ms, 2 for lp)",
    )
    p.add_argument(
        "--harmonics",
        type=_harmonics_arg,
        help=f"harmonics of --method hb, 1 to {MAX_HARMONICS} (default: 15; for lp and mlp: "
        "of their Fourier series, default 15); for --method shb the harmonic set, a comma "
        "list such as 1,3 (default: 1)",
    )
    p.add_argument(
        "--one-branch",
        action="store_true",
        help="--method hb: only the branch connected to the high end of the window "
        "(default: every branch found from seeds, branch points and mirror images)",
    )
    p.add_argument(
        "--compare",
        choices=["exact"],
        help="add a rel_error column against the exact solution (default: none)",
    )
    p.add_argument(
        "--output",
        help="systems: what the amplitude (simulate: the output column) measures, a "
        "coordinate or a linear combination such as x2 or 'x1 - x2' (default: the first "
        "coordinate); an oscillator takes x only",
    )
    p.add_argument("--out", help="CSV file (default: standard output)")
    p.add_argument("--plot", help="PNG file (default: none)")
    p.set_defaults(func=_cmd_frc)

    p = sub.add_parser("simulate", help="time history (exact, event-driven, LCP or ODE)")
    p.add_argument(
        "model",
        help="builtin model or system name, an equation string, or one equation per "
        "coordinate separated by ';'",
    )
    p.add_argument("--param", action="append", metavar="NAME=VALUE", help="parameter value")
    p.add_argument(
        "--y0",
        help="initial state x0,v0 (default 0,0); for a system its states in the order "
        "perturb models lists (default all 0)",
    )
    p.add_argument(
        "--t",
        default="0:100",
        help=f"time span t0:t1 (default 0:100), at most {MAX_PERIODS} periods of "
        "2 pi/max(Omega, 1)",
    )
    p.add_argument(
        "--samples",
        type=int,
        default=2001,
        help=f"output samples (default 2001, at most {MAX_SAMPLES})",
    )
    p.add_argument(
        "--method",
        default="auto",
        help="auto, exact, event, lcp or ode (default auto); a system: auto, exact, ode or "
        "events (auto: events with stops or friction, exact when piecewise affine, else ode)",
    )
    p.add_argument("--h", type=_finite("--h"), help="LCP step (default: period/200)")
    p.add_argument(
        "--output",
        help="systems: what the amplitude (simulate: the output column) measures, a "
        "coordinate or a linear combination such as x2 or 'x1 - x2' (default: the first "
        "coordinate); an oscillator takes x only",
    )
    p.add_argument(
        "--out",
        help="CSV file t,x,v (a system: t, every state, output) (default: standard output)",
    )
    p.add_argument("--plot", help="PNG file")
    p.set_defaults(func=_cmd_simulate)

    p = sub.add_parser("periodic", help="all periodic orbits at one forcing frequency")
    p.add_argument(
        "model",
        help="builtin model or system name, an equation string, or one equation per "
        "coordinate separated by ';'",
    )
    p.add_argument("--param", action="append", metavar="NAME=VALUE", help="parameter value")
    p.add_argument(
        "--omega",
        type=_finite("--omega"),
        help="forcing frequency (required, except for an autonomous system such as belt or "
        "drill_string: its limit cycles have their own period, and --omega is refused)",
    )
    p.add_argument(
        "--m",
        type=int,
        default=1,
        help=f"forcing periods per orbit (default 1, at most {MAX_SUBHARMONIC})",
    )
    p.add_argument(
        "--invariants",
        metavar="V1[,V2...]",
        help="systems with conserved combinations (mount_linear: p1 + 100*p2): the period-mean "
        "value of each, pinning one orbit of the family (default 0, the rest state's)",
    )
    p.add_argument(
        "--output",
        help="systems: what the amplitude (simulate: the output column) measures, a "
        "coordinate or a linear combination such as x2 or 'x1 - x2' (default: the first "
        "coordinate); an oscillator takes x only",
    )
    p.add_argument(
        "--method",
        choices=["exact", "hb"],
        help="autonomous systems: exact (default: shooting from settled runs, equilibria too) "
        "or hb (autonomous harmonic balance, --harmonics H, one cycle)",
    )
    p.add_argument(
        "--harmonics",
        type=int,
        help=f"--method hb: harmonics, 1 to {MAX_HARMONICS} (default 7)",
    )
    p.add_argument("--out", help="CSV file (default: standard output)")
    p.set_defaults(func=_cmd_periodic)

    p = sub.add_parser(
        "derive",
        help="derive an approximation (text, LaTeX, JSON)",
        epilog=_methods_epilog(("symbolic",)),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "method",
        help="method short name: "
        + ", ".join(symbolic_names())
        + "; for a system of several coordinates: "
        + ", ".join(SYSTEM_DERIVATION_NAMES),
    )
    p.add_argument("model", help="builtin model name or an equation string")
    p.add_argument(
        "--order",
        type=int,
        help=f"expansion order, for ms, lp and mlp, 1 to {MAX_ORDER} (default: the method's)",
    )
    p.add_argument("--param", action="append", metavar="NAME=VALUE", help="parameter value")
    p.add_argument("--latex", help="write a standalone LaTeX document")
    p.add_argument("--json", help="write the approximation as JSON (expressions as srepr)")
    p.add_argument("--no-cache", action="store_true", help="do not read or write the cache")
    p.set_defaults(func=_cmd_derive)

    p = sub.add_parser("run", help="answer a scene file (default: the embedded default scene)")
    p.add_argument("scene", nargs="?", help="scene TOML file")
    p.add_argument("--out", default="out", help="output directory (default ./out)")
    p.add_argument(
        "--rtol", type=_finite("--rtol"), help="override [accuracy] rtol of a method = auto scene"
    )
    p.set_defaults(func=_cmd_run)

    from perturb.apps.grid_cli import add_parser as add_sweep_parser

    add_sweep_parser(sub)
    from perturb.apps.bench import add_parser as add_bench_parser

    add_bench_parser(sub)
    return parser


def _debug() -> bool:
    return os.environ.get(DEBUG_ENV, "") not in ("", "0")


def _one_line(text: str) -> str:
    """``text`` on one line (a multi-line message joined with ' | ')."""
    return " | ".join(part.strip() for part in str(text).splitlines() if part.strip())


def _error(message: str) -> None:
    with contextlib.suppress(Exception):
        sys.stderr.write(f"perturb: error: {_one_line(message)}\n")
        sys.stderr.flush()


def _os_error_message(exc: OSError) -> str:
    what = exc.strerror or str(exc) or type(exc).__name__
    name = exc.filename
    if name is not None:
        return f"cannot write or read {os.fspath(name)!r}: {what}"
    return f"input/output error: {what}"


#: Seconds between a signal and a forced exit when the main thread cannot act on it (a long
#: computation in compiled code, or clean-up that hangs).
_GRACE = 5.0


#: Whether :func:`_signals` is active in this process (forked children reset it).
_SIGNALS_ACTIVE = False


def _reset_signals_in_child() -> None:
    """In a forked child (process pools): default SIGTERM and no wakeup fd, so a signal to the
    child neither raises :class:`_Terminated` there nor wakes the parent's watchdog through
    the inherited pipe."""
    global _SIGNALS_ACTIVE
    if not _SIGNALS_ACTIVE:
        return
    _SIGNALS_ACTIVE = False
    with contextlib.suppress(ValueError, OSError):
        signal.set_wakeup_fd(-1)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_reset_signals_in_child)


@contextlib.contextmanager
def _signals() -> Iterator[None]:
    """SIGTERM raises :class:`_Terminated` in the main thread (SIGINT raises
    KeyboardInterrupt as always), so ``finally`` blocks run and temporary files are removed;
    a watchdog thread woken by the signal itself (``signal.set_wakeup_fd``, written by the
    C-level handler even while the main thread is busy in compiled code) ends the process
    ``_GRACE`` seconds later if it is still running. Installed only in the main thread;
    everything is restored on exit."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def on_term(signum, frame):
        raise _Terminated()

    old_term = signal.signal(signal.SIGTERM, on_term)
    r, w = os.pipe()
    os.set_blocking(w, False)
    try:
        old_fd = signal.set_wakeup_fd(w, warn_on_full_buffer=False)
    except (ValueError, OSError):  # pragma: no cover - not the main thread after all
        old_fd = None
    done = threading.Event()

    def watchdog() -> None:
        while True:
            try:
                data = os.read(r, 64)
            except OSError:
                return
            if not data or done.is_set():
                return
            sigs = set(data) & {signal.SIGINT, signal.SIGTERM}
            if not sigs:
                continue
            if done.wait(_GRACE):
                return
            code = 143 if signal.SIGTERM in sigs else 130
            _error(
                ("terminated" if code == 143 else "interrupted")
                + f": did not stop within {_GRACE:g} s, exiting now"
            )
            os._exit(code)

    global _SIGNALS_ACTIVE
    thread = threading.Thread(target=watchdog, name="perturb-signal-watchdog", daemon=True)
    thread.start()
    _SIGNALS_ACTIVE = True
    try:
        yield
    finally:
        _SIGNALS_ACTIVE = False
        done.set()
        if old_fd is not None:
            with contextlib.suppress(ValueError, OSError):
                signal.set_wakeup_fd(old_fd)
        signal.signal(signal.SIGTERM, old_term)
        os.close(w)  # the watchdog reads end-of-file and returns
        thread.join(1.0)
        with contextlib.suppress(OSError):
            os.close(r)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``perturb`` console script.

    Returns the exit status: 0 on success, 2 on any error (one line ``perturb: error: ...`` on
    standard error), 130 after Ctrl-C and 143 after SIGTERM.
    """
    try:
        with _signals(), warnings.catch_warnings():
            warnings.showwarning = _show_warning
            return _main(argv)
    except KeyboardInterrupt:
        _error("interrupted (Ctrl-C); outputs are complete or absent")
        return 130
    except _Terminated:
        _error("terminated (SIGTERM); outputs are complete or absent")
        return 143


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """A library warning as one line ``perturb: warning: ...`` (no file path, no source line);
    with ``PERTURB_DEBUG=1`` Python's own format."""
    if _debug():
        sys.stderr.write(warnings.formatwarning(message, category, filename, lineno, line))
        return
    text = " ".join(str(message).split())
    print(f"perturb: warning: {text}", file=sys.stderr)


def _main(argv: Sequence[str] | None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except _UsageError as exc:
        _error(str(exc))
        return 2
    if not getattr(args, "command", None):
        parser.print_help()
        return 0
    try:
        return int(args.func(args))
    except PerturbError as exc:
        _error(str(exc))
        return 2
    except BrokenPipeError:  # output piped into `head` and closed: not an error
        with contextlib.suppress(Exception):
            sys.stderr.close()
        return 0
    except OSError as exc:  # an output folder that vanished, a full disk, ...
        if _debug():
            raise
        _error(_os_error_message(exc))
        return 2
    except MemoryError:
        _error("out of memory: ask for fewer harmonics, points, samples or a smaller window")
        return 2
    except RecursionError:
        _error("the input is nested too deeply to process")
        return 2
    except Exception as exc:  # noqa: BLE001 - the promise is one line, whatever failed
        if _debug():
            raise
        text = _one_line(str(exc))[:300]
        _error(
            f"internal error {type(exc).__name__}"
            + (f": {text}" if text else "")
            + f" (please report it; rerun with {DEBUG_ENV}=1 for the traceback)"
        )
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
