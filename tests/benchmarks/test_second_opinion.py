"""benchmarks/second_opinion.py: the perturbed second opinion moves only moving particles' inputs, the shifted one
the whole scene with its walls; the rates."""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

import second_opinion


@dataclass(frozen=True)
class Case:
    """What the perturbation reads of a trajectory."""

    position: np.ndarray
    particle_type: np.ndarray


def test_the_perturbation_shifts_each_moving_particle_alike_in_every_input_frame():
    position = np.random.default_rng(0).random((8, 5, 2)).astype(np.float32)
    case = Case(position=position, particle_type=np.array([6, 6, 3, 6, 3]))
    simulator = SimpleNamespace(predicted_mask=lambda types: types != 3)
    moved = second_opinion.perturbed(case, simulator, history=6, sigma=0.01, seed=1)
    shift = moved.position - position
    assert np.allclose(shift[:6], shift[0], atol=1e-7), "one offset per particle: velocities are kept"
    assert not shift[:6, [2, 4]].any(), "kinematic particles follow their prescribed path"
    assert np.abs(shift[0, [0, 1, 3]]).min() > 0 and np.abs(shift[0]).max() < 0.1
    assert not shift[6:].any(), "the truth after the inputs is not touched"


def test_hit_and_false_alarm_rates():
    rows = [
        {"error": {"extent": 30.0, "height": 1.0}, "disagreement": {"extent": 12.0, "height": 0.0}},
        {"error": {"extent": 20.0, "height": 1.0}, "disagreement": {"extent": 2.0, "height": 0.0}},
        {"error": {"extent": 2.0, "height": 1.0}, "disagreement": {"extent": 11.0, "height": 0.0}},
        {"error": {"extent": 2.0, "height": 1.0}, "disagreement": {"extent": 1.0, "height": 0.0}},
    ]
    rates = second_opinion.rates(rows, 10.0)
    assert (rates["bad"], rates["good"], rates["hit_rate"], rates["false_alarm_rate"]) == (2, 2, 0.5, 0.5)


def test_only_the_second_rollout_starts_perturbed():
    case = Case(position=np.zeros((8, 3, 2), np.float32), particle_type=np.array([6, 6, 6]))
    primary = SimpleNamespace(simulator=SimpleNamespace(predicted_mask=lambda types: types == 6))
    (first_model, first, _), (second_model, second, back) = second_opinion.rollouts(
        case, primary, primary, 6, {"perturb": 0.01}, seed=0
    )
    assert first_model is primary and second_model is primary and back is second_opinion.unchanged
    assert first is case and np.abs(second.position[:6]).max() > 0
    other = SimpleNamespace()
    unchanged = second_opinion.unchanged
    assert second_opinion.rollouts(case, primary, other, 6, {}, seed=0) == [
        (primary, case, unchanged),
        (other, case, unchanged),
    ]


@dataclass(frozen=True)
class Walled:
    """What the translation reads of a trajectory."""

    position: np.ndarray
    bounds: np.ndarray | None


def test_the_shifted_opinion_moves_the_scene_and_its_walls_and_is_moved_back():
    case = Walled(position=np.zeros((8, 3, 2), np.float32), bounds=np.array([[0.0, 2.0], [0.0, 1.0]], np.float32))
    primary = SimpleNamespace()
    (_, first, none), (_, second, back) = second_opinion.rollouts(case, primary, primary, 6, {"shift": 0.01}, 0)
    assert first is case and none is second_opinion.unchanged
    assert np.allclose(second.position, 0.01) and np.allclose(second.bounds, case.bounds + 0.01)
    assert np.allclose(back(second.position), case.position)
    assert second_opinion.shifted(Walled(case.position, None), 0.5).bounds is None


def test_a_simulators_cloud_stands_in_for_the_truth_with_its_own_particles():
    from gns_framework.data.trajectory import Trajectory
    from gns_framework.evaluation.records import Prediction

    case = Trajectory(np.zeros((8, 3, 2), np.float32), np.array([6, 6, 6]), key="c")
    other = Prediction(np.ones((2, 5, 2), np.float32), np.full(5, 6), np.full((5, 2), 0.5, np.float32))
    truth = second_opinion._as_case(other, case, history=6)
    assert truth.position.shape == (8, 5, 2) and (truth.particle_type == 6).all()
    assert np.allclose(truth.position[:6], 0.5) and np.allclose(truth.position[6:], 1.0)
    own = second_opinion._own_particles(Prediction(np.zeros((2, 3, 2), np.float32)), case, history=6)
    assert own.particle_type is case.particle_type and np.array_equal(own.start, case.position[5])


def test_the_mirrored_opinion_reflects_the_scene_and_its_side_walls_and_is_reflected_back():
    from gns_framework.data.trajectory import Trajectory

    position = np.zeros((8, 2, 2), np.float32)
    position[:, :, 0] = [0.5, 1.5]
    walls = np.array([[0.1, 0.0], [0.2, 1.0], [0.3, 0.0], [0.0, 0.0]], np.float32)
    case = Trajectory(position, np.array([6, 6]), key="c", bounds=np.array([[0.0, 3.0], [0.0, 1.0]]), walls=walls)
    (_, first, _), (_, second, back) = second_opinion.rollouts(case, None, None, 6, {"mirror": True}, 0)
    assert first is case
    np.testing.assert_allclose(second.position[0, :, 0], [2.5, 1.5])
    np.testing.assert_array_equal(second.walls, walls[[1, 0, 2, 3]])
    np.testing.assert_allclose(back(second.position), position)
