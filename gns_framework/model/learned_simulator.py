"""The learned simulator: graph builder, features, encoder, processor, decoder and integrator.

The hot path calls the components directly (never through pluggy); ``forward`` is the training computation (DDP
wraps it). Periodic domains: histories made continuous before features and targets, predictions wrapped back.
"""

from __future__ import annotations

from dataclasses import replace

import torch
from torch import Tensor, nn

from ..contracts import Decoder, Encoder, Graph, GraphBuilder, Integrator, ModelSetup, Processor
from ..data.batch import ParticleBatch
from ..moved import renamed
from ..runtime.host_sync import avoids_read_backs
from .features import FeatureBuilder
from .normalization import Stats
from .periodic import PeriodicBox
from .unrolled_loss import unrolled_outputs


@renamed("scene", "setup")  # its names until 0.2
class LearnedSimulator(nn.Module):
    """Predicts the next positions of every particle from its last C positions."""

    kinematic_type: Tensor  # a buffer (register_buffer)

    def __init__(
        self,
        setup: ModelSetup,
        features: FeatureBuilder,
        graph_builder: GraphBuilder,
        encoder: Encoder,
        processor: Processor,
        decoder: Decoder,
        integrator: Integrator,
        output_stats: Stats,
    ):
        super().__init__()
        self.setup = setup
        self.features = features
        self.graph_builder = graph_builder
        self.encoder = encoder
        self.processor = processor
        self.decoder = decoder
        self.integrator = integrator
        self.output_stats = output_stats
        # Only a domain that wraps around needs its history made continuous and its predictions wrapped back.
        self.box = PeriodicBox(setup) if setup.periodic_dims else None
        kinematic = torch.zeros(max(setup.particle_types) + 1, dtype=torch.bool)
        kinematic[list(setup.kinematic_types)] = True
        self.register_buffer("kinematic_type", kinematic, persistent=False)

    def predicted_mask(self, particle_type: Tensor) -> Tensor:
        """(N,) True for particles whose motion the model predicts (not kinematic)."""
        return ~self.kinematic_type[particle_type]

    def continuous(self, position_sequence: Tensor) -> Tensor:
        """(N, C, d) history made continuous across periodic boundaries (the stored one is wrapped)."""
        return position_sequence if self.box is None else self.box.unwrap_history(position_sequence)

    def wrapped(self, position: Tensor) -> Tensor:
        """(N, d) positions wrapped back into a periodic box."""
        return position if self.box is None else self.box.wrap(position)

    def build_graph(self, position_sequence: Tensor, batch: ParticleBatch) -> Graph:
        """The builder's edges, with the particles' current positions and examples attached (see :class:`Graph`)."""
        position = position_sequence[:, -1]
        graph = self.graph_builder.build(position, batch.batch, batch.num_examples)
        on_nodes = lambda rows: rows if graph.node_particle is None else rows[graph.node_particle]  # noqa: E731
        if batch.owned is not None:  # a piece of a split scene: messages into its owned particles only
            graph = graph.received_by(on_nodes(batch.owned), batch.exchange)
        return replace(graph, position=on_nodes(position), batch=on_nodes(batch.batch), num_examples=batch.num_examples)

    def encode_inputs(self, position_sequence: Tensor, batch: ParticleBatch) -> tuple[Tensor, Tensor, Graph]:
        """Node features (graph.num_nodes, node_in), edge features (E, edge_in) and the graph."""
        graph = self.build_graph(position_sequence, batch)
        per_node = lambda field: None if field is None else field[batch.batch]  # noqa: E731
        nodes = self.features.node_features(
            position_sequence,
            batch.particle_type,
            batch.material_property,
            per_node(batch.context),
            bounds=per_node(batch.bounds),
            walls=per_node(batch.walls) if self.setup.wall_conditions else None,
        )
        nodes = nodes if graph.node_particle is None else nodes[graph.node_particle]
        return nodes, self.features.edge_features(graph), graph

    def processed_latent(self, position_sequence: Tensor, batch: ParticleBatch) -> Tensor:
        """Node latents (N, L) after encoder and processor; the history must be continuous."""
        node_features, edge_features, graph = self.encode_inputs(position_sequence, batch)
        node_latent, edge_latent = self.encoder(node_features, edge_features)
        node_latent, _ = self.processor(node_latent, edge_latent, graph)
        return node_latent[: len(position_sequence)]  # a fixed-size graph's sink nodes dropped

    def normalized_prediction(self, position_sequence: Tensor, batch: ParticleBatch) -> Tensor:
        """The decoder's output (N, d): normalised acceleration (or velocity) of every particle.

        Every row is decoded, kinematic ones included, so outputs compare one to one with reference implementations.
        """
        return self.decoder(self.processed_latent(self.continuous(position_sequence), batch))

    def predict_next_position(self, batch: ParticleBatch, prescribed: Tensor | None = None) -> Tensor:
        """(N, d) next positions: predicted for moving particles, prescribed for kinematic ones.

        On the CPU kinematic particles are neither decoded nor integrated. On accelerators every row is, and the
        kinematic rows are then replaced: selecting the moving rows would read their count back from the device at
        every step. The moving rows' values are the same either way (the decoder and integrator work row by row).

        Args:
            batch: the current windows.
            prescribed: (N, d) next positions whose kinematic rows are used; when None,
                kinematic particles stay where they are.
        """
        sequence = self.continuous(batch.position_sequence)
        moving = self.predicted_mask(batch.particle_type)
        node_latent = self.processed_latent(sequence, batch)
        base = batch.position_sequence[:, -1] if prescribed is None else prescribed
        if not avoids_read_backs(node_latent.device):
            next_position = base.clone()
            prediction = self.output_stats.denormalize(self.decoder(node_latent[moving]))
            next_position[moving] = self.wrapped(self.integrator.next_position(sequence[moving], prediction))
            return next_position
        prediction = self.output_stats.denormalize(self.decoder(node_latent))
        predicted = self.wrapped(self.integrator.next_position(sequence, prediction))
        return torch.where(moving[:, None], predicted.to(base.dtype), base)

    def forward(self, batch: ParticleBatch, position_noise: Tensor, unrolled_steps: int = 0) -> tuple[Tensor, Tensor]:
        """Training prediction and target on noise-corrupted inputs.

        The noise is added to the inputs, and the target next position moves with the last input's noise, so the
        target corrects the velocity noise but not the position noise (Sanchez-Gonzalez et al. 2020, Sec. 3).

        Args:
            batch: windows with ``next_position``.
            position_noise: (N, C, d), zero for kinematic particles.

        Returns:
            predicted and target normalised outputs, (N, d) each.
        """
        if unrolled_steps:  # this step, then that many of the model's own, with gradient: ((1 + K) N, d) each
            return unrolled_outputs(self, batch, position_noise, unrolled_steps)
        assert batch.next_position is not None  # training windows have their target
        sequence = self.continuous(batch.position_sequence)
        next_position = (
            batch.next_position if self.box is None else self.box.unwrap_next(sequence[:, -1], batch.next_position)
        )
        noisy_sequence = sequence + position_noise
        prediction = self.decoder(self.processed_latent(noisy_sequence, batch))
        next_position_adjusted = next_position + position_noise[:, -1]
        target = self.output_stats.normalize(self.integrator.target(noisy_sequence, next_position_adjusted))
        return prediction, target
