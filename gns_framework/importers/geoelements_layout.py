"""Where each parameter of a geoelements/gns ``LearnedSimulator`` goes in the built-in components.

geoelements (https://github.com/geoelements/gns, MIT) names its parameters

=====================================================================  =============================================
geoelements ``state_dict`` key                                          built-in key (``LearnedSimulator``)
=====================================================================  =============================================
``_particle_type_embedding.weight``                                     ``features.type_embedding.weight``
``_encode_process_decode._encoder.{node,edge}_fn.0.NN-k.*``            ``encoder.{node,edge}_mlp.mlp.linears.k.*``
``_encode_process_decode._encoder.{node,edge}_fn.1.*``                 ``encoder.{node,edge}_mlp.norm.*``
``_encode_process_decode._processor.gnn_stacks.m.{node,edge}_fn.0.NN-k.*``  ``processor.steps.m.{node,edge}_mlp.mlp.linears.k.*``
``_encode_process_decode._processor.gnn_stacks.m.{node,edge}_fn.1.*``  ``processor.steps.m.{node,edge}_mlp.norm.*``
``_encode_process_decode._decoder.node_fn.NN-k.*``                     ``decoder.mlp.linears.k.*``
=====================================================================  =============================================

Two layouts differ and are converted:

* First processor layers: geoelements concatenates ``[x_receiver, x_sender, e]`` for
  the edge MLP and ``[aggregate, x]`` for the node MLP; the built-ins use DeepMind's
  ``[e, x_receiver, x_sender]`` and ``[x, aggregate]``. The weight columns (input
  features) of ``NN-0`` are permuted accordingly; nothing else changes.
* Type embedding: geoelements has one row per type id ``0 .. nparticle_types-1`` and
  uses it only when ``nparticle_types > 1``; ours has one row per type of the scene,
  in ascending id order. The scene's rows are taken. A scene with a single type has
  no embedding: its (constant) row is folded into the encoder's first node bias,
  ``b + W[:, emb] @ row``, which gives the same features.

The same linear maps apply to gradients and to Adam's moments (:meth:`ParameterMap.tensor`).
"""  # noqa: E501 - the table above is as wide as its longest key pair

from __future__ import annotations

import re
from dataclasses import dataclass

import torch
from torch import Tensor

from ..errors import CheckpointError

EMBEDDING_KEY = "_particle_type_embedding.weight"
_PREFIX = "_encode_process_decode."
_RULES: tuple[tuple[re.Pattern, str], ...] = (
    (re.compile(r"_encoder\.(node|edge)_fn\.0\.NN-(\d+)\.(weight|bias)"), r"encoder.\1_mlp.mlp.linears.\2.\3"),
    (re.compile(r"_encoder\.(node|edge)_fn\.1\.(weight|bias)"), r"encoder.\1_mlp.norm.\2"),
    (
        re.compile(r"_processor\.gnn_stacks\.(\d+)\.(node|edge)_fn\.0\.NN-(\d+)\.(weight|bias)"),
        r"processor.steps.\1.\2_mlp.mlp.linears.\3.\4",
    ),
    (
        re.compile(r"_processor\.gnn_stacks\.(\d+)\.(node|edge)_fn\.1\.(weight|bias)"),
        r"processor.steps.\1.\2_mlp.norm.\3",
    ),
    (re.compile(r"_decoder\.node_fn\.NN-(\d+)\.(weight|bias)"), r"decoder.mlp.linears.\1.\2"),
)
_PROCESSOR_FIRST_WEIGHT = re.compile(r"_processor\.gnn_stacks\.\d+\.(node|edge)_fn\.0\.NN-0\.weight")
ENCODER_NODE_FIRST_WEIGHT = _PREFIX + "_encoder.node_fn.0.NN-0.weight"
ENCODER_NODE_FIRST_BIAS = _PREFIX + "_encoder.node_fn.0.NN-0.bias"


def built_in_name(key: str) -> str | None:
    """The built-in parameter a geoelements key maps to (None for the type embedding, which is special)."""
    if key == EMBEDDING_KEY or not key.startswith(_PREFIX):
        return None
    rest = key[len(_PREFIX) :]
    for pattern, template in _RULES:
        if pattern.fullmatch(rest):
            return pattern.sub(template, rest)
    return None


def edge_inputs_to_ours(weight: Tensor, latent: int) -> Tensor:
    """(H, 3L) columns ``[receiver, sender, edge]`` -> ``[edge, receiver, sender]``."""
    return torch.cat([weight[:, 2 * latent :], weight[:, :latent], weight[:, latent : 2 * latent]], dim=1)


def node_inputs_to_ours(weight: Tensor, latent: int) -> Tensor:
    """(H, 2L) columns ``[aggregate, node]`` -> ``[node, aggregate]``."""
    return torch.cat([weight[:, latent:], weight[:, :latent]], dim=1)


