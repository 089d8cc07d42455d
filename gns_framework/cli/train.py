"""``gns train``: train a learned simulator from a recipe (resumable; multi-process under torchrun)."""

from __future__ import annotations

import argparse
import contextlib
import signal
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

from ..config.recipe import load_recipe
from ..errors import GnsError, RecipeError
from ..io.checkpoint import list_checkpoints
from ..plugins import load_registry
from ..training import distributed
from ..training.distributed import processes_from_environment
from ..training.run_lock import run_folder_lock
from ..training.trainer import Trainer
from .arguments import add_allow_pickle, positive_float, positive_int
from .tracking_options import add_tracking_arguments, check_tracking_arguments, with_mlflow


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recipe", type=Path, help="recipe YAML file")
    parser.add_argument("--steps", type=positive_int, help="total training steps (overrides training.steps)")
    parser.add_argument(
        "--dataset",
        type=Path,
        help="dataset folder (overrides dataset.path; recorded as the run's dataset.path, so rollouts use it)",
    )
    add_allow_pickle(parser)
    parser.add_argument("--out", type=Path, help="run folder (overrides output_dir; default runs/<name>)")
    start = parser.add_mutually_exclusive_group()
    start.add_argument(
        "--resume",
        nargs="?",
        const="auto",
        metavar="CHECKPOINT",
        help="continue from CHECKPOINT, or with no value from the newest good checkpoint of the run folder "
        "(automatic after an elastic restart under torchrun). Refused when every checkpoint there is damaged, "
        "or when the run folder holds newer checkpoints than CHECKPOINT (branch into another folder with --out)",
    )
    start.add_argument(
        "--restart",
        action="store_true",
        help="start afresh at step 0 in a run folder that holds checkpoints (damaged ones included): they and the "
        "record of their MLflow run move to <run>/earlier-N/, nothing is deleted. Without --resume or --restart "
        "such a folder is refused",
    )
    parser.add_argument(
        "--init-from",
        type=Path,
        metavar="CHECKPOINT",
        help="fine-tune: start at step 0 from the weights of a trained checkpoint of the same model and scene "
        "(its weight average when it has one) with a fresh optimiser and schedule, e.g. on more data of the "
        "same envelope; the training noise (model.noise_std, noise_relative) may differ; recorded in every "
        "checkpoint. Not with --resume (a resumed run keeps its own weights)",
    )
    parser.add_argument("--device", help="cpu, cuda or cuda:N (overrides training.device)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument(
        "--time-limit",
        type=positive_float,
        metavar="MINUTES",
        help="stop after the first step past MINUTES of training, with a checkpoint of it, to go on with --resume "
        "(on this machine or another: a run started on a GPU resumes on the CPU)",
    )
    add_tracking_arguments(parser, "<run>/metrics.jsonl", "the recipe's name")


def run(args: argparse.Namespace) -> int:
    if args.init_from is not None and args.resume is not None:
        raise GnsError(
            "--init-from and --resume: a resumed run continues from its own checkpoint; fine-tune into a new run "
            "folder (--out NEW) with --init-from alone"
        )
    check_tracking_arguments(args)
    registry = load_registry()
    overrides: dict = {}
    if args.steps is not None:
        overrides.setdefault("training", {})["steps"] = args.steps
    if args.device is not None:
        overrides.setdefault("training", {})["device"] = args.device
    recipe = load_recipe(args.recipe, registry, overrides)
    processes = processes_from_environment()
    run_dir = args.out if args.out is not None else recipe.run_dir
    # One writer per run folder, for the whole run (fresh, --resume, --restart): rank 0 holds the lock.
    with run_folder_lock(run_dir, take=processes.is_chief):
        try:
            try:
                trainer = Trainer(
                    recipe,
                    registry,
                    run_dir=run_dir,
                    dataset_path=args.dataset,
                    processes=processes,
                    progress=not args.no_progress,
                    allow_pickle=args.allow_pickle,
                )
            except RecipeError as refused:
                # The trainer knows the recipe, not its file: name the file the user gave.
                raise RecipeError(args.recipe, refused.problems) from None
            try:
                with stopped_by_signals():
                    return _train(trainer, args)
            except KeyboardInterrupt as stop:
                # Ctrl-C or SIGTERM: the run is KILLED in MLflow (or left in mlflow_unsent.json for track-sync), the
                # lock is released on the way out, and every checkpoint written so far stays.
                trainer.close(killed=True)
                written = list_checkpoints(trainer.checkpoint_dir)
                kept = f"the newest checkpoint is {written[-1][1]}" if written else "no checkpoint was written yet"
                name = str(stop) or "SIGINT"
                print(f"gns train: stopped by {name} at step {trainer.step}; {kept} (--resume)", file=sys.stderr)
                return 128 + int(getattr(signal, name, signal.SIGINT))
            except BaseException:
                trainer.close(failed=True)
                raise
        finally:
            distributed.stop()


