"""``python -m perturb``: the ``perturb`` command."""

from perturb.apps.cli import main

raise SystemExit(main())
