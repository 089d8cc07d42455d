"""One scene over several processes: slabs or blocks, halos, the exchanges between processes, a rollout and a training
step.

docs/domain_decomposition.md says how to launch it and what it measured.
"""