class StoppedBySignal(KeyboardInterrupt):
    """SIGTERM (a scheduler's or `kill`'s stop), raised where the main thread is, as Ctrl-C is."""


@contextlib.contextmanager
def stopped_by_signals() -> Iterator[None]:
    """SIGTERM raises StoppedBySignal in the main thread for the block, so training ends as after Ctrl-C."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def stop(signum, frame):
        raise StoppedBySignal(signal.Signals(signum).name)

    previous = signal.signal(signal.SIGTERM, stop)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _train(trainer: Trainer, args: argparse.Namespace) -> int:
    processes = trainer.processes
    say = print if processes.is_chief else (lambda *a, **k: None)
    resume, restart = args.resume, args.restart
    # After an elastic restart torchrun starts every worker afresh, with the same arguments: continue from the
    # checkpoints this run has written since, not from --resume's older one nor afresh again.
    if processes.restart_count > 0:
        written = processes.broadcast(processes.is_chief and bool(list_checkpoints(trainer.checkpoint_dir)))
        if written:
            resume, restart = "auto", False
    resumed = None
    if resume is not None:
        resumed = trainer.checkpoints.resume(None if resume == "auto" else resume)
        say(
            f"resumed from {resumed} at step {trainer.step}"
            if resumed
            else "no checkpoint to resume from; starting at step 0"
        )
    if resumed is None:
        earlier = trainer.checkpoints.start_afresh(restart)
        if earlier is not None:
            say(f"starting afresh at step 0; the earlier run's checkpoints are kept in {earlier}")
        if args.init_from is not None:
            step = trainer.checkpoints.initialize_from(args.init_from)
            say(f"fine-tuning from {args.init_from} (trained {step} steps)")
    # MLflow only once the data and any checkpoint have loaded, so a run that cannot start leaves no trace there;
    # a run from step 0 is a new history, so a new MLflow run.
    if processes.is_chief:
        assert trainer.tracker is not None  # rank 0 has one
        trainer.tracker = with_mlflow(args, trainer.recipe.name, trainer.run_dir, trainer.tracker, resumed is not None)
    if processes.distributed:
        say(f"training on {processes.world_size} processes ({trainer.device.type})")
    trainer.train(time_limit_s=None if args.time_limit is None else args.time_limit * 60)
    if trainer.stopped_by_time:
        trainer.close()
        processes.barrier()
        say(
            f"stopped at the time limit ({args.time_limit:g} min) at step {trainer.step} of "
            f"{trainer.recipe.training.steps}; checkpoints in {trainer.checkpoint_dir}: go on with --resume"
        )
        return 0
    # The loop validates at its last step; a run resumed at its end has not validated yet.
    final = trainer.last_validation if trainer.last_validation is not None else trainer.validate()
    trainer.close()
    # Leave together: a rank that tears its process group down while rank 0 still
    # validates can abort at exit.
    processes.barrier()
    summary = "".join(f", {k} {v:.4g}" for k, v in final.items())
    say(f"trained {trainer.recipe.name} to step {trainer.step}{summary}; checkpoints in {trainer.checkpoint_dir}")
    sys.stdout.flush()
    return 0
