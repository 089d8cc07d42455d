"""Searching the scaled unknowns ``u`` in [0, 1]^k: projected Adam, or SciPy's bounded L-BFGS-B.

Each loss evaluation is one learned rollout and its backward. Both optimisers report
every iteration (``on_iteration``) with the loss at the iterate they have just
accepted, so progress bars, logs and plots show the path the search took.

Adam also searches M starting points at once: ``u`` is then (M, k), the loss returns
one value per start, and since Adam's update is elementwise (and the starts' rollouts
never meet) that is M independent searches sharing each model call.

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
    """One accepted iterate: 1-based iteration, loss there, the scaled unknowns, the held-out misfit if any,
    and which start of a multi-start search it belongs to (0 for a single search)."""

    iteration: int
    loss: float
    u: np.ndarray
    held_out: float | None = None
    start: int = 0

    @property
    def score(self) -> float:
        """What the best iterate is chosen by: the held-out misfit when there is one, else the loss."""
        return self.loss if self.held_out is None else self.held_out


def best_iterate(history: list[Iterate]) -> Iterate:
    """The iterate of lowest :attr:`Iterate.score` (the earliest of equals)."""
    if not history:
        raise ValueError("no iterate to choose from")
    return min(history, key=lambda it: (it.score, it.iteration, it.start))


@dataclass(frozen=True)
class Solution:
    u: np.ndarray
    """(k,) the optimiser's final point, or (M, k) one per start."""
    iterations: int
    evaluations: int
    message: str
    stopped: tuple[int, ...] = ()
    """Starts of a multi-start search that went non-finite and stopped at their last finite iterate."""


LossFunction = Callable[[Tensor], "Tensor | tuple[Tensor, Tensor | None]"]
Observer = Callable[[Iterate], None]


