"""The ``gns invert`` configuration (``gns_framework.inverse.config``): every schema problem at once with its
location, the rules between fields (bounds and starts, held-out frames, Adam's decay), default starts, and the
shipped inversions, whose model and data are named relative to the config file."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from inverse_cases import config_mapping

from gns_framework.assembly.trained import load_trained
from gns_framework.errors import RecipeError
from gns_framework.inverse.config import (
    PropertyUnknown,
    VelocityUnknown,
    load_invert_config,
    parse_invert_config,
)

ROOT = Path(__file__).resolve().parents[2]


def test_schema_problems_are_reported_at_once_with_their_location():
    raw = config_mapping(Path("m.pt"), Path("d"), optimizer={"name": "sgd", "iterations": 0}, loss="runnout")
    raw["unknowns"] = {
        "friction": {"bounds": [0.4, 1.0], "initial": 1.2},
        "initial_velocity": {"particle_type": 6, "bounds": [[1, -1], [0, 1]]},
    }
    with pytest.raises(RecipeError) as caught:
        parse_invert_config(raw, "inv.yaml")
    locations = {loc for loc, _ in caught.value.problems}
    assert {
        "optimizer.name",
        "optimizer.iterations",
        "loss",
        "unknowns.friction",
        "unknowns.initial_velocity",
    } <= locations
    text = str(caught.value)
    assert "initial 1.2 lies outside its bounds [0.4, 1.0]" in text
    assert "axis 0: bounds must be [low, high] with low <= high" in text


def raw_config(**changes) -> dict:
    raw = {
        "model": "m.pt",
        "observed": {"dataset": "d", "frames": [8, 10]},
        "unknowns": {"friction": {"bounds": [0.4, 1.0]}},
        "optimizer": {"name": "adam", "lr": 0.05},
    }
    for key, value in changes.items():
        raw[key] = {**raw[key], **value}
    return raw


def test_lr_decay_and_held_out_frames_are_validated_with_their_location():
    config, _ = parse_invert_config(raw_config(optimizer={"lr_decay": 0.9}, observed={"held_out": [12]}), "x")
    assert config.optimizer.lr_decay == 0.9 and config.observed.held_out == [12]
    cases = [
        (
            raw_config(optimizer={"name": "lbfgs", "lr_decay": 0.9}),
            "optimizer",
            "lr_decay: only adam takes a step size",
        ),
        (raw_config(optimizer={"lr_decay": 0}), "optimizer.lr_decay", "greater than 0"),
        (raw_config(optimizer={"lr_decay": 1.5}), "optimizer.lr_decay", "less than or equal to 1"),
        (raw_config(optimizer={"name": "lbfgs", "starts": 4}), "optimizer", "starts: 4 starts run as one batch"),
        (raw_config(optimizer={"starts": 0}), "optimizer.starts", "greater than or equal to 1"),
        (raw_config(observed={"held_out": [10, 12]}), "observed", "frames [10] are also in frames"),
        (raw_config(observed={"frames": "all", "held_out": [12]}), "observed", "leaves no frame to hold out"),
    ]
    for raw, location, message in cases:
        with pytest.raises(RecipeError) as caught:
            parse_invert_config(raw, "inv.yaml")
        assert any(loc == location and message in text for loc, text in caught.value.problems), caught.value.problems


def test_equal_bounds_are_refused_for_a_property():
    with pytest.raises(RecipeError, match=r"unknowns.friction: .*low < high"):
        parse_invert_config(
            {"model": "m", "observed": {"dataset": "d"}, "unknowns": {"friction": {"bounds": [0.5, 0.5]}}}, "x"
        )


def test_gravity_needs_one_entry_per_axis_of_the_bounds():
    with pytest.raises(RecipeError, match=r"gravity has 3 entries but bounds has 2"):
        parse_invert_config(
            {
                "model": "m",
                "observed": {"dataset": "d"},
                "unknowns": {
                    "initial_velocity": {"particle_type": 6, "bounds": [[0, 1], [0, 1]], "gravity": [0, 0, -9.81]}
                },
            },
            "x",
        )


def test_what_is_not_an_unknown_is_named():
    with pytest.raises(RecipeError) as caught:
        parse_invert_config({"model": "m", "observed": {"dataset": "d"}, "unknowns": {"friction": 0.7}}, "inv.yaml")
    assert ("unknowns.friction", "expected a mapping such as {bounds: [low, high]}, got 0.7") in caught.value.problems
    with pytest.raises(RecipeError) as caught:
        parse_invert_config({"model": "m", "observed": {"dataset": "d"}, "unknowns": {}}, "inv.yaml")
    assert any("name at least one unknown" in message for _, message in caught.value.problems)


def test_a_search_starts_in_the_middle_of_its_bounds_unless_told():
    assert PropertyUnknown(bounds=(0.4, 1.0)).start == [pytest.approx(0.7, abs=1e-15)]
    assert PropertyUnknown(bounds=(0.4, 1.0), initial=0.45).start == [0.45]
    velocity = VelocityUnknown(particle_type=6, bounds=[(-1.0, 3.0), (0.2, 0.2)])
    assert velocity.start == [1.0, 0.2]  # an axis fixed by equal bounds starts at its value
    assert VelocityUnknown(particle_type=6, bounds=[(-1.0, 3.0)], initial=[2.5]).start == [2.5]


def test_model_and_data_are_read_beside_the_config_file(tmp_path, monkeypatch):
    (tmp_path / "configs").mkdir()
    (tmp_path / "configs" / "model.pt").write_bytes(b"")
    config_file = tmp_path / "configs" / "inv.yaml"
    config_file.write_text(yaml.safe_dump(config_mapping(Path("model.pt"), Path("../data"))))
    (tmp_path / "data").mkdir()
    monkeypatch.chdir(tmp_path)
    config, unknowns = load_invert_config(config_file)
    assert Path(config.model) == Path("configs/model.pt")
    assert Path(config.observed.dataset).resolve() == (tmp_path / "data").resolve()
    assert unknowns == {"friction": PropertyUnknown(bounds=(0.4, 1.0), initial=0.7)}


@pytest.mark.parametrize("path", sorted((ROOT / "inversions").glob("*.yaml")))
def test_the_example_inversions_name_a_shipped_model_and_validate(path, registry):
    config, unknowns = load_invert_config(path)  # the model is named relative to the config file
    model = load_trained(config.model, registry, "cpu")
    for name, unknown in unknowns.items():
        assert name in model.simulator.setup.property_names or isinstance(unknown, VelocityUnknown)


@pytest.mark.parametrize("path", sorted((ROOT / "inversions").glob("*.yaml")))
def test_the_shipped_inversions_name_their_model_relative_to_themselves(path, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    config, _ = load_invert_config(path)
    assert Path(config.model).resolve().is_file() and Path(config.model).resolve().parent == ROOT / "models"
    assert Path(config.observed.dataset).resolve().parent == ROOT / "data"
