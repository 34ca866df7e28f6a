"""The ``perturb`` command.

Subcommands::

    perturb --version
    perturb models                                  list the builtin models
    perturb fourier "EXPR" --A 2 [--b 0] --n 15     Fourier coefficients of a force f(x)
    perturb frc MODEL [--method hb1] [--param k=-2 ...] [--omega 0.2:2.0[:N] | w1,w2]
                      [--out frc.csv] [--plot frc.png]
    perturb simulate MODEL [--param ...] --y0 x,v --t 0:100 [--method auto|exact|event|lcp|ode]
    perturb periodic MODEL [--param ...] --omega 0.6 [--m 1]
    perturb derive METHOD MODEL [--order N] [--param ...] [--latex F.tex] [--json F.json]
    perturb run [SCENE.toml] [--out DIR] [--rtol R] answer a scene (default: the embedded one)

Errors a user can cause print one line ``perturb: error: ...`` and exit with status 2;
nothing typed on the command line is evaluated as code.
"""

from __future__ import annotations

import argparse
import math
import re
import sys
from collections.abc import Sequence
from pathlib import Path

from . import __version__
from .errors import ParameterError, PerturbError

__all__ = ["main", "parse_param", "parse_omega"]

_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]*")


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
        number = float(value)
    except ValueError:
        raise ParameterError(f"--param {text!r}: value {value!r} is not a number") from None
    if not math.isfinite(number):
        raise ParameterError(f"--param {text!r}: expected a finite number, got {value}")
    return name, number


def _finite(flag: str):
    def convert(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{flag} {text!r}: expected a number") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"{flag} {text!r}: expected a finite number")
        return value

    return convert


def _cmd_models(args: argparse.Namespace) -> int:
    from .model import BUILTIN_MODELS

    for spec in BUILTIN_MODELS.values():
        defaults = ", ".join(f"{k}={v:g}" for k, v in spec.defaults.items())
        print(f"{spec.name}")
        print(f"    {spec.equation}")
        print(f"    {spec.description}")
        print(f"    defaults: {defaults}")
    return 0


def _cmd_fourier(args: argparse.Namespace) -> int:
    import sympy as sp

    from .fourier_symbols import series_coefficients
    from .parsing import parse_expression, real_symbol

    expr = parse_expression(args.expr)
    x = real_symbol(args.var)
    values = dict(parse_param(p) for p in args.param or ())
    subs = {real_symbol(k): sp.Float(v) for k, v in values.items()}
    expr = expr.xreplace(subs)
    free = sorted(s.name for s in expr.free_symbols if s != x)
    if free:
        raise ParameterError(
            f"expression {args.expr!r} has parameters without values: {', '.join(free)}; "
            "give them with --param NAME=VALUE"
        )
    if args.A < 0:
        raise ParameterError(f"--A {args.A}: expected an amplitude >= 0")
    if args.n < 0 or args.n > 100_000:
        raise ParameterError(f"--n {args.n}: expected 0 <= n <= 100000")
    print(f"# Fourier coefficients of f({args.var}) = {args.expr}")
    print(f"# under {args.var} = A cos(psi) + b, A = {args.A:g}, b = {args.b:g}:")
    print("# f = a_0/2 + sum_n a_n cos(n psi)   (no sine terms: f depends on x alone)")
    print("n,a_n")
    for n, value in enumerate(series_coefficients(expr, x, args.n, args.A, args.b)):
        print(f"{n},{float(value):.17g}")
    return 0


def parse_omega(text: str) -> tuple[str, list[float]]:
    """``--omega`` forms: ``lo:hi`` (a traced curve), ``lo:hi:count`` (exactly ``count``
    equally spaced frequencies) or ``w1,w2,...`` (exactly those frequencies).

    Returns ``("range", [lo, hi])`` or ``("points", [...])``.

    Raises
    ------
    ParameterError
        Naming the bad text.
    """
    text = text.strip()
    usage = f"--omega {text!r}: expected start:stop, start:stop:count or a list like 0.6,0.9"
    parts = text.split(":")
    try:
        numbers = [float(p) for p in parts] if ":" in text else []
        values = [float(w) for w in text.split(",") if w.strip()] if ":" not in text else []
    except ValueError:
        raise ParameterError(usage) from None
    if ":" in text:
        if len(parts) not in (2, 3):
            raise ParameterError(usage)
        lo, hi = numbers[0], numbers[1]
        if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo < hi):
            raise ParameterError(f"--omega {text!r}: expected 0 < start < stop")
        if len(parts) == 2:
            return "range", [lo, hi]
        count = numbers[2]
        if count != int(count) or not 2 <= count <= 1_000_000:
            raise ParameterError(f"--omega {text!r}: expected a whole count from 2 to 1e6")
        # decimal arithmetic on the typed numbers, so 0.5:0.7:5 gives 0.65, not
        # 0.6499999999999999: the values written are the values a reader expects
        from decimal import Decimal

        a, b, n = Decimal(parts[0].strip()), Decimal(parts[1].strip()), int(count)
        return "points", [float(a + (b - a) * i / (n - 1)) for i in range(n)]
    if not values:
        raise ParameterError(usage)
    if not all(math.isfinite(w) and w > 0 for w in values):
        raise ParameterError(f"--omega {text!r}: frequencies must be positive and finite")
    return "points", values


