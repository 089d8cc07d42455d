"""Running an inversion from its config: load the model and the observation, search, write the results.

The values returned are those of the best iterate: the lowest loss, or the lowest
misfit on the observation's held-out frames when the config names some
(``observed.held_out``); the last iterate is kept in ``result.json`` beside it.

Outputs in the inversion's folder:
    result.json       recovered (best) unknowns, their loss, best and last iteration, the true
                      values when the dataset records them (drawn.json), evaluations, seconds
    metrics.jsonl     loss and unknowns at every iteration (written as the search goes)
    convergence.png   loss and each unknown over the iterations
    rollout.npz       the learned rollout from the recovered unknowns, with the observation
    rollout.gif       the same, animated beside the observation
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Mapping
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
from ..model.envelope import (
    PROPERTY_SLACK,
    SPEED_SLACK,
    Envelope,
    OutsideEnvelope,
    envelope_message,
    outside_envelope,
)
from ..plugins import Registry, load_registry
from ..runtime.activation_memory import activations_recomputed
from .config import InvertConfig, PropertyUnknown, VelocityUnknown
from .optimize import Iterate, Solution, adam, best_iterate, lbfgs, spread_starts
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
    truth: dict | None = None
    """The true value of each unknown the dataset records (drawn.json, or the data's property column), by name."""


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
    frames = observed_frames(observed.frames, model.simulator.setup.history, trajectory.num_steps)
    shared = sorted(set(frames) & set(observed.held_out or ()))
    if shared:
        from ..errors import RecipeError

        raise RecipeError(
            source,
            [
                (
                    "observed.held_out",
                    f"frames {shared} are also compared by the loss (frames: {observed.frames}); hold out others",
                )
            ],
        )
    setup = model.simulator.setup
    warnings = _envelope_warnings(model, dataset.metadata(), trajectory, unknowns, outside_envelope, observed.dataset)
    problem = InverseProblem(
        model.simulator,
        trajectory,
        dataset.metadata(),
        unknowns,
        config.loss,
        frames,
        granular_types=granular_particle_types(setup, registry),
        checkpoint_every=config.checkpoint_every,
        device=device,
        held_out=observed.held_out or (),
        guard=model.rollout_guard(),
    )
    truth = true_values(observed.dataset, trajectory, unknowns, model.simulator)
    return Inversion(config, problem, model, trajectory, warnings, truth)


def true_values(dataset: str | Path, trajectory: Trajectory, unknowns: dict, simulator) -> dict | None:
    """``{unknown: true value}`` of the unknowns the observed dataset records; None when it records none.

    An initial velocity is the one ``gns generate`` drew for the blocks of its particle
    type (drawn.json); a material property is the drawn one, else the data's own column
    when it is the same for every particle concerned.
    """
    from ..ground_truth.drawn import read_drawn, true_property, true_velocity

    record = None
    try:
        record = read_drawn(dataset, trajectory.key) if trajectory.key else None
    except Exception:  # a truth that cannot be read is not known; the inversion still runs
        record = None
    truth: dict = {}
    names = list(simulator.setup.property_names)
    for name, unknown in unknowns.items():
        value: list[float] | float | None
        if isinstance(unknown, VelocityUnknown):
            value = None if record is None else true_velocity(record, unknown.particle_type)
        else:
            value = None if record is None else true_property(record, name, unknown.particle_type)
            if value is None and trajectory.material_property is not None and name in names:
                kind = unknown.particle_type
                chosen = (
                    trajectory.particle_type == kind
                    if kind is not None
                    else simulator.predicted_mask(torch.from_numpy(np.asarray(trajectory.particle_type))).numpy()
                )
                column = np.asarray(trajectory.material_property)[chosen, names.index(name)]
                if column.size and np.allclose(column, column[0], rtol=0, atol=1e-6):
                    value = float(column[0])
        if value is not None:
            truth[name] = value
    return truth or None


def unknown_bounds_problems(envelope: Envelope, unknowns: Mapping[str, PropertyUnknown | VelocityUnknown]) -> list[str]:
    """The unknowns whose search bounds leave what the model trained on, one line each (none: all inside).

    A property searched over [low, high] must lie in the trained range (within
    ``PROPERTY_SLACK`` of its width); an initial velocity's fastest corner within
    ``SPEED_SLACK`` times the largest speed the model saw.
    """
    problems = []
    searched = {name: unknown for name, unknown in unknowns.items() if isinstance(unknown, PropertyUnknown)}
    velocity = [u for u in unknowns.values() if isinstance(u, VelocityUnknown)]
    for name in sorted(searched):
        low, high = searched[name].bounds
        trained = envelope.properties.get(name)
        if (
            trained is None
            or low < trained[0] - PROPERTY_SLACK * (trained[1] - trained[0]) - 1e-12
            or (high > trained[1] + PROPERTY_SLACK * (trained[1] - trained[0]) + 1e-12)
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
    return problems


def _envelope_warnings(model, metadata, trajectory, unknowns, allowed: bool, source) -> tuple[str, ...]:
    """The observation checked against the envelope, its unknown quantities replaced by their search bounds.

    A property or initial velocity being searched is not what the file holds but
    anything in its bounds: those bounds must lie in the trained range.
    """
    envelope = model.envelope
    if envelope is None:
        return ()
    setup = model.simulator.setup
    searched = {name for name, unknown in unknowns.items() if isinstance(unknown, PropertyUnknown)}
    velocity = [u for u in unknowns.values() if isinstance(u, VelocityUnknown)]
    problems = [
        line
        for line in outside_envelope(envelope, metadata, [trajectory], setup.history, setup.kinematic_types)
        if not any(line.startswith(f"property {name} ") for name in searched)
        and not (velocity and line.startswith("input speed "))
    ]
    problems += unknown_bounds_problems(envelope, unknowns)
    if not problems:
        return ()
    if not allowed:
        raise OutsideEnvelope(envelope_message(f"{source} (observed)", str(model.path), problems), problems)
    return tuple(f"outside the envelope of {model.path}: {line}" for line in problems)


@dataclass(frozen=True)
class StartResult:
    """One start of a multi-start search: where it began, its best iterate and its optimiser's final point."""

    start: int
    initial: dict
    best: Iterate
    unknowns: dict
    last: Iterate
    stopped: bool
    """It went non-finite and stopped at its last finite iterate."""


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
    best: Iterate | None = None
    """The iterate returned (lowest loss, or lowest held-out misfit)."""
    last: Iterate | None = None
    """The optimiser's own final point (Adam: after its last step), evaluated too."""
    last_unknowns: dict | None = None
    starts: tuple[StartResult, ...] = ()
    """Each start of a multi-start search (``optimizer.starts`` > 1); empty for one start."""

    @property
    def selected_by(self) -> str:
        return "held_out" if self.best is not None and self.best.held_out is not None else "loss"

    def errors(self, truth: dict | None, unknowns: dict | None = None) -> dict | None:
        """Relative error (%) of ``unknowns`` (default: the returned ones) against ``truth``, by name."""
        if not truth:
            return None
        errors = {}
        for name, true in truth.items():
            found = np.atleast_1d(np.asarray((unknowns or self.unknowns)[name], dtype=np.float64))
            true = np.atleast_1d(np.asarray(true, dtype=np.float64))
            scale = float(np.linalg.norm(true))
            errors[name] = (
                100 * float(np.linalg.norm(found - true)) / scale if scale > 0 else float(np.linalg.norm(found - true))
            )
        return errors

    def as_json(self, inversion: Inversion) -> dict:
        observed = inversion.config.observed
        truth = inversion.truth
        last = None
        if self.last is not None:
            last = {
                "iteration": self.last.iteration,
                "unknowns": self.last_unknowns,
                "loss": self.last.loss,
                **({"held_out_loss": self.last.held_out} if self.last.held_out is not None else {}),
                **({"error_pct": self.errors(truth, self.last_unknowns)} if truth else {}),
            }
        return {
            "unknowns": self.unknowns,
            "initial": self.initial,
            "loss": self.loss,
            "loss_name": inversion.config.loss,
            "loss_unit": LOSS_UNITS[inversion.config.loss],
            "best_iteration": None if self.best is None else self.best.iteration,
            "selected_by": self.selected_by,
            **(
                {"held_out_loss": self.best.held_out}
                if self.best is not None and self.best.held_out is not None
                else {}
            ),
            **({"truth": truth, "error_pct": self.errors(truth)} if truth else {}),
            "last": last,
            **(
                {"best_start": self.best.start, "starts": self._starts_json(truth)}
                if self.starts and self.best is not None
                else {}
            ),
            "iterations": self.iterations,
            "evaluations": self.evaluations,
            "seconds": self.seconds,
            "optimizer": inversion.config.optimizer.model_dump(),
            "stopped": self.message,
            "model": str(inversion.config.model),
            "observed": {**observed.model_dump(), "key": inversion.trajectory.key},
            **({"outside_envelope": list(inversion.warnings)} if inversion.warnings else {}),
        }

    def _starts_json(self, truth: dict | None) -> list[dict]:
        return [
            {
                "start": start.start,
                "initial": start.initial,
                "unknowns": start.unknowns,
                "loss": start.best.loss,
                "best_iteration": start.best.iteration,
                **({"held_out_loss": start.best.held_out} if start.best.held_out is not None else {}),
                **({"error_pct": self.errors(truth, start.unknowns)} if truth else {}),
                "stopped": start.stopped,
            }
            for start in self.starts
        ]


def solve(inversion: Inversion, on_iteration=lambda iterate: None) -> InversionResult:
    """Search the unknowns and return the best iterate; the loss reported is the one at the returned values.

    The optimiser's final point (after Adam's last step, which no iteration evaluated)
    is evaluated too and is a candidate; it is reported to ``on_iteration`` as iteration
    ``iterations + 1`` when it is a new point. With ``optimizer.starts`` M > 1 the M
    starts are searched together (:func:`solve_starts`).
    """
    if inversion.config.optimizer.starts > 1:
        return solve_starts(inversion, on_iteration)
    problem, spec = inversion.problem, inversion.config.optimizer
    parameters = problem.parameters
    history: list[Iterate] = []
    observe, describe = _recorder(history, on_iteration), _describer(parameters)

    started = time.perf_counter()
    with activations_recomputed(problem.checkpoint_every > 0):
        if spec.name == "adam":
            solution: Solution = adam(
                problem.losses, problem.start, spec.lr, spec.iterations, observe, describe, problem.dtype, spec.lr_decay
            )
        else:
            solution = lbfgs(problem.losses, problem.start, spec.iterations, observe, describe, problem.dtype)
        evaluations = solution.evaluations

        def evaluated(u: np.ndarray) -> tuple[float, float | None]:
            nonlocal evaluations
            evaluations += 1
            with torch.no_grad():
                loss, held_out = problem.losses(torch.from_numpy(np.asarray(u, dtype=np.float64)))
            return float(loss), None if held_out is None else float(held_out)

        last = next((it for it in reversed(history) if np.array_equal(it.u, solution.u)), None)
        if last is None:
            loss, held_out = evaluated(solution.u)
            last = Iterate(len(history) + 1, loss, np.asarray(solution.u).copy(), held_out)
            observe(last)
        if problem.held_out:
            # L-BFGS may accept a point after a line search evaluated others: give every iterate its held-out misfit.
            for index, iterate in enumerate(history):
                if iterate.held_out is None:
                    history[index] = Iterate(iterate.iteration, iterate.loss, iterate.u, evaluated(iterate.u)[1])
            last = next(it for it in history if it.iteration == last.iteration)
    seconds = time.perf_counter() - started
    best = best_iterate(history)
    values = parameters.values(torch.from_numpy(best.u)).tolist()
    start = parameters.values(torch.from_numpy(problem.start)).tolist()
    last_values = parameters.values(torch.from_numpy(last.u)).tolist()
    return InversionResult(
        u=np.asarray(best.u).copy(),
        unknowns=parameters.as_record(values, problem.unknowns),
        initial=parameters.as_record(start, problem.unknowns),
        loss=best.loss,
        iterations=solution.iterations,
        evaluations=evaluations,
        seconds=seconds,
        message=solution.message,
        history=history,
        best=best,
        last=last,
        last_unknowns=parameters.as_record(last_values, problem.unknowns),
    )


def _recorder(history: list[Iterate], on_iteration) -> Callable[[Iterate], None]:
    """A callback that appends each iterate to ``history`` and passes it on to ``on_iteration``."""

    def observe(iterate: Iterate) -> None:
        history.append(iterate)
        on_iteration(iterate)

    return observe


def _describer(parameters) -> Callable[[np.ndarray], str]:
    """``u`` (the optimiser's unconstrained vector) as "name value, ..." in the unknowns' own units."""

    def describe(u: np.ndarray) -> str:
        values = parameters.values(torch.from_numpy(np.asarray(u, dtype=np.float64))).tolist()
        return ", ".join(f"{name} {value:.4g}" for name, value in zip(parameters.names, values, strict=True))

    return describe


def solve_starts(inversion: Inversion, on_iteration=lambda iterate: None) -> InversionResult:
    """Adam from ``optimizer.starts`` starting points at once, every iteration one batched rollout of them all.

    The answer is the best iterate over every start; each start's own best and final
    point are kept in :attr:`InversionResult.starts`. Every start's final point (after
    its last step) is evaluated, all in one more batched rollout.
    """
    problem, spec = inversion.problem, inversion.config.optimizer
    parameters = problem.parameters
    history: list[Iterate] = []
    observe, describe = _recorder(history, on_iteration), _describer(parameters)

    u0 = spread_starts(problem.start, spec.starts, spec.seed, parameters.high == parameters.low)
    started = time.perf_counter()
    with activations_recomputed(problem.checkpoint_every > 0):
        solution = adam(problem.losses, u0, spec.lr, spec.iterations, observe, describe, problem.dtype, spec.lr_decay)
        with torch.no_grad():
            losses, held_out = problem.losses(torch.from_numpy(np.asarray(solution.u, dtype=np.float64)))
    seconds = time.perf_counter() - started
    lasts: dict[int, Iterate] = {}
    for start, point in enumerate(solution.u):
        own = [it for it in history if it.start == start]
        if start in solution.stopped or np.array_equal(own[-1].u, point):
            lasts[start] = own[-1]  # stopped where it was last finite, or no step moved it
            continue
        held = None if held_out is None else float(held_out[start])
        lasts[start] = Iterate(spec.iterations + 1, float(losses[start]), np.asarray(point).copy(), held, start)
        observe(lasts[start])
    as_record = lambda u: parameters.as_record(parameters.values(torch.from_numpy(u)).tolist(), problem.unknowns)  # noqa: E731
    starts = []
    for start in range(spec.starts):
        own_best = best_iterate([it for it in history if it.start == start])
        starts.append(
            StartResult(
                start,
                as_record(u0[start]),
                own_best,
                as_record(own_best.u),
                lasts[start],
                start in solution.stopped,
            )
        )
    best = best_iterate(history)
    last = lasts[best.start]
    return InversionResult(
        u=np.asarray(best.u).copy(),
        unknowns=as_record(best.u),
        initial=as_record(u0[0]),
        loss=best.loss,
        iterations=solution.iterations,
        evaluations=solution.evaluations + 1,
        seconds=seconds,
        message=solution.message,
        history=history,
        best=best,
        last=last,
        last_unknowns=as_record(last.u),
        starts=tuple(starts),
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
    history = problem.simulator.setup.history
    device = problem.prescribed.device
    observed = torch.from_numpy(trajectory.position[history:]).to(device, problem.dtype)
    with torch.no_grad():
        state = problem.model_inputs(u)
        predicted = differentiable_rollout(problem.simulator, state, observed, guard=problem.guard)
    initial = state.position_sequence.transpose(0, 1).cpu().numpy()
    recovered = None if state.material_property is None else state.material_property.cpu().numpy()
    truth = np.concatenate([initial, observed.cpu().numpy()])
    return Rollout(
        truth=replace(trajectory, position=truth, material_property=recovered),
        predicted=predicted.cpu().numpy(),
        history=history,
        predicted_particles=problem.moving.cpu().numpy(),
    )


def plot_convergence(history: list[Iterate], inversion: Inversion, path: Path, best: Iterate | None = None) -> Path:
    """Loss (log scale) and every unknown over the iterations, one panel each.

    The held-out misfit is drawn beside the loss when there is one, the returned
    (best) iterate is marked on every panel, and each unknown's true value is a
    dashed line when the dataset records it. A multi-start search draws one line per
    start, the others faint beside the start the answer came from.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    problem = inversion.problem
    names = problem.parameters.names
    figure, axes = plt.subplots(1 + len(names), 1, figsize=(6, 2.2 * (1 + len(names))), sharex=True)
    starts = sorted({it.start for it in history})
    several = len(starts) > 1
    for start in starts:
        # One line per start of a multi-start search (faint but the best start's), one line for a single search.
        own = [it for it in history if it.start == start]
        chosen = best is None or best.start == start
        style = {"marker": ".", "alpha": 1.0 if chosen or not several else 0.35}
        iterations = [it.iteration for it in own]
        values = np.array([problem.parameters.values(torch.from_numpy(it.u)).tolist() for it in own])
        label = f"start {start}" if several else "loss"
        axes[0].semilogy(iterations, [max(it.loss, 1e-30) for it in own], label=label, **style)
        if any(it.held_out is not None for it in own):
            axes[0].semilogy(
                [it.iteration for it in own if it.held_out is not None],
                [max(it.held_out, 1e-30) for it in own if it.held_out is not None],
                color="tab:green",
                label=None if several and not chosen else "held-out frames",
                **style,
            )
        for axis, column in zip(axes[1:], values.T, strict=True):
            axis.plot(iterations, column, **style)
    axes[0].set_ylabel(f"loss ({inversion.config.loss})")
    truth = inversion.truth or {}
    true_columns = []
    for name, unknown in problem.unknowns.items():
        value = truth.get(name)
        width = len(unknown.start)
        true_columns += [None] * width if value is None else list(np.atleast_1d(np.asarray(value, dtype=np.float64)))
    for axis, name, true in zip(axes[1:], names, true_columns, strict=True):
        if true is not None:
            axis.axhline(true, color="black", linestyle="--", linewidth=1, label=f"true {true:.4g}")
            axis.legend(loc="best", fontsize=8)
        axis.set_ylabel(name)
    if best is not None:
        where = f", start {best.start}" if several else ""
        axes[0].plot(
            [best.iteration],
            [max(best.score, 1e-30)],
            marker="*",
            markersize=14,
            color="tab:red",
            linestyle="none",
            label=f"returned: iteration {best.iteration}{where}",
        )
        for axis, value in zip(axes[1:], problem.parameters.values(torch.from_numpy(best.u)).tolist(), strict=True):
            axis.plot([best.iteration], [value], marker="*", markersize=14, color="tab:red", linestyle="none")
        for axis in axes:
            axis.axvline(best.iteration, color="tab:red", linewidth=0.8, alpha=0.5)
    axes[0].legend(loc="best", fontsize=8)
    axes[-1].set_xlabel("iteration")
    figure.suptitle(f"gns invert: {inversion.trajectory.key}")
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)
    return path


def write_outputs(inversion: Inversion, result: InversionResult, out: Path, gif: bool = True) -> dict[str, Path]:
    """result.json (last, atomically), convergence plot, rollout file and GIF."""
    paths = {"convergence": plot_convergence(result.history, inversion, out / "convergence.png", result.best)}
    rollout = recovered_rollout(inversion, result)
    metadata = inversion.problem.metadata
    if inversion.warnings:
        metadata = metadata.model_copy(update={"outside_envelope": list(inversion.warnings)})
    paths["rollout"] = write_rollout(out / "rollout.npz", rollout, metadata)
    if gif:
        from ..io.rollout_file import load_rollout
        from ..viz.animation import animate_rollout

        saved = load_rollout(paths["rollout"])
        names = load_registry().material_names(saved.particle_type)
        paths["animation"] = animate_rollout(saved, out / "rollout.gif", every=2, material_names=names)
    paths["result"] = out / "result.json"
    write_text_atomic(paths["result"], json.dumps(result.as_json(inversion), indent=2) + "\n")
    return paths


def iteration_metrics(inversion: Inversion, iterate: Iterate) -> dict[str, float]:
    """``{"loss": ..., "held_out_loss": ..., "friction": ..., "initial_velocity.x": ...}`` of one iterate, in physical
    units.

    In a multi-start search each name is prefixed by the iterate's start (``start2.loss``).
    """
    values = inversion.problem.parameters.values(torch.from_numpy(iterate.u)).tolist()
    held_out = {} if iterate.held_out is None else {"held_out_loss": iterate.held_out}
    metrics = {"loss": iterate.loss, **held_out, **dict(zip(inversion.problem.parameters.names, values, strict=True))}
    if inversion.config.optimizer.starts == 1:
        return metrics
    return {f"start{iterate.start}.{name}": value for name, value in metrics.items()}
