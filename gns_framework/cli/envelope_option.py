"""``--outside-envelope`` and the check every command that rolls out a model runs first.

A model refuses data outside what it was trained on (its envelope,
:mod:`gns_framework.model.envelope`), naming each quantity, its value and the
trained range; ``--outside-envelope`` rolls out anyway, and the warning then goes
with every output (rollout files, the report, MLflow).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from ..assembly.trained import LoadedModel
from ..data.metadata import DatasetMetadata
from ..data.trajectory import Trajectory
from ..decomposition.envelope import measured_in_parts
from ..model.envelope import OutsideEnvelope, envelope_message, outside_envelope, outside_envelope_of
from ..runtime.processes import Processes


def add_outside_envelope(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--outside-envelope",
        action="store_true",
        help="roll out data outside what the model was trained on (particle spacing, step, materials, property "
        "ranges, domain sizes, walls, speeds, particle counts: its envelope); without it such data is refused. "
        "The warning is recorded in every output",
    )


def enforce_envelope(
    loaded: LoadedModel,
    metadata: DatasetMetadata,
    trajectories: Sequence[Trajectory],
    allowed: bool,
    source: str,
    command: str,
    *,
    count: int | None = None,
    processes: Processes | None = None,
) -> list[str]:
    """Refuse the first ``count`` of ``trajectories`` (default: all) where they lie outside ``loaded``'s envelope
    (OutsideEnvelope) unless ``allowed``.

    Returns the warnings to record with the outputs: one line per quantity outside,
    naming the model; empty when the data is inside (or the checkpoint records no
    envelope, which is said on stderr). Over several ``processes``, each measures its own run of every scene's
    particles and none reads a scene whole (:func:`~gns_framework.decomposition.envelope.measured_in_parts`).
    """
    if loaded.envelope is None:
        print(
            f"gns {command}: warning: {loaded.path} records no training envelope (written before checkpoints "
            "recorded one): the data is not checked against what the model was trained on",
            file=sys.stderr,
        )
        return []
    setup, count = loaded.simulator.setup, len(trajectories) if count is None else count
    if processes is not None and processes.world_size > 1:
        measures = measured_in_parts(trajectories, count, metadata, setup, processes)
        problems = outside_envelope_of(loaded.envelope, metadata, measures)
    else:
        scenes = [trajectories[i] for i in range(count)]
        problems = outside_envelope(loaded.envelope, metadata, scenes, setup.history, setup.kinematic_types)
    if not problems:
        return []
    message = envelope_message(source, str(loaded.path), problems)
    if not allowed:
        raise OutsideEnvelope(message, problems)
    warnings = [f"outside the envelope of {loaded.path}: {line}" for line in problems]
    for line in warnings:
        print(f"gns {command}: warning: {line}", file=sys.stderr)
    return warnings
