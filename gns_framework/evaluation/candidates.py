"""What ``gns evaluate`` compares: test cases, learned models and the ground-truth simulator's settings."""

from __future__ import annotations

from collections.abc import Callable, Collection, Sequence
from dataclasses import replace
from typing import cast

import numpy as np
import torch

from ..assembly.trained import LoadedModel
from ..contracts import ModelSetup
from ..data.metadata import DatasetMetadata
from ..data.stride import strided
from ..data.trajectory import Trajectory
from ..errors import DatasetError, RolloutDiverged
from ..model.batched_rollout import rollout_batch
from ..model.deposit_warning import WarningScore
from ..model.learned_simulator import LearnedSimulator
from ..model.rollout import rollout
from ..model.rollout_guard import RolloutGuard, held_particles
from ..plugins import Registry
from ..runtime.precision import Precision
from .report import Candidate, Prediction, Report, evaluate


def cases_from_split(trajectories: Sequence[Trajectory]) -> list[Trajectory]:
    """Each test trajectory as a case, named ``case_<i>`` where it has no key (report rows and file names)."""
    return [t if t.key else replace(t, key=f"case_{i}") for i, t in enumerate(trajectories)]


def learned_positions(
    simulator: LearnedSimulator, trajectory: Trajectory, device: torch.device | str, precision: Precision = "float32"
) -> np.ndarray:
    """(S, N, d) positions of :func:`learned_prediction` with the default guard (non-finite positions only)."""
    return cast("np.ndarray", learned_prediction(simulator, trajectory, device, precision).position)


def learned_prediction(
    simulator: LearnedSimulator,
    trajectory: Trajectory,
    device: torch.device | str,
    precision: Precision = "float32",
    guard: RolloutGuard | None = None,
) -> Prediction:
    """The (S, N, d) positions ``simulator`` rolls out from the first C frames of ``trajectory``, and the
    particles a wall held.

    ``guard`` is the one ``gns rollout`` uses (the model's ``rollout.guard``): under
    ``clamp`` escaped particles are put back and counted, so every command reports the
    same rollout. A diverged model is a result, not an error: its positions are NaN,
    which the metrics count as diverged with infinite error.
    """
    try:
        result = rollout(simulator, trajectory, device=device, precision=precision, guard=guard)
    except RolloutDiverged:
        shape = (trajectory.num_steps - simulator.setup.history, *trajectory.position.shape[1:])
        return Prediction(np.full(shape, np.nan, dtype=trajectory.position.dtype))
    return Prediction(result.predicted, held=held_particles(result.guard_violations))


def learned_positions_batch(
    simulator: LearnedSimulator,
    cases: Sequence[Trajectory],
    device: torch.device | str,
    precision: Precision = "float32",
) -> list[np.ndarray]:
    """Each case's (S, N, d) positions of :func:`learned_predictions_batch` with the default guard."""
    return [cast("np.ndarray", p.position) for p in learned_predictions_batch(simulator, cases, device, precision)]


def learned_predictions_batch(
    simulator: LearnedSimulator,
    cases: Sequence[Trajectory],
    device: torch.device | str,
    precision: Precision = "float32",
    guard: RolloutGuard | None = None,
) -> list[Prediction]:
    """Each case's rolled-out positions and held particles, the cases of one length stepped as one batch.

    A batch in which some scene diverges is rolled out again one scene at a time, so
    that only the diverged scenes come back NaN (as in :func:`learned_prediction`).
    """
    out: list[Prediction | None] = [None] * len(cases)
    lengths: dict[int, list[int]] = {}
    for index, case in enumerate(cases):
        lengths.setdefault(case.num_steps, []).append(index)
    for indices in lengths.values():
        try:
            batch = [cases[i] for i in indices]
            rolled = rollout_batch(simulator, batch, device=device, precision=precision, guard=guard)
            for i, result in zip(indices, rolled, strict=True):
                out[i] = Prediction(result.predicted, held=held_particles(result.guard_violations))
        except RolloutDiverged:
            for i in indices:
                out[i] = learned_prediction(simulator, cases[i], device, precision, guard)
    return cast("list[Prediction]", out)  # every case is filled in


