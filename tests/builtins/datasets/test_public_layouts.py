"""Readers and ``gns convert`` on files written as DeepMind, LagrangeBench and geoelements write them.

The fixtures in tests/fixtures/public_layouts are made by the generate.py beside
them from the public specifications (TFRecord framing, protobuf wire format, h5py,
numpy), not with gns-framework's writers, so a mistake shared by a reader and its
writer cannot hide here.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest
from load_script import load_script
from gns_builtins.datasets._formats.tfrecord_format import SequenceExample, read_records

from gns_framework.cli import main
from gns_framework.errors import DatasetError

FIXTURES = Path(__file__).resolve().parents[2] / "fixtures" / "public_layouts"
FLOAT32 = float(np.finfo(np.float32).eps)
"""Relative resolution of the stored float32 positions (values of order 0.1 to 1)."""


def expected_position(frames: int, particles: int, number: int) -> np.ndarray:
    """The positions generate.py writes, restated: x = 0.2 + 0.1 i + 0.01 t + 0.05 number, y = 0.3 + 0.1 i - 0.02 t."""
    t, i = np.mgrid[0:frames, 0:particles]
    return np.stack([0.2 + 0.1 * i + 0.01 * t + 0.05 * number, 0.3 + 0.1 * i - 0.02 * t], axis=-1)


def read(registry, layout: str, path: Path):
    cls = registry.get("dataset", layout)
    dataset = cls(cls.Params(), path)
    return dataset.metadata(), {name: list(dataset.split(name)) for name in dataset.splits()}


def convert(source: Path, source_layout: str, target_layout: str, out: Path) -> None:
    assert main(["convert", str(source), "--from", source_layout, "--to", target_layout, "--out", str(out)]) == 0


def test_deepmind_tfrecord_is_read_as_written(registry):
    metadata, splits = read(registry, "tfrecord", FIXTURES / "deepmind")
    # DeepMind's sequence_length 3 counts steps: 4 frames.
    assert metadata.sequence_length == 4 and metadata.dt == 0.0025 and metadata.dim == 2
    assert metadata.bounds == [(0.1, 0.9), (0.1, 0.9)] and metadata.default_connectivity_radius == 0.015
    assert list(splits) == ["train", "test"]
    train, test = splits["train"], splits["test"]
    assert [t.key for t in train] == ["0", "1"] and [t.key for t in test] == ["1"]
    np.testing.assert_array_equal(train[0].particle_type, [6, 6, 3])
    np.testing.assert_array_equal(train[1].particle_type, [5, 5, 5, 3])
    np.testing.assert_array_equal(test[0].particle_type, [6, 3])
    np.testing.assert_allclose(train[1].position, expected_position(4, 4, 1), rtol=FLOAT32)
    np.testing.assert_allclose(test[0].position, expected_position(4, 2, 1), rtol=FLOAT32)
    np.testing.assert_allclose(train[1].position[3, 2], [0.48, 0.44], rtol=FLOAT32)
    assert train[0].material_property is None and train[0].step_context is None


def test_the_committed_tfrecord_files_are_the_generators_bytes(tmp_path):
    generate = load_script(FIXTURES / "generate.py")
    assert generate.crc32c(b"123456789") == 0xE3069283  # the CRC-32C check value
    generate.write_deepmind(tmp_path)
    for split in ("train", "test"):
        assert (tmp_path / f"{split}.tfrecord").read_bytes() == (
            FIXTURES / "deepmind" / f"{split}.tfrecord"
        ).read_bytes()


def test_lagrangebench_is_read_as_lagrangebench_defines_it(registry):
    metadata, splits = read(registry, "lagrangebench", FIXTURES / "lagrangebench")
    # sequence_length_train 4 counts steps: 5 frames; dt is the solver step, frames are write_every steps apart.
    assert metadata.sequence_length == 5
    assert metadata.dt == pytest.approx(0.0007 * 100, rel=1e-12)
    extra = metadata.model_extra
    assert extra["solver_dt"] == 0.0007 and extra["write_every"] == 100
    assert extra["solver"] == "SPH" and extra["dx"] == 0.1 and extra["case"] == "TGV"
    # Three entries in 2D, as LagrangeBench writes them: the first two are the axes.
    assert metadata.periodic_boundary_conditions == [True, True]
    assert {name: [t.num_steps for t in trajectories] for name, trajectories in splits.items()} == {
        "train": [5, 5],
        "valid": [4],
        "test": [4],  # valid: no sequence_length_valid, taken from the file
    }
    assert [t.key for t in splits["train"]] == ["00000", "00001"]
    np.testing.assert_array_equal(splits["train"][1].particle_type, [0, 0, 0])
    assert splits["train"][1].particle_type.dtype == np.int64
    np.testing.assert_allclose(splits["train"][1].position, expected_position(5, 3, 1), rtol=FLOAT32)
    np.testing.assert_allclose(splits["test"][0].position, expected_position(4, 3, 0), rtol=FLOAT32)


def test_lagrangebench_length_disagreeing_with_its_metadata_is_located(registry, tmp_path):
    shutil.copytree(FIXTURES / "lagrangebench", tmp_path / "lb")
    file = tmp_path / "lb" / "metadata.json"
    file.write_text(json.dumps({**json.loads(file.read_text()), "sequence_length_test": 4}))
    with pytest.raises(
        DatasetError,
        match=r"test\.h5: trajectory '00000': position: has 4 frames but metadata\.json's "
        r"sequence_length_test = 4 .* promises 5",
    ):
        read(registry, "lagrangebench", tmp_path / "lb")


def test_geoelements_npz_is_read_as_numpy_saved_it(registry):
    metadata, splits = read(registry, "npz", FIXTURES / "geoelements")
    # geoelements' metadata is DeepMind's: sequence_length 3 counts steps, 4 frames.
    assert metadata.sequence_length == 4 and metadata.dim == 2 and list(splits) == ["train", "test"]
    first, second = splits["train"]
    assert (first.key, second.key) == ("simulation_trajectory_0", "simulation_trajectory_1")
    np.testing.assert_array_equal(first.particle_type, [6, 6, 3])
    np.testing.assert_array_equal(second.particle_type, [6, 3])
    assert first.material_property is None
    np.testing.assert_allclose(second.material_property, [[0.6], [0.0]], rtol=FLOAT32)
    np.testing.assert_allclose(second.position, expected_position(4, 2, 1), rtol=FLOAT32)
    np.testing.assert_allclose(splits["test"][0].position, expected_position(4, 2, 0), rtol=FLOAT32)


def test_converting_keeps_trajectory_numbers(registry, tmp_path):
    convert(FIXTURES / "deepmind", "tfrecord", "tfrecord", tmp_path / "tf")
    records = [SequenceExample.parse(r) for r in read_records(tmp_path / "tf" / "test.tfrecord")]
    assert [int(r.context["key"].values[0]) for r in records] == [1]
    assert "trajectory_key" not in records[0].context  # nothing DeepMind's files lack
    convert(FIXTURES / "deepmind", "tfrecord", "lagrangebench", tmp_path / "lb")
    with h5py.File(tmp_path / "lb" / "test.h5", "r") as handle:
        assert list(handle) == ["00001"]
    convert(tmp_path / "lb", "lagrangebench", "tfrecord", tmp_path / "back")
    _, splits = read(registry, "tfrecord", tmp_path / "back")
    assert [t.key for t in splits["test"]] == ["1"] and [t.key for t in splits["train"]] == ["0", "1"]


@pytest.mark.parametrize("through", [None, "safe", "npz"])
def test_converting_lagrangebench_keeps_its_metadata(through, tmp_path):
    source = FIXTURES / "lagrangebench"
    if through is None:
        convert(source, "lagrangebench", "lagrangebench", tmp_path / "lb")
    else:
        convert(source, "lagrangebench", through, tmp_path / through)
        convert(tmp_path / through, through, "lagrangebench", tmp_path / "lb")
    original = json.loads((source / "metadata.json").read_text())
    written = json.loads((tmp_path / "lb" / "metadata.json").read_text())
    for key, value in original.items():
        expected = value[:2] if key == "periodic_boundary_conditions" else value
        assert written[key] == expected, key
    # The valid split it holds too, in LagrangeBench's terms.
    assert written["sequence_length_valid"] == 3 and written["num_trajs_valid"] == 1


def test_deepmind_layout_refuses_splits_of_other_lengths(tmp_path, capsys):
    out = tmp_path / "tf"
    assert (
        main(
            [
                "convert",
                str(FIXTURES / "lagrangebench"),
                "--from",
                "lagrangebench",
                "--to",
                "tfrecord",
                "--out",
                str(out),
            ]
        )
        == 2
    )
    assert (
        "valid.tfrecord: trajectory '00000': position: has 4 frames, but DeepMind's layout holds one "
        "sequence_length for every split and it is 5 frames"
    ) in capsys.readouterr().err
    assert not out.exists() or not any(out.iterdir())


def test_geoelements_npz_converts_to_deepminds_layout(registry, tmp_path):
    convert(FIXTURES / "geoelements", "npz", "tfrecord", tmp_path / "tf")
    assert json.loads((tmp_path / "tf" / "metadata.json").read_text())["sequence_length"] == 3
    _, splits = read(registry, "tfrecord", tmp_path / "tf")
    np.testing.assert_allclose(splits["train"][1].position, expected_position(4, 2, 1), rtol=FLOAT32)
