"""What the learned parts (encoder, processor, decoder) share: a torch module built from its recipe parameters and the
model's sizes."""

from __future__ import annotations

from typing import ClassVar

from torch import nn

from .params import ComponentParams, Params
from .setup import ModelSizes


class LearnedPart(nn.Module):
    """Base of :class:`Encoder`, :class:`Processor` and :class:`Decoder`.

    A subclass names itself (``name``, what a recipe writes), declares its recipe
    parameters (``Params``, a strict pydantic model) and builds its layers in
    ``__init__`` from them and the model's sizes (latent size, MLP width and depth,
    feature sizes: :class:`ModelSizes`).
    """

    name: ClassVar[str]
    Params: ClassVar[type[Params]] = Params

    def __init__(self, params: ComponentParams, sizes: ModelSizes):
        super().__init__()
        self.params = params
