"""A scene read in parts (data/in_parts.py): each process's run of the particles, checked on its own particles only;
the runs of P processes cover every particle once."""

from __future__ import annotations

import numpy as np
import pytest

from gns_framework.data.in_parts import particle_run, scene_in_parts
from gns_framework.data.lazy import TrajectorySequence
from gns_framework.data.stride import StridedSplit
from gns_framework.data.trajectory import DomainCheck, Trajectory
from gns_framework.errors import DatasetError


def _scene(frames: int = 5, particles: int = 10) -> Trajectory:
    rng = np.random.default_rng(0)
    position = rng.uniform(0.1, 0.9, (frames, particles, 2)).astype(np.float32)
    return Trajectory(position, np.full(particles, 6), rng.uniform(0.3, 0.7, (particles, 1)), key="scene")


@pytest.mark.parametrize("particles, world", [(10, 1), (10, 3), (7, 4), (3, 4), (1000, 8)])
def test_the_runs_cover_every_particle_once_in_order(particles, world):
    runs = [particle_run(particles, rank, world) for rank in range(world)]
    covered = np.concatenate([np.arange(particles)[run] for run in runs])
    assert np.array_equal(covered, np.arange(particles))
    sizes = [run.stop - run.start for run in runs]
    assert max(sizes) - min(sizes) <= 1


def test_a_scene_in_parts_leaves_its_positions_to_the_runs_and_each_run_checks_only_its_own():
    raw = _scene()
    raw.position[3, 8, 1] = np.nan  # particle 8: the last run's
    domain = DomainCheck(np.array([[0.0, 1.0], [0.0, 1.0]]), 0.1)
    split = TrajectorySequence(["scene"], lambda key: raw, "data/test.npz", domain)
    with pytest.raises(DatasetError, match="non-finite value at frame 3, particle 8"):
        split[0]  # checked whole
    scene = scene_in_parts(split, 0)
    assert scene.unchecked is not None
    first = scene.particles(particle_run(10, 0, 2))  # particles 0-4: the NaN is not theirs
    assert first.unchecked is None and first.num_particles == 5
    np.testing.assert_array_equal(first.position, raw.position[:, :5])
    np.testing.assert_array_equal(first.material_property, raw.material_property[:5].astype(np.float32))
    with pytest.raises(DatasetError, match=r"test\.npz: trajectory 'scene': position: non-finite value at frame 3, "):
        scene.particles(particle_run(10, 1, 2))
    with pytest.raises(DatasetError, match="particle 8"):  # numbered in the scene, not in the run
        scene.particles(particle_run(10, 1, 2))


def test_a_run_outside_the_domain_is_refused_naming_its_particle_in_the_scene():
    raw = _scene()
    raw.position[0, 6, 0] = 3.0
    split = TrajectorySequence(["scene"], lambda key: raw, "f", DomainCheck(np.array([[0.0, 1.0], [0.0, 1.0]]), 0.1))
    scene = scene_in_parts(split, 0)
    scene.particles(slice(0, 5))
    with pytest.raises(DatasetError, match="particle 6 at frame 0 is at 3 on axis 0, outside the domain"):
        scene.particles(slice(5, 10))


def test_what_does_not_depend_on_the_positions_values_is_checked_at_once():
    raw = _scene()
    bad_types = Trajectory(raw.position, np.full(10, -1), key="scene")
    split = TrajectorySequence(["scene"], lambda key: bad_types, "f", 2)
    with pytest.raises(DatasetError, match="ids must be >= 0"):
        scene_in_parts(split, 0)
    together = Trajectory(np.zeros((3, 4, 2), np.float32), np.full(4, 6), key="point")
    with pytest.raises(DatasetError, match="all 4 particles of frame 0 are at one point"):
        scene_in_parts(TrajectorySequence(["point"], lambda key: together, "f", 2), 0)


def test_a_strided_split_strides_the_scene_it_leaves_to_the_runs():
    raw = _scene(frames=9)
    raw.position[1, 2, 0] = np.nan  # a frame the stride skips
    strided = StridedSplit(TrajectorySequence(["scene"], lambda key: raw, "f", 2), stride=2)
    scene = scene_in_parts(strided, 0)
    assert scene.num_steps == 5 and scene.unchecked is not None
    np.testing.assert_array_equal(scene.particles(slice(0, 10)).position, raw.position[::2])


def test_a_split_that_cannot_defer_gives_its_scene_whole():
    scene = _scene()
    assert scene_in_parts([scene], 0) is scene
