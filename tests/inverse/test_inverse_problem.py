"""An inverse problem (``gns_framework.inverse.problem``): gradients of the learned rollout against finite
differences, the unknowns put in place of what the observation holds, and the problems only the model and the data
reveal.

The gradient checks run the shipped model in float64 on a short rollout of a
synthetic granular-like trajectory. The loss is smooth only piecewise: a pair of
particles crossing the connectivity radius adds or removes an edge. Central
differences in float64 with step h have truncation error O(h^2 f''') and round-off
O(eps f / h), both ~1e-9 relative at h = 1e-6 of the unit-scaled unknown; a larger
step (1e-5) already crosses such a kink on this trajectory and is off by 0.4 %.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch
from inverse_cases import SAND, autograd_and_central_differences, problem_of

from gns_framework.errors import RecipeError
from gns_framework.inverse.config import VelocityUnknown, parse_invert_config
from gns_framework.inverse.problem import check_against_model, observed_frames


@pytest.mark.parametrize("loss", ["positions", "runout"])
def test_the_gradient_of_every_unknown_matches_central_differences(shipped_float64, observed, loss):
    gradient, differences = autograd_and_central_differences(problem_of(shipped_float64, observed, loss))
    assert np.all(np.abs(differences) > 0), "every unknown moves the loss"
    relative = np.abs(gradient - differences) / np.abs(differences)
    assert relative.max() <= 1e-3, (gradient, differences)


def test_the_sinkhorn_gradient_matches_central_differences(shipped_float64, observed):
    # geomloss differentiates the converged dual potentials (envelope theorem), so the
    # gradient is that of the Sinkhorn divergence itself, to the solver's tolerance.
    gradient, differences = autograd_and_central_differences(problem_of(shipped_float64, observed, "sinkhorn"))
    relative = np.abs(gradient - differences) / np.abs(differences)
    assert relative.max() <= 1e-3, (gradient, differences)


def test_the_gradient_check_catches_a_wrong_gradient(shipped_float64, observed):
    """The same comparison fails when the unknown's path into the model is cut (a detach)."""
    problem = problem_of(shipped_float64, observed, "positions")
    inputs = problem.model_inputs

    def detached_property(u):
        state = inputs(u)
        return replace(state, material_property=state.material_property.detach())

    problem.model_inputs = detached_property
    gradient, differences = autograd_and_central_differences(problem)
    relative = np.abs(gradient - differences) / np.abs(differences)
    assert relative[0] > 1e-3


def test_the_observed_value_of_an_unknown_is_never_read(shipped_float64, observed):
    trajectory, metadata = observed
    altered = replace(
        trajectory,
        material_property=np.full_like(trajectory.material_property, 0.1),
        position=trajectory.position.copy(),
    )
    altered.position[1:6] += 0.01  # the C - 1 input frames after the first: rebuilt from the unknown velocity
    u = torch.tensor(problem_of(shipped_float64, observed, "positions").start)
    with torch.no_grad():
        first = problem_of(shipped_float64, observed, "positions").loss(u)
        second = problem_of(shipped_float64, (altered, metadata), "positions").loss(u)
    assert float(first) == float(second)


def test_equal_bounds_fix_a_known_velocity_axis(shipped_float64, observed):
    unknowns = {"initial_velocity": VelocityUnknown(particle_type=SAND, bounds=[(0.0, 1.0), (-0.2, -0.2)])}
    problem = problem_of(shipped_float64, observed, "positions", unknowns=unknowns)
    assert problem.start.tolist() == [0.5, 0.5]
    u = torch.tensor(problem.start, requires_grad=True)
    gradient = torch.autograd.grad(problem.loss(u), u)[0]
    assert gradient[0] != 0 and gradient[1] == 0
    assert problem.parameters.values(torch.tensor([0.25, 0.9], dtype=torch.float64)).tolist() == [0.25, -0.2]


