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
import os

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

#: status codes of :data:`scan_modal`
NO_CROSSING, CROSSING, OVER_BUDGET, OVERFLOW, WRONG_SIDE = 0, 1, 2, 3, 4
#: kinds of the events of ``first_event``
_NONE, _CROSS, _TANG = 0, 1, 2


_KERNEL: list = []  # [the compiled scan or None], once looked up
_KERNELS: dict = {}  # (module, name) -> the compiled function or None


def compiled_kernel(module: str, name: str):
    """The function ``name`` of the numba module ``module`` (a dotted path in perturb), or
    None: numba not installed, or ``PERTURB_COMPILED=0``.  numba is imported at the first
    call, not with perturb; a kernel is compiled at its own first call, or loaded from
    numba's cache."""
    key = (module, name)
    if key not in _KERNELS:
        kernel = None
        flag = os.environ.get("PERTURB_COMPILED", "1").strip().lower()
        if flag not in ("0", "false", "no", "off"):
            try:
                mod = importlib.import_module(module)
            except ImportError:
                pass
            else:
                kernel = getattr(mod, name)
        _KERNELS[key] = kernel
    return _KERNELS[key]


def compiled_scan():
    """The compiled scan ``scan_modal(W, Y, mupow, amupow, sig, absd, tol_ulps, tau_end,
    touching, budget_left)``, or None (numba not installed, or ``PERTURB_COMPILED=0``)."""
    if not _KERNEL:
        _KERNEL.append(compiled_kernel("perturb.simulate.flows.scan_kernel_numba", "scan_modal"))
    return _KERNEL[0]
