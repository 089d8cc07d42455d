"""Boundary conditions of the MLS-MPM grid update: which nodes are walls, and what each wall does.

These tests drive the grid-update kernel directly: every node gets unit mass
and a chosen velocity, and the velocity after the update shows which
boundary condition acted on it.
"""

from __future__ import annotations

import numpy as np
import pytest

from gns_framework.assembly.ground_truth import build_ground_truth_simulator
from gns_framework.ground_truth.sampling import sample_scene
from gns_framework.ground_truth.scene_spec import parse_scene
from gns_framework.ground_truth.shapes import polygon_contains, rotate_xy

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
    from gns_builtins.simulators._mpm.solver import MpmSolver

    scene = parse_scene(raw)
    simulator = build_ground_truth_simulator(scene, registry, "<test>")
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


FACE_CONDITIONS = {"x_min": "slip", "x_max": "no_slip", "y_min": 0.3, "z_min": 0.3, "z_max": "slip"}
"""Per-face conditions of the tests below; the faces not named (y_max) keep wall_friction = 2.0 (sticking)."""


def expected_wall_velocity(condition, normal_speed: float, tangential: np.ndarray) -> tuple[float, np.ndarray]:
    """(normal speed, tangential velocity) after the wall: Coulomb with mu, slip, or no-slip."""
    if condition == "no_slip":
        return max(normal_speed, 0.0), tangential * 0.0
    if normal_speed >= 0:
        return normal_speed, tangential
    mu = 0.0 if condition == "slip" else condition
    norm = np.linalg.norm(tangential)
    return 0.0, tangential * max(0.0, 1.0 + mu * normal_speed / norm)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("normal_speed", [-1.0, 0.5])
def test_each_face_applies_its_own_condition(dim, normal_speed, sim_registry):
    """Nodes moving along a face and towards it (or away from it): each face's condition alone acts on its nodes."""
    bounds = [[0.0, 1.0], [0.1, 0.6], [-0.2, 0.4]][:dim]
    walls = {face: c for face, c in FACE_CONDITIONS.items() if face[0] in "xyz"[:dim]}
    _scene, solver = solver_for(scene_in(bounds, 16, wall_friction=2.0, walls=walls), sim_registry)
    index = node_indices(solver)
    lower = np.full(dim, 3)
    upper = np.array([solver.wall_upper[a] for a in range(dim)])
    for axis in range(dim):
        for side, face in enumerate(("xyz"[axis] + "_min", "xyz"[axis] + "_max")):
            outward = np.zeros(dim)
            outward[axis] = -1.0 if side == 0 else 1.0
            tangential = np.where(np.arange(dim) == axis, 0.0, 0.8)
            velocity = -normal_speed * outward + tangential  # normal_speed along the inward normal
            after = grid_update(solver, np.broadcast_to(velocity, index.shape).copy())
            others = np.arange(dim) != axis
            interior = ((index[:, others] > lower[others]) & (index[:, others] < upper[others])).all(axis=1)
            on_face = (index[:, axis] <= lower[axis]) if side == 0 else (index[:, axis] >= upper[axis])
            nodes = after[on_face & interior]
            assert len(nodes) > 0
            normal, tangent = expected_wall_velocity(walls.get(face, 2.0), normal_speed, tangential)
            atol = 1e-6
            np.testing.assert_allclose(-nodes @ outward, normal, atol=atol, err_msg=face)
            np.testing.assert_allclose(
                nodes[:, others], np.broadcast_to(tangent[others], (len(nodes), dim - 1)), atol=atol, err_msg=face
            )


SHAPED_OBSTACLES = {
    2: [
        {"shape": "box", "position": [0.3, 0.4], "size": [0.4, 0.1], "angle": 30.0},
        {"shape": "ellipsoid", "position": [0.4, 0.3], "size": [0.3, 0.3]},  # a disc
        {"shape": "ellipsoid", "position": [0.2, 0.2], "size": [0.5, 0.2], "angle": -50.0},
        {"shape": "polygon", "position": [0.2, 0.1], "vertices": [[0, 0], [0.5, 0.1], [0.3, 0.3], [0.25, 0.12]]},
        {"shape": "plane", "position": [0.5, 0.35], "angle": 25.0},
        {"shape": "plane", "position": [0.5, 0.5], "angle": -40.0},
    ],
    3: [
        {"shape": "box", "position": [0.3, 0.3, 0.2], "size": [0.4, 0.1, 0.3], "angle": -20.0},
        {"shape": "ellipsoid", "position": [0.3, 0.2, 0.3], "size": [0.3, 0.3, 0.3]},  # a sphere
        {"shape": "plane", "position": [0.5, 0.4, 0.5], "angle": 35.0},
    ],
}


def inside_margin(obstacle: dict, points: np.ndarray) -> np.ndarray:
    """(n,) signed depth of each point inside the shape (positive inside), from the spec alone, float64."""
    d = points.shape[1]
    angle = obstacle.get("angle", 0.0)
    position = np.array(obstacle["position"], dtype=float)
    if obstacle["shape"] == "plane":
        return -rotate_xy(points - position, -angle, np.zeros(d))[:, 1]
    if obstacle["shape"] == "polygon":
        corners = position[:2] + np.array(obstacle["vertices"], dtype=float)
        a, b = corners, np.roll(corners, -1, axis=0)
        p = points[:, None, :2]
        t = np.clip(((p - a) * (b - a)).sum(-1) / ((b - a) ** 2).sum(-1), 0, 1)
        gap = np.linalg.norm(p - (a + t[..., None] * (b - a)), axis=-1).min(axis=1)
        return np.where(polygon_contains(points, corners), gap, -gap)
    half = np.array(obstacle["size"]) / 2
    local = rotate_xy(points, -angle, position + half) - (position + half)
    if obstacle["shape"] == "box":
        return (half - np.abs(local)).min(axis=1)
    return (1.0 - np.linalg.norm(local / half, axis=1)) * half.min()


@pytest.mark.parametrize(
    "dim, obstacle",
    [(dim, o) for dim, shapes in SHAPED_OBSTACLES.items() for o in shapes],
    ids=lambda v: v if isinstance(v, int) else f"{v['shape']}{v.get('angle', 0):+g}",
)
def test_shaped_obstacle_acts_on_exactly_the_nodes_inside_it(dim, obstacle, sim_registry):
    """Nodes moving with +c or -c against a sticking obstacle: every node inside it is stopped by one of
    the two, and no node outside it is touched (the kernel's signed distance against the spec's shape)."""
    raw = scene_in([[0.0, 1.0]] * dim, 24 if dim == 2 else 12)
    raw["blocks"][0]["position"] = [0.9] * dim
    raw["obstacles"] = [{"material": "rigid", "friction": 100.0, **obstacle}]
    scene, solver = solver_for(raw, sim_registry)
    index = node_indices(solver)
    position = (index - 3) * scene.domain.cell_size
    walls = ((index <= 3) | (index >= np.array([solver.wall_upper[a] for a in range(dim)]))).any(axis=1)
    touched = np.zeros(len(index), bool)
    c = np.array([0.6, -0.9, 0.4][:dim])
    for sign in (1.0, -1.0):
        velocity = np.broadcast_to(sign * c, index.shape).copy()
        touched |= np.abs(grid_update(solver, velocity) - velocity).max(axis=1) > 1e-6
    depth = inside_margin(obstacle, position)
    margin = 1e-4
    assert (touched[(depth > margin) & ~walls]).all()
    assert not touched[(depth < -margin) & ~walls].any()
    assert (depth > margin).sum() > 3
