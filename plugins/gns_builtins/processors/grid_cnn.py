"""A grid processor in the spirit of NeuralMPM (Viquerat et al. 2024): particles to grid, a CNN, grid to particles.

Message passing over edges costs work per edge; an MPM-like model moves the
particles' information onto a regular grid instead, lets a convolutional network
mix it there (dense, regular, cheap per cell), and reads it back at the particles.
First the edge latents e (E, L) of the encoder (relative positions within one
connectivity radius: detail finer than a cell) are summed at their receivers once,
``h_i <- h_i + LN(MLP([h_i, sum_j e_ij]))``. Then each of the M rounds, with node
latents h (N, L) and positions x (N, d)::

    w_pc      = prod_k hat((x_pk - X_ck) / h)            linear (tent) weights, 2^d cells per particle
    g_c       = [sum_p w_pc h_p / sum_p w_pc, sum_p w_pc]  particles to grid: mean latent and occupancy
    g         = CNN(g)                                    3^d convolutions, dilations 1, 2, 4, ...
    h_p      <- h_p + LN(MLP([h_p, sum_c w_pc g_c]))       grid to particles, residual update

The grid spacing is ``cell_size`` connectivity radii; the grid of each example
starts one cell below its lowest particle on a lattice fixed in space (so a
translation by whole cells moves the grid with the particles) and is as large as
the largest example needs. The edge latents are returned unchanged. Domains that
wrap around (periodic) are not handled: the grid has edges.
"""

from __future__ import annotations

import itertools

import torch
from pydantic import Field
from torch import Tensor, nn

from gns_framework.api import NormedMLP
from gns_framework.contracts import ComponentParams, Graph, ModelSizes, Processor


class ParticleGrid:
    """Where each particle's 2^d tent weights fall on the batch's grids.

    Shapes: ``cells`` (N, 2^d) flat indices into (B * prod(shape)) cells, ``weights``
    (N, 2^d), summing to 1 per particle; ``shape`` the d grid sizes of every example.
    """

    def __init__(self, position: Tensor, batch: Tensor | None, num_examples: int, spacing: float):
        dim = position.shape[1]
        batch = torch.zeros(position.shape[0], dtype=torch.long, device=position.device) if batch is None else batch
        # Each example's lowest particle, snapped down to the fixed lattice, minus one cell of margin.
        lowest = torch.full((num_examples, dim), torch.inf, dtype=position.dtype, device=position.device)
        lowest = lowest.scatter_reduce(0, batch[:, None].expand(-1, dim), position.detach(), "amin")
        origin = (torch.floor(lowest / spacing) - 1) * spacing
        u = (position - origin[batch]) / spacing
        base = torch.floor(u.detach())
        frac = u - base
        base = base.long()
        # Each example's own grid ends one cell beyond its highest particle's cell; the batch's grids
        # share the largest shape, and the cells beyond an example's own are masked to zero after every
        # convolution, as zero padding at its own edge would be: an example's result never depends on
        # the others in its batch.
        own = torch.zeros((num_examples, dim), dtype=torch.long, device=position.device)
        own = own.scatter_reduce(0, batch[:, None].expand(-1, dim), base + 2, "amax")
        self.shape = tuple(int(s) for s in own.amax(0).tolist())
        axes = [torch.arange(size, device=position.device) for size in self.shape]
        cell = torch.stack(torch.meshgrid(*axes, indexing="ij"), dim=-1)  # (*shape, d) cell coordinates
        inside = (cell[None] < own.view(num_examples, *[1] * dim, dim)).all(-1)
        self.inside = inside[:, None].to(position.dtype)
        """(B, 1, *shape) 1 in each example's own cells, 0 beyond."""
        strides = [1] * dim
        for k in range(dim - 2, -1, -1):
            strides[k] = strides[k + 1] * self.shape[k + 1]
        per_example = strides[0] * self.shape[0]
        cells, weights = [], []
        for corner in itertools.product((0, 1), repeat=dim):
            offset = torch.tensor(corner, device=position.device)
            index = ((base + offset) * torch.tensor(strides, device=position.device)).sum(-1) + batch * per_example
            weight = torch.where(offset.bool(), frac, 1 - frac).prod(-1)
            cells.append(index)
            weights.append(weight)
        self.cells = torch.stack(cells, -1)
        self.weights = torch.stack(weights, -1)
        self.num_cells = num_examples * per_example
        self.num_examples = num_examples

    def to_grid(self, values: Tensor) -> Tensor:
        """(N, F) particle values -> (B, F + 1, *shape): tent-weighted mean per cell, then the weights' sum.

        The sums are taken in the positions' precision (float32 under bfloat16 autocast).
        """
        values = values.to(self.weights.dtype)
        features = values.shape[1]
        weighted = torch.cat([values[:, None, :] * self.weights[..., None], self.weights[..., None]], dim=-1)
        grid = values.new_zeros(self.num_cells, features + 1)
        grid = grid.index_add(0, self.cells.reshape(-1), weighted.reshape(-1, features + 1))
        occupancy = grid[:, -1:]
        mean = grid[:, :-1] / occupancy.clamp(min=1e-6)
        grid = torch.cat([mean, occupancy], dim=-1)
        return grid.reshape(self.num_examples, *self.shape, features + 1).movedim(-1, 1)

    def to_particles(self, grid: Tensor) -> Tensor:
        """(B, F, *shape) grid values -> (N, F), tent-interpolated at each particle."""
        flat = grid.movedim(1, -1).reshape(self.num_cells, grid.shape[1]).to(self.weights.dtype)
        return (flat[self.cells] * self.weights[..., None]).sum(1)


