"""``gns evaluate``: error against run time of trained models and of the ground-truth simulator."""

from __future__ import annotations

import argparse
import dataclasses
import re
from pathlib import Path

from ..errors import GnsError
from ..io.run_folder import RunFolder
from ..safe_names import ensure_inside, require_component, safe_component, unique_components
from .arguments import add_allow_pickle, add_overwrite, positive_int
from .envelope_option import add_outside_envelope, enforce_envelope
from .progress import report_progress


def _scales(text: str) -> list[float]:
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated positive numbers, got {text!r}") from None
    if not values or any(v <= 0 for v in values):
        raise argparse.ArgumentTypeError(f"expected comma-separated positive numbers, got {text!r}")
    return values


def _precisions(text: str) -> list[str]:
    from ..runtime.precision import PRECISIONS

    values = [v.strip() for v in text.split(",")]
    unknown = [v for v in values if v not in PRECISIONS]
    if not values or unknown or len(set(values)) != len(values):
        raise argparse.ArgumentTypeError(
            f"expected comma-separated distinct precisions among {', '.join(PRECISIONS)}, got {text!r}"
        )
    return values


def model_labels(recipe_names: list[str], checkpoints: list[Path]) -> list[str]:
    """One label per model, safe as a file name and unique: rollouts and GIFs are written under it.

    Models of different recipes are labelled by their recipes' names; models that share
    a recipe name by recipe, run folder and checkpoint file
    (``sand2d.run-a.checkpoint-000001000``), since two checkpoints of one recipe often
    share a file name. Characters outside ``[A-Za-z0-9_.-]`` become ``_``, and a label
    seen before gets ``-2``, ``-3``, ...; what is left is a safe file name
    (:func:`gns_framework.safe_names.unique_components`).
    """
    if len(set(recipe_names)) == len(recipe_names):
        raw = list(recipe_names)
    else:
        raw = [
            f"{name}.{RunFolder.of_checkpoint(path.resolve()).root.name}.{path.stem}"
            for name, path in zip(recipe_names, checkpoints, strict=True)
        ]
    return unique_components(re.sub(r"[^A-Za-z0-9_.-]+", "_", text).strip(".") or "model" for text in raw)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("checkpoints", nargs="+", type=Path, metavar="CHECKPOINT", help="trained models to compare")
    parser.add_argument("--dataset", type=Path, help="dataset folder (default: the first model's)")
    add_allow_pickle(parser)
    parser.add_argument("--split", default="test", help="split to evaluate on (default test)")
    parser.add_argument("--trajectories", type=positive_int, help="use only the first K trajectories")
    parser.add_argument("--out", type=Path, default=Path("runs/evaluation"), help="report folder")
    parser.add_argument(
        "--grid-scales",
        type=_scales,
        default=[0.5, 1.0],
        help="simulator grid resolutions relative to the data's (default 0.5,1)",
    )
    parser.add_argument(
        "--substep-scales", type=_scales, default=[1.0], help="simulator substeps relative to the data's (default 1)"
    )
    parser.add_argument("--no-simulator", action="store_true", help="compare learned models only")
    parser.add_argument(
        "--repeats", type=positive_int, default=3, help="timed runs per case; the median counts (default 3)"
    )
    parser.add_argument("--warmup", type=int, default=1, help="untimed runs first (default 1)")
    parser.add_argument("--error-metric", default="sinkhorn_final_pct", help="metric plotted against run time")
    parser.add_argument("--device", default="auto", help="device of the learned models")
    parser.add_argument(
        "--batch",
        type=positive_int,
        default=1,
        metavar="B",
        help="also roll each model out on B cases at a time as one batch, a second row beside one at a time "
        "(default 1: one at a time only)",
    )
    parser.add_argument(
        "--precisions",
        type=_precisions,
        default=["float32"],
        metavar="P[,P]",
        help="precisions of the learned models' products, each giving every model its rows (e.g. float32,bfloat16: "
        "bfloat16's error and speed beside float32's in one run; default float32)",
    )
    parser.add_argument("--vtk", action="store_true", help="also write VTK frames of each model's first rollout")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar while models are timed and scored")
    parser.add_argument(
        "--gif", action="store_true", help="also write a prediction-vs-truth GIF of each model's first rollout"
    )
    add_overwrite(parser, "write into --out even when it holds something other than a report")
    add_outside_envelope(parser)


