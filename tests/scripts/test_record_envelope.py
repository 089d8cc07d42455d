"""scripts/record_envelope.py: the envelope measured on the model's training data, whole or field by field."""

from __future__ import annotations

import pytest
from load_script import load_script

from gns_framework.io.checkpoint import load_checkpoint, save_checkpoint

record_envelope = load_script("scripts/record_envelope.py")

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _older(trained, tmp_path):
    """``trained`` as a checkpoint from before fixed particles' properties were measured, with one field edited."""
    state = load_checkpoint(trained)
    state.pop("format", None)
    envelope = {k: v for k, v in state["envelope"].items() if k != "fixed_properties"}
    path = tmp_path / "older.pt"
    save_checkpoint(path, {**state, "envelope": {**envelope, "max_speed": 123.0}})
    return path


def test_only_the_named_fields_are_recorded_and_the_stored_others_kept(trained, dataset_multimaterial, tmp_path):
    older, out = _older(trained, tmp_path), tmp_path / "fields.pt"
    args = [str(older), "--dataset", str(dataset_multimaterial), "--out", str(out)]
    assert record_envelope.main([*args, "--fields", "fixed_properties"]) == 0
    envelope = load_checkpoint(out)["envelope"]
    assert envelope["fixed_properties"] == load_checkpoint(trained)["envelope"]["fixed_properties"]
    assert envelope["max_speed"] == 123.0, "a field not named keeps its stored value"
    whole = tmp_path / "whole.pt"
    assert record_envelope.main([str(older), "--dataset", str(dataset_multimaterial), "--out", str(whole)]) == 0
    assert load_checkpoint(whole)["envelope"]["max_speed"] != 123.0, "without --fields all is measured again"


def test_an_unknown_field_or_an_existing_output_is_refused_and_nothing_written(
    trained, dataset_multimaterial, tmp_path, capsys
):
    out = tmp_path / "x.pt"
    args = [str(trained), "--dataset", str(dataset_multimaterial), "--out", str(out)]
    assert record_envelope.main([*args, "--fields", "fixed_propertys"]) == 2
    assert "unknown field(s) ['fixed_propertys']" in capsys.readouterr().err and not out.exists()
    out.write_bytes(b"mine")
    assert record_envelope.main(args) == 2
    assert out.read_bytes() == b"mine"
