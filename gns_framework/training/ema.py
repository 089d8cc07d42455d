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

    @property
    def module(self) -> ModelT:
        """The model with the averaged weights."""
        return cast(ModelT, self._averaged.module)  # AveragedModel holds a deep copy of the model

    @torch.no_grad()
    def update(self, model: torch.nn.Module) -> None:
        self._averaged.update_parameters(model)

    def state_dict(self) -> dict:
        """The averaged model's weights (keys as the model's) and how many updates they hold."""
        return {"model": self.module.state_dict(), "updates": int(self._averaged.n_averaged)}

    def load_state_dict(self, state: dict) -> None:
        self.module.load_state_dict(state["model"])
        self._averaged.n_averaged.fill_(int(state["updates"]))
