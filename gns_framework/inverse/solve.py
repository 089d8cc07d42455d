"""Running an inversion from its config: load the model and the observation, search, write the results.

Outputs in the inversion's folder:
    result.json       recovered unknowns, final loss, iterations, evaluations, seconds
    metrics.jsonl     loss and unknowns at every iteration (written as the search goes)
    convergence.png   loss and each unknown over the iterations
    rollout.npz       the learned rollout from the recovered unknowns, with the observation
    rollout.gif       the same, animated beside the observation
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch

from ..assembly.data import open_dataset
from ..assembly.trained import LoadedModel, load_trained
from ..data.atomic import write_text_atomic
from ..data.rollout import Rollout
from ..data.trajectory import Trajectory
from ..evaluation.candidates import granular_particle_types
from ..io.rollout_file import write_rollout
from ..model.envelope import PROPERTY_SLACK, SPEED_SLACK, OutsideEnvelope, envelope_message, outside_envelope
from ..plugins import Registry
from ..runtime.activation_memory import activations_recomputed
from .config import InvertConfig, PropertyUnknown, VelocityUnknown
from .optimize import Iterate, Solution, adam, lbfgs
from .problem import LOSS_UNITS, InverseProblem, check_against_model, observed_frames
from .rollout import differentiable_rollout


@dataclass
class Inversion:
    """An inverse problem ready to solve, and where it came from."""

    config: InvertConfig
    problem: InverseProblem
    model: LoadedModel
    trajectory: Trajectory
    warnings: tuple[str, ...] = ()
    """Where the observation or the search lies outside the model's training envelope (``outside_envelope``)."""


def prepare(
    config: InvertConfig,
    unknowns: dict[str, PropertyUnknown | VelocityUnknown],
    source: str | Path,
    registry: Registry,
    allow_pickle: Path | None = None,
    outside_envelope: bool = False,
) -> Inversion:
    """Load the model and the observed trajectory; every problem they reveal is one RecipeError.

    The observation and the unknowns' bounds must lie inside the model's training
    envelope (OutsideEnvelope names what does not) unless ``outside_envelope``: then the
    inversion runs and its ``warnings`` say where the model extrapolates.
    """
    device = torch.device(config.device)
    model = load_trained(config.model, registry, device)
    observed = config.observed
    spec = model.recipe.dataset
    if observed.layout is not None:
        spec = spec.model_copy(update={"name": observed.layout})
    dataset = open_dataset(spec, registry, observed.dataset, allow_pickle)
    trajectories = dataset.split(observed.split)
    check_against_model(config, unknowns, model.simulator, trajectories, source)
    trajectory = trajectories[observed.trajectory]
    scene = model.simulator.scene
    warnings = _envelope_warnings(model, dataset.metadata(), trajectory, unknowns, outside_envelope, observed.dataset)
    problem = InverseProblem(
        model.simulator,
        trajectory,
        dataset.metadata(),
        unknowns,
        config.loss,
        observed_frames(observed.frames, scene.history, trajectory.num_steps),
        granular_types=granular_particle_types(scene, registry),
        checkpoint_every=config.checkpoint_every,
        device=device,
    )
    return Inversion(config, problem, model, trajectory, warnings)


def _envelope_warnings(model, metadata, trajectory, unknowns, allowed: bool, source) -> tuple[str, ...]:
    """The observation checked against the envelope, its unknown quantities replaced by their search bounds.

    A property or initial velocity being searched is not what the file holds but
    anything in its bounds: those bounds must lie in the trained range.
    """
    envelope = model.envelope
    if envelope is None:
        return ()
    scene = model.simulator.scene
    searched = {name for name, unknown in unknowns.items() if isinstance(unknown, PropertyUnknown)}
    velocity = [u for u in unknowns.values() if isinstance(u, VelocityUnknown)]
    problems = [
        line
        for line in outside_envelope(envelope, metadata, [trajectory], scene.history, scene.kinematic_types)
        if not any(line.startswith(f"property {name} ") for name in searched)
        and not (velocity and line.startswith("input speed "))
    ]
    for name in sorted(searched):
        low, high = unknowns[name].bounds
        trained = envelope.properties.get(name)
        if trained is None or low < trained[0] - PROPERTY_SLACK * (trained[1] - trained[0]) - 1e-12 or (
            high > trained[1] + PROPERTY_SLACK * (trained[1] - trained[0]) + 1e-12
        ):
            described = "not a model input" if trained is None else f"{trained[0]:.4g} .. {trained[1]:.4g}"
            problems.append(f"unknowns.{name}.bounds [{low:.4g}, {high:.4g}] (trained: {described})")
    for unknown in velocity:
        fastest = math.sqrt(sum(max(abs(lo), abs(hi)) ** 2 for lo, hi in unknown.bounds))
        if fastest > SPEED_SLACK * envelope.max_speed:
            problems.append(
                f"unknowns.initial_velocity.bounds up to {fastest:.3g} m/s "
                f"(trained: up to {envelope.max_speed:.3g} m/s, accepted {SPEED_SLACK:g}x)"
            )
    if not problems:
        return ()
    if not allowed:
        raise OutsideEnvelope(envelope_message(f"{source} (observed)", str(model.path), problems), problems)
    return tuple(f"outside the envelope of {model.path}: {line}" for line in problems)


