"""Boundary conditions of the MLS-MPM grid update: which nodes are walls, and what each wall does.

These tests drive the grid-update kernel directly: every node gets unit mass
and a chosen velocity, and the velocity after the update shows which
boundary condition acted on it.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from gns_framework.simulation.build import build_simulator
from gns_framework.simulation.sampling import sample_scene
from gns_framework.simulation.scene_spec import parse_scene

pytest.importorskip("warp")


def scene_in(bounds: list[list[float]], grid: int, **domain) -> dict:
    """A weightless scene with one small sand block in the middle of ``bounds``."""
    dim = len(bounds)
    middle = [lo + 0.45 * (hi - lo) for lo, hi in bounds]
    size = [0.05 * max(hi - lo for lo, hi in bounds)] * dim
    return {
        "dim": dim,
        "domain": {"bounds": bounds, "grid": grid, **domain},
        "time": {"frame_dt": 1e-3, "substeps": 20, "frames": 3},
        "gravity": [0.0] * dim,
        "blocks": [{"material": "sand", "position": middle, "size": size}],
    }


def solver_for(raw: dict, registry):
    from plugins.gns_builtins.simulators.mpm_solver import MpmSolver

    scene = parse_scene(raw)
    simulator = build_simulator(scene, registry, "<test>")
    sample = sample_scene(scene, 0)
    position = np.concatenate([b.position for b in sample.blocks])
    return scene, MpmSolver(
        scene, position, np.zeros_like(position), simulator._particle_arrays(scene, sample), sample.obstacles, "cpu"
    )


def grid_update(solver, velocity: np.ndarray) -> np.ndarray:
    """(nodes, d) node velocities after one grid update of unit-mass nodes moving at ``velocity`` (nodes, d)."""
    import warp as wp

    solver.grid_mass.assign(wp.array(np.ones(solver.num_nodes, np.float32), dtype=float, device="cpu"))
    solver.grid_momentum.assign(wp.array(velocity.astype(np.float32), dtype=solver.k.vec, device="cpu"))
    solver.launches[1].launch()
    return solver.grid_velocity.numpy()


def node_indices(solver) -> np.ndarray:
    """(nodes, d) integer grid index of every node, in the kernels' row-major order."""
    res = [solver.res[a] for a in range(len(solver.res))]
    return np.stack(np.meshgrid(*[np.arange(r) for r in res], indexing="ij"), axis=-1).reshape(-1, len(res))


OFF_ZERO_DOMAINS = [
    ([[0.025, 0.975], [0.025, 0.975]], 76),
    ([[0.025, 0.975], [0.025, 0.975]], 80),
    ([[0.1, 0.9], [0.1, 0.5]], 48),
    ([[0.013, 0.77], [-0.2, 0.3]], 64),
    ([[-1.1, 0.4], [0.05, 1.05]], 32),
    ([[0.025, 0.975], [0.025, 0.5], [0.1, 0.9]], 16),
    ([[0.013, 0.77], [0.1, 0.9], [-1.1, 0.4]], 24),
]


@pytest.mark.parametrize("bounds, grid", OFF_ZERO_DOMAINS)
def test_wall_nodes_are_exactly_the_nodes_on_or_beyond_the_bounds(bounds, grid, sim_registry):
    """Nodes moving into every wall at once: a frictionless wall stops exactly the nodes whose
    exact (float64) position is on or beyond it, and no node one cell inside (issue 19: rounding of
    float32 positions moved walls by a cell when the bounds do not start at 0)."""
    scene, solver = solver_for(scene_in(bounds, grid, wall_friction=0.0), sim_registry)
    dx = scene.domain.cell_size
    index = node_indices(solver)
    position = np.array([lo for lo, _ in bounds]) + (index - 3) * dx
    lower = np.array([lo for lo, _ in bounds])
    upper = np.array([hi for _, hi in bounds])
    tolerance = 1e-6 * dx
    for sign, on_wall in [(-1.0, position <= lower + tolerance), (1.0, position >= upper - tolerance)]:
        after = grid_update(solver, np.full(index.shape, sign))
        stopped = after == 0.0
        for axis in range(scene.dim):
            wrong = np.flatnonzero(stopped[:, axis] != on_wall[:, axis])
            assert wrong.size == 0, f"axis {axis}, sign {sign}: nodes {index[wrong[:3]].tolist()} misclassified"