def learned_candidate(
    model: LoadedModel,
    name: str,
    device: torch.device,
    batch: int = 1,
    precision: Precision = "float32",
    *,
    granular_types: Collection[int] = (),
    dataset_bounds: np.ndarray | None = None,
) -> Candidate:
    """A trained simulator rolled out from each case's input frames (kinematic particles prescribed).

    With ``batch`` > 1 the cases are rolled out that many at a time as one batch
    (:func:`~gns_framework.model.batched_rollout.rollout_batch`), each charged its
    share of the batch's time; the row is named ``<name> [batch B]``. In another
    ``precision`` than float32 (:mod:`gns_framework.runtime.precision`) the row is
    named ``<name> [bfloat16]`` (``<name> [bfloat16, batch B]``).

    A model that carries a deposit warning scores each rollout with it (``warn``): its particles of
    ``granular_types`` are the sand, and a case without bounds of its own has ``dataset_bounds`` (d, 2).
    """

    guard = model.rollout_guard()

    def simulate(case: Trajectory) -> Prediction:
        return learned_prediction(model.simulator, case, device, precision, guard)

    def simulate_batch(cases: Sequence[Trajectory]) -> list[Prediction]:
        return learned_predictions_batch(model.simulator, cases, device, precision, guard)

    warn = None
    if model.deposit_warning is not None and granular_types and dataset_bounds is not None:
        scored = model.deposit_warning.bound(model.simulator.setup, granular_types, dataset_bounds)

        def warn(case: Trajectory, prediction: Prediction) -> WarningScore | None:
            return scored(np.asarray(torch.as_tensor(prediction.position).cpu()), case, prediction.held or 0)

    settings = f"{model.path.name} (step {model.step})"
    if precision != "float32":
        settings += f", products in {precision}"
        name = f"{name} [{precision}" + (f", batch {batch}]" if batch > 1 else "]")
    elif batch > 1:
        name = f"{name} [batch {batch}]"
    if batch > 1:
        return Candidate(
            name,
            "learned",
            simulate,
            settings=f"{settings}, {batch} scenes per batch",
            device=str(device),
            simulate_batch=simulate_batch,
            batch=batch,
            warn=warn,
        )
    return Candidate(name, "learned", simulate, settings=settings, device=str(device), warn=warn)


def simulator_candidates(
    metadata: DatasetMetadata,
    registry: Registry,
    cases: Sequence[Trajectory],
    history: int,
    grid_scales: Sequence[float],
    substep_scales: Sequence[float],
    *,
    fresh_jitter: bool = False,
) -> list[Candidate]:
    """The simulator that generated the data, re-run on each case's seed at other grids and time steps.

    Each predicts the frames after the first ``history`` of its own run. The unscaled
    setting is the reference (it reproduces the ground truth). Needs the provenance
    ``gns generate`` stores in metadata.json. With ``fresh_jitter`` every setting, the
    unscaled one too, refills the drawn scene with a fresh lattice jitter: the unscaled row is
    then another run of the same scene as valid as the data's, and its distance from the data
    is the simulator's own spread (no reference; a simulator that cannot refill a scene is refused).
    """
    from ..assembly.ground_truth import build_ground_truth_simulator
    from ..ground_truth.generate import trajectory_seeds
    from ..ground_truth.scene_spec import SceneSpec

    provenance = getattr(metadata, "generated_from", None)
    if not isinstance(provenance, dict):
        raise DatasetError(
            "metadata.json: generated_from: missing; only datasets written by `gns generate` can be re-simulated "
            "(use --no-simulator for others)"
        )
    scene = SceneSpec.model_validate(provenance["scene"])
    counts = provenance["trajectories"]
    seeds = trajectory_seeds(scene.seed, counts["train"] + counts["valid"] + counts["test"])[-counts["test"] :]
    seed_of = {case.key: seed for case, seed in zip(cases, seeds, strict=True)}
    # A model trained with dataset.frame_stride k sees every k-th stored frame (its metadata's dt is k frame_dt).
    stride = max(1, round(metadata.dt / scene.time.frame_dt))

    candidates = []
    for grid_scale in grid_scales:
        for substep_scale in substep_scales:
            grid = max(4, round(scene.domain.grid * grid_scale))
            substeps = max(1, round(scene.time.substeps * substep_scale))
            variant = scene.model_copy(
                update={
                    "domain": scene.domain.model_copy(update={"grid": grid}),
                    "time": scene.time.model_copy(update={"substeps": substeps}),
                }
            )
            simulator = build_ground_truth_simulator(variant, registry, "metadata.json: generated_from")
            reference = grid == scene.domain.grid and substeps == scene.time.substeps and not fresh_jitter
            # Every row runs the scene the data holds, as drawn: a scene drawn anew at another grid would put
            # its columns, frictions and obstacles elsewhere (sampling.at_resolution).
            as_drawn = not reference and _runs_drawn_scenes(simulator)
            if fresh_jitter and not as_drawn:
                raise DatasetError(
                    f"metadata.json: generated_from: simulator {simulator.name!r} cannot refill a drawn scene "
                    "(simulate_at_resolution), so it cannot run the data's scenes with a fresh jitter"
                )

            def simulate(case: Trajectory, simulator=simulator, variant=variant, as_drawn=as_drawn) -> Prediction:
                seed = seed_of[case.key]
                run = (
                    simulator.simulate_at_resolution(scene, seed, variant)
                    if as_drawn
                    else simulator.simulate(variant, seed)
                )
                trajectory = strided(run, stride)
                return Prediction(
                    trajectory.position[history:], trajectory.particle_type, trajectory.position[history - 1]
                )

            settings = f"grid {grid}, dt {variant.time.frame_dt / substeps:.3g} s"
            if fresh_jitter:
                settings += ", the data's scenes with a fresh lattice jitter"
            if not reference and not as_drawn:
                settings += ", each scene drawn anew (this simulator cannot refill a drawn one)"
            candidates.append(
                Candidate(
                    f"{simulator.name} grid {grid} x {substeps} substeps",
                    "simulator",
                    simulate,
                    reference=reference,
                    settings=settings,
                )
            )
    return candidates


