"""The searches over the scaled unknowns (``gns_framework.inverse.optimize``): projected Adam (its step size, its
decay, the bounds it never leaves), SciPy's L-BFGS-B (the losses it reports in the problem's units), the held-out
misfit carried with each iterate, the best iterate, and non-finite losses or gradients refused naming the field.
Each loss here is a closed-form function of ``u``, so the expected iterates are known exactly."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from gns_framework.inverse.optimize import InversionDiverged, Iterate, adam, best_iterate, lbfgs, spread_starts


def test_adam_stops_on_a_non_finite_loss_naming_the_field():
    def loss(u):
        return (u * float("nan")).sum()

    with pytest.raises(InversionDiverged, match=r"loss: non-finite value at evaluation 1 \(friction 0.7\)"):
        adam(loss, np.array([0.5]), 0.1, 3, lambda it: None, lambda u: "friction 0.7")


def test_adam_decays_its_step_size():
    def loss(u):
        return (u - 0.3).abs().sum()  # constant gradient: Adam's steps are its step size

    def path(decay):
        seen = []
        adam(loss, np.array([0.9]), 0.05, 6, lambda it: seen.append(float(it.u[0])), lambda u: "", torch.float64, decay)
        return -np.diff(seen)

    np.testing.assert_allclose(path(None), 0.05, rtol=1e-6)
    np.testing.assert_allclose(path(0.5), 0.05 * 0.5 ** np.arange(5), rtol=1e-6)


def test_the_best_iterate_is_chosen_by_the_held_out_misfit_when_there_is_one():
    u = np.zeros(1)
    by_loss = [Iterate(1, 3.0, u), Iterate(2, 1.0, u), Iterate(3, 2.0, u)]
    assert best_iterate(by_loss).iteration == 2
    held_out = [Iterate(1, 3.0, u, 0.5), Iterate(2, 1.0, u, 0.9), Iterate(3, 2.0, u, 0.7)]
    assert best_iterate(held_out).iteration == 1


def test_a_non_finite_gradient_is_refused_too():
    def loss(u):
        return u.abs().sqrt().sum()  # finite at 0, but its gradient there is not (0 times infinity)

    with pytest.raises(InversionDiverged, match=r"non-finite gradient at evaluation 1 \(friction 0.4\)"):
        lbfgs(loss, np.array([0.0]), 3, lambda it: None, lambda u: "friction 0.4")


def test_adam_never_leaves_the_bounds():
    seen = []

    def loss(u):
        return ((u - torch.tensor([1.5, -0.5], dtype=u.dtype)) ** 2).sum()  # minimum outside [0, 1]^2

    solution = adam(loss, np.array([0.5, 0.5]), 0.2, 12, seen.append, lambda u: "", torch.float64)
    assert all(0.0 <= value <= 1.0 for iterate in seen for value in iterate.u)
    np.testing.assert_array_equal(solution.u, [1.0, 0.0])  # pressed against the nearest corner
    assert (solution.iterations, solution.evaluations) == (12, 12)  # one evaluation per step
    assert solution.message == "12 Adam steps"
    # Each iterate reports the loss at its own point.
    for iterate in seen:
        assert iterate.loss == pytest.approx(float(loss(torch.tensor(iterate.u))), rel=1e-12)


def test_lbfgs_reports_losses_in_the_problems_units_and_finds_a_bounded_minimum():
    target = np.array([0.3, 1.4])  # the second coordinate's minimum lies beyond its bound 1

    def loss(u):
        # Of order 1e4 at the start: SciPy sees it divided by that, the iterates report it undivided.
        return 1e4 * ((u - torch.tensor(target, dtype=u.dtype)) ** 2).sum()

    seen = []
    solution = lbfgs(loss, np.array([0.9, 0.1]), 30, seen.append, lambda u: "", torch.float64)
    # A quadratic with a diagonal Hessian: L-BFGS-B reaches the projected minimum within SciPy's default
    # gradient tolerance (pgtol 1e-5 on the scaled loss), far tighter than 1e-4 in u.
    np.testing.assert_allclose(solution.u, [0.3, 1.0], rtol=0, atol=1e-4)
    assert [iterate.iteration for iterate in seen] == list(range(1, len(seen) + 1))
    assert 1 <= solution.iterations <= 30 and solution.evaluations >= solution.iterations + 1  # + the scale
    for iterate in seen:
        assert iterate.loss == pytest.approx(float(loss(torch.tensor(iterate.u))), rel=1e-9)
    assert seen[-1].loss == pytest.approx(1e4 * 0.4**2, rel=1e-6)  # only the bounded coordinate is off, by 0.4


def test_each_iterate_carries_the_held_out_misfit_of_its_own_rollout():
    def losses(u):
        loss = ((u - 0.2) ** 2).sum()
        return loss, 10 * loss.detach() + 1  # a stand-in: any value computed from the same point

    seen = []
    adam(losses, np.array([0.9]), 0.1, 3, seen.append, lambda u: "", torch.float64)
    for iterate in seen:
        assert iterate.held_out == pytest.approx(10 * iterate.loss + 1, rel=1e-12)
        assert iterate.score == iterate.held_out
    assert Iterate(1, 0.5, np.zeros(1)).score == 0.5  # without a held-out misfit, the loss


def test_the_earliest_of_equally_good_iterates_is_the_best_and_none_is_an_error():
    u = np.zeros(1)
    assert best_iterate([Iterate(1, 2.0, u), Iterate(2, 1.0, u), Iterate(3, 1.0, u)]).iteration == 2
    with pytest.raises(ValueError, match="no iterate to choose from"):
        best_iterate([])


def test_adam_from_several_starts_takes_each_starts_own_steps():
    """M starts searched together follow exactly the paths of M searches one at a time (Adam is elementwise)."""
    target = torch.tensor([0.3, 0.8], dtype=torch.float64)

    def loss(u):
        return ((u - target) ** 2).sum(-1) * (1 + u.sum(-1))  # coupled within a start, never across starts

    starts = np.array([[0.5, 0.5], [0.9, 0.1], [0.0, 1.0]])
    together = []
    solution = adam(loss, starts, 0.1, 5, together.append, lambda u: "", torch.float64)
    assert solution.u.shape == (3, 2) and solution.evaluations == 5 and solution.stopped == ()
    for start, u0 in enumerate(starts):
        alone = []
        single = adam(loss, u0, 0.1, 5, alone.append, lambda u: "", torch.float64)
        mine = [it for it in together if it.start == start]
        np.testing.assert_allclose([it.u for it in mine], [it.u for it in alone], rtol=0, atol=1e-15)
        np.testing.assert_allclose([it.loss for it in mine], [it.loss for it in alone], rtol=1e-14)
        np.testing.assert_allclose(solution.u[start], single.u, rtol=0, atol=1e-15)


def test_a_start_that_turns_non_finite_stops_where_it_was_finite_and_the_others_go_on():
    def loss(u):
        # Start 1 walks towards u > 0.75, where its loss is NaN; start 0 stays well inside.
        value = ((u - 1.0) ** 2).sum(-1)
        return torch.where(u[:, 0] > 0.75, torch.nan, value)

    seen = []
    solution = adam(loss, np.array([[0.1], [0.6]]), 0.1, 6, seen.append, lambda u: "", torch.float64)
    assert solution.stopped == (1,) and "starts [1] stopped" in solution.message
    stopped_at = [it for it in seen if it.start == 1]
    assert all(np.isfinite(it.loss) for it in seen)
    np.testing.assert_array_equal(solution.u[1], stopped_at[-1].u)  # its last finite iterate
    assert len([it for it in seen if it.start == 0]) == 6
    assert len(stopped_at) < 6


def test_a_start_non_finite_at_its_first_point_is_an_error_naming_it():
    def loss(u):
        return torch.where(u[:, 0] > 0.5, torch.nan, (u**2).sum(-1))

    with pytest.raises(InversionDiverged, match=r"starting point of start 1 \(friction 0.9\)"):
        adam(loss, np.array([[0.1], [0.9]]), 0.1, 3, lambda it: None, lambda u: "friction 0.9", torch.float64)


def test_starts_are_the_given_one_then_a_latin_hypercube_that_keeps_fixed_axes():
    u0 = np.array([0.25, 0.5, 0.7])
    points = spread_starts(u0, 9, seed=3, fixed=np.array([False, True, False]))
    assert points.shape == (9, 3)
    np.testing.assert_array_equal(points[0], u0)
    np.testing.assert_array_equal(points[:, 1], 0.5)  # a known axis stays known
    for axis in (0, 2):
        # One start in each eighth of the range: the hypercube's promise.
        np.testing.assert_array_equal(np.sort(np.floor(points[1:, axis] * 8)), np.arange(8))
    np.testing.assert_array_equal(spread_starts(u0, 9, seed=3, fixed=np.zeros(3, bool))[1:, 0], points[1:, 0])
    np.testing.assert_array_equal(spread_starts(u0, 1, seed=3, fixed=np.zeros(3, bool)), u0[None])
