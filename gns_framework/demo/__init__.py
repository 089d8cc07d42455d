"""The embedded default: a small physical scene generated in-process, for the demo and tests."""
