"""A scene read in parts: each process of a scene split over P processes reads, checks and holds only its own run
of the particles, every frame of them, and together they check the whole scene once.

Process r of P takes particles ``[r N / P, (r + 1) N / P)``. Of a memory-mapped split (a layout that maps
its positions, such as ``safe`` with ``dataset.memory: windows``) nothing else of the positions is read: the scene
is opened with its positions' values left unchecked (:meth:`~.lazy.TrajectorySequence.in_parts`), and
:meth:`~.trajectory.Trajectory.particles` checks the run it cuts.
"""

from __future__ import annotations

from collections.abc import Sequence

from .trajectory import Trajectory


def scene_in_parts(split: Sequence[Trajectory], index: int) -> Trajectory:
    """Trajectory ``index`` of ``split`` with its positions left to each process's run where the split can leave
    them (the framework's lazy splits); other splits give it checked whole."""
    in_parts = getattr(split, "in_parts", None)
    return split[index] if in_parts is None else in_parts(index)


def particle_run(particles: int, rank: int, world: int) -> slice:
    """The run of ``particles`` that process ``rank`` of ``world`` reads: ``[rank N / P, (rank + 1) N / P)``."""
    return slice(particles * rank // world, particles * (rank + 1) // world)
