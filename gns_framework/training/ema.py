"""An exponential moving average of the weights: what validation, best.pt and rollouts use (``training.ema_decay``).

Late in training the optimiser's steps still move the weights by amounts that change
a long rollout's error from one evaluation to the next (rollout error swung between
10 % and 53 % while the one-step loss fell, issue 32). The average over the last
~1 / (1 - decay) steps keeps the descent and drops that jitter (Polyak averaging);
it costs one copy of the weights. Training itself goes on with the raw weights, so
checkpoints keep both (``model``: raw, ``ema``: the average) and resume exactly.
"""

from __future__ import annotations

from typing import Generic, TypeVar, cast

import torch
from torch.optim.swa_utils import AveragedModel, get_ema_multi_avg_fn

ModelT = TypeVar("ModelT", bound=torch.nn.Module)


class WeightAverage(Generic[ModelT]):
    """``average = decay * average + (1 - decay) * weights`` after every optimiser step.

    The first update copies the weights (no bias towards the initial ones). Buffers
    (normalisation statistics, type tables) are the model's own: they do not train.
    """

    def __init__(self, model: ModelT, decay: float):
        if not 0.0 < decay < 1.0:
            raise ValueError(f"ema_decay must lie in (0, 1), got {decay}")
        self.decay = decay
        self._averaged = AveragedModel(model, multi_avg_fn=get_ema_multi_avg_fn(decay), use_buffers=False)
        self._averaging = False  # whether an update has copied the weights (the count, kept on the host)

    @property
    def module(self) -> ModelT:
        """The model with the averaged weights."""
        return cast(ModelT, self._averaged.module)  # AveragedModel holds a deep copy of the model

    @torch.no_grad()
    def update(self, model: torch.nn.Module) -> None:
        if not self._averaging:
            self._averaged.update_parameters(model)  # the first update copies
            self._averaging = True
            return
        # The same lerp as AveragedModel's, without its comparisons of the count with 0 on the host at every
        # call: two read-backs a step, which a captured training step cannot make.
        torch._foreach_lerp_(list(self.module.parameters()), list(model.parameters()), 1.0 - self.decay)
        self._averaged.n_averaged += 1

    def tensors(self) -> list[torch.Tensor]:
        """What an update changes: the averaged weights and the update count."""
        return [*self.module.parameters(), self._averaged.n_averaged]

    def state_dict(self) -> dict:
        """The averaged model's weights (keys as the model's) and how many updates they hold."""
        return {"model": self.module.state_dict(), "updates": int(self._averaged.n_averaged)}

    def load_state_dict(self, state: dict) -> None:
        self.module.load_state_dict(state["model"])
        self._averaged.n_averaged.fill_(int(state["updates"]))
        self._averaging = int(state["updates"]) > 0
