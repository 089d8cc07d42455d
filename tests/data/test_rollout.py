"""The rollout record: a true trajectory and the predicted frames after its first C."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest


def test_the_views_slice_the_truth_at_the_history(make_rollout):
    rollout = make_rollout(steps=8, particles=12, history=6)
    np.testing.assert_array_equal(rollout.initial_positions, rollout.truth.position[:6])
    np.testing.assert_array_equal(rollout.ground_truth, rollout.truth.position[6:])
    np.testing.assert_array_equal(rollout.predicted_trajectory()[6:], rollout.predicted)
    assert (rollout.num_steps, rollout.num_particles, rollout.dim, rollout.key) == (8, 12, 2, "memory")


def test_a_prediction_of_other_frames_is_refused(make_rollout):
    rollout = make_rollout(steps=8, history=6)
    with pytest.raises(ValueError, match=r"predicted: expected shape \(8, 12, 2\), got \(7, 12, 2\)"):
        replace(rollout, predicted=rollout.predicted[:7])
    with pytest.raises(ValueError, match="history: expected 1 to 13"):
        replace(rollout, history=14)


def test_position_mse_counts_the_predicted_particles_only(make_rollout):
    rollout = make_rollout(steps=2, particles=4, history=6)
    with pytest.raises(ValueError, match="which particles the model predicts is not recorded"):
        rollout.position_mse  # noqa: B018 - reading the property is what raises
    moving = np.array([True, True, False, False])
    # The fixture's prediction is off by 0.001 k in every component at step k.
    assert replace(rollout, predicted_particles=moving).position_mse == pytest.approx(1e-6 * (1 + 4) / 2, rel=1e-3)
