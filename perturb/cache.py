"""On-disk cache of derivations, stored as text.

A derivation is keyed by the method, its options, the oscillator's equation (``srepr``) and
parameter values, perturb's version and a hash of the method's source file — so editing a
method invalidates its entries. Entries are JSON with expressions as ``srepr`` text, read back
by :func:`perturb.serialize.expr_from_text`, which never evaluates code: a tampered or
corrupted entry is recomputed, never trusted and never executed.

Location: ``$PERTURB_CACHE_DIR``, else ``$XDG_CACHE_HOME/perturb``, else
``~/.cache/perturb``; ``PERTURB_CACHE=0`` switches caching off.
"""

from __future__ import annotations

import hashlib
import inspect
import json
import os
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import sympy as sp

from .approximation import Approximation
from .errors import PerturbError
from .model import Oscillator
from .serialize import FORMAT_VERSION, approximation_from_dict, approximation_to_dict

__all__ = ["cache_dir", "cached_derivation", "derivation_key"]


def cache_dir() -> Path:
    """The cache folder (created on first write)."""
    if os.environ.get("PERTURB_CACHE_DIR"):
        return Path(os.environ["PERTURB_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "perturb"


def _source_hash(fn: Callable[..., Any]) -> str:
    try:
        module = sys.modules[fn.__module__]
        text = inspect.getsource(module)
    except (KeyError, OSError, TypeError):
        text = repr(fn)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def derivation_key(method: str, fn: Callable[..., Any], osc: Oscillator, options: dict) -> str:
    """The cache key: a hash of everything the derivation depends on."""
    from . import __version__

    payload = {
        "format": FORMAT_VERSION,
        "version": __version__,
        "method": method,
        "source": _source_hash(fn),
        "options": {k: repr(v) for k, v in sorted(options.items())},
        "equation": sp.srepr(osc.equation),
        "params": {k: repr(v) for k, v in sorted(osc.params.items())},
    }
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()


def cached_derivation(
    method: str,
    fn: Callable[..., Approximation],
    osc: Oscillator,
    *,
    use_cache: bool | None = None,
    **options: Any,
) -> Approximation:
    """``fn(osc, **options)``, from the cache when an intact entry exists.

    The result is identical either way (same expressions and steps); a cache that cannot be
    read or written only costs time.
    """
    if use_cache is None:
        use_cache = os.environ.get("PERTURB_CACHE", "1") != "0"
    if not use_cache:
        return fn(osc, **options)
    key = derivation_key(method, fn, osc, options)
    path = cache_dir() / f"{key}.json"
    if path.is_file():
        try:
            data = json.loads(path.read_text())
            return approximation_from_dict(data, osc)
        except (OSError, ValueError, KeyError, TypeError, PerturbError):
            pass  # corrupted or foreign entry: recompute and overwrite below
    approx = fn(osc, **options)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        text = json.dumps(approximation_to_dict(approx), sort_keys=True)
        with tempfile.NamedTemporaryFile("w", dir=path.parent, delete=False, suffix=".tmp") as fh:
            fh.write(text)
        os.replace(fh.name, path)
    except OSError:
        pass  # a read-only or full disk must not break the derivation
    return approx
