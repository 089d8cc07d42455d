"""Node and edge features of the reference model, built only from what the scene has.

Node features, in column order (N rows):
    1. normalised velocity history, time-major ``[v0x, v0y, v1x, ...]``   (C-1)*d
    2. wall distances ``[p - lower, upper - p] / R`` clipped to +-clamp  2w   (w dims with walls)
       each walled face's friction coefficient, same face order         2w   (wall conditions)
    3. learned particle-type embedding                                   emb  (more than one type)
    4. per-particle material properties                                  P    (scenes with properties)
    5. normalised global context of the frame                            c    (scenes with context)
Edge features (E rows): ``(p_sender - p_receiver) / R`` and its norm, d + 1 columns. The norm is
:func:`safe_norm`: every self-edge has length 0, where the Euclidean norm is not differentiable twice.

Dimensions that wrap around (periodic) have no walls; the history passed in must already be continuous there (see
:class:`~gns_framework.model.periodic.PeriodicBox`).

The walls are the model's bounds unless the data gives each example its own domain (``bounds`` per particle, from
its trajectory): one model then rolls out in boxes of other sizes, as a particle sees a wall only within ``clamp * R``.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from ..contracts import Graph, ModelSetup
from ..moved import renamed
from .normalization import Stats


def safe_norm(vector: Tensor) -> Tensor:
    """``torch.linalg.vector_norm(vector, dim=-1, keepdim=True)`` with finite derivatives of every order at 0.

    The values are bitwise those of ``vector_norm``. Its first derivative at the zero vector is already 0, but its
    second is NaN (``x / |x|`` differentiated at 0), and a NaN in any self-edge poisons gradient penalties,
    Hessian-vector products and optimisers that differentiate through a rollout. Zero rows are evaluated at a
    stand-in vector of ones instead and their result replaced by 0, so no branch that autograd visits ever divides
    by a zero length; the gradient there is 0.

    Shapes: (..., d) -> (..., 1).
    """
    nonzero = (vector != 0).any(dim=-1, keepdim=True)
    stand_in = torch.where(nonzero, vector, torch.ones_like(vector))
    norm = torch.linalg.vector_norm(stand_in, dim=-1, keepdim=True)
    return torch.where(nonzero, norm, torch.zeros_like(norm))


def node_feature_size(setup: ModelSetup, type_embedding_size: int) -> int:
    size = (setup.history - 1) * setup.dim
    size += 2 * len(setup.wall_dims) * (2 if setup.wall_conditions else 1)
    size += type_embedding_size if setup.uses_type_embedding else 0
    return size + len(setup.property_names) + setup.context_size


def edge_feature_size(setup: ModelSetup) -> int:
    return setup.dim + 1


@renamed("scene", "setup")  # its names until 0.2
class FeatureBuilder(nn.Module):
    """Builds node and edge features; owns the particle-type embedding when one is needed."""

    bounds: Tensor  # buffers (register_buffer)
    walled_dims: Tensor
    walled_bounds: Tensor
    walled_faces: Tensor
    type_row: Tensor

    def __init__(
        self,
        setup: ModelSetup,
        velocity_stats: Stats,
        type_embedding_size: int,
        context_stats: Stats | None = None,
    ):
        super().__init__()
        self.setup = setup
        self.velocity_stats = velocity_stats
        self.context_stats = context_stats
        self.register_buffer("bounds", torch.tensor(setup.bounds, dtype=torch.float32))
        # The walled dimensions as index tensors that move with the module: a list index would be
        # copied from the host on every call.
        walled = torch.tensor(setup.wall_dims, dtype=torch.long)
        self.has_walls = bool(setup.wall_dims)
        self.register_buffer("walled_dims", walled, persistent=False)
        self.register_buffer("walled_bounds", self.bounds[walled], persistent=False)
        # Faces of the walled dimensions in the order of the distance features: lower faces, then upper.
        faces = torch.cat([2 * walled, 2 * walled + 1])
        self.register_buffer("walled_faces", faces, persistent=False)
        self.type_embedding: nn.Embedding | None = None
        if setup.uses_type_embedding:
            self.type_embedding = nn.Embedding(setup.num_particle_types, type_embedding_size)
            table = torch.full((max(setup.particle_types) + 1,), -1, dtype=torch.long)
            table[list(setup.particle_types)] = torch.arange(setup.num_particle_types)
            self.register_buffer("type_row", table)

    def node_features(
        self,
        position_sequence: Tensor,
        particle_type: Tensor,
        material_property: Tensor | None = None,
        context: Tensor | None = None,
        bounds: Tensor | None = None,
        walls: Tensor | None = None,
    ) -> Tensor:
        """(N, C, d) history [+ (N,) types, (N, P) properties, (N, c) context] -> (N, node_in).

        ``bounds`` (N, d, 2): each particle's domain (default: the model's); ``walls``
        (N, 2d, 2): its domain's face conditions, needed when the scene has wall conditions.
        """
        setup = self.setup
        n = position_sequence.shape[0]
        velocity_sequence = position_sequence[:, 1:] - position_sequence[:, :-1]
        parts = [self.velocity_stats.normalize(velocity_sequence).reshape(n, -1)]
        if self.has_walls:
            most_recent = position_sequence[:, -1].index_select(1, self.walled_dims)
            if bounds is None:
                lower, upper = self.walled_bounds[:, 0][None], self.walled_bounds[:, 1][None]
            else:
                walled = bounds.index_select(1, self.walled_dims).to(most_recent.dtype)
                lower, upper = walled[..., 0], walled[..., 1]
            distance = torch.cat([most_recent - lower, upper - most_recent], dim=1) / setup.connectivity_radius
            limit = setup.boundary_clamp_limit
            parts.append(torch.clamp(distance, -limit, limit))
            if setup.wall_conditions:
                if walls is None:
                    raise ValueError("the model takes wall conditions as inputs, but the data records no walls")
                parts.append(walls[:, :, 0].index_select(1, self.walled_faces).to(most_recent.dtype))
        if self.type_embedding is not None:
            parts.append(self.type_embedding(self.type_row[particle_type]))
        if setup.property_names:
            assert material_property is not None, "the scene has material properties: the data records them"
            parts.append(material_property.reshape(n, len(setup.property_names)))
        if setup.context_size:
            # build_learned_simulator gives context statistics to a scene with context, whose data records it.
            assert self.context_stats is not None and context is not None
            parts.append(self.context_stats.normalize(context))
        return torch.cat(parts, dim=-1)

    def edge_features(self, graph: Graph) -> Tensor:
        """(E, d + 1): relative displacement over R, and its length."""
        relative = graph.displacement / self.setup.connectivity_radius
        return torch.cat([relative, safe_norm(relative)], dim=-1)
