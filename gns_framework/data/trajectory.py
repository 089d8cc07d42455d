"""The in-memory trajectory every dataset plugin yields and every writer takes."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..errors import DatasetError


@dataclass(frozen=True)
class Trajectory:
    """One simulated scene.

    Attributes:
        position: (T, N, d) float32, particle positions per frame (time-major, as
            every public format stores them).
        particle_type: (N,) int64 particle-type ids (3 = kinematic in the public data).
        material_property: (N, P) float32 per-particle material properties, or None.
        step_context: (T, C) float32 global context per frame, or None.
        key: identifier of the trajectory inside its file (for error messages).
        bounds: (d, 2) float32 lower and upper wall per axis of this trajectory's domain, or
            None (the dataset's ``metadata.bounds``).
        walls: (2d, 2) float32 condition of each face (x_min, x_max, y_min, ...): its Coulomb
            friction coefficient and 1 if no-slip else 0; or None (not recorded).
    """

    position: np.ndarray
    particle_type: np.ndarray
    material_property: np.ndarray | None = None
    step_context: np.ndarray | None = None
    key: str = ""
    bounds: np.ndarray | None = None
    walls: np.ndarray | None = None

    @property
    def num_steps(self) -> int:
        return int(self.position.shape[0])

    @property
    def num_particles(self) -> int:
        return int(self.position.shape[1])

    @property
    def dim(self) -> int:
        return int(self.position.shape[2])

    def first_frames(self, count: int) -> "Trajectory":
        """The first ``count`` frames: position (count, N, d) and step_context (count, C) cut, the rest kept."""
        context = None if self.step_context is None else self.step_context[:count]
        return replace(self, position=self.position[:count], step_context=context)

    def validated(self, source: str, dim: int | None = None) -> "Trajectory":
        """Check shapes, dtypes and values (type ids >= 0); return a copy with canonical dtypes.

        Raises DatasetError naming ``source``, the trajectory key and the field.
        """
        where = f"{source}: trajectory {self.key!r}"
        pos = np.asarray(self.position)
        if pos.ndim != 3:
            raise DatasetError(f"{where}: position: expected shape (T, N, d), got {pos.shape}")
        t, n, d = pos.shape
        if d not in (2, 3):
            raise DatasetError(f"{where}: position: expected d = 2 or 3 spatial dimensions, got {d}")
        if dim is not None and d != dim:
            raise DatasetError(f"{where}: position: has d = {d} but metadata says dim = {dim}")
        if t < 2 or n < 1:
            raise DatasetError(f"{where}: position: needs at least 2 frames and 1 particle, got {pos.shape}")
        if not np.isfinite(pos).all():
            bad = np.argwhere(~np.isfinite(pos))[0]
            raise DatasetError(f"{where}: position: non-finite value at frame {bad[0]}, particle {bad[1]}")
        ptype = np.asarray(self.particle_type)
        if ptype.shape != (n,):
            raise DatasetError(f"{where}: particle_type: expected shape ({n},), got {ptype.shape}")
        if not np.issubdtype(ptype.dtype, np.integer):
            if not np.all(np.equal(np.mod(ptype, 1), 0)):
                raise DatasetError(f"{where}: particle_type: expected integer ids, got {ptype.dtype}")
        ptype = ptype.astype(np.int64)
        if ptype.min() < 0:
            raise DatasetError(f"{where}: particle_type: ids must be >= 0, got [{ptype.min()}, {ptype.max()}]")
        prop = self.material_property
        if prop is not None:
            prop = np.asarray(prop, dtype=np.float32)
            if prop.ndim == 1:
                prop = prop[:, None]
            if prop.ndim != 2 or prop.shape[0] != n:
                raise DatasetError(f"{where}: material_property: expected shape ({n},) or ({n}, P), got {prop.shape}")
            if not np.isfinite(prop).all():
                raise DatasetError(f"{where}: material_property: contains NaN or Inf")
        ctx = self.step_context
        if ctx is not None:
            ctx = np.asarray(ctx, dtype=np.float32)
            if ctx.ndim == 1:
                ctx = ctx[:, None]
            if ctx.ndim != 2 or ctx.shape[0] != t:
                raise DatasetError(f"{where}: step_context: expected shape ({t}, C), got {ctx.shape}")
            if not np.isfinite(ctx).all():
                raise DatasetError(f"{where}: step_context: contains NaN or Inf")
        bounds = self.bounds
        if bounds is not None:
            bounds = np.asarray(bounds, dtype=np.float32)
            if bounds.shape != (d, 2):
                raise DatasetError(f"{where}: bounds: expected shape ({d}, 2), got {bounds.shape}")
            if not np.isfinite(bounds).all() or not (bounds[:, 0] < bounds[:, 1]).all():
                raise DatasetError(
                    f"{where}: bounds: expected finite [lower, upper] with lower < upper, got {bounds.tolist()}"
                )
        walls = self.walls
        if walls is not None:
            walls = np.asarray(walls, dtype=np.float32)
            if walls.shape != (2 * d, 2):
                raise DatasetError(
                    f"{where}: walls: expected shape ({2 * d}, 2) (friction, no-slip per face), got {walls.shape}"
                )
            if not np.isfinite(walls).all() or (walls[:, 0] < 0).any() or not np.isin(walls[:, 1], (0, 1)).all():
                raise DatasetError(
                    f"{where}: walls: expected friction >= 0 and a no-slip flag 0 or 1 per face, got {walls.tolist()}"
                )
        return Trajectory(pos.astype(np.float32, copy=False), ptype, prop, ctx, self.key, bounds, walls)
