"""The switch scan of one modal piece, compiled with numba when it is installed.

The same algorithm as :func:`perturb.simulate.flows.affine_exact._scan` and its helpers
(``_first_event``, ``_crossing_or_graze``, ``_solve_halley``, ``_solve``), written on arrays
for a piece of a modal region without resonant pairs (the common case): the switching
functions are exponential sums ``g_j(t) = Re sum_q W_jq e^{mu_q t}`` (times the side
``sigma_j``), their grid values and derivative bounds are loops over a handful of terms, and
the recursive bisection of ``_first_event`` is a depth-first stack.  The Python version
spends ~50 us per piece in the fixed cost of small numpy calls; compiled, the scan is a few
microseconds.

Results agree with the Python version to rounding (the sums are taken in another order), not
bit for bit.  Without numba (an optional dependency: ``pip install perturb[fast]``),
:func:`compiled_scan` is None and the Python version runs.  Set ``PERTURB_COMPILED=0`` to
turn the compiled scan off.  The kernel itself is :mod:`.scan_kernel_numba`; this module
holds what both versions share (the constants of the algorithm) and the switch.
"""

from __future__ import annotations

import importlib
import importlib.util
import os
import stat
import warnings

import numpy as np

#: machine epsilon
EPS = float(np.finfo(float).eps)
#: grid steps per fastest time scale 1/rho
STEPS_PER_SCALE = 8.0
#: grid intervals per batch: first batch, largest batch
BATCH_FIRST, BATCH_MAX = 32, 256
#: halvings of an interval before it is treated as one convex/concave piece
MAX_DEPTH = 60
#: iterations of the Newton-bisection root solvers (they stop at full precision long before)
ROOT_ITER = 200
#: intervals examined by one search for a surface's first event before giving up (a search
#: normally examines a few dozen)
MAX_NODES = 100_000

#: status codes of the compiled scan
NO_CROSSING, CROSSING, OVER_BUDGET, OVERFLOW, WRONG_SIDE, UNDECIDED = 0, 1, 2, 3, 4, 5
#: kinds of the events of ``first_event``
_NONE, _CROSS, _TANG, _UNDECIDED = 0, 1, 2, 3


def _private(path: str) -> bool:
    """Whether ``path`` (a directory, when it exists) is writable by its owner only, and that
    owner is the current user (or root): nobody else can plant files there."""
    try:
        st = os.stat(path)
    except OSError:
        return True  # (not there: numba creates it, with the user's umask)
    if st.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
        return False
    return not hasattr(os, "getuid") or st.st_uid in (os.getuid(), 0)


def _cache_ok() -> bool:
    """numba's cache loads its index with pickle, so it is used only where other users cannot
    write: this package's directories and ``__pycache__``, and ``NUMBA_CACHE_DIR`` when set
    (numba falls back to the user's own cache directory when the package's is read-only).
    Elsewhere the kernels are compiled once per process instead."""
    here = os.path.dirname(os.path.abspath(__file__))
    dirs = [here, os.path.join(here, "__pycache__")]
    up = os.path.join(os.path.dirname(here), "exact_response")
    dirs += [up, os.path.join(up, "__pycache__")]
    custom = os.environ.get("NUMBA_CACHE_DIR")
    if custom:
        dirs.append(custom)
    return all(_private(d) for d in dirs)


#: whether the compiled kernels keep their machine code in numba's cache (see _cache_ok)
CACHE_OK = _cache_ok()

_KERNEL: list = []  # [the compiled scan or None], once looked up
_KERNELS: dict = {}  # (module, name) -> the compiled function or None


def _off() -> bool:
    flag = os.environ.get("PERTURB_COMPILED", "1").strip().lower()
    return flag in ("0", "false", "no", "off")


def wanted() -> bool:
    """Whether the compiled kernels will be used (numba installed and not switched off),
    without importing numba: results agree with the numpy code's to rounding only, so a
    checkpointed sweep records it (a resume with the other setting would not be
    bit-identical)."""
    return not _off() and importlib.util.find_spec("numba") is not None


def _load(module: str):
    """Import a kernel module; None (with one warning) when numba is missing or unusable."""
    try:
        mod = importlib.import_module(module)
    except ImportError:
        return None
    except Exception as exc:  # numba present but broken (llvmlite, no cache location, ...)
        warnings.warn(
            f"perturb: the compiled kernels are off ({type(exc).__name__}: {exc}); "
            "the numpy code runs instead (PERTURB_COMPILED=0 silences this)",
            RuntimeWarning,
            stacklevel=3,
        )
        return None
    check = getattr(mod, "constants", None)
    if check is not None and tuple(check()) != _CONSTANTS:
        # numba froze the constants of an earlier scan_kernel.py into its cache (the cache
        # is keyed by the kernel module's own source): compile again from today's
        for obj in vars(mod).values():
            recompile = getattr(obj, "recompile", None)
            if callable(recompile) and getattr(obj, "py_func", None) is not None:
                recompile()
        if tuple(check()) != _CONSTANTS:
            warnings.warn(
                f"perturb: the compiled kernels of {module} keep constants other than "
                "scan_kernel's after recompiling; the numpy code runs instead",
                RuntimeWarning,
                stacklevel=3,
            )
            return None
    return mod


_CONSTANTS = (EPS, STEPS_PER_SCALE, BATCH_FIRST, BATCH_MAX, MAX_DEPTH, ROOT_ITER, MAX_NODES)


def compiled_kernel(module: str, name: str):
    """The function ``name`` of the numba module ``module`` (a dotted path in perturb), or
    None: numba not installed or unusable, or ``PERTURB_COMPILED=0``.  numba is imported at
    the first call, not with perturb; a kernel is compiled at its own first call, or loaded
    from numba's cache."""
    key = (module, name)
    if key not in _KERNELS:
        mod = None if _off() else _load(module)
        _KERNELS[key] = None if mod is None else getattr(mod, name)
    return _KERNELS[key]


def disable(module: str, name: str, exc: BaseException) -> None:
    """Turn a kernel off for this process after it failed to compile or run (a numba that
    cannot type it): one warning, then the numpy code."""
    _KERNELS[(module, name)] = None
    if name == "scan_modal":
        _KERNEL[:] = [None]
    warnings.warn(
        f"perturb: the compiled kernel {name} failed ({type(exc).__name__}: {exc}); the numpy "
        "code runs instead",
        RuntimeWarning,
        stacklevel=3,
    )


def compiled_scan():
    """The compiled scan ``scan_modal(W, Y, mupow, amupow, sig, absd, tol_ulps, tau_end,
    touching, budget_left, C, d, cc)``, or None (numba not installed or unusable, or
    ``PERTURB_COMPILED=0``)."""
    if not _KERNEL:
        _KERNEL.append(compiled_kernel("perturb.simulate.flows.scan_kernel_numba", "scan_modal"))
    return _KERNEL[0]