def run(args: argparse.Namespace) -> int:
    from ..assembly.data import open_dataset
    from ..assembly.trained import load_trained
    from ..evaluation.candidates import cases_from_split, compare
    from ..evaluation.report import write_report
    from ..outputs import check_folder, claim_folder
    from ..plugins import load_registry
    from ..runtime.device import resolve_device

    check_folder(args.out, "evaluate", args.overwrite, own=_earlier_report)
    registry = load_registry()
    device = resolve_device(args.device)
    models = [load_trained(path, registry, device) for path in args.checkpoints]
    histories = {m.simulator.setup.history for m in models}
    if len(histories) > 1:
        raise GnsError(f"the models need different input histories {sorted(histories)}; evaluate them separately")
    dataset = open_dataset(models[0].recipe.dataset, registry, args.dataset, args.allow_pickle)
    metadata = dataset.metadata()
    trajectories = dataset.split(require_component(args.split, "--split"))
    if args.trajectories:
        trajectories = trajectories[: args.trajectories]
    cases = cases_from_split(trajectories)
    warnings: dict[Path, list[str]] = {}
    for model in models:
        # Each model is judged on the data as it sees it (its own frame stride); the split already
        # opened serves every model that sees it as the first does.
        if model.recipe.dataset == models[0].recipe.dataset:
            seen, split = dataset, trajectories
        else:
            seen = open_dataset(model.recipe.dataset, registry, dataset.path, args.allow_pickle)
            split = seen.split(args.split)
            split = split[: args.trajectories] if args.trajectories else split
        warnings[model.path] = enforce_envelope(
            model,
            seen.metadata(),
            list(split),
            args.outside_envelope,
            f"{dataset.path} (split {args.split})",
            "evaluate",
        )

    names = model_labels([m.recipe.name for m in models], args.checkpoints)
    claim_folder(args.out, "evaluate", args.overwrite, own=_earlier_report)
    with report_progress(args.no_progress) as progress:
        report = compare(
            list(zip(names, models, strict=True)),
            cases,
            metadata,
            registry,
            device,
            grid_scales=args.grid_scales,
            substep_scales=args.substep_scales,
            with_simulator=not args.no_simulator,
            repeats=args.repeats,
            warmup=args.warmup,
            error_metric=args.error_metric,
            rollout_dir=args.out / "rollouts" if (args.vtk or args.gif) else None,
            batch=args.batch,
            precisions=args.precisions,
            progress=progress,
        )
    report = dataclasses.replace(report, warnings=tuple(line for lines in warnings.values() for line in lines))
    paths = write_report(report, args.out)
    print(paths["markdown"].read_text())
    for kind, path in paths.items():
        print(f"{kind}: {path}")
    animations = _render_first_rollouts(args, names, report, registry) if (args.vtk or args.gif) else {}
    _log_to_training_runs(report, models, names, [*paths.values()], animations, warnings)
    return 0


def _log_to_training_runs(
    report,
    models,
    names: list[str],
    report_files: list[Path],
    animations: dict[str, Path],
    warnings: dict[Path, list[str]],
) -> None:
    """Attach the report (and the model's animation) to each model's MLflow run, when it was tracked."""
    from ..training.mlflow_tracker import log_to_recorded_run

    entries = {entry.name: entry for entry in report.entries}
    for model, name in zip(models, names, strict=True):
        entry = entries[name]
        metrics = {"evaluation_seconds_per_rollout": entry.seconds}
        batched = next((e for e in report.entries if e.name.startswith(f"{name} [batch ")), None)
        if batched is not None:
            metrics["evaluation_batched_seconds_per_rollout"] = batched.seconds
        if entry.speedup is not None:
            metrics["evaluation_speedup"] = entry.speedup
        # MLflow metric names take no brackets: "mse_full[sand]" becomes "mse_full.sand".
        metrics.update(
            {
                f"evaluation_{k}".replace("[", ".").replace("]", ""): v
                for k, v in entry.metrics.items()
                if isinstance(v, float)
            }
        )
        files = report_files + ([animations[name]] if name in animations else [])
        own = warnings[model.path]
        tags = {"outside_envelope": "; ".join(own)} if own else None
        tracked = log_to_recorded_run(
            RunFolder.of_checkpoint(model.path).root, metrics, model.step, files, "evaluation", tags
        )
        if tracked:
            print(f"logged the evaluation report of {name} to MLflow run {tracked}")


def _render_first_rollouts(args: argparse.Namespace, names: list[str], report, registry) -> dict[str, Path]:
    """VTK and/or GIF of each model's first rollout; returns the GIFs by model name.

    The rollout is the file the report says it wrote; every output is a safe file
    name inside ``--out`` (:mod:`gns_framework.safe_names`).
    """
    from ..io.rollout_file import load_rollout

    entries = {entry.name: entry for entry in report.entries}
    animations = {}
    for name in names:
        written = entries[name].rollout_files
        if not written or written[0] is None:
            continue
        rollout = load_rollout(written[0])
        materials = registry.material_names(rollout.particle_type)
        if args.vtk:
            from ..io.vtk import write_rollout_vtk

            folder = ensure_inside(args.out / "vtk" / safe_component(name), args.out)
            for part, pvd in write_rollout_vtk(rollout, folder, material_names=materials).items():
                print(f"vtk {name} {part}: {pvd}")
        if args.gif:
            from ..viz.animation import animate_rollout

            gif = ensure_inside(args.out / f"{safe_component(name)}.gif", args.out)
            animations[name] = animate_rollout(rollout, gif, every=2, material_names=materials)
            print(f"animation {name}: {animations[name]}")
    return animations


def _earlier_report(folder: Path) -> bool:
    """A report folder gns evaluate wrote before output folders were marked."""
    return (folder / "report.md").is_file() and (folder / "report.csv").is_file()