class _Evaluator:
    """Loss and gradient at ``u``, counted, refusing non-finite values with the field to change."""

    def __init__(self, loss: LossFunction, describe: Callable[[np.ndarray], str], dtype: torch.dtype):
        self.loss, self.describe, self.dtype = loss, describe, dtype
        self.count = 0
        self.held_out: float | None = None
        """The held-out misfit of the last evaluation (None when the loss gives none)."""

    def _evaluate(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Loss, gradient and held-out misfit at ``u`` (k,) or per start at ``u`` (M, k), unchecked."""
        self.count += 1
        point = torch.tensor(u, dtype=self.dtype, requires_grad=True)
        returned = self.loss(point)
        loss: Tensor
        held_out: Tensor | None = None
        if isinstance(returned, tuple):
            loss, held_out = returned
        else:
            loss = returned
        # Each start's loss depends on its own point only: the gradient of the sum is each one's gradient.
        (loss_gradient,) = torch.autograd.grad(loss.sum(), point)
        return (
            loss.detach().double().numpy(),
            loss_gradient.detach().double().numpy(),
            None if held_out is None else held_out.detach().double().numpy(),
        )

    def starts(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray]:
        """Per start of ``u`` (M, k): losses (M,), gradients (M, k), held-out misfits (M,) or None, and which are
        finite."""
        values, gradients, held_out = self._evaluate(u)
        return values, gradients, held_out, np.isfinite(values) & np.isfinite(gradients).all(axis=1)

    def __call__(self, u: np.ndarray) -> tuple[float, np.ndarray]:
        values, gradient, held_out = self._evaluate(u)
        value = float(values)
        self.held_out = None if held_out is None else float(held_out)
        if not (np.isfinite(value) and np.isfinite(gradient).all()):
            raise InversionDiverged(
                f"loss: non-finite {'value' if not np.isfinite(value) else 'gradient'} at evaluation {self.count} "
                f"({self.describe(u)}): the learned rollout left the range it was trained on; narrow the unknowns' "
                "bounds or lower optimizer.lr"
            )
        return value, gradient


def _adam_on(u0: np.ndarray, lr: float, lr_decay: float | None):
    """(u, Adam over it, its exponential step-size decay or None): ``u`` a float64 copy of ``u0`` with a zero grad."""
    u = torch.tensor(u0, dtype=torch.float64)
    u.grad = torch.zeros_like(u)
    optimizer = torch.optim.Adam([u], lr=lr)
    schedule = None if lr_decay is None else torch.optim.lr_scheduler.ExponentialLR(optimizer, gamma=lr_decay)
    return u, optimizer, schedule


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
    ``u0`` (M, k) searches M starts at once (:func:`_adam_starts`).
    """
    evaluate = _Evaluator(loss, describe, dtype)
    if np.ndim(u0) == 2:
        return _adam_starts(evaluate, u0, lr, iterations, on_iteration, lr_decay)
    u, optimizer, schedule = _adam_on(u0, lr, lr_decay)
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


def _adam_starts(
    evaluate: _Evaluator, u0: np.ndarray, lr: float, iterations: int, on_iteration: Observer, lr_decay: float | None
) -> Solution:
    """Adam from each row of ``u0`` (M, k), every start's loss from one batched evaluation.

    A start whose loss or gradient turns non-finite stops where it last was finite (its
    steps are undone, it reports no more iterates) and the others go on; a non-finite
    value at a start's very first point, or every start stopping, is an error.
    """
    u, optimizer, schedule = _adam_on(u0, lr, lr_decay)
    stopped = np.zeros(len(u0), dtype=bool)
    previous = u.detach().clone()
    for iteration in range(1, iterations + 1):
        points = u.detach().numpy().copy()
        values, gradients, held_out, finite = evaluate.starts(points)
        newly = ~finite & ~stopped
        if newly.any() and iteration == 1:
            first = int(np.flatnonzero(newly)[0])
            raise InversionDiverged(
                f"loss: non-finite value or gradient at the starting point of start {first} "
                f"({evaluate.describe(points[first])}): narrow the unknowns' bounds"
            )
        stopped |= newly
        if stopped.all():
            raise InversionDiverged(
                f"loss: every start turned non-finite by iteration {iteration}: the learned rollout left the range it "
                "was trained on; narrow the unknowns' bounds or lower optimizer.lr"
            )
        with torch.no_grad():
            u[torch.from_numpy(newly)] = previous[torch.from_numpy(newly)]  # back to its last finite iterate
        for start in np.flatnonzero(~stopped):
            held = None if held_out is None else float(held_out[start])
            on_iteration(Iterate(iteration, float(values[start]), points[start], held, int(start)))
        u.grad = torch.from_numpy(np.where(stopped[:, None], 0.0, gradients))
        previous = u.detach().clone()
        optimizer.step()
        if schedule is not None:
            schedule.step()
        with torch.no_grad():
            u.clamp_(0.0, 1.0)
            # Adam's momentum would still move a stopped start: keep it where it stopped.
            u[torch.from_numpy(stopped)] = previous[torch.from_numpy(stopped)]
    decayed = "" if lr_decay is None else f", step size decayed by {lr_decay:g} per step"
    halted = "" if not stopped.any() else f"; starts {np.flatnonzero(stopped).tolist()} stopped (non-finite)"
    return Solution(
        u.detach().numpy().copy(),
        iterations,
        evaluate.count,
        f"{iterations} Adam steps from {len(u0)} starts{decayed}{halted}",
        tuple(int(s) for s in np.flatnonzero(stopped)),
    )


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


def spread_starts(u0: np.ndarray, starts: int, seed: int, fixed: np.ndarray) -> np.ndarray:
    """(M, k) starting points: ``u0`` first, then M - 1 Latin-hypercube points of [0, 1]^k.

    A Latin hypercube puts one start in each of M - 1 equal slices of every unknown's
    range, so even a few starts cover each unknown's bounds. Axes that are ``fixed``
    (equal bounds, a known value) keep ``u0``'s value in every start.
    """
    from scipy.stats import qmc

    u0 = np.asarray(u0, dtype=np.float64)
    if starts == 1:
        return u0[None].copy()
    spread = qmc.LatinHypercube(d=len(u0), seed=seed).random(starts - 1)
    spread = np.where(np.asarray(fixed, dtype=bool)[None], u0[None], spread)
    return np.concatenate([u0[None], spread])