def _model_from_arg(text: str, params: dict[str, float]):
    from .model import BUILTIN_MODELS, Oscillator, builtin_model

    if text in BUILTIN_MODELS:
        return builtin_model(text, **params)
    if "''" in text:
        return Oscillator.parse(text, params)
    raise PerturbError(
        f"model {text!r}: expected a builtin name ({', '.join(BUILTIN_MODELS)}) or an "
        "equation such as \"x'' + mu*x' + x + x**3 = F*cos(Omega*t)\""
    )


def _cmd_frc(args: argparse.Namespace) -> int:
    from .api import ALIASES, frequency_response
    from .methods import METHODS
    from .report.figures import plot_frequency_response

    params = dict(parse_param(p) for p in args.param or ())
    osc = _model_from_arg(args.model, params)
    method = ALIASES.get(args.method, args.method)
    if method not in ("exact", "hb") and method not in METHODS:
        names = ["exact", *ALIASES, *METHODS]
        raise PerturbError(f"--method {args.method!r}: expected one of {', '.join(names)}")
    if args.compare not in (None, "exact"):
        raise PerturbError(f"--compare {args.compare!r}: expected exact")
    kind, omegas = parse_omega(args.omega)
    extra = {"harmonics": args.harmonics} if method == "hb" else {"order": args.order}
    if method == "exact":
        extra = {}
    if kind == "range" and method in ("exact", "hb"):
        resp = frequency_response(osc, method, omegas, **extra)
    elif kind == "range":
        resp = frequency_response(osc, method, omegas, points=args.points, **extra)
    else:
        resp = frequency_response(osc, method, frequencies=omegas, **extra)
    print(repr(resp), file=sys.stderr)
    rel = None
    if args.compare == "exact":
        from .numeric.compare import compare, relative_errors

        if kind == "range":
            ref = frequency_response(osc, "exact", omegas)
        else:
            ref = frequency_response(osc, "exact", frequencies=omegas)
        rel = relative_errors(resp, ref)
        print(str(compare(resp, ref)), file=sys.stderr)
    text = resp.to_csv(args.out, extra=None if rel is None else {"rel_error": rel})
    if args.out is None:
        sys.stdout.write(text)
    if args.plot:
        plot_frequency_response(resp, args.plot)
    return 0


def _pair(flag: str, text: str) -> list[float]:
    try:
        values = [float(p) for p in text.split(",")]
    except ValueError:
        raise ParameterError(f"{flag} {text!r}: expected two numbers like 0.3,0.1") from None
    if len(values) != 2 or not all(math.isfinite(v) for v in values):
        raise ParameterError(f"{flag} {text!r}: expected two finite numbers like 0.3,0.1")
    return values


def _cmd_simulate(args: argparse.Namespace) -> int:
    from .simulate.time_history import time_history

    params = dict(parse_param(p) for p in args.param or ())
    osc = _model_from_arg(args.model, params)
    t0, t1 = _pair("--t", args.t.replace(":", ","))
    hist = time_history(
        osc, _pair("--y0", args.y0), (t0, t1), method=args.method, samples=args.samples, h=args.h
    )
    print(repr(hist), file=sys.stderr)
    text = hist.to_csv(args.out)
    if args.out is None:
        sys.stdout.write(text)
    if args.plot:
        from .report.figures import plot_time_history

        plot_time_history(hist, args.plot, title=str(osc))
    return 0


def _cmd_periodic(args: argparse.Namespace) -> int:
    from .simulate.orbits import periodic_orbits

    params = dict(parse_param(p) for p in args.param or ())
    osc = _model_from_arg(args.model, params)
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
        with open(args.out, "w") as fh:
            fh.write(text)
    else:
        sys.stdout.write(text)
    print(f"{len(orbits)} period-{args.m} orbits at Omega = {args.omega}", file=sys.stderr)
    return 0


