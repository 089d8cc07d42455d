"""Running an inversion (``gns_framework.inverse.solve``): the search returns its best iterate (by the loss, or by
the held-out misfit when there is one) with the optimiser's final point evaluated too, the values in physical units,
their errors against the truth, and the truth the observed dataset records. A closed-form stand-in for the learned
problem keeps the expected iterates exact; ``gns invert`` end to end is tested in tests/cli/test_invert.py."""

from __future__ import annotations

import json
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from inverse_cases import SAND

from gns_framework.inverse.config import InvertOptimizer, PropertyUnknown, VelocityUnknown
from gns_framework.inverse.optimize import Iterate
from gns_framework.inverse.problem import parameters_of
from gns_framework.inverse.solve import InversionResult, iteration_metrics, solve, true_values

FRICTION = {"friction": PropertyUnknown(bounds=(0.4, 1.0))}


class Quadratic:
    """A stand-in inverse problem in friction: loss (f - 0.55)^2, held-out misfit (f - 0.7)^2 if asked."""

    def __init__(self, held_out: bool):
        self.unknowns = FRICTION
        self.parameters, self.start = parameters_of(FRICTION)
        self.checkpoint_every = 0
        self.dtype = torch.float64
        self.held_out = [14] if held_out else []

    def losses(self, u):
        friction = self.parameters.values(u)[0]
        held_out = (friction.detach() - 0.7) ** 2 if self.held_out else None
        return (friction - 0.55) ** 2, held_out


def config_of(**optimizer) -> SimpleNamespace:
    return SimpleNamespace(optimizer=InvertOptimizer(**optimizer))


def inversion_of(problem, **optimizer) -> SimpleNamespace:
    return SimpleNamespace(problem=problem, config=config_of(**optimizer))


class TwoMinima(Quadratic):
    """Friction with a shallow minimum at 0.55 (loss 0.01) and the true one at 0.9 (loss 0), apart at 0.71.

    One value (k,) or one per start (M, k), like the learned problem.
    """

    def __init__(self):
        super().__init__(held_out=False)

    def losses(self, u):
        friction = self.parameters.values(u)[..., 0]
        return torch.minimum((friction - 0.55) ** 2 + 0.01, (friction - 0.9) ** 2), None


def test_adam_returns_its_lowest_loss_iterate_and_evaluates_its_final_point():
    seen = []
    problem = Quadratic(held_out=False)
    result = solve(inversion_of(problem, name="adam", lr=0.05, iterations=4), seen.append)
    # Adam's first steps are about lr each: from u 0.5 (friction 0.7) down towards 0.55 (u 0.25).
    assert [it.iteration for it in seen] == [1, 2, 3, 4, 5]  # 5: the point after the last step
    assert result.evaluations == 5 and result.iterations == 4
    assert result.last is seen[-1] and result.history == seen
    assert result.best == min(seen, key=lambda it: it.loss) and result.selected_by == "loss"
    assert result.loss == result.best.loss
    assert result.initial == {"friction": pytest.approx(0.7, abs=1e-15)}
    # The unknowns returned are the best iterate's, in physical units: 0.4 + 0.6 u.
    assert result.unknowns["friction"] == pytest.approx(0.4 + 0.6 * result.best.u[0], abs=1e-15)
    assert result.last_unknowns["friction"] == pytest.approx(0.4 + 0.6 * seen[-1].u[0], abs=1e-15)
    assert result.best.loss == pytest.approx((result.unknowns["friction"] - 0.55) ** 2, rel=1e-12)


def test_with_held_out_frames_the_best_iterate_is_the_one_they_prefer():
    problem = Quadratic(held_out=True)
    result = solve(inversion_of(problem, name="adam", lr=0.05, iterations=4))
    # The loss pulls friction from 0.7 towards 0.55; the held-out frames prefer 0.7, the start.
    assert result.selected_by == "held_out" and result.best.iteration == 1
    assert result.unknowns["friction"] == pytest.approx(0.7, abs=1e-15)
    assert result.history[-1].loss < result.best.loss  # a lower loss did not win
    for iterate in result.history:
        friction = 0.4 + 0.6 * iterate.u[0]
        assert iterate.held_out == pytest.approx((friction - 0.7) ** 2, rel=1e-12, abs=1e-15)


def test_lbfgs_iterates_all_get_their_held_out_misfit():
    problem = Quadratic(held_out=True)
    result = solve(inversion_of(problem, name="lbfgs", iterations=10))
    # SciPy may accept a point after evaluating others: those held-out misfits are computed afterwards.
    assert all(iterate.held_out is not None for iterate in result.history)
    for iterate in result.history:
        friction = 0.4 + 0.6 * iterate.u[0]
        assert iterate.held_out == pytest.approx((friction - 0.7) ** 2, rel=1e-9, abs=1e-15)
    assert result.best == min(result.history, key=lambda it: (it.held_out, it.iteration))
    # L-BFGS-B ends on its last iterate: no extra point to evaluate, so its final point is the last iterate.
    assert result.last is result.history[-1]
    assert result.last_unknowns["friction"] == pytest.approx(0.55, abs=1e-4)


