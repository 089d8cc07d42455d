"""The in-memory trajectory every dataset plugin yields and every writer takes."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..errors import DatasetError


@dataclass(frozen=True)
class DomainCheck:
    """Where a dataset's particles may be: its domain, widened by ``margin`` on every side.

    A trajectory's own ``bounds`` (when it has them) replace the dataset's. Particles
    50 m outside a 1 m box, or at 3e38, are not a scene a model can be judged on:
    they are refused by name, not rolled out as if clean.

    Attributes:
        bounds: (d, 2) the dataset's lower and upper wall per axis (``metadata.bounds``).
        margin: metres a particle may lie beyond a wall (a few particle spacings: MPM
            and SPH particles sit up to about one spacing outside the walls they touch).
    """

    bounds: np.ndarray
    margin: float


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
        unchecked: the check of the positions' values still owed, for a scene read in parts (one run of its
            particles per process, :meth:`particles`); None when they were checked (or are not yet validated).
    """

    position: np.ndarray
    particle_type: np.ndarray
    material_property: np.ndarray | None = None
    step_context: np.ndarray | None = None
    key: str = ""
    bounds: np.ndarray | None = None
    walls: np.ndarray | None = None
    unchecked: PositionCheck | None = None

    @property
    def num_steps(self) -> int:
        return int(self.position.shape[0])

    @property
    def num_particles(self) -> int:
        return int(self.position.shape[1])

    @property
    def dim(self) -> int:
        return int(self.position.shape[2])

    def first_frames(self, count: int) -> Trajectory:
        """The first ``count`` frames: position (count, N, d) and step_context (count, C) cut, the rest kept."""
        context = None if self.step_context is None else self.step_context[:count]
        return replace(self, position=self.position[:count], step_context=context)

    def particles(self, rows: slice) -> Trajectory:
        """The particles ``rows`` (every frame of them), the rest kept; positions still unchecked are checked on these
        particles only, so of a memory-mapped scene nothing else is read."""
        prop = None if self.material_property is None else self.material_property[rows]
        position, particle_type = self.position[:, rows], self.particle_type[rows]
        part = replace(self, position=position, particle_type=particle_type, material_property=prop, unchecked=None)
        if self.unchecked is not None:
            self.unchecked.check(part.position, first_particle=rows.indices(self.num_particles)[0])
        return part

    def validated(
        self, source: str, dim: int | None = None, domain: DomainCheck | None = None, in_parts: bool = False
    ) -> Trajectory:
        """Check shapes, dtypes and values (type ids >= 0; inside ``domain`` when given); return a copy with canonical
        dtypes.

        ``in_parts``: leave the positions' values to each reader of a run of the particles (:meth:`particles`; the
        rest is checked now), for a scene split over processes that each read their own particles.
        Raises DatasetError naming ``source``, the trajectory key and the field (and frame and particle).
        """
        where = f"{source}: trajectory {self.key!r}"
        pos = np.asanyarray(self.position)  # a memory map stays one: it checks its file whenever a window is taken
        if pos.ndim != 3:
            raise DatasetError(f"{where}: position: expected shape (T, N, d), got {pos.shape}")
        t, n, d = pos.shape
        if d not in (2, 3):
            raise DatasetError(f"{where}: position: expected d = 2 or 3 spatial dimensions, got {d}")
        if dim is not None and d != dim:
            raise DatasetError(f"{where}: position: has d = {d} but metadata says dim = {dim}")
        if t < 2 or n < 1:
            raise DatasetError(f"{where}: position: needs at least 2 frames and 1 particle, got {pos.shape}")
        ptype = np.asarray(self.particle_type)
        if ptype.shape != (n,):
            raise DatasetError(f"{where}: particle_type: expected shape ({n},), got {ptype.shape}")
        if not np.issubdtype(ptype.dtype, np.integer) and not np.all(np.equal(np.mod(ptype, 1), 0)):
            raise DatasetError(f"{where}: particle_type: expected integer ids, got {ptype.dtype}")
        ptype = ptype.astype(np.int64)
        if ptype.min() < 0:
            raise DatasetError(f"{where}: particle_type: ids must be >= 0, got [{ptype.min()}, {ptype.max()}]")
        prop = _table(self.material_property, n, f"{where}: material_property", f"({n},) or ({n}, P)")
        ctx = _table(self.step_context, t, f"{where}: step_context", f"({t}, C)")
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
        check = PositionCheck(where, bounds, domain)
        if not in_parts:
            check.check(pos)  # a non-finite value first: it is what makes any other check of it meaningless
        if n > 1 and not np.ptp(pos[0], axis=0).any():  # frame 0 only: NaN there leaves it to the runs' check
            raise DatasetError(f"{where}: position: all {n} particles of frame 0 are at one point {pos[0, 0].tolist()}")
        pos = pos.astype(np.float32, copy=False)
        return Trajectory(pos, ptype, prop, ctx, self.key, bounds, walls, check if in_parts else None)


def _table(values, rows: int, field: str, expected: str) -> np.ndarray | None:
    """``values`` as a finite float32 (rows, k) table (a (rows,) vector becomes one column); None stays None."""
    if values is None:
        return None
    table = np.asarray(values, dtype=np.float32)
    if table.ndim == 1:
        table = table[:, None]
    if table.ndim != 2 or table.shape[0] != rows:
        raise DatasetError(f"{field}: expected shape {expected}, got {table.shape}")
    if not np.isfinite(table).all():
        raise DatasetError(f"{field}: contains NaN or Inf")
    return table


@dataclass(frozen=True)
class PositionCheck:
    """The check of a trajectory's position values: finite, and inside ``domain`` (with the trajectory's own
    ``bounds`` where it has them); ``where`` names the trajectory in messages."""

    where: str
    bounds: np.ndarray | None
    domain: DomainCheck | None

    def check(self, pos: np.ndarray, first_particle: int = 0) -> None:
        """Refuse the first bad value of (T, n, d) ``pos``, particles numbered from ``first_particle``; frames in
        chunks, so that a mapped trajectory is never copied whole."""
        where, domain = self.where, self.domain
        bounds = None
        if domain is not None:
            bounds = np.asarray(self.bounds if self.bounds is not None else domain.bounds, dtype=np.float64)
            if bounds.shape != (pos.shape[2], 2):
                bounds = None  # the dimension check names it
        for start in range(0, pos.shape[0], 64):
            frames = pos[start : start + 64]
            bad = ~np.isfinite(frames)
            if bad.any():
                frame, particle, _ = np.argwhere(bad)[0] + (start, first_particle, 0)
                raise DatasetError(f"{where}: position: non-finite value at frame {frame}, particle {particle}")
            if domain is None or bounds is None:
                continue
            outside = (frames < bounds[:, 0] - domain.margin) | (frames > bounds[:, 1] + domain.margin)
            if outside.any():
                frame, particle, axis = (int(i) for i in np.argwhere(outside)[0])
                value = float(frames[frame, particle, axis])
                raise DatasetError(
                    f"{where}: position: particle {first_particle + particle} at frame {start + frame} is at "
                    f"{value:.6g} on axis {axis}, outside the domain [{bounds[axis, 0]:.6g}, {bounds[axis, 1]:.6g}] "
                    f"by more than {domain.margin:.3g} (the data contradicts its own bounds)"
                )
