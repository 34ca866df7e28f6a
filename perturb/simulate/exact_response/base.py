"""Constants of the exact frequency response: node growth and node cap, statistics and
signature sampling, the join fraction, the statistics tolerance, the step-attempt and stall
caps, the multiplier ceiling, and the kinds of special points.

Part of :mod:`perturb.simulate.exact_response` (the method is described there).
"""

from __future__ import annotations

from typing import Literal

#: Largest growth of perturbations per shooting node before another node is added (beyond
#: ~100 the initial state alone no longer separates neighbouring orbits at 0.5 % spacing).
NODE_GROWTH = 100.0


#: Largest number of shooting nodes per forcing period.
MAX_NODES = 64


#: Samples per forcing period for the mean and the first harmonic (continuous PWL forces
#: alias like n^-5: ~1e-7 relative at 128); the extrema of x are refined by a quintic
#: Hermite interpolant of (x, v, a) (~1e-10 relative).
STAT_SAMPLES = 128


#: Phases per forcing period of the orbit signature (states compared by proximity tests).
SIG_PHASES = 8


#: A point lies on a traced curve within this fraction of the longest of ds_max, the curve's
#: segment and the point's own step (a sampled curve deviates from its chords by
#: kappa L^2 / 8, far below this unless the curve turns within a step).
JOIN_FRACTION = 0.25


#: Largest last Newton correction (scaled) whose iterate supplies the orbit statistics.
STATS_TOL = 1.0e-7


#: The same for a System of n states: its coordinates' maxima and multipliers are compared with
#: independent references to 1e-9 and 1e-7 (issue #15), which the oscillator's 1e-7 misses by
#: up to ~5e-9 and ~3e-7 (nsd2); 1e-9 costs ~10 % more corrector iterations.  A smaller ``tol``
#: tightens it to ``10 tol``.
ND_STATS_TOL = 1.0e-9


#: A march stops after this many consecutive steps no longer than STALL_DS * ds_min.
STALL_STEPS, STALL_DS = 100, 4.0


#: Largest number of predictor-corrector attempts for one continuation step.
MAX_STEP_ATTEMPTS = 400


#: A multiplier modulus above this is reported as this (e^700 would overflow later products).
MAX_MULTIPLIER = 1.0e300


SpecialKind = Literal["fold", "branch_point", "period_doubling", "torus", "grazing"]
