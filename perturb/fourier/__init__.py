"""The Fourier layer: closed-form Fourier coefficients of nonsmooth terms.

- :mod:`perturb.fourier.coefficients`: numeric coefficients (vectorised, closed form);
- :mod:`perturb.fourier.symbols`: the same coefficients as SymPy functions for derivations;
- :mod:`perturb.fourier.trig`: harmonic bookkeeping of trigonometric polynomials;
- :mod:`perturb.fourier.projection`: exact Galerkin projection of piecewise-linear forces on
  multi-harmonic signals (switching angles, projection and its Jacobian).
"""