def test_errors_are_relative_percentages_and_absolute_against_a_zero_truth():
    result = InversionResult(
        u=np.zeros(3),
        unknowns={"friction": 0.55, "initial_velocity": [3.0, 4.5], "still": [0.3, 0.4]},
        initial={},
        loss=0.0,
        iterations=1,
        evaluations=1,
        seconds=0.0,
        message="",
        history=[],
    )
    errors = result.errors({"friction": 0.5, "initial_velocity": [3.0, 4.0], "still": [0.0, 0.0]})
    # 0.05 of 0.5; |(0, 0.5)| of |(3, 4)| = 5; a zero truth has no scale, so the distance itself, 0.5.
    assert errors == {
        "friction": pytest.approx(10.0, rel=1e-12),
        "initial_velocity": pytest.approx(10.0, rel=1e-12),
        "still": pytest.approx(0.5, rel=1e-12),
    }
    assert result.errors(None) is None and result.errors({}) is None
    assert result.errors({"friction": 0.5}, {"friction": 0.6}) == {"friction": pytest.approx(20.0, rel=1e-12)}


def test_iteration_metrics_are_the_losses_and_each_unknown_in_physical_units():
    unknowns = {**FRICTION, "initial_velocity": VelocityUnknown(particle_type=SAND, bounds=[(-1.0, 1.0), (0.0, 2.0)])}
    parameters, start = parameters_of(unknowns)
    inversion = SimpleNamespace(problem=SimpleNamespace(parameters=parameters), config=config_of())
    metrics = iteration_metrics(inversion, Iterate(3, 0.25, np.array([0.5, 0.75, 0.25]), held_out=0.5))
    assert metrics == {
        "loss": 0.25,
        "held_out_loss": 0.5,
        "friction": pytest.approx(0.7, abs=1e-15),
        "initial_velocity.x": pytest.approx(0.5, abs=1e-15),
        "initial_velocity.y": pytest.approx(0.5, abs=1e-15),
    }
    assert "held_out_loss" not in iteration_metrics(inversion, Iterate(1, 0.25, start))
    # In a multi-start search every name says which start it is of.
    several = SimpleNamespace(problem=inversion.problem, config=config_of(starts=3))
    assert set(iteration_metrics(several, Iterate(1, 0.25, start, start=2))) == {
        "start2.loss",
        "start2.friction",
        "start2.initial_velocity.x",
        "start2.initial_velocity.y",
    }


def test_the_truth_is_what_the_dataset_drew_else_a_constant_property_column(shipped_float64, observed, tmp_path):
    trajectory, _ = observed
    unknowns = {
        "friction": PropertyUnknown(bounds=(0.4, 1.0)),
        "initial_velocity": VelocityUnknown(particle_type=SAND, bounds=[(-1.0, 1.0), (-1.0, 1.0)]),
    }
    # Without drawn.json: the friction column, the same for every particle the model moves; no velocity.
    column = float(trajectory.material_property[0, 0])
    assert true_values(tmp_path, trajectory, unknowns, shipped_float64) == {"friction": pytest.approx(column)}
    # With drawn.json: what was drawn for the blocks of the unknown's particle type.
    drawn = {"blocks[0]": {"particle_type": SAND, "velocity": [0.3, -0.1], "friction": 0.62}}
    (tmp_path / "drawn.json").write_text(json.dumps({"format": 1, "trajectories": {"block": drawn}}))
    assert true_values(tmp_path, trajectory, unknowns, shipped_float64) == {
        "friction": 0.62,
        "initial_velocity": [0.3, -0.1],
    }
    # A column that varies between particles is no single truth, and nothing else records one.
    varied = replace(trajectory, material_property=np.linspace(0.4, 0.9, trajectory.num_particles)[:, None])
    assert true_values(tmp_path / "nowhere", varied, unknowns, shipped_float64) is None


def test_several_starts_find_the_minimum_one_start_misses():
    problem = TwoMinima()
    one = solve(inversion_of(problem, name="adam", lr=0.05, iterations=40))
    assert one.unknowns["friction"] == pytest.approx(0.55, abs=0.03) and one.loss > 0.009  # from 0.7: the shallow one
    seen = []
    several = solve(inversion_of(problem, name="adam", lr=0.05, iterations=40, starts=4, seed=0), seen.append)
    assert several.unknowns["friction"] == pytest.approx(0.9, abs=0.03) and several.loss < 1e-3
    assert several.best.start != 0 and several.best == min(seen, key=lambda it: (it.loss, it.iteration, it.start))
    assert several.evaluations == 41  # 40 batched rollouts and one of the final points
    assert [start.start for start in several.starts] == [0, 1, 2, 3]
    # The first start is the configured one and ends where the single search did.
    assert several.starts[0].initial == {"friction": pytest.approx(0.7, abs=1e-12)}
    assert several.starts[0].best.loss == pytest.approx(one.loss, rel=1e-12)
    for start in several.starts:
        own = [it for it in seen if it.start == start.start]
        assert [it.iteration for it in own] == list(range(1, 42))  # 41: its final point
        assert start.last is own[-1] and start.best == min(own, key=lambda it: (it.loss, it.iteration))
        assert start.unknowns["friction"] == pytest.approx(0.4 + 0.6 * start.best.u[0], abs=1e-15)
    record = several.as_json(
        SimpleNamespace(
            config=SimpleNamespace(
                observed=SimpleNamespace(model_dump=lambda: {}),
                loss="positions",
                optimizer=InvertOptimizer(starts=4),
                model="m.pt",
            ),
            truth={"friction": 0.9},
            trajectory=SimpleNamespace(key="k"),
            warnings=(),
        )
    )
    assert record["best_start"] == several.best.start and len(record["starts"]) == 4
    assert record["starts"][0]["error_pct"]["friction"] == pytest.approx(100 * 0.35 / 0.9, abs=4)
    assert min(entry["error_pct"]["friction"] for entry in record["starts"]) == record["error_pct"]["friction"]
