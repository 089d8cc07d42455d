"""The envelope check of scenes split over processes: each process measures its own run of every scene's
particles (:mod:`gns_framework.data.in_parts`), the runs' measures travel in one gather and merge into the
whole scenes', and every process judges the same scenes the same way. No process reads a whole scene's frames;
the run that starts at particle 0 reads frame 0 whole, for the particle spacing.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import reduce

from ..contracts import ModelSetup
from ..data.in_parts import particle_run, scene_in_parts
from ..data.metadata import DatasetMetadata
from ..data.trajectory import Trajectory
from ..errors import DatasetError, GnsError
from ..model.envelope import SceneMeasures, scene_measures
from ..runtime.processes import Processes
from .exchange import objects_everywhere


def measured_in_parts(
    split: Sequence[Trajectory], count: int, metadata: DatasetMetadata, setup: ModelSetup, processes: Processes
) -> list[SceneMeasures]:
    """The envelope measures of the first ``count`` scenes of ``split``, each process measuring (and checking) its
    run of every scene's particles; data refused on any process stops every process, naming what was refused."""
    mine: list[SceneMeasures] = []
    failure: GnsError | None = None
    try:
        for index in range(count):
            scene = scene_in_parts(split, index)
            run = particle_run(scene.num_particles, processes.rank, processes.world_size)
            mine.append(scene_measures(scene, metadata, setup.history, setup.kinematic_types, rows=run))
    except GnsError as exc:
        failure = exc
    everyone = objects_everywhere(processes, (None if failure is None else str(failure), mine))
    if failure is not None:
        raise failure
    refused = [reason for reason, _ in everyone if reason is not None]
    if refused:
        raise DatasetError(f"another process refused the data: {refused[0]}")
    return [reduce(SceneMeasures.merged, runs) for runs in zip(*(measures for _, measures in everyone), strict=True)]