def _runs_drawn_scenes(simulator) -> bool:
    """Whether ``simulator`` implements ``simulate_at_resolution`` (the contract's default raises)."""
    from ..contracts import GroundTruthSimulator

    return type(simulator).simulate_at_resolution is not GroundTruthSimulator.simulate_at_resolution


def compare(
    models: Sequence[tuple[str, LoadedModel]],
    cases: Sequence[Trajectory],
    metadata: DatasetMetadata,
    registry: Registry,
    device: torch.device,
    *,
    grid_scales: Sequence[float] = (0.5, 1.0),
    substep_scales: Sequence[float] = (1.0,),
    with_simulator: bool = True,
    repeats: int = 3,
    warmup: int = 1,
    error_metric: str = "sinkhorn_final_pct",
    rollout_dir=None,
    batch: int = 1,
    precisions: Sequence[Precision] = ("float32",),
    progress: Callable[[str, int, int], None] | None = None,
) -> Report:
    """Error against run time of named trained models (and the ground-truth simulator) on ``cases``.

    The models share one input history C (the first model's); each case's first C frames are the input.
    With ``batch`` > 1 each model has a second row, its cases rolled out ``batch`` at a time,
    beside the one-at-a-time row: the throughput gain measured in the same run. Each of
    ``precisions`` gives every model its rows in that precision, so the error and time
    bfloat16 products change are measured side by side. ``progress`` is :func:`evaluate`'s.
    """
    setup = models[0][1].simulator.setup
    granular, bounds = granular_particle_types(setup, registry), np.asarray(metadata.bounds, dtype=float)
    candidates = []
    for precision in precisions:
        for size in (1, batch) if batch > 1 else (1,):
            candidates += [
                learned_candidate(model, name, device, size, precision, granular_types=granular, dataset_bounds=bounds)
                for name, model in models
            ]
    if with_simulator:
        candidates += simulator_candidates(metadata, registry, cases, setup.history, grid_scales, substep_scales)
    return evaluate(
        candidates,
        cases,
        metadata,
        setup.history,
        repeats=repeats,
        warmup=warmup,
        error_metric=error_metric,
        granular_types=granular,
        material_names=registry.material_names(setup.particle_types),
        kinematic_types=setup.kinematic_types,
        metrics=registry.metrics(),
        rollout_dir=rollout_dir,
        progress=progress,
    )


def granular_particle_types(scene: ModelSetup, registry: Registry) -> list[int]:
    """The scene's particle types whose material is granular (runout and pile profile are measured on them)."""
    materials = {t: registry.material_by_type(t).cls for t in scene.particle_types}
    return [t for t, m in materials.items() if m.granular]