@dataclass(frozen=True)
class Architecture:
    """The constructor arguments of a geoelements ``LearnedSimulator``, read from tensor shapes."""

    latent: int
    mlp_hidden: int
    mlp_hidden_layers: int
    message_passing_steps: int
    num_types: int
    embedding_size: int
    node_in: int
    edge_in: int

    @property
    def dim(self) -> int:
        return self.edge_in - 1

    @property
    def uses_embedding(self) -> bool:
        """geoelements embeds types only when built with more than one."""
        return self.num_types > 1

    @classmethod
    def infer(cls, state_dict: dict[str, Tensor], source: str) -> Architecture:
        def shape(key: str, ndim: int) -> tuple[int, ...]:
            if key not in state_dict:
                raise CheckpointError(f"{source}: {key}: missing (not a geoelements/gns LearnedSimulator state_dict?)")
            value = state_dict[key]
            if not isinstance(value, Tensor) or value.ndim != ndim:
                found = tuple(value.shape) if isinstance(value, Tensor) else type(value).__name__
                raise CheckpointError(f"{source}: {key}: expected a {ndim}-D tensor, got {found}")
            return tuple(value.shape)

        encoder_layers = _indices(state_dict, r"_encoder\.node_fn\.0\.NN-(\d+)\.weight")
        steps = _indices(state_dict, r"_processor\.gnn_stacks\.(\d+)\.")
        if not encoder_layers or not steps:
            raise CheckpointError(
                f"{source}: no {_PREFIX}_encoder / _processor keys: not a geoelements/gns LearnedSimulator state_dict"
            )
        hidden_layers = max(encoder_layers)
        hidden_out, node_in = shape(ENCODER_NODE_FIRST_WEIGHT, 2)
        _, edge_in = shape(_PREFIX + "_encoder.edge_fn.0.NN-0.weight", 2)
        (latent,) = shape(_PREFIX + "_encoder.node_fn.1.weight", 1)
        num_types, embedding_size = shape(EMBEDDING_KEY, 2)
        return cls(
            latent=latent,
            mlp_hidden=hidden_out if hidden_layers > 0 else latent,
            mlp_hidden_layers=hidden_layers,
            message_passing_steps=max(steps) + 1,
            num_types=num_types,
            embedding_size=embedding_size,
            node_in=node_in,
            edge_in=edge_in,
        )

    def keys(self) -> list[str]:
        """Every ``state_dict`` key a geoelements model of this architecture has."""
        linears = [f"NN-{k}.{p}" for k in range(self.mlp_hidden_layers + 1) for p in ("weight", "bias")]
        norm = ["1.weight", "1.bias"]

        def block(prefix: str) -> list[str]:
            return [f"{prefix}.0.{linear}" for linear in linears] + [f"{prefix}.{n}" for n in norm]

        keys = [EMBEDDING_KEY]
        keys += block(_PREFIX + "_encoder.node_fn") + block(_PREFIX + "_encoder.edge_fn")
        for m in range(self.message_passing_steps):
            keys += block(f"{_PREFIX}_processor.gnn_stacks.{m}.node_fn") + block(
                f"{_PREFIX}_processor.gnn_stacks.{m}.edge_fn"
            )
        return keys + [f"{_PREFIX}_decoder.node_fn.{linear}" for linear in linears]


def _indices(state_dict: dict, pattern: str) -> list[int]:
    regex = re.compile(re.escape(_PREFIX) + pattern)
    return sorted({int(m.group(1)) for key in state_dict if (m := regex.match(key))})


class ParameterMap:
    """Converts geoelements parameters (and their gradients or optimizer moments) to built-in ones.

    Args:
        architecture: the geoelements model's sizes.
        particle_types: sorted type ids of the scene (embedding rows to keep).
        walls_width: columns of the node features before the embedding ((C-1)*d + 2d).
    """

    def __init__(self, architecture: Architecture, particle_types: tuple[int, ...], walls_width: int):
        self.architecture = architecture
        self.particle_types = particle_types
        self.embedding_columns = slice(walls_width, walls_width + architecture.embedding_size)
        self.folds_embedding = architecture.uses_embedding and len(particle_types) == 1

    def name(self, key: str) -> str | None:
        """Built-in name of a geoelements parameter; None when it has no counterpart."""
        if key == EMBEDDING_KEY:
            keeps_rows = self.architecture.uses_embedding and not self.folds_embedding
            return "features.type_embedding.weight" if keeps_rows else None
        return built_in_name(key)

    def tensor(self, key: str, value: Tensor) -> Tensor:
        """``value`` in the built-in layout (a linear map, so valid for gradients and moments too)."""
        latent = self.architecture.latent
        if key == EMBEDDING_KEY:
            return value[list(self.particle_types)]
        if key == ENCODER_NODE_FIRST_WEIGHT and self.folds_embedding:
            keep = [
                c for c in range(value.shape[1]) if not self.embedding_columns.start <= c < self.embedding_columns.stop
            ]
            return value[:, keep]
        match = _PROCESSOR_FIRST_WEIGHT.fullmatch(key[len(_PREFIX) :]) if key.startswith(_PREFIX) else None
        if match:
            return (edge_inputs_to_ours if match.group(1) == "edge" else node_inputs_to_ours)(value, latent)
        return value

    def state_dict(self, reference: dict[str, Tensor]) -> dict[str, Tensor]:
        """Built-in parameters from a geoelements ``state_dict`` (folding a single type's embedding)."""
        ours: dict[str, Tensor] = {}
        for k, v in reference.items():
            ours_name = self.name(k)
            if ours_name is not None:
                ours[ours_name] = self.tensor(k, v)
        if self.folds_embedding:
            row = reference[EMBEDDING_KEY][self.particle_types[0]]
            weight = reference[ENCODER_NODE_FIRST_WEIGHT][:, self.embedding_columns]
            name = built_in_name(ENCODER_NODE_FIRST_BIAS)
            assert name is not None  # the encoder's first bias has a built-in counterpart
            ours[name] = reference[ENCODER_NODE_FIRST_BIAS] + weight @ row
        return ours