class GridRound(nn.Module):
    """One round: particles to grid, ``layers`` convolutions, grid to particles, residual node update."""

    def __init__(self, dim: int, latent: int, channels: int, layers: int, hidden: int, hidden_layers: int):
        super().__init__()
        conv = nn.Conv2d if dim == 2 else nn.Conv3d
        sizes = [latent + 1] + [channels] * (layers - 1) + [latent]
        # Dilations 1, 2, 4, 1, 2, 4, ...: the receptive field grows fast without pooling.
        self.convs = nn.ModuleList(
            conv(a, b, kernel_size=3, padding=2 ** (k % 3), dilation=2 ** (k % 3))
            for k, (a, b) in enumerate(itertools.pairwise(sizes))
        )
        self.activation = nn.SiLU()
        self.node_mlp = NormedMLP(2 * latent, hidden, hidden_layers, latent)

    def forward(self, h: Tensor, grid: ParticleGrid) -> Tensor:
        values = grid.to_grid(h)
        for k, conv in enumerate(self.convs):
            values = conv(values)
            if k < len(self.convs) - 1:
                values = self.activation(values) * grid.inside
        return h + self.node_mlp(torch.cat([h, grid.to_particles(values).to(h.dtype)], dim=-1))


class GridProcessor(Processor):
    """M rounds of particles -> grid -> CNN -> particles on the node latents (``Graph.position`` required)."""

    name = "grid_cnn"

    class Params(ComponentParams):
        message_passing_steps: int = Field(2, ge=1, description="M, rounds of particles -> grid -> CNN -> particles")
        cell_size: float = Field(1.0, gt=0, description="grid spacing, in connectivity radii R")
        conv_layers: int = Field(4, ge=2, description="3^d convolutions per round")
        channels: int | None = Field(
            None, ge=1, description="channels of the hidden convolutions (default: the latent size)"
        )

    def __init__(self, params: Params, sizes: ModelSizes):
        super().__init__(params, sizes)
        if sizes.dim not in (2, 3):
            raise ValueError(f"grid_cnn: grids in 2 or 3 dimensions, got dim = {sizes.dim}")
        self.spacing = params.cell_size * sizes.connectivity_radius
        channels = params.channels or sizes.latent
        self.edge_mlp = NormedMLP(2 * sizes.latent, sizes.mlp_hidden, sizes.mlp_hidden_layers, sizes.latent)
        self.rounds = nn.ModuleList(
            GridRound(sizes.dim, sizes.latent, channels, params.conv_layers, sizes.mlp_hidden, sizes.mlp_hidden_layers)
            for _ in range(params.message_passing_steps)
        )

    def forward(self, node_latent: Tensor, edge_latent: Tensor, graph: Graph) -> tuple[Tensor, Tensor]:
        if graph.position is None:
            raise ValueError(
                "grid_cnn needs the particles' positions (Graph.position); the learned simulator gives them"
            )
        local = edge_latent.new_zeros(node_latent.shape).index_add(0, graph.receivers, edge_latent)
        node_latent = node_latent + self.edge_mlp(torch.cat([node_latent, local.to(node_latent.dtype)], dim=-1))
        grid = ParticleGrid(graph.position, graph.batch, graph.num_examples, self.spacing)
        if graph.node_particle is not None:  # a fixed-size graph's sink nodes leave no trace on the grid
            nodes = torch.arange(graph.num_nodes, device=node_latent.device)
            grid.weights = grid.weights * (graph.node_particle == nodes)[:, None].to(grid.weights.dtype)
        for round_ in self.rounds:
            node_latent = round_(node_latent, grid)
        return node_latent, edge_latent
