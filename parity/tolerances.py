"""Float32 parity tolerances, from the fixture README ("Suggested parity tolerances").

They cover an implementation whose edge order differs from the reference's
(ours sorts by receiver, then sender): order only changes the rounding of the sum
aggregation, so order-free quantities are compared exactly (1e-6) and the rest at
the spread measured between edge orders of the reference itself.
"""

EXACT = 1e-6
"""Node and edge features, encoder latents, training target (abs)."""
PROCESSOR_LATENT = 5e-5
"""Node latents and (pair-matched) edge latents after the processor (abs)."""
NORMALIZED_ACCELERATION = 1e-4
"""Decoder output, inference and training (abs)."""
NEXT_POSITION = 2e-7
"""One predicted step, dataset units (abs)."""
LOSS_RELATIVE = 1e-5
"""Training loss (relative)."""
GRADIENT_RELATIVE_TO_MAX = 2e-3
"""Full gradient tensors: max |difference| / max |reference gradient| of the tensor."""
GRADIENT_NORM_RELATIVE = 5e-4
"""Gradient L2 norms (relative); also bounds sums via Cauchy-Schwarz, see :mod:`parity.harness`."""
ADAM_STEP = 2.5e-4
"""Parameters after one Adam step (abs): 2 * lr, since a ~0 gradient's sign may flip."""
ROLLOUT_FIRST_STEPS = 2e-6
"""Rollout positions, steps 1-5 (abs)."""
ROLLOUT_FIRST_STEP_COUNT = 5
ROLLOUT_ALL_STEPS = 5e-3
"""Rollout positions, all 20 steps (abs): a near-radius pair may change side late."""
