"""Work-precision benchmark of every frequency-response method (issue 7 item 1).

Reproduce with::

    python benchmarks/work_precision.py --out out/bench

(the same as ``perturb bench --out out/bench``; measured 231 s wall, 246 s CPU at load
1.1-1.6 on 2 cores, 697 s wall / 285 s CPU at load 3-10; ``--fast`` for one run per method
and a 10 s timeout).  Writes ``work_precision.md``,
``work_precision.csv`` and one log-log work-precision PNG per problem into ``--out``; see
:mod:`perturb.apps.bench` for the problems, methods and what is timed.  ``--problems`` and
``--methods`` (fnmatch patterns such as ``hb-exact-*``) select a subset.
"""

from __future__ import annotations

import sys

from perturb.apps.bench import main

if __name__ == "__main__":
    sys.exit(main())
