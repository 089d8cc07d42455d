"""Inverse problems through the differentiable learned simulator (``gns invert``).

config    the validated YAML configuration
problem   unknowns -> model inputs -> learned rollout -> loss against the observation
rollout   the differentiable rollout, with gradient checkpointing
optimize  projected Adam and bounded L-BFGS-B over the scaled unknowns
solve     loading, searching and writing the results
"""