def _cmd_derive(args: argparse.Namespace) -> int:
    import inspect
    import json

    from .cache import cached_derivation
    from .methods import METHODS
    from .report.latex import latex_document
    from .serialize import approximation_to_dict

    if args.method not in METHODS:
        raise PerturbError(f"method {args.method!r}: expected one of {', '.join(METHODS)}")
    fn = METHODS[args.method]
    params = dict(parse_param(p) for p in args.param or ())
    osc = _model_from_arg(args.model, params)
    options = {}
    if args.order is not None:
        if "order" not in inspect.signature(fn).parameters:
            raise PerturbError(f"method {args.method!r} has no --order option")
        if args.order < 1:
            raise ParameterError(f"--order {args.order}: expected an order >= 1")
        options["order"] = args.order
    approx = cached_derivation(args.method, fn, osc, use_cache=not args.no_cache, **options)
    # files first: the summary may go to a pipe that closes early
    if args.latex:
        latex_document(approx, args.latex)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(approximation_to_dict(approx), fh, indent=1, sort_keys=True)
    print(str(approx))
    return 0


def _cmd_run(args: argparse.Namespace) -> int:
    from .scene import default_scene, load_scene, run_scene

    if args.scene and _is_sweep_scene(args.scene):
        # a scene with a [sweep] table asks for a map: answer it as `perturb sweep` would,
        # into the output directory
        from .sweep_cli import build_args, cmd_sweep

        Path(args.out).mkdir(parents=True, exist_ok=True)
        return cmd_sweep(build_args(args.scene, str(Path(args.out) / "map.nc")))
    scene = load_scene(args.scene) if args.scene else default_scene()
    if args.rtol is not None:
        import dataclasses

        from .adaptive import check_rtol

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


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="perturb",
        description="Periodic responses of nonlinear and piecewise-linear oscillators.",
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
    p.add_argument("--n", type=int, default=10, help="highest harmonic (default 10)")
    p.add_argument("--var", default="x", help="the variable (default x)")
    p.add_argument("--param", action="append", metavar="NAME=VALUE", help="parameter value")
    p.set_defaults(func=_cmd_fourier)

    p = sub.add_parser("frc", help="frequency response of a model (CSV, optional PNG)")
    p.add_argument("model", help="builtin model name or an equation string")
    p.add_argument(
        "--method",
        default="hb1",
        help="hb1 (default), hb, mlp, mms (ms), avg (kb), vdp, lp or exact",
    )
    p.add_argument("--param", action="append", metavar="NAME=VALUE", help="parameter value")
    p.add_argument(
        "--omega",
        default="0.2:2.0",
        help="start:stop (traced curve), start:stop:count or w1,w2,... (exact frequencies)",
    )
    p.add_argument("--points", type=int, default=2000, help="curve resolution for start:stop")
    p.add_argument("--order", type=int, help="expansion order of the method (mlp, mms, lp)")
    p.add_argument("--harmonics", type=int, help="harmonics of --method hb (default 15)")
    p.add_argument("--compare", help="exact: add a rel_error column against the exact solution")
    p.add_argument("--out", help="CSV file (default: standard output)")
    p.add_argument("--plot", help="PNG file")
    p.set_defaults(func=_cmd_frc)

    p = sub.add_parser("simulate", help="time history (exact, event-driven, LCP or ODE)")
    p.add_argument("model", help="builtin model name or an equation string")
    p.add_argument("--param", action="append", metavar="NAME=VALUE", help="parameter value")
    p.add_argument("--y0", default="0,0", help="initial state x0,v0 (default 0,0)")
    p.add_argument("--t", default="0:100", help="time span t0:t1 (default 0:100)")
    p.add_argument("--samples", type=int, default=2001, help="output samples (default 2001)")
    p.add_argument("--method", default="auto", help="auto, exact, event, lcp or ode")
    p.add_argument("--h", type=_finite("--h"), help="LCP step (default: period/200)")
    p.add_argument("--out", help="CSV file t,x,v (default: standard output)")
    p.add_argument("--plot", help="PNG file")
    p.set_defaults(func=_cmd_simulate)

    p = sub.add_parser("periodic", help="all periodic orbits at one forcing frequency")
    p.add_argument("model", help="builtin model name or an equation string")
    p.add_argument("--param", action="append", metavar="NAME=VALUE", help="parameter value")
    p.add_argument("--omega", type=_finite("--omega"), required=True, help="forcing frequency")
    p.add_argument("--m", type=int, default=1, help="forcing periods per orbit (default 1)")
    p.add_argument("--out", help="CSV file (default: standard output)")
    p.set_defaults(func=_cmd_periodic)

    p = sub.add_parser("derive", help="derive an approximation (text, LaTeX, JSON)")
    p.add_argument("method", help="method short name (perturb.methods.METHODS)")
    p.add_argument("model", help="builtin model name or an equation string")
    p.add_argument("--order", type=int, help="expansion order, for methods that have one")
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

    from .sweep_cli import add_parser as add_sweep_parser

    add_sweep_parser(sub)
    from .bench import add_parser as add_bench_parser

    add_bench_parser(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``perturb`` console script."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "command", None):
        parser.print_help()
        return 0
    try:
        return int(args.func(args))
    except PerturbError as exc:
        print(f"perturb: error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # output piped into `head` and closed: not an error
        sys.stderr.close()
        return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
