"""Numerical kernels the built-in components share: not components themselves (none is registered).

A module here that assigns ``IMPLEMENTS`` computes faster what the code it names computes plainly (the
interaction network's edge block: chunked, fused C loops, Triton); its mirror tests hold the two equal, so
a reader follows the plain form, and ``benchmarks/reading_cost.py`` counts such modules apart.
"""
