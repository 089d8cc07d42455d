"""Particle and grid state of one MLS-MPM run on a Warp device, advanced frame by frame."""

from __future__ import annotations

import math
import os
import sys
import tempfile

import numpy as np
import warp as wp

from gns_framework.api import BodySample, SceneSpec, choose_device

from .kernels import BOX, ELLIPSOID, PLANE, POLYGON, kernels

GRID_MARGIN = 3
"""Grid cells beyond each wall, so every particle's 3^d stencil stays on the grid."""


NO_CUDA_DRIVER = "Could not find or load the NVIDIA CUDA driver"
"""Warp's native warning on machines without a CUDA driver (written straight to file descriptor 2)."""


def init_warp(cuda_wanted: bool) -> None:
    """``wp.init()``; on a machine with no CUDA driver, its warning is dropped unless CUDA was asked for.

    The warning comes from Warp's C++ core (``fprintf(stderr, ...)``), so it is caught at
    file descriptor 2 for the length of the call; every other line written there passes
    through unchanged.
    """
    if cuda_wanted:
        wp.init()
        return
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as captured:
        os.dup2(captured.fileno(), 2)
        try:
            wp.init()
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        captured.seek(0)
        kept = [line for line in captured.read().splitlines(keepends=True) if NO_CUDA_DRIVER.encode() not in line]
    if kept:
        os.write(2, b"".join(kept))


def resolve_device(name: str) -> str:
    """The Warp device ``name`` (auto, cpu, cuda or cuda:N) means here, by the project's one device policy."""
    init_warp(cuda_wanted=name.startswith("cuda"))
    return choose_device(name, wp.get_cuda_device_count, "simulator.device (or --device)")


def obstacle_arrays(obstacles: list[BodySample], d: int, vec) -> list[tuple[np.ndarray, type]]:
    """The grid update's obstacle inputs (see ``grid_update``): per-obstacle shape id, centre at t = 0,
    half extents, rotation (cos, sin), velocity, friction, first vertex and vertex count, then all
    polygon vertices (one dummy when there are none: Warp arrays are never empty here)."""
    shape_ids = {"box": BOX, "ellipsoid": ELLIPSOID, "polygon": POLYGON, "plane": PLANE}
    centre = [np.zeros(d) if o.shape == "polygon" else o.lower + o.size / 2 for o in obstacles]
    angle = [0.0 if o.shape == "polygon" else math.radians(o.angle) for o in obstacles]
    polygons = [o.vertices if o.vertices is not None else np.zeros((0, 2)) for o in obstacles]
    counts = np.array([len(v) for v in polygons], dtype=np.int32)
    vertices = np.concatenate([*polygons, np.zeros((1, 2))])
    return [
        (np.array([shape_ids[o.shape] for o in obstacles], dtype=np.int32), int),
        (np.array(centre, dtype=np.float32).reshape(-1, d), vec),
        (np.array([o.size / 2 for o in obstacles], dtype=np.float32).reshape(-1, d), vec),
        (np.array([(math.cos(a), math.sin(a)) for a in angle], dtype=np.float32).reshape(-1, 2), wp.vec2),
        (np.array([o.velocity for o in obstacles], dtype=np.float32).reshape(-1, d), vec),
        (np.array([o.friction for o in obstacles], dtype=np.float32), float),
        (np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int32)[: len(obstacles)], int),
        (counts, int),
        (vertices.astype(np.float32), wp.vec2),
    ]


