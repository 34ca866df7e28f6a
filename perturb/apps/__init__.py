"""Applications on top of the library: the ``perturb`` command, scenes, parameter grids and
the benchmark."""
