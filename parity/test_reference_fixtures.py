"""The built-in components, loaded with the reference's parameters, reproduce every stored output.

One test per (case, stage); cases are every fixture in the parity folder. Failures
list each quantity over its tolerance, with where the worst difference is.
"""

from __future__ import annotations

import pytest

from .harness import STAGES, compare_case


@pytest.mark.parametrize("stage", STAGES)
def test_stage_matches_reference(reference_case, stage, record_deviations):
    deviations = compare_case(reference_case, reference_case.import_model(), [stage])
    record_deviations(reference_case.name, deviations)
    assert deviations
    failed = [str(d) for d in deviations if not d.ok]
    assert not failed, f"{reference_case.name}, {stage}:\n  " + "\n  ".join(failed)


def test_case_uses_the_documented_format(reference_case):
    """The suite relies on these members; a new case must carry them."""
    required = [
        "input/position_sequence",
        "input/trajectory",
        "input/particle_type",
        "input/nparticles_per_example",
        "pre/node_features",
        "pre/edge_index",
        "canon/out/normalized_acceleration",
        "canon/rollout/predicted",
        "train/position_noise",
        "canon/train/loss",
        "stats/param_keys",
        "canon/stats/gradnorm",
    ]
    missing = [key for key in required if key not in reference_case]
    assert not missing, f"{reference_case.path}: missing members {missing}"
    assert reference_case.meta["reference"]["repository"].endswith("geoelements/gns")


@pytest.mark.parametrize("stage", ["latents", "outputs", "training"])
def test_the_plain_interaction_step_matches_reference(reference_case, stage):
    """The paper's form of the step (``edge_block: plain``), not only the fused one, reproduces the reference."""
    imported = reference_case.import_model()
    steps = getattr(imported.simulator.processor, "steps", None)
    if steps is None:
        pytest.skip(f"{reference_case.name}: its processor has no interaction steps")
    for step in steps:
        step.edge_block = "plain"
    deviations = compare_case(reference_case, imported, [stage])
    failed = [str(d) for d in deviations if not d.ok]
    assert deviations and not failed, f"{reference_case.name}, {stage} (plain):\n  " + "\n  ".join(failed)
