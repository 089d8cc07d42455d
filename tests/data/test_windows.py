"""Training windows and their order: every window once per epoch, ranks disjoint, derived from the step alone."""

from __future__ import annotations

import numpy as np
import pytest

from gns_framework.data.trajectory import Trajectory
from gns_framework.data.windows import WindowIndex, WindowOrder


def trajectory(frames: int, particles: int, offset: float = 0.0) -> Trajectory:
    position = offset + np.arange(frames, dtype=np.float32)[:, None, None] * np.ones((1, particles, 2), np.float32)
    return Trajectory(position, np.full(particles, 5, np.int64))


def test_every_window_of_every_trajectory_is_indexed_with_its_target_and_frames_ahead():
    index = WindowIndex([trajectory(10, 3), trajectory(8, 5, offset=100.0)], history=6, ahead=1)
    # 10 - 6 - 1 = 3 windows, then 8 - 6 - 1 = 1.
    assert len(index) == 4
    assert [index.num_particles(i) for i in range(4)] == [3, 3, 3, 5]
    last = index.example(3)
    np.testing.assert_array_equal(last.position_sequence[0, :, 0].numpy(), 100.0 + np.arange(6))
    assert float(last.next_position[0, 0]) == 106.0 and float(last.ahead[0, 0, 0]) == 107.0


def test_too_short_trajectories_are_refused_naming_the_frames_needed():
    with pytest.raises(ValueError, match="history \\+ frames ahead = 7 frames"):
        WindowIndex([trajectory(7, 2)], history=6, ahead=1)


def test_each_epoch_visits_every_window_once_and_ranks_take_disjoint_shares():
    windows, batch, ranks = 10, 2, 2
    orders = [WindowOrder(windows, batch, seed=3, rank=r, world_size=ranks) for r in range(ranks)]
    steps_per_epoch = windows // (batch * ranks)
    seen = [w for step in range(steps_per_epoch) for order in orders for w in order.draw(step).mine]
    assert len(seen) == len(set(seen)) == steps_per_epoch * batch * ranks
    # Within an epoch; a step that straddles two epochs may give both ranks one window again.
    for step in range(steps_per_epoch):
        assert not set(orders[0].draw(step).mine) & set(orders[1].draw(step).mine)


def test_the_order_is_a_function_of_the_step_so_a_resumed_run_sees_the_same_windows():
    straight = WindowOrder(50, 4, seed=1)
    sequence = [straight.draw(step).mine for step in range(40)]
    resumed = WindowOrder(50, 4, seed=1)
    assert [resumed.draw(step).mine for step in range(20, 40)] == sequence[20:]
    assert WindowOrder(50, 4, seed=2).draw(0).mine != sequence[0]


def test_a_step_draws_its_global_batch_rank_major_and_each_rank_its_slots_of_it():
    orders = [WindowOrder(10, 2, seed=3, rank=r, world_size=2) for r in range(2)]
    drawn = [order.draw(4) for order in orders]
    assert drawn[0].every == drawn[1].every and len(drawn[0].every) == 4 and drawn[0].step == 4
    assert list(drawn[0].slots) == [0, 1] and list(drawn[1].slots) == [2, 3]
    assert drawn[0].mine + drawn[1].mine == drawn[0].every
    assert WindowOrder(10, 4, seed=3).draw(4).every == drawn[0].every  # one process of 4 windows: the same batch
