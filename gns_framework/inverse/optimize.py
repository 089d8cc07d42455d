"""Searching the scaled unknowns ``u`` in [0, 1]^k: projected Adam, or SciPy's bounded L-BFGS-B.

Each loss evaluation is one learned rollout and its backward. Both optimisers report
every iteration (``on_iteration``) with the loss at the iterate they have just
accepted, so progress bars, logs and plots show the path the search took.

A loss function may return ``(loss, held_out)``: the misfit of the same rollout on
observed frames the loss does not compare, recorded with each iterate (never
differentiated) so that the best iterate can be chosen by it (:func:`best_iterate`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from ..errors import GnsError


class InversionDiverged(GnsError):
    """The loss or its gradient became non-finite during the search."""


@dataclass(frozen=True)
class Iterate:
    """One accepted iterate: 1-based iteration, loss there, the scaled unknowns, the held-out misfit if any."""

    iteration: int
    loss: float
    u: np.ndarray
    held_out: float | None = None

    @property
    def score(self) -> float:
        """What the best iterate is chosen by: the held-out misfit when there is one, else the loss."""
        return self.loss if self.held_out is None else self.held_out


def best_iterate(history: list[Iterate]) -> Iterate:
    """The iterate of lowest :attr:`Iterate.score` (the earliest of equals)."""
    if not history:
        raise ValueError("no iterate to choose from")
    return min(history, key=lambda it: (it.score, it.iteration))


@dataclass(frozen=True)
class Solution:
    u: np.ndarray
    iterations: int
    evaluations: int
    message: str


LossFunction = Callable[[Tensor], "Tensor | tuple[Tensor, Tensor | None]"]
Observer = Callable[[Iterate], None]


class _Evaluator:
    """Loss and gradient at ``u``, counted, refusing non-finite values with the field to change."""

    def __init__(self, loss: LossFunction, describe: Callable[[np.ndarray], str], dtype: torch.dtype):
        self.loss, self.describe, self.dtype = loss, describe, dtype
        self.count = 0
        self.held_out: float | None = None
        """The held-out misfit of the last evaluation (None when the loss gives none)."""

    def __call__(self, u: np.ndarray) -> tuple[float, np.ndarray]:
        self.count += 1
        point = torch.tensor(u, dtype=self.dtype, requires_grad=True)
        returned = self.loss(point)
        loss: Tensor
        held_out: Tensor | None = None
        if isinstance(returned, tuple):
            loss, held_out = returned
        else:
            loss = returned
        self.held_out = None if held_out is None else float(held_out.detach())
        (loss_gradient,) = torch.autograd.grad(loss, point)
        value, gradient = float(loss.detach()), loss_gradient.detach().double().numpy()
        if not (np.isfinite(value) and np.isfinite(gradient).all()):
            raise InversionDiverged(
                f"loss: non-finite {'value' if not np.isfinite(value) else 'gradient'} at evaluation {self.count} "
                f"({self.describe(u)}): the learned rollout left the range it was trained on; narrow the unknowns' "
                "bounds or lower optimizer.lr"
            )
        return value, gradient


def adam(
    loss: LossFunction,
    u0: np.ndarray,
    lr: float,
    iterations: int,
    on_iteration: Observer,
    describe: Callable[[np.ndarray], str],
    dtype: torch.dtype = torch.float32,
    lr_decay: float | None = None,
) -> Solution:
    """Adam on ``u``, projected back onto [0, 1]^k after every step.

    ``lr_decay``: the step size is multiplied by it after each step (exponential
    decay, so the iterates settle instead of circling the minimum); None keeps it.
    The returned ``u`` is the point after the last step, which no iteration evaluated.
    """
    evaluate = _Evaluator(loss, describe, dtype)
    u = torch.tensor(u0, dtype=torch.float64)
    u.grad = torch.zeros_like(u)
    optimizer = torch.optim.Adam([u], lr=lr)
    schedule = None if lr_decay is None else torch.optim.lr_scheduler.ExponentialLR(optimizer, gamma=lr_decay)
    for iteration in range(1, iterations + 1):
        value, gradient = evaluate(u.detach().numpy())
        on_iteration(Iterate(iteration, value, u.detach().numpy().copy(), evaluate.held_out))
        u.grad = torch.from_numpy(gradient)
        optimizer.step()
        if schedule is not None:
            schedule.step()
        with torch.no_grad():
            u.clamp_(0.0, 1.0)
    decayed = "" if lr_decay is None else f", step size decayed by {lr_decay:g} per step"
    return Solution(u.detach().numpy().copy(), iterations, evaluate.count, f"{iterations} Adam steps{decayed}")


def lbfgs(
    loss: LossFunction,
    u0: np.ndarray,
    iterations: int,
    on_iteration: Observer,
    describe: Callable[[np.ndarray], str],
    dtype: torch.dtype = torch.float32,
) -> Solution:
    """SciPy's L-BFGS-B within [0, 1]^k, at most ``iterations`` iterations.

    The loss is divided by its value at ``u0`` before SciPy sees it, so SciPy's
    absolute stopping tolerances mean the same for a loss in m^2 as for one in %.
    """
    from scipy.optimize import minimize

    evaluate = _Evaluator(loss, describe, dtype)
    scale = max(evaluate(u0)[0], np.finfo(np.float64).tiny)

    accepted_count = 1
    last_evaluated = np.asarray(u0, dtype=np.float64).copy()

    def scaled(u: np.ndarray) -> tuple[float, np.ndarray]:
        nonlocal last_evaluated
        value, gradient = evaluate(u)
        last_evaluated = np.asarray(u).copy()
        return value / scale, gradient / scale

    def accepted(intermediate_result) -> None:
        # SciPy passes the OptimizeResult only to a parameter of exactly this name.
        # The held-out misfit of the accepted point: SciPy evaluated it last unless a line search went on.
        nonlocal accepted_count
        x = np.asarray(intermediate_result.x).copy()
        held_out = evaluate.held_out if np.array_equal(x, last_evaluated) else None
        on_iteration(Iterate(accepted_count, float(intermediate_result.fun) * scale, x, held_out))
        accepted_count += 1

    result = minimize(
        scaled,
        np.asarray(u0, dtype=np.float64),
        jac=True,
        method="L-BFGS-B",
        bounds=[(0.0, 1.0)] * len(u0),
        callback=accepted,
        options={"maxiter": iterations, "maxfun": 4 * iterations},
    )
    return Solution(np.asarray(result.x, dtype=np.float64), int(result.nit), evaluate.count, str(result.message))
