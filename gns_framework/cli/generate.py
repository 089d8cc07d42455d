"""``gns generate``: simulate a scene spec into a dataset (train/valid/test splits and metadata.json)."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from ..assembly.ground_truth import build_ground_truth_simulator
from ..errors import GnsError
from ..ground_truth.generate import generate_dataset, is_up_to_date, provenance
from ..ground_truth.scene_spec import load_scene
from ..limits import check_scene
from ..outputs import check_folder, replaced_whole
from ..plugins import load_registry
from ..specs import ComponentSpec
from .arguments import add_overwrite, non_negative_int


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scene", type=Path, help="scene spec YAML (see scenes/)")
    parser.add_argument("--trajectories", type=int, required=True, help="trajectories in all splits together")
    parser.add_argument("--out", type=Path, required=True, help="dataset folder to write")
    parser.add_argument("--valid", type=int, help="validation trajectories (default: 10%%, at least 1 when N >= 3)")
    parser.add_argument("--test", type=int, help="test trajectories (default: 10%%, at least 1 when N >= 3)")
    parser.add_argument("--layout", default="safe", help="dataset plugin to write with (default: safe)")
    parser.add_argument(
        "--seed",
        type=non_negative_int,
        help="scene seed (overrides the scene file's seed): another seed gives trajectories none of the file's seed "
        "produces, e.g. a held-out test set",
    )
    parser.add_argument("--device", help="simulator device, e.g. cpu or cuda (overrides simulator.device)")
    parser.add_argument("--force", action="store_true", help="regenerate even if DIR already holds this dataset")
    add_overwrite(parser, "replace DIR whole even when it holds something other than a dataset gns generate wrote")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def split_counts(total: int, valid: int | None, test: int | None) -> dict[str, int]:
    """Trajectories per split; the rest of ``total`` trains.

    All of them may be held out (``--trajectories 20 --test 20``: a test set of
    unseen seeds for a model trained elsewhere); then no trajectory trains.
    """
    default = max(1, round(0.1 * total)) if total >= 3 else 0
    valid = default if valid is None else valid
    test = default if test is None else test
    if min(total, valid, test) < 0 or total - valid - test < 0:
        raise GnsError(f"--trajectories {total} is fewer than the {valid} valid and {test} test trajectories asked for")
    return {"train": total - valid - test, "valid": valid, "test": test}


def run(args: argparse.Namespace) -> int:
    registry = load_registry()
    scene = load_scene(args.scene)
    if args.seed is not None:
        scene = scene.model_copy(update={"seed": args.seed})
    if args.device is not None:
        chosen = ComponentSpec(name=scene.simulator.name, **{**scene.simulator.params, "device": args.device})
        scene = scene.model_copy(update={"simulator": chosen})
    # Before the simulator or any particle is allocated: particles, grid and memory against the limits.
    check_scene(scene, args.scene, max(args.trajectories, 1))
    simulator = build_ground_truth_simulator(scene, registry, args.scene)
    layout = registry.get("dataset", args.layout)
    if not layout.writable:
        writable = [n for n in registry.names("dataset") if registry.get("dataset", n).writable]
        raise GnsError(f"dataset layout {args.layout!r} is read-only; writable: {', '.join(writable)}")
    counts = split_counts(args.trajectories, args.valid, args.test)
    if not args.force and is_up_to_date(args.out, provenance(scene, simulator, counts)):
        print(f"{args.out} already holds this dataset (same scene, simulator and counts); --force regenerates it")
        return 0
    replacing = check_folder(args.out, "generate", args.overwrite, own=_generated)
    start = time.perf_counter()
    # Written whole beside --out and renamed into place: never a mix of the old dataset and this one.
    with replaced_whole(args.out, "generate") as tmp:
        metadata = generate_dataset(scene, simulator, tmp, layout, counts, progress=not args.no_progress)
    if replacing:
        print(f"replaced the earlier contents of {args.out}")
    print(
        f"wrote {sum(counts.values())} trajectories ({', '.join(f'{k} {v}' for k, v in counts.items())}) "
        f"of {scene.name} to {args.out} in {time.perf_counter() - start:.1f} s; "
        f"suggested connectivity radius {metadata.default_connectivity_radius}"
    )
    return 0


def _generated(folder: Path) -> bool:
    """A dataset gns generate wrote before output folders were marked: its metadata records what it came from."""
    import json

    try:
        with open(folder / "metadata.json", "rb") as handle:
            metadata = json.loads(handle.read(1 << 20))
    except (OSError, ValueError):
        return False
    return isinstance(metadata, dict) and "generated_from" in metadata
