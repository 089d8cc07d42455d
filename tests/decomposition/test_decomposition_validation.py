"""Validation of scenes split over 2 and 4 gloo processes gives rank 0 the single process's measures
(decomposition/validation.py)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from decomposition_cases import CASES, case_simulator, case_trajectory, diverging, pushforward_batch, validation_worker
from spawned import free_loopback_port, run_processes

from gns_framework.evaluation.candidates import learned_positions
from gns_framework.training.validation import one_step_errors

pytestmark = pytest.mark.usefixtures("one_torch_thread")

RELATIVE = 1e-10
"""float64 sums in another order: about 1e-16 relative per addition, over a few thousand terms."""


@pytest.fixture(scope="module")
def single_process() -> dict[str, dict]:
    return {
        name: {
            "one_step": one_step_errors(case_simulator(name).double().eval(), pushforward_batch(name)),
            "positions": learned_positions(case_simulator(name), case_trajectory(name), "cpu"),
        }
        for name in CASES
    }


@pytest.mark.parametrize("halo", ["positions", "latents"])
@pytest.mark.parametrize("processes", [2, 4])
def test_split_validation_gives_rank_0_the_single_process_measures(tmp_path, single_process, processes, halo):
    """2D and 3D, walls and periodic boundaries, kinematic particles, material properties, two windows per batch."""
    run_processes(validation_worker, (processes, free_loopback_port(), str(tmp_path), list(CASES), halo), processes)
    for name, reference in single_process.items():
        ranks = [torch.load(tmp_path / f"{name}-rank{rank}.pt", weights_only=False) for rank in range(processes)]
        # Every process gets the one-step errors (their sums are all-reduced); rank 0 alone the positions.
        for saved in ranks:
            assert saved["one_step"] == pytest.approx(reference["one_step"], rel=RELATIVE), name
        assert all(saved["positions"] is None and saved["diverged"] is None for saved in ranks[1:]), name
        rolled = reference["positions"]
        # One float32 rounding per step at most (tests/decomposition/test_decomposition_rollout.py).
        tolerance = np.finfo(np.float32).eps * float(np.abs(rolled).max()) * rolled.shape[0]
        np.testing.assert_allclose(ranks[0]["positions"], rolled, rtol=0, atol=tolerance, err_msg=name)
        # A diverged rollout is a result: NaN everywhere, as one process gives it.
        diverged = learned_positions(diverging(case_simulator(name)), case_trajectory(name), "cpu")
        assert np.isnan(diverged).all() and np.isnan(ranks[0]["diverged"]).all(), name
        assert ranks[0]["diverged"].shape == rolled.shape, name
