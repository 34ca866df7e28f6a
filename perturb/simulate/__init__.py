"""Reference integrators: exact piecewise-analytic propagation, event-driven, shooting."""
