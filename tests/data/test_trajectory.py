"""The trajectory record: validated shapes and values, its own domain and walls kept through every copy."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from gns_framework.data.batch import collate, window
from gns_framework.data.stride import strided
from gns_framework.data.trajectory import Trajectory
from gns_framework.errors import DatasetError


def _trajectory(**fields) -> Trajectory:
    base = dict(
        position=np.random.default_rng(0).uniform(0.1, 0.4, (8, 5, 2)).astype(np.float32),
        particle_type=np.full(5, 6),
        key="t",
        bounds=np.array([[0.0, 0.5], [0.0, 0.75]]),
        walls=np.array([[0.3, 0], [0.0, 0], [0.5, 0], [0.0, 0]]),
    )
    return Trajectory(**{**base, **fields})


def test_domain_and_walls_survive_validation_striding_and_windows():
    trajectory = _trajectory().validated("data")
    assert trajectory.bounds.dtype == np.float32 and trajectory.walls.shape == (4, 2)
    assert strided(trajectory, 2).bounds is trajectory.bounds
    example = window(trajectory, 0, 6)
    torch.testing.assert_close(example.bounds, torch.tensor([[[0.0, 0.5], [0.0, 0.75]]]))
    batch = collate([example, window(_trajectory(bounds=np.array([[0.0, 2.0], [0.0, 1.0]])).validated("d"), 1, 6)])
    assert batch.bounds.shape == (2, 2, 2) and batch.walls.shape == (2, 4, 2)
    assert batch.bounds[1, 0, 1] == 2.0


@pytest.mark.parametrize(
    "fields, message",
    [
        (dict(bounds=np.zeros((3, 2))), r"bounds: expected shape \(2, 2\)"),
        (dict(bounds=np.array([[0.0, 0.5], [0.5, 0.5]])), "lower < upper"),
        (dict(bounds=np.array([[0.0, np.inf], [0.0, 1.0]])), "bounds: expected finite"),
        (dict(walls=np.zeros((2, 2))), r"walls: expected shape \(4, 2\)"),
        (dict(walls=np.array([[-0.1, 0], [0, 0], [0, 0], [0, 0]])), "friction >= 0"),
        (dict(walls=np.array([[0.1, 0.5], [0, 0], [0, 0], [0, 0]])), "no-slip flag 0 or 1"),
    ],
)
def test_bad_domain_or_walls_name_the_file_trajectory_and_field(fields, message):
    with pytest.raises(DatasetError, match=message) as info:
        _trajectory(**fields).validated("data/train.npz")
    assert "data/train.npz: trajectory 't'" in str(info.value)


def test_a_rollout_file_keeps_the_trajectory_domain_and_walls(tmp_path):
    from gns_framework.data.metadata import DatasetMetadata
    from gns_framework.data.rollout import Rollout
    from gns_framework.io.rollout_file import load_rollout, save_rollout

    truth = _trajectory().validated("d")
    metadata = DatasetMetadata(
        bounds=[(0.0, 2.0), (0.0, 1.0)],
        sequence_length=8,
        default_connectivity_radius=0.02,
        dim=2,
        dt=0.01,
        vel_mean=[0, 0],
        vel_std=[1, 1],
        acc_mean=[0, 0],
        acc_std=[1, 1],
    )
    rollout = Rollout(truth, truth.position[6:], 6, metadata)
    loaded = load_rollout(save_rollout(tmp_path / "r.npz", rollout))
    np.testing.assert_array_equal(loaded.truth.bounds, truth.bounds)
    np.testing.assert_array_equal(loaded.truth.walls, truth.walls)
    bare = load_rollout(
        save_rollout(
            tmp_path / "bare.npz", Rollout(_trajectory(bounds=None, walls=None), truth.position[6:], 6, metadata)
        )
    )
    assert bare.truth.bounds is None and bare.truth.walls is None


# ---- data that contradicts its own domain (issue 47) --------------------------------------------------------------


def _box(frames: int = 5, particles: int = 6) -> np.ndarray:
    rng = np.random.default_rng(0)
    return rng.uniform(0.2, 0.8, size=(frames, particles, 2)).astype(np.float32)


@pytest.mark.parametrize(("value", "shown"), [(50.5, "50.5"), (3e38, r"3e\+38"), (-0.3, "-0.3")])
def test_a_particle_beyond_the_walls_by_more_than_the_margin_is_named_with_its_frame(value, shown):
    from gns_framework.data.trajectory import DomainCheck

    domain = DomainCheck(np.array([[0.0, 1.0], [0.0, 1.0]]), margin=0.05)
    position = _box()
    position[3, 4, 1] = value
    with pytest.raises(
        DatasetError,
        match=rf"^train\.npz: trajectory 'a': position: particle 4 at frame 3 is at {shown} on axis 1, outside the "
        r"domain \[0, 1\] by more than 0\.05 \(the data contradicts its own bounds\)$",
    ):
        Trajectory(position, np.full(6, 6), key="a").validated("train.npz", domain=domain)
    # Within the margin (a particle that touches a wall), and without a domain to check: accepted.
    position[3, 4, 1] = 1.04
    Trajectory(position, np.full(6, 6), key="a").validated("train.npz", domain=domain)


def test_a_trajectory_s_own_bounds_replace_the_dataset_s():
    from gns_framework.data.trajectory import DomainCheck

    domain = DomainCheck(np.array([[0.0, 1.0], [0.0, 1.0]]), margin=0.01)
    position = _box() * 2.0  # in [0.4, 1.6]: outside the dataset's box, inside its own
    own = np.array([[0.0, 2.0], [0.0, 2.0]], np.float32)
    Trajectory(position, np.full(6, 6), key="a", bounds=own).validated("f", domain=domain)
    with pytest.raises(DatasetError, match="outside the domain"):
        Trajectory(position, np.full(6, 6), key="a").validated("f", domain=domain)


def test_all_particles_at_one_point_is_one_line():
    position = np.full((4, 5, 2), 0.5, np.float32)
    with pytest.raises(
        DatasetError, match=r"^f: trajectory 'a': position: all 5 particles of frame 0 are at one point"
    ):
        Trajectory(position, np.full(5, 6), key="a").validated("f")
    Trajectory(position[:, :1], np.full(1, 6), key="a").validated("f")  # one particle is a point, rightly


def test_every_command_refuses_such_data_in_one_line(tmp_path, capsys):
    from synthetic import write_synthetic_dataset

    from gns_framework.cli import main

    data = write_synthetic_dataset(tmp_path / "data", train=2, valid=1, test=1)
    with np.load(data / "test.npz") as archive:
        arrays = {name: archive[name] for name in archive.files}
    key = next(name for name in arrays if name.endswith("/position"))
    arrays[key] = arrays[key].copy()
    arrays[key][2, 1, 0] = 50.0
    np.savez(data / "test.npz", **arrays)
    assert main(["convert", str(data), "--from", "safe", "--to", "npz", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert f"test.npz: trajectory '{key.rpartition('/')[0]}': position: particle 1 at frame 2 is at 50 on axis 0" in err
