"""Training windows and their order: every window once per epoch, ranks disjoint, derived from the step alone."""

from __future__ import annotations

import numpy as np
import pytest

from gns_framework.data.trajectory import Trajectory
from gns_framework.data.windows import WindowIndex, WindowOrder, window_noise_generator


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
    with pytest.raises(ValueError, match="history \\+ push-forward = 7 frames"):
        WindowIndex([trajectory(7, 2)], history=6, ahead=1)


def test_each_epoch_visits_every_window_once_and_ranks_take_disjoint_shares():
    windows, batch, ranks = 10, 2, 2
    orders = [WindowOrder(windows, batch, seed=3, rank=r, world_size=ranks) for r in range(ranks)]
    steps_per_epoch = windows // (batch * ranks)
    seen = [w for step in range(steps_per_epoch) for order in orders for w in order.indices(step)]
    assert len(seen) == len(set(seen)) == steps_per_epoch * batch * ranks
    # Within an epoch; a step that straddles two epochs may give both ranks one window again.
    for step in range(steps_per_epoch):
        assert not set(orders[0].indices(step)) & set(orders[1].indices(step))


def test_the_order_is_a_function_of_the_step_so_a_resumed_run_sees_the_same_windows():
    straight = WindowOrder(50, 4, seed=1)
    sequence = [straight.indices(step) for step in range(40)]
    resumed = WindowOrder(50, 4, seed=1)
    assert [resumed.indices(step) for step in range(20, 40)] == sequence[20:]
    assert WindowOrder(50, 4, seed=2).indices(0) != sequence[0]


def test_one_process_of_w_windows_gets_the_noise_of_w_processes_of_one():
    one = [window_noise_generator(0, 5, slot).initial_seed() for slot in range(4)]
    assert len(set(one)) == 4, "every window of a step its own stream"
    assert window_noise_generator(0, 5, 2).initial_seed() == one[2]
    assert window_noise_generator(0, 6, 2).initial_seed() != one[2]
