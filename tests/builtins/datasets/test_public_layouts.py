"""``gns convert`` between the files written as DeepMind, LagrangeBench and geoelements write them.

The fixtures in tests/fixtures/public_layouts are made by the generate.py beside
them from the public specifications (TFRecord framing, protobuf wire format, h5py,
numpy), not with gns-framework's writers, so a mistake shared by a reader and its
writer cannot hide here. How each layout's reader reads them is tested in its
mirror (test_tfrecord.py, test_lagrangebench.py, test_npz.py).
"""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import pytest
from layout_fixtures import FIXTURES, FLOAT32, expected_position, read
from load_script import load_script

from gns_builtins.datasets._formats.tfrecord_format import SequenceExample, read_records
from gns_framework.cli import main


def convert(source: Path, source_layout: str, target_layout: str, out: Path) -> None:
    assert main(["convert", str(source), "--from", source_layout, "--to", target_layout, "--out", str(out)]) == 0


def test_the_committed_tfrecord_files_are_the_generators_bytes(tmp_path):
    generate = load_script(FIXTURES / "generate.py")
    assert generate.crc32c(b"123456789") == 0xE3069283  # the CRC-32C check value
    generate.write_deepmind(tmp_path)
    for split in ("train", "test"):
        assert (tmp_path / f"{split}.tfrecord").read_bytes() == (
            FIXTURES / "deepmind" / f"{split}.tfrecord"
        ).read_bytes()


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
