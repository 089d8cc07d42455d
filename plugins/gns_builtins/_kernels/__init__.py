"""Numerical kernels the built-in components share: not components themselves (none is registered)."""
