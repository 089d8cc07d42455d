"""What the learned parts (encoder, processor, decoder) share: a torch module built from its recipe parameters and the
model's sizes."""

from __future__ import annotations

from fnmatch import fnmatch
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

    node_module_names: ClassVar[tuple[str, ...]] = ()
    """Patterns (``fnmatch``, e.g. ``steps.*.node_mlp``) of the submodules that act on node rows alone, row by row
    (no edges, no reads of values): the node side, what :func:`~gns_framework.runtime.compiled.compile_node_side`
    compiles."""

    def node_modules(self) -> list[nn.Module]:
        """The submodules ``node_module_names`` names, in module order."""
        names = self.node_module_names
        return [module for path, module in self.named_modules() if any(fnmatch(path, p) for p in names)]