@dataclass(frozen=True)
class InversionResult:
    u: np.ndarray
    """(k,) the recovered unknowns, scaled to [0, 1] over their bounds."""
    unknowns: dict
    initial: dict
    loss: float
    iterations: int
    evaluations: int
    seconds: float
    message: str
    history: list[Iterate]

    def as_json(self, inversion: Inversion) -> dict:
        observed = inversion.config.observed
        return {
            "unknowns": self.unknowns,
            "initial": self.initial,
            "loss": self.loss,
            "loss_name": inversion.config.loss,
            "loss_unit": LOSS_UNITS[inversion.config.loss],
            "iterations": self.iterations,
            "evaluations": self.evaluations,
            "seconds": self.seconds,
            "optimizer": inversion.config.optimizer.model_dump(),
            "stopped": self.message,
            "model": str(inversion.config.model),
            "observed": {**observed.model_dump(), "key": inversion.trajectory.key},
            **({"outside_envelope": list(inversion.warnings)} if inversion.warnings else {}),
        }


def solve(inversion: Inversion, on_iteration=lambda iterate: None) -> InversionResult:
    """Search the unknowns; the loss reported is the one at the returned values."""
    problem, spec = inversion.problem, inversion.config.optimizer
    parameters = problem.parameters
    history: list[Iterate] = []

    def observe(iterate: Iterate) -> None:
        history.append(iterate)
        on_iteration(iterate)

    def describe(u: np.ndarray) -> str:
        values = parameters.values(torch.from_numpy(np.asarray(u, dtype=np.float64))).tolist()
        return ", ".join(f"{name} {value:.4g}" for name, value in zip(parameters.names, values))

    started = time.perf_counter()
    with activations_recomputed(problem.checkpoint_every > 0):
        if spec.name == "adam":
            solution: Solution = adam(problem.loss, problem.start, spec.lr, spec.iterations, observe, describe, problem.dtype)
        else:
            solution = lbfgs(problem.loss, problem.start, spec.iterations, observe, describe, problem.dtype)
        with torch.no_grad():
            final_loss = float(problem.loss(torch.from_numpy(solution.u)))
    seconds = time.perf_counter() - started
    values = parameters.values(torch.from_numpy(solution.u)).tolist()
    start = parameters.values(torch.from_numpy(problem.start)).tolist()
    return InversionResult(
        u=solution.u,
        unknowns=parameters.as_record(values, problem.unknowns),
        initial=parameters.as_record(start, problem.unknowns),
        loss=final_loss,
        iterations=solution.iterations,
        evaluations=solution.evaluations,
        seconds=seconds,
        message=solution.message,
        history=history,
    )


def recovered_rollout(inversion: Inversion, result: InversionResult) -> Rollout:
    """The learned rollout of the whole observed trajectory from the recovered unknowns.

    Its truth is the observation after the C input frames the recovered unknowns give
    (an initial velocity changes them), with the recovered material properties: a
    rollout file holds one set of input frames and properties for both trajectories.
    """
    problem = inversion.problem
    u = torch.from_numpy(result.u)
    trajectory = inversion.trajectory
    history = problem.simulator.scene.history
    device = problem.prescribed.device
    observed = torch.from_numpy(trajectory.position[history:]).to(device, problem.dtype)
    with torch.no_grad():
        state = problem.model_inputs(u)
        predicted = differentiable_rollout(problem.simulator, state, observed)
    initial = state.position_sequence.transpose(0, 1).cpu().numpy()
    recovered = None if state.material_property is None else state.material_property.cpu().numpy()
    truth = np.concatenate([initial, observed.cpu().numpy()])
    return Rollout(
        truth=replace(trajectory, position=truth, material_property=recovered),
        predicted=predicted.cpu().numpy(),
        history=history,
        predicted_particles=problem.moving.cpu().numpy(),
    )


def plot_convergence(history: list[Iterate], inversion: Inversion, path: Path) -> Path:
    """Loss (log scale) and every unknown over the iterations, one panel each."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    problem = inversion.problem
    names = problem.parameters.names
    iterations = [it.iteration for it in history]
    values = np.array([problem.parameters.values(torch.from_numpy(it.u)).tolist() for it in history])
    figure, axes = plt.subplots(1 + len(names), 1, figsize=(6, 2.2 * (1 + len(names))), sharex=True)
    axes[0].semilogy(iterations, [max(it.loss, 1e-30) for it in history], marker=".")
    axes[0].set_ylabel(f"loss ({inversion.config.loss})")
    for axis, name, column in zip(axes[1:], names, values.T):
        axis.plot(iterations, column, marker=".")
        axis.set_ylabel(name)
    axes[-1].set_xlabel("iteration")
    figure.suptitle(f"gns invert: {inversion.trajectory.key}")
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)
    return path


def write_outputs(inversion: Inversion, result: InversionResult, out: Path, gif: bool = True) -> dict[str, Path]:
    """result.json (last, atomically), convergence plot, rollout file and GIF."""
    paths = {"convergence": plot_convergence(result.history, inversion, out / "convergence.png")}
    rollout = recovered_rollout(inversion, result)
    metadata = inversion.problem.metadata
    if inversion.warnings:
        metadata = metadata.model_copy(update={"outside_envelope": list(inversion.warnings)})
    paths["rollout"] = write_rollout(out / "rollout.npz", rollout, metadata)
    if gif:
        from ..io.rollout_file import load_rollout
        from ..viz.animation import animate_rollout

        paths["animation"] = animate_rollout(load_rollout(paths["rollout"]), out / "rollout.gif", every=2)
    paths["result"] = out / "result.json"
    write_text_atomic(paths["result"], json.dumps(result.as_json(inversion), indent=2) + "\n")
    return paths


def iteration_metrics(inversion: Inversion, iterate: Iterate) -> dict[str, float]:
    """``{"loss": ..., "friction": ..., "initial_velocity.x": ...}`` of one iterate, in physical units."""
    values = inversion.problem.parameters.values(torch.from_numpy(iterate.u)).tolist()
    return {"loss": iterate.loss, **dict(zip(inversion.problem.parameters.names, values))}
