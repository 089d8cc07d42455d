"""Checkpoint files: written whole, read without running code, damage named, retention keeps other histories."""

from __future__ import annotations

import pickle

import pytest
import torch

from gns_framework.errors import CheckpointError
from gns_framework.io.checkpoint import (
    FORMAT,
    checkpoint_history,
    list_checkpoints,
    load_checkpoint,
    prune_checkpoints,
    save_checkpoint,
)
from gns_framework.io.run_folder import checkpoint_name


def state(step: int, history: str = "h1") -> dict:
    """The fields every checkpoint must hold (io.checkpoint.REQUIRED), small."""
    return {
        "step": step,
        "model": {"w": torch.arange(4.0) * step},
        "history": history,
        "recipe": {"model": {}},
        "scene": {},
        "metadata": {},
        "plugins": {},
    }


def test_a_checkpoint_missing_a_required_field_is_not_written(tmp_path):
    incomplete = state(1)
    del incomplete["recipe"]
    with pytest.raises(CheckpointError, match="without recipe"):
        save_checkpoint(tmp_path / "c.pt", incomplete)
    assert not list(tmp_path.iterdir())


def test_a_checkpoint_round_trips_with_its_format_and_history(tmp_path):
    path = save_checkpoint(tmp_path / "c.pt", state(3))
    loaded = load_checkpoint(path)
    assert loaded["format"] == FORMAT and loaded["step"] == 3
    assert torch.equal(loaded["model"]["w"], torch.arange(4.0) * 3)
    assert checkpoint_history(path) == "h1"
    assert not list(tmp_path.glob(".checkpoint-*")), "no partial file is left beside it"


def test_a_central_directory_claiming_an_unknown_zip_version_is_a_damaged_checkpoint(tmp_path):
    # Found by tests/fuzz (6 bytes set to ff): zipfile raises NotImplementedError("zip file version 25.5") on
    # opening such an archive, which must end as the one-line refusal, not a traceback.
    path = save_checkpoint(tmp_path / "c.pt", state(1))
    data = bytearray(path.read_bytes())
    entry = data.index(b"PK\x01\x02")  # the first central directory entry; "version needed" is 6 bytes in
    data[entry + 6 : entry + 8] = b"\xff\x00"
    path.write_bytes(bytes(data))
    with pytest.raises(CheckpointError, match=r"damaged checkpoint.*zip file version 25\.5"):
        load_checkpoint(path)


def test_a_pickle_that_would_run_code_is_refused_not_run(tmp_path):
    class Payload:
        def __reduce__(self):
            return (exec, ("raise SystemExit('ran code from a checkpoint')",))

    path = tmp_path / "evil.pt"
    torch.save({"format": FORMAT, "payload": Payload()}, path, pickle_module=pickle)
    with pytest.raises(CheckpointError, match=r"evil\.pt"):
        load_checkpoint(path)


def test_a_missing_file_and_a_folder_are_named(tmp_path):
    with pytest.raises(CheckpointError, match="checkpoint not found"):
        load_checkpoint(tmp_path / "nothing.pt")
    with pytest.raises(CheckpointError, match="a directory, not a checkpoint file"):
        load_checkpoint(tmp_path)


def test_retention_keeps_the_newest_of_its_own_history_and_never_another(tmp_path):
    for step in (1, 2, 3, 4):
        save_checkpoint(tmp_path / checkpoint_name(step), state(step, "mine"))
    save_checkpoint(tmp_path / checkpoint_name(0), state(0, "theirs"))
    prune_checkpoints(tmp_path, keep=2, history="mine")
    assert [step for step, _ in list_checkpoints(tmp_path)] == [0, 3, 4]
