"""scripts/refuse_types.py: a refusal recorded in a checkpoint travels with it and is enforced by gns rollout."""

from __future__ import annotations

import pytest
from load_script import load_script

from gns_framework.assembly.data import open_dataset
from gns_framework.assembly.trained import load_trained
from gns_framework.cli import main
from gns_framework.errors import GnsError
from gns_framework.io.checkpoint import load_checkpoint
from gns_framework.model.envelope import outside_envelope

refuse_types = load_script("scripts/refuse_types.py")

pytestmark = pytest.mark.usefixtures("one_torch_thread")

REFUSED = 5
"""The second material of the synthetic multimaterial data (tests/synthetic.py): every test trajectory holds it."""


def test_the_refusal_is_recorded_and_everything_else_is_kept(trained, tmp_path, registry):
    out = tmp_path / "refusing.pt"
    reason = "31 % off on held-out scenes holding it"
    assert refuse_types.main([str(trained), "--type", str(REFUSED), "--reason", reason, "--out", str(out)]) == 0
    before, after = load_checkpoint(trained), load_checkpoint(out)
    assert after["envelope"]["refused_types"] == {str(REFUSED): reason}
    assert {k: v for k, v in after["envelope"].items() if k != "refused_types"} == {
        k: v for k, v in before["envelope"].items() if k != "refused_types"
    }
    assert after["step"] == before["step"] and after["recipe"] == before["recipe"]
    assert all((after["model"][k] == v).all() for k, v in before["model"].items())
    model = load_trained(out, registry)
    assert model.envelope is not None and model.envelope.refused_types == {str(REFUSED): reason}
    cleared = tmp_path / "accepting.pt"
    assert refuse_types.main([str(out), "--clear", "--out", str(cleared)]) == 0
    assert load_checkpoint(cleared)["envelope"]["refused_types"] == {}


def test_data_holding_a_refused_type_is_named_with_the_reason(trained, dataset_multimaterial, tmp_path, registry):
    out = tmp_path / "refusing.pt"
    refuse_types.refuse(trained, out, [REFUSED], "measured 31 % off")
    model = load_trained(out, registry)
    assert model.envelope is not None
    data = open_dataset(model.recipe.dataset, registry, dataset_multimaterial)
    scene = model.simulator.setup
    lines = outside_envelope(model.envelope, data.metadata(), data.split("test"), scene.history, scene.kinematic_types)
    # The synthetic data's frictions are random: the test split may lie outside the trained range too.
    (line,) = [line for line in lines if "refused" in line]
    assert f"particles (type {REFUSED}) present in trajectory" in line
    assert line.endswith("(trained: on them, but refused: measured 31 % off)"), line
    before = load_trained(trained, registry).envelope
    assert before is not None
    unrefused = outside_envelope(before, data.metadata(), data.split("test"), scene.history, scene.kinematic_types)
    assert unrefused == [other for other in lines if other != line]


def test_gns_rollout_refuses_it_and_runs_it_with_outside_envelope(trained, dataset_multimaterial, tmp_path, capsys):
    out = tmp_path / "refusing.pt"
    refuse_types.refuse(trained, out, [REFUSED], "measured 31 % off")
    rollout = ["rollout", str(out), "--dataset", str(dataset_multimaterial), "--no-progress"]
    assert main([*rollout, "--out", str(tmp_path / "refused")]) == 2
    assert "but refused: measured 31 % off" in capsys.readouterr().err
    assert not (tmp_path / "refused").exists()
    assert main([*rollout, "--out", str(tmp_path / "anyway"), "--outside-envelope"]) == 0
    assert "but refused: measured 31 % off" in capsys.readouterr().err


def test_bad_requests_are_refused_and_nothing_is_overwritten(trained, tmp_path, capsys):
    taken = tmp_path / "taken.pt"
    taken.write_bytes(b"keep me")
    with pytest.raises(GnsError, match="exists"):
        refuse_types.refuse(trained, taken, [REFUSED], "why")
    assert taken.read_bytes() == b"keep me"
    assert refuse_types.main([str(trained), "--type", "9", "--reason", "x", "--out", str(tmp_path / "n.pt")]) == 2
    assert "--type 9: the model was not trained on it" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        refuse_types.main([str(trained), "--type", str(REFUSED), "--out", str(tmp_path / "m.pt")])
    assert not (tmp_path / "n.pt").exists() and not (tmp_path / "m.pt").exists()