def test_a_ballistic_start_is_rebuilt_exactly(shipped_float64, observed):
    """With the scene's gravity the input frames of a body in free flight are those the data holds."""
    trajectory, metadata = observed
    dt, launch, gravity = metadata.dt, np.array([0.3, 0.5]), np.array([0.0, -9.81])
    times = np.arange(trajectory.num_steps)[:, None, None] * dt
    flight = trajectory.position[0][None] + times * launch + 0.5 * times**2 * gravity
    flying = replace(trajectory, position=flight.astype(np.float64))
    unknowns = {
        "initial_velocity": VelocityUnknown(
            particle_type=SAND, bounds=[(0.0, 1.0), (0.0, 1.0)], gravity=gravity.tolist()
        )
    }
    problem = problem_of(shipped_float64, (flying, metadata), "positions", unknowns=unknowns)
    u = torch.tensor(problem.parameters.scaled(launch))
    rebuilt = problem.model_inputs(u).position_sequence.transpose(0, 1).numpy()
    np.testing.assert_allclose(rebuilt, flight[:6], rtol=0, atol=1e-12)


def test_the_unknowns_are_scaled_in_the_order_given_and_recorded_by_name(shipped_float64, observed):
    problem = problem_of(shipped_float64, observed, "positions")
    assert problem.parameters.names == ("friction", "initial_velocity.x", "initial_velocity.y")
    # friction 0.7 in [0.4, 1.0], velocity (0.1, -0.05) in [-0.5, 0.5]^2.
    np.testing.assert_allclose(problem.start, [0.5, 0.6, 0.45], rtol=0, atol=1e-15)  # float64 round-off
    values = problem.parameters.values(torch.tensor(problem.start, dtype=torch.float64)).tolist()
    record = problem.parameters.as_record(values, problem.unknowns)
    # Values of order 0.1-1 through a scale and back: float64 round-off, 1e-15.
    assert list(record) == ["friction", "initial_velocity"]
    assert record["friction"] == pytest.approx(0.7, abs=1e-15)
    assert record["initial_velocity"] == pytest.approx([0.1, -0.05], abs=1e-15)


def test_the_positions_loss_is_the_mean_squared_offset_of_the_moving_particles(shipped_float64, observed):
    problem = problem_of(shipped_float64, observed, "positions")
    state = problem.model_inputs(torch.tensor(problem.start, dtype=torch.float64))
    assert problem.misfit(state, problem.observed.clone()).item() == 0.0
    # Every compared coordinate off by 0.01: the mean of the squares is 1e-4 (float64: to ~1e-16 relative).
    shifted = problem.observed + 0.01
    assert problem.misfit(state, shifted).item() == pytest.approx(1e-4, rel=1e-12)
    # Only frames 9 and 11 are compared (rollout rows 3 and 5): an offset elsewhere costs nothing.
    elsewhere = problem.observed.clone()
    elsewhere[[0, 1, 2, 4]] += 1.0
    assert problem.misfit(state, elsewhere).item() == 0.0
    assert problem.misfit(state, shifted, frames=[6]).item() == pytest.approx(1e-4, rel=1e-12)
    runout = problem_of(shipped_float64, observed, "runout")
    assert runout.misfit(state, runout.observed.clone()).item() == 0.0


def test_compared_frames_are_the_last_every_rolled_out_one_or_those_listed():
    assert observed_frames("last", history=6, num_frames=12) == [11]
    assert observed_frames("all", history=6, num_frames=12) == [6, 7, 8, 9, 10, 11]
    assert observed_frames([11, 8, 8], history=6, num_frames=12) == [8, 11]  # sorted, each once


def parsed(unknowns: dict, **observed) -> tuple:
    raw = {"model": "m.pt", "observed": {"dataset": "d", **observed}, "unknowns": unknowns}
    return parse_invert_config(raw, "inv.yaml")


def problems_found(shipped_float64, trajectories, unknowns: dict, **observed) -> dict[str, str]:
    config, typed = parsed(unknowns, **observed)
    with pytest.raises(RecipeError) as caught:
        check_against_model(config, typed, shipped_float64, trajectories, "inv.yaml")
    return dict(caught.value.problems)


def test_what_the_model_has_no_input_for_is_named_with_what_it_has(shipped_float64, observed):
    trajectory, _ = observed
    found = problems_found(
        shipped_float64,
        [trajectory],
        {
            "cohesion": {"bounds": [0, 1]},
            "friction": {"bounds": [0.4, 1.0], "particle_type": 5},
            "initial_velocity": {"particle_type": SAND, "bounds": [[0, 1], [0, 1], [0, 1]]},
        },
        trajectory=1,
    )
    assert found == {
        "unknowns.cohesion": "the model has no input 'cohesion': it was trained with the material properties: "
        "friction (or use initial_velocity)",
        "unknowns.friction.particle_type": "5 is not among the model's particle types [6]",
        "unknowns.initial_velocity.bounds": "needs 2 [low, high] pairs (one per axis), got 3",
        "observed.trajectory": "1 is out of range: split 'test' of d holds 1 trajectories (0 .. 0)",
    }


