"""Measurement models of fgnav: pure numpy/numba residuals with analytic Jacobians,
and thin GTSAM adapters. This package never imports ``fgnav``."""
