"""``gns convert``: read a dataset in one layout and write it in another, validating every trajectory."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..data.pickle_grant import pickle_granted
from ..errors import GnsError, RecipeError
from ..outputs import check_folder, replaced_whole
from ..plugins import load_registry
from ..safe_names import require_component
from .arguments import add_allow_pickle, add_overwrite


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("source", type=Path, help="dataset folder to read")
    parser.add_argument("--from", dest="source_layout", required=True, help="layout of SOURCE (a dataset plugin)")
    parser.add_argument("--to", dest="target_layout", required=True, help="layout to write (a writable dataset plugin)")
    parser.add_argument("--out", type=Path, required=True, help="dataset folder to write")
    add_allow_pickle(parser)
    parser.add_argument(
        "--map-types",
        type=type_map,
        default={},
        metavar="FROM=TO,...",
        help="renumber particle types, e.g. 0=5,1=3: LagrangeBench's fluid (0) and walls (1) as this framework's "
        "water (5) and rigid (3); types not named keep their id (gns plugins lists the materials' ids)",
    )
    add_overwrite(parser, "replace --out whole even when it holds something other than an earlier gns convert result")


def run(args: argparse.Namespace) -> int:
    registry = load_registry()
    source_cls, params = _layout(registry, args.source_layout, "--from")
    target_cls, _ = _layout(registry, args.target_layout, "--to")
    if not target_cls.writable:
        writable = [n for n in registry.names("dataset") if registry.get("dataset", n).writable]
        raise GnsError(f"dataset layout {args.target_layout!r} is read-only; writable: {', '.join(writable)}")
    if args.source.resolve() == args.out.resolve():
        raise GnsError("--out must differ from SOURCE: converting in place could overwrite the files being read")
    replacing = check_folder(args.out, "convert", args.overwrite)
    source = source_cls(params, args.source, allow_pickle=pickle_granted(args.source, args.allow_pickle))
    metadata = source.metadata()
    # A split is written as <out>/<split>.<ext>: its name (from the source's plugin) must be a plain file name.
    splits = {require_component(name, f"{args.source}: split"): list(source.split(name)) for name in source.splits()}
    if args.map_types:
        splits = {name: [renumbered(t, args.map_types) for t in trajectories] for name, trajectories in splits.items()}
    if not splits:
        raise GnsError(f"{args.source}: no train, valid or test split in layout {args.source_layout!r}")
    total = sum(len(trajectories) for trajectories in splits.values())
    print(
        f"converting {total} trajectories of {args.source} ({args.source_layout}) to {args.target_layout} ...",
        flush=True,
    )
    # Written whole beside --out and renamed into place: never a mix of the old dataset and this one.
    with replaced_whole(args.out, "convert") as tmp:
        target_cls.write(tmp, metadata, splits)
    if replacing:
        print(f"replaced the earlier contents of {args.out}")
    counts = ", ".join(f"{name} {len(trajectories)}" for name, trajectories in splits.items())
    print(f"converted {args.source} ({args.source_layout}) to {args.out} ({args.target_layout}): {counts}")
    return 0


def type_map(text: str) -> dict[int, int]:
    """``"0=5,1=3"`` -> ``{0: 5, 1: 3}``: each source type id at most once."""
    mapping: dict[int, int] = {}
    for item in text.split(","):
        source, equals, target = item.partition("=")
        try:
            pair = int(source), int(target)
        except ValueError:
            pair = None
        if not equals or pair is None or min(pair) < 0:
            raise argparse.ArgumentTypeError(f"expected FROM=TO pairs of type ids such as 0=5,1=3, got {text!r}")
        if pair[0] in mapping:
            raise argparse.ArgumentTypeError(f"type {pair[0]} is mapped twice in {text!r}")
        mapping[pair[0]] = pair[1]
    return mapping


def renumbered(trajectory, mapping: dict[int, int]):
    """``trajectory`` with its particle types renumbered by ``mapping`` (types not in it unchanged)."""
    from dataclasses import replace

    import numpy as np

    types = trajectory.particle_type
    present, where = np.unique(types, return_inverse=True)
    renamed = np.array([mapping.get(int(t), int(t)) for t in present], dtype=types.dtype)
    return replace(trajectory, particle_type=renamed[where].reshape(types.shape))


def _layout(registry, name: str, option: str):
    """The dataset plugin a command-line option names, with its default parameters."""
    try:
        return registry.resolve("dataset", {"name": name})
    except RecipeError as exc:
        raise GnsError(f"{option} {name}: " + "; ".join(message for _, message in exc.problems)) from None