def test_frames_must_be_rolled_out_and_the_properties_the_model_reads_must_be_there(shipped_float64, observed):
    trajectory, _ = observed
    velocity = {"initial_velocity": {"particle_type": SAND, "bounds": [[0, 1], [0, 1]]}}
    found = problems_found(shipped_float64, [trajectory], velocity, frames=[3, 8, 12], held_out=[20])
    # 12 frames, the first 6 the model's input: frames 6 .. 11 are rolled out.
    assert found["observed.frames"] == (
        "frames [3, 12] are not rolled out: give indices in [6, 11] (the first 6 are the model's input)"
    )
    assert found["observed.held_out"].startswith("frames [20] are not rolled out")
    # Without a friction column the model lacks an input the unknowns do not provide.
    bare = replace(trajectory, material_property=None)
    found = problems_found(shipped_float64, [bare], velocity)
    assert found == {
        "observed.dataset": "trajectory 'block' has no material_property, and the model needs ['friction'] "
        "besides the unknowns"
    }
    short = replace(trajectory, position=trajectory.position[:6])
    assert problems_found(shipped_float64, [short], {"friction": {"bounds": [0.4, 1.0]}}) == {
        "observed.trajectory": "has 6 frames; the model needs more than its 6 input frames"
    }


def test_a_problem_the_model_and_data_can_solve_passes(shipped_float64, observed):
    trajectory, _ = observed
    config, typed = parsed({"friction": {"bounds": [0.4, 1.0], "particle_type": SAND}}, frames=[8, 11])
    check_against_model(config, typed, shipped_float64, [trajectory], "inv.yaml")  # raises nothing


@pytest.mark.parametrize("loss", ["positions", "runout", "sinkhorn"])
def test_starts_searched_as_one_batch_have_each_its_own_loss_and_gradient(shipped_float64, observed, loss):
    """Three points (M, k) rolled out together give, per start, the loss and gradient of that point alone.

    float64 throughout: only the row order of the batched products differs, so agreement is to ~1e-12
    of the loss; a start reading another's unknowns (the check below) is off by the loss's whole change.
    """
    problem = problem_of(shipped_float64, observed, loss)
    points = torch.tensor(
        np.array([problem.start, [0.2, 0.3, 0.8], [0.9, 0.6, 0.1]]), dtype=torch.float64, requires_grad=True
    )
    losses, _ = problem.losses(points)
    (gradients,) = torch.autograd.grad(losses.sum(), points)
    assert losses.shape == (3,)
    for start, point in enumerate(points.detach()):
        alone = point.clone().requires_grad_(True)
        value = problem.loss(alone)
        (gradient,) = torch.autograd.grad(value, alone)
        assert losses[start].item() == pytest.approx(value.item(), rel=1e-9, abs=1e-15)
        np.testing.assert_allclose(
            gradients[start].numpy(), gradient.numpy(), rtol=1e-7, atol=1e-12 * abs(value.item())
        )
    # The check has teeth: the same points, but every particle reading the first start's values.
    inputs = problem.model_inputs

    def all_read_the_first(u):
        return inputs(u[:1].expand_as(u)) if u.ndim == 2 else inputs(u)

    problem.model_inputs = all_read_the_first
    mixed, _ = problem.losses(points.detach())
    assert abs(mixed[1].item() - losses[1].item()) > 1e-3 * abs(losses[1].item())


def test_the_observations_own_box_and_walls_reach_the_model(shipped_float64, observed):
    trajectory, metadata = observed
    walled = replace(trajectory, bounds=np.array([[0.0, 0.9], [0.0, 0.45]]))
    problem = problem_of(shipped_float64, (walled, metadata), "positions")
    box = np.float32(walled.bounds)  # batches hold the box in float32
    np.testing.assert_array_equal(problem.model_inputs(torch.tensor(problem.start)).bounds[0].numpy(), box)
    starts = problem.model_inputs(torch.tensor(np.stack([problem.start] * 3)))
    assert starts.num_examples == 3 and starts.bounds.shape == (3, 2, 2)