class MpmSolver:
    """Holds particles (x, v, C, F, J) and the grid; :meth:`advance_frame` runs the substeps of one frame.

    Args:
        scene: the validated scene (domain, grid, time, gravity).
        position: (N, d) initial positions of the MPM particles, metres.
        velocity: (N, d) initial velocities, m/s.
        particles: per-particle kernel inputs (``model``, ``mass``, ``volume``,
            ``mu``, ``lam``, ``param_a``, ``param_b``), each (N,).
        obstacles: kinematic bodies, applied as grid boundary conditions.
        device: Warp device name or ``auto``.
    """

    def __init__(
        self,
        scene: SceneSpec,
        position: np.ndarray,
        velocity: np.ndarray,
        particles: dict[str, np.ndarray],
        obstacles: list[BodySample],
        device: str,
    ):
        self.device = resolve_device(device)
        self.k = kernels(scene.dim)
        d = scene.dim
        n = position.shape[0]
        self.dt = scene.time.substep_dt
        self.substeps = scene.time.substeps
        self.step = 0
        dx = scene.domain.cell_size
        self.dx, self.inv_dx = dx, 1.0 / dx
        lower = np.array([lo for lo, _ in scene.domain.bounds])
        upper = np.array([hi for _, hi in scene.domain.bounds])
        self.lower, self.upper = self.k.vec(*lower), self.k.vec(*upper)
        self.origin = self.k.vec(*(lower - GRID_MARGIN * dx))
        cells = [math.ceil((hi - lo) / dx - 1e-9) for lo, hi in scene.domain.bounds]
        nodes = [c + 2 * GRID_MARGIN + 1 for c in cells]
        self.res = self.k.ivec(*nodes)
        # The node on each lower wall, and the node on or first beyond each upper wall.
        self.wall_lower = self.k.ivec(*[GRID_MARGIN] * d)
        self.wall_upper = self.k.ivec(*[GRID_MARGIN + c for c in cells])
        num_nodes = int(np.prod(nodes))
        self.gravity = self.k.vec(*scene.gravity_vector)

        def array(values, dtype):
            return wp.array(np.ascontiguousarray(values), dtype=dtype, device=self.device)

        walls = scene.domain.wall_conditions()
        self.walls = [
            array(np.array([friction for friction, _ in walls], dtype=np.float32), float),
            array(np.array([no_slip for _, no_slip in walls], dtype=np.int32), int),
        ]
        self.x = array(position.astype(np.float32), self.k.vec)
        self.v = array(velocity.astype(np.float32), self.k.vec)
        self.C = wp.zeros(n, dtype=self.k.mat, device=self.device)
        self.F = array(np.broadcast_to(np.eye(d, dtype=np.float32), (n, d, d)), self.k.mat)
        self.J = array(np.ones(n, dtype=np.float32), float)
        self.model = array(particles["model"], int)
        self.params = [array(particles[name], float) for name in ("mass", "volume", "mu", "lam", "param_a", "param_b")]
        self.obstacles = [array(values, dtype) for values, dtype in obstacle_arrays(obstacles, d, self.k.vec)]
        self.grid_momentum = wp.zeros(num_nodes, dtype=self.k.vec, device=self.device)
        self.grid_mass = wp.zeros(num_nodes, dtype=float, device=self.device)
        self.grid_velocity = wp.zeros(num_nodes, dtype=self.k.vec, device=self.device)
        self.num_particles, self.num_nodes = n, num_nodes
        self._record_launches()

    def _record_launches(self) -> None:
        """Launches are recorded once: replaying them skips Warp's per-call argument packing."""
        k = self.k

        def record(kernel, dim, inputs):
            return wp.launch(kernel, dim=dim, inputs=inputs, device=self.device, record_cmd=True)

        self.launches = [
            record(
                k.p2g,
                self.num_particles,
                [
                    self.x,
                    self.v,
                    self.C,
                    self.F,
                    self.J,
                    self.model,
                    *self.params,
                    self.origin,
                    self.inv_dx,
                    self.dt,
                    self.res,
                    self.grid_momentum,
                    self.grid_mass,
                ],
            ),
            record(
                k.grid_update,
                self.num_nodes,
                [
                    self.grid_momentum,
                    self.grid_mass,
                    self.origin,
                    self.dx,
                    self.res,
                    self.dt,
                    0.0,
                    self.gravity,
                    self.wall_lower,
                    self.wall_upper,
                    *self.walls,
                    *self.obstacles,
                    self.grid_velocity,
                ],
            ),
            record(
                k.g2p,
                self.num_particles,
                [
                    self.grid_velocity,
                    self.origin,
                    self.inv_dx,
                    self.res,
                    self.dt,
                    self.lower,
                    self.upper,
                    self.x,
                    self.v,
                    self.C,
                ],
            ),
        ]
        self.p2g_graph = None
        if wp.get_device(self.device).is_cuda:
            # A plain launch of P2G's deterministic atomics reads their record counts and an overflow
            # flag back to the host after every substep (three waits for the GPU); launched from a
            # captured graph they reduce their fixed-size record buffers and read nothing back. The
            # buffers are sized for the 3^d adds every thread makes (kernels.py), so none can overflow.
            with wp.ScopedCapture(device=self.device) as capture:
                self.launches[0].launch()
            self.p2g_graph = capture.graph

    def substep(self) -> None:
        """One explicit MLS-MPM step of ``dt``: P2G, grid update (obstacles placed at the step's start), G2P."""
        p2g, grid_update, g2p = self.launches
        grid_update.set_param_by_name("time", self.step * self.dt)
        if self.p2g_graph is not None:
            wp.capture_launch(self.p2g_graph)
        else:
            p2g.launch()
        grid_update.launch()
        g2p.launch()
        self.step += 1

    def advance_frame(self) -> None:
        for _ in range(self.substeps):
            self.substep()

    def position(self) -> np.ndarray:
        """(N, d) float32 current positions, copied to the host."""
        return self.x.numpy().copy()

    def velocity(self) -> np.ndarray:
        """(N, d) float32 current velocities, copied to the host."""
        return self.v.numpy().copy()
