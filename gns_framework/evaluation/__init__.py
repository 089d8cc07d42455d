"""Evaluation of learned simulators: rollout files, metrics, honest timing and reports.

Submodules import their optional dependencies (geomloss, matplotlib) only when a
function that needs them runs, so importing this package stays cheap.
"""
