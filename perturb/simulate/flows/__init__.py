"""Flows: the time-``t`` maps of the reference solvers (exact piecewise-analytic propagation,
event-driven integration, LCP time-stepping, plain ODE integration)."""
