"""The grid processor: tent weights that move mass conservatively, examples kept apart, translation by whole cells."""

from __future__ import annotations

import pytest
import torch

from gns_builtins.processors.grid_cnn import GridProcessor, ParticleGrid
from gns_framework.contracts import Graph
from gns_framework.testing import small_sizes

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _graph(position: torch.Tensor, batch=None, examples: int = 1) -> Graph:
    empty = torch.zeros(0, dtype=torch.long)
    return Graph(empty, empty, position.new_zeros(0, position.shape[1]), position.shape[0], position, batch, examples)


@pytest.mark.parametrize("dim", [2, 3])
def test_tent_weights_sum_to_one_and_reproduce_linear_fields(dim):
    generator = torch.Generator().manual_seed(0)
    position = torch.rand(50, dim, generator=generator, dtype=torch.float64)
    grid = ParticleGrid(position, None, 1, spacing=0.1)
    torch.testing.assert_close(grid.weights.sum(-1), torch.ones(50, dtype=torch.float64))
    assert (grid.weights >= 0).all()
    # A field linear in space, sampled at the cell corners, is read back exactly at every particle.
    corners = torch.stack(
        torch.meshgrid(*[torch.arange(s, dtype=torch.float64) for s in grid.shape], indexing="ij"), -1
    )
    origin = (torch.floor(position.min(0).values / 0.1) - 1) * 0.1
    field = ((origin + 0.1 * corners) * torch.arange(1, dim + 1, dtype=torch.float64)).sum(-1)
    read = grid.to_particles(field[None, None])
    torch.testing.assert_close(read[:, 0], (position * torch.arange(1, dim + 1, dtype=torch.float64)).sum(-1))


def test_to_grid_conserves_each_examples_mass_and_keeps_examples_apart():
    position = torch.tensor([[0.05, 0.05], [0.31, 0.12], [0.05, 0.05], [0.5, 0.5]], dtype=torch.float64)
    batch = torch.tensor([0, 0, 1, 1])
    grid = ParticleGrid(position, batch, 2, spacing=0.1)
    values = torch.tensor([[1.0], [3.0], [5.0], [7.0]], dtype=torch.float64)
    gridded = grid.to_grid(values)
    assert gridded.shape[:2] == (2, 2)
    occupancy = gridded[:, 1].reshape(2, -1).sum(-1)
    torch.testing.assert_close(occupancy, torch.tensor([2.0, 2.0], dtype=torch.float64))
    # Each example's cells hold means of its own values only (1 and 3; 5 and 7). Cells that hold almost no
    # weight fade to 0 (the mean is taken over at least 1e-6 of weight), so only well-filled cells are compared.
    filled = gridded[:, 1] > 1e-3
    assert ((gridded[0, 0][filled[0]] >= 1.0) & (gridded[0, 0][filled[0]] <= 3.0)).all()
    assert ((gridded[1, 0][filled[1]] >= 5.0) & (gridded[1, 0][filled[1]] <= 7.0)).all()
    assert (gridded[0, 0][filled[0]] == 1.0).any() and (gridded[1, 0][filled[1]] == 5.0).any()


def test_the_processor_is_invariant_to_a_translation_by_whole_cells_and_needs_positions():
    sizes = small_sizes()
    processor = GridProcessor(GridProcessor.Params(message_passing_steps=2, conv_layers=2), sizes).double()
    generator = torch.Generator().manual_seed(1)
    position = torch.rand(30, sizes.dim, generator=generator, dtype=torch.float64)
    latent = torch.randn(30, sizes.latent, generator=generator, dtype=torch.float64)
    edges = torch.zeros(0, sizes.latent, dtype=torch.float64)
    out, passed = processor(latent, edges, _graph(position))
    shift = 3 * processor.spacing
    moved, _ = processor(latent, edges, _graph(position + shift))
    torch.testing.assert_close(moved, out, rtol=0, atol=1e-10)
    assert passed is edges
    half, _ = processor(latent, edges, _graph(position + processor.spacing / 2))
    assert not torch.allclose(half, out), "a shift by half a cell moves the particles across their cells"
    with pytest.raises(ValueError, match=r"Graph\.position"):
        processor(
            latent,
            edges,
            Graph(position.new_zeros(0, dtype=torch.long), position.new_zeros(0, dtype=torch.long), edges[:, :2], 30),
        )


def test_an_example_comes_out_of_a_batch_as_it_comes_out_alone():
    """Grids of a batch share the largest shape; each example's cells beyond its own are masked like zero padding."""
    sizes = small_sizes()
    processor = GridProcessor(GridProcessor.Params(message_passing_steps=2, conv_layers=3), sizes).double()
    generator = torch.Generator().manual_seed(2)
    small = torch.rand(12, sizes.dim, generator=generator, dtype=torch.float64) * 0.3
    large = torch.rand(20, sizes.dim, generator=generator, dtype=torch.float64) * 2.0
    latent = torch.randn(32, sizes.latent, generator=generator, dtype=torch.float64)
    edges = torch.zeros(0, sizes.latent, dtype=torch.float64)
    batch = torch.cat([torch.zeros(12, dtype=torch.long), torch.ones(20, dtype=torch.long)])
    together, _ = processor(latent, edges, _graph(torch.cat([small, large]), batch, 2))
    alone_small, _ = processor(latent[:12], edges, _graph(small))
    alone_large, _ = processor(latent[12:], edges, _graph(large))
    torch.testing.assert_close(together[:12], alone_small, rtol=0, atol=1e-12)
    torch.testing.assert_close(together[12:], alone_large, rtol=0, atol=1e-12)
