"""Parity suite: the built-in components against the reference implementation and the paper's equations."""
