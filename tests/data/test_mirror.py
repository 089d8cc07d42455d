"""Mirror images of training trajectories: positions reflected in the box, the walls across the axis swapped,
the train split holding each trajectory beside its images, its statistics those of both."""

from __future__ import annotations

import numpy as np
import pytest

from gns_framework.contracts import Dataset, Params
from gns_framework.data.metadata import DatasetMetadata
from gns_framework.data.mirror import MirroredDataset, MirroredSplit, mirrored
from gns_framework.data.trajectory import Trajectory
from gns_framework.errors import DatasetError

BOX = np.array([[0.0, 2.0], [0.0, 1.0]])
WALLS = np.array([[0.1, 0.0], [0.2, 1.0], [0.3, 0.0], [0.4, 0.0]], np.float32)  # x_min, x_max, y_min, y_max


def _sliding(key: str = "t", bounds: np.ndarray | None = None, frames: int = 5) -> Trajectory:
    """Particle 0 slides towards +x at 0.1 per frame from x = 0.5; particle 1 is kinematic, still at x = 1.5."""
    position = np.zeros((frames, 2, 2), np.float32)
    position[:, 0, 0] = 0.5 + 0.1 * np.arange(frames)
    position[:, :, 1] = 0.25
    position[:, 1, 0] = 1.5
    return Trajectory(position, np.array([5, 3]), key=key, bounds=bounds, walls=WALLS.copy())


class InMemory(Dataset):
    """A layout holding its metadata and splits in memory; its box is :data:`BOX`."""

    name = "in_memory"

    def __init__(self, splits: dict[str, list[Trajectory]], dim: int = 2):
        super().__init__(Params(), "in_memory_folder", allow_pickle=False)
        self._splits, self._dim = splits, dim

    def metadata(self):
        stored = {f"{q}_{s}": [99.0] * self._dim for q in ("vel", "acc") for s in ("mean", "std")}
        bounds = [tuple(b) for b in BOX] + [(0.0, 1.0)] * (self._dim - 2)
        return DatasetMetadata(
            bounds=bounds, sequence_length=5, default_connectivity_radius=0.1, dim=self._dim, dt=0.01, **stored
        )

    def split(self, name):
        return self._splits[name]

    def has_split(self, name):
        return name in self._splits


def test_a_mirror_image_reflects_every_particle_and_swaps_the_walls_across_the_axis():
    trajectory = _sliding()
    image = mirrored(trajectory, 0, BOX)
    np.testing.assert_allclose(image.position[:, 0, 0], 1.5 - 0.1 * np.arange(5), atol=1e-6)  # slides towards -x
    np.testing.assert_allclose(image.position[:, 1, 0], 0.5, atol=1e-6)  # the kinematic particle too
    np.testing.assert_array_equal(image.position[..., 1], trajectory.position[..., 1])
    np.testing.assert_array_equal(image.walls, WALLS[[1, 0, 2, 3]])
    assert image.key == "t~mirror0"
    np.testing.assert_array_equal(trajectory.walls, WALLS)  # the stored trajectory is untouched
    twice = mirrored(image, 0, BOX)
    np.testing.assert_allclose(twice.position, trajectory.position, atol=1e-6)
    np.testing.assert_array_equal(twice.walls, WALLS)


def test_a_trajectory_with_a_box_of_its_own_is_reflected_in_it():
    own = np.array([[0.0, 1.0], [0.0, 1.0]], np.float32)
    split = MirroredSplit([_sliding(bounds=own)], [0], BOX)
    np.testing.assert_allclose(split[1].position[0, 0, 0], 0.5, atol=1e-6)  # 1.0 - 0.5, not 2.0 - 0.5


def test_the_train_split_holds_each_trajectory_beside_its_images_and_the_others_as_stored():
    inner = InMemory({"train": [_sliding("a"), _sliding("b")], "valid": [_sliding("v")]})
    dataset = MirroredDataset(inner, [0], kinematic_types=[3])
    assert [t.key for t in dataset.split("train")] == ["a", "a~mirror0", "b", "b~mirror0"]
    assert [t.key for t in dataset.split("valid")] == ["v"]
    assert dataset.name == "in_memory" and dataset.splits() == ["train", "valid"]
    with pytest.raises(IndexError):
        dataset.split("train")[4]


def test_two_axes_give_every_combination_of_images():
    position = np.full((3, 1, 3), 0.25, np.float32)
    trajectory = Trajectory(position, np.array([5]), key="c")
    inner = InMemory({"train": [trajectory]}, dim=3)
    split = MirroredDataset(inner, [0, 2], kinematic_types=[]).split("train")
    assert [t.key for t in split] == ["c", "c~mirror0", "c~mirror2", "c~mirror0~mirror2"]
    np.testing.assert_allclose(split[3].position[0, 0], [1.75, 0.25, 0.75], atol=1e-6)


def test_the_statistics_are_those_of_both_images():
    """The particle moves +0.1 per frame as stored and -0.1 mirrored: mean x velocity 0, spread 0.1; the kinematic
    particle (type 3) is left out, the stored 99s replaced."""
    inner = InMemory({"train": [_sliding()]})
    metadata = MirroredDataset(inner, [0], kinematic_types=[3]).metadata()
    assert metadata.vel_mean == pytest.approx([0.0, 0.0], abs=1e-6)
    assert metadata.vel_std[0] == pytest.approx(0.1, rel=1e-4)
    assert metadata.acc_mean == pytest.approx([0.0, 0.0], abs=1e-6)


@pytest.mark.parametrize("axes", [[2], [-1], [0, 0]])
def test_axes_outside_the_data_or_repeated_are_refused_by_name(axes):
    with pytest.raises(
        DatasetError, match=r"in_memory_folder: dataset.mirror_axes: expected distinct axes in \[0, 1\]"
    ):
        MirroredDataset(InMemory({"train": [_sliding()]}), axes, kinematic_types=[3])


def test_a_trajectory_with_a_step_context_is_refused_not_reflected_silently():
    trajectory = _sliding()
    with_context = Trajectory(
        trajectory.position, trajectory.particle_type, step_context=np.zeros((5, 2), np.float32), key="w"
    )
    with pytest.raises(DatasetError, match=r"w: dataset\.mirror_axes: the trajectory has a step context"):
        mirrored(with_context, 0, BOX)


def test_the_recipe_field_mirrors_a_strided_dataset_too(tmp_path):
    """``dataset.mirror_axes`` in a recipe: the stride applies first, then every strided trajectory gains its image
    in the dataset's box (synthetic data: bounds [0.1, 0.9] per axis)."""
    from synthetic import write_synthetic_dataset

    from gns_framework.assembly.data import open_dataset
    from gns_framework.config.recipe import DatasetSpec
    from gns_framework.plugins import load_registry

    write_synthetic_dataset(tmp_path, train=1, valid=1, test=0)
    spec = DatasetSpec(path=str(tmp_path), frame_stride=2, mirror_axes=[0])
    dataset = open_dataset(spec, load_registry())
    train = dataset.split("train")
    assert [t.key for t in train] == ["train_000", "train_000~mirror0"] and train[1].num_steps == 20
    np.testing.assert_allclose(train[1].position[..., 0], 1.0 - train[0].position[..., 0], atol=1e-6)
    assert [t.key for t in dataset.split("valid")] == ["valid_000"]
