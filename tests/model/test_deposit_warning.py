"""gns_framework.model.deposit_warning: the score is the logistic model's log-odds of the standardised inputs,
a rollout is flagged at or above the threshold, a scene is scored only where the warning applies, and a stored
record is read back exactly or refused naming what is wrong."""

from __future__ import annotations

import numpy as np
import pytest

from gns_framework.contracts import ModelSetup
from gns_framework.data.trajectory import Trajectory
from gns_framework.model.deposit_signals import deposit_signals
from gns_framework.model.deposit_warning import INPUTS, DepositWarning, WarningScore, warning_inputs

H = 0.125
NAMES = tuple(INPUTS)


def column_scene(frames: int = 12, history: int = 3):
    """A 5 x 5 sand column (type 6, tan phi 0.6) spreading right toward a 3-particle block (type 3) in a 3 x 2 m
    box: the trajectory (``history`` input frames, then the spreading) and its frames after the inputs."""
    x, y = np.meshgrid(H * np.arange(5), H * np.arange(5))
    sand = np.stack([x.ravel(), y.ravel()], axis=1)
    final = sand.copy()
    final[:, 0] = sand[:, 0] * 2.5
    t = np.r_[np.zeros(history), np.linspace(0.0, 1.0, frames - history)][:, None, None]
    sand_path = sand[None] + t * (final - sand)[None]
    block = np.array([[1.5, 0.0], [1.5 + H, 0.0], [1.5, H]])
    position = np.concatenate([sand_path, np.broadcast_to(block, (frames, 3, 2))], axis=1).astype(np.float32)
    types = np.r_[np.full(25, 6), np.full(3, 3)]
    friction = np.r_[np.full(25, 0.6), np.zeros(3)].astype(np.float32)[:, None]
    bounds = np.array([[0.0, 3.0], [0.0, 2.0]], dtype=np.float32)
    case = Trajectory(position, types, friction, key="column", bounds=bounds)
    return case, position[history:]


SETUP = ModelSetup(
    dim=2,
    bounds=((0.0, 3.0), (0.0, 2.0)),
    connectivity_radius=0.2,
    particle_types=(3, 6),
    kinematic_types=(3,),
    property_names=("friction",),
)


def warning(weights=None, intercept=0.5, threshold=1.0, **fields) -> DepositWarning:
    rng = np.random.default_rng(0)
    weights = tuple(rng.normal(size=len(NAMES))) if weights is None else weights
    mean = tuple(rng.normal(size=len(NAMES)))
    scale = tuple(rng.uniform(0.5, 2.0, size=len(NAMES)))
    return DepositWarning(NAMES, mean, scale, weights, intercept, threshold, **fields)


def test_the_score_is_the_log_odds_of_the_standardised_inputs():
    case, predicted = column_scene()
    sand = case.particle_type == 6
    signals = deposit_signals(
        predicted[:, sand], case.position[2, sand], np.full(25, 0.6), case.position[-1, ~sand], case.bounds
    )
    fitted = warning()
    x = warning_inputs(signals)
    expected = sum(w * (v - m) / s for w, v, m, s in zip(fitted.weights, x, fitted.mean, fitted.scale, strict=True))
    scored = fitted.score_signals(signals)
    assert scored.score == pytest.approx(expected + 0.5, rel=1e-12)
    assert scored.threshold == 1.0 and scored.flagged == (scored.score >= 1.0)


def test_a_rollout_is_flagged_at_the_threshold_itself_and_not_just_below():
    assert WarningScore(1.0, 1.0, 15.0).flagged
    assert not WarningScore(np.nextafter(1.0, 0.0), 1.0, 15.0).flagged
    assert "may be more than 15 % off" in WarningScore(2.0, 1.0, 15.0).describe()
    assert "below threshold" in WarningScore(0.0, 1.0, 15.0).describe()


def test_assess_scores_the_sand_of_a_whole_rollout_among_the_fixed_particles_in_the_cases_own_box():
    case, predicted = column_scene()
    fitted = warning()
    assessed = fitted.assess(predicted, case, 3, SETUP, [6], np.array([[0.0, 1.0], [0.0, 1.0]]), held=2)
    sand = case.particle_type == 6
    # The case's own 3 m box, not the dataset's 1 m one; the block's particles are the obstacle.
    friction, fixed = case.material_property[sand, 0], case.position[-1, ~sand]
    signals = deposit_signals(predicted[:, sand], case.position[2, sand], friction, fixed, case.bounds.astype(float), 2)
    assert assessed == fitted.score_signals(signals)
    assert signals.leading().side == "right" and signals.leading().gap < 5, "the block is just ahead of the front"


def test_assess_does_not_apply_to_a_partial_rollout_a_scene_without_sand_or_without_friction():
    case, predicted = column_scene()
    fitted, bounds = warning(), np.asarray(SETUP.bounds)
    assert fitted.assess(predicted[:-1], case, 3, SETUP, [6], bounds) is None, "no deposit before the end"
    assert fitted.assess(predicted, case, 3, SETUP, [5], bounds) is None, "no particle of a granular type"
    unnamed = ModelSetup(**{**SETUP.__dict__, "property_names": ("cohesion",)})
    assert fitted.assess(predicted, case, 3, unnamed, [6], bounds) is None
    without = Trajectory(case.position, case.particle_type, None, key="column", bounds=case.bounds)
    assert fitted.assess(predicted, without, 3, SETUP, [6], bounds) is None


def test_a_bound_warning_scores_as_assess_with_its_setups_history_and_the_datasets_box():
    case, predicted = column_scene()
    fitted, setup = warning(), ModelSetup(**{**SETUP.__dict__, "history": 3})
    unboxed = Trajectory(case.position, case.particle_type, case.material_property, key="column")
    scored = fitted.bound(setup, [6], np.asarray(SETUP.bounds))
    assert scored(predicted, unboxed, 2) == fitted.assess(
        predicted, unboxed, 3, setup, [6], np.asarray(SETUP.bounds), 2
    )
    assert scored(predicted[:-1], unboxed) is None, "its history decides where the case's rollout ends"
    shorter = fitted.bound(ModelSetup(**{**SETUP.__dict__, "history": 4}), [6], np.asarray(SETUP.bounds))
    assert shorter(predicted[:-1], unboxed) is not None


def test_a_record_reads_back_as_the_same_warning():
    fitted = warning(fitted_on="250 training scenes")
    assert DepositWarning.from_dict(fitted.to_dict()) == fitted


@pytest.mark.parametrize(
    "change, message",
    [
        ({"slope": 1.0}, r"unknown field\(s\) \['slope'\]"),
        ({"threshold": None}, "not numbers where numbers belong"),
        ({"weights": [1.0]}, "one value per input each"),
        ({"inputs": ["run share", "luck", *NAMES[2:]]}, r"inputs: unknown \['luck'\]"),
        ({"scale": [0.0] * len(NAMES)}, "every scale > 0"),
        ({"mean": [float("nan")] * len(NAMES)}, "must be finite"),
        ({"fitted_on": 3}, "fitted_on: expected text"),
    ],
)
def test_a_broken_record_is_refused_naming_what_is_wrong(change, message):
    record = {**warning().to_dict(), **change}
    with pytest.raises(ValueError, match=message):
        DepositWarning.from_dict(record)


def test_a_record_without_its_threshold_is_refused_naming_it():
    record = warning().to_dict()
    del record["threshold"]
    with pytest.raises(ValueError, match=r"missing field\(s\) \['threshold'\]"):
        DepositWarning.from_dict(record)
