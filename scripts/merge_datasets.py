"""Join datasets of one envelope into one (safe layout): their splits concatenated, statistics recomputed.

For training one model on scenes that were generated from several scene files (e.g.
``scenes/sand_general_2d.yaml`` and its obstacle-rich variant). The datasets must agree
on dimension, bounds, frame step and material properties; the connectivity radius is the
first dataset's (``--radius`` to choose). Velocity and acceleration statistics are
recomputed over the joined train split. The output records where each part came from
(``merged_from`` in metadata.json). An existing output folder is refused (nothing is
overwritten).

Usage::

    python scripts/merge_datasets.py data/sand_general_2d data/sand_general_2d_obstacles \\
        --out data/sand_general_2d_merged [--valid-each 6] [--test-each 6]
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path


def merge(
    sources: list[Path], out: Path, valid_each: int | None, test_each: int | None, radius: float | None = None
) -> dict[str, int]:
    """Write the joined dataset to ``out``; returns the trajectory count per split."""
    from gns_framework.assembly.data import open_dataset
    from gns_framework.config.recipe import DatasetSpec
    from gns_framework.data.metadata import DatasetMetadata, compute_statistics
    from gns_framework.errors import DatasetError
    from gns_framework.plugins import load_registry

    if out.exists():
        raise DatasetError(f"{out}: exists; merge into a new folder (nothing is overwritten)")
    registry = load_registry()
    layout = registry.get("dataset", "safe")
    datasets = [open_dataset(DatasetSpec(name="safe", path=str(source)), registry) for source in sources]
    metadatas = [dataset.metadata() for dataset in datasets]
    first = metadatas[0]
    for source, metadata in zip(sources[1:], metadatas[1:], strict=True):
        for field in ("dim", "bounds", "dt"):
            if getattr(metadata, field) != getattr(first, field):
                raise DatasetError(
                    f"{source}/metadata.json: {field} {getattr(metadata, field)!r} differs from "
                    f"{sources[0]}'s {getattr(first, field)!r}: the datasets are of different envelopes"
                )
        extra, first_extra = metadata.model_extra or {}, first.model_extra or {}
        if extra.get("material_properties") != first_extra.get("material_properties"):
            raise DatasetError(f"{source}/metadata.json: material_properties differ from {sources[0]}'s")
    limits = {"valid": valid_each, "test": test_each}
    splits: dict[str, list] = {"train": [], "valid": [], "test": []}
    for index, dataset in enumerate(datasets):
        for split in splits:
            if not dataset.has_split(split):
                continue
            # A split reads a trajectory on first access: only those taken are read.
            trajectories = list(dataset.split(split)[: limits.get(split)])
            # Keys stay unique and say where each trajectory came from.
            splits[split] += [replace(t, key=f"part{index}_{t.key}") for t in trajectories]
    statistics = compute_statistics(splits["train"], registry.kinematic_types())
    raw = first.model_dump()
    for key in ("vel_mean", "vel_std", "acc_mean", "acc_std"):
        raw[key] = statistics[key]
    raw.pop("generated_from", None)
    raw["sequence_length"] = max(m.sequence_length for m in metadatas)
    if radius is not None:
        raw["default_connectivity_radius"] = radius
    raw["merged_from"] = [
        {"path": str(source), "generated_from": (metadata.model_extra or {}).get("generated_from")}
        for source, metadata in zip(sources, metadatas, strict=True)
    ]
    layout.write(out, DatasetMetadata(**raw), {k: v for k, v in splits.items() if v})
    return {k: len(v) for k, v in splits.items()}


def parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("sources", nargs="+", type=Path, help="dataset folders (safe layout), two or more")
    parser.add_argument("--out", type=Path, required=True, help="new dataset folder")
    parser.add_argument("--valid-each", type=int, help="valid trajectories taken from each source (default all)")
    parser.add_argument("--test-each", type=int, help="test trajectories taken from each source (default all)")
    parser.add_argument("--radius", type=float, help="default connectivity radius (default the first source's)")
    return parser


def main() -> int:
    parser_ = parser()
    args = parser_.parse_args()
    if len(args.sources) < 2:
        parser_.error("give two or more datasets to merge")
    from gns_framework.errors import GnsError

    try:
        counts = merge(args.sources, args.out, args.valid_each, args.test_each, args.radius)
    except GnsError as exc:
        print(f"merge_datasets: {exc}", file=sys.stderr)
        return 1
    print(f"wrote {args.out}: " + json.dumps(counts))
    return 0


if __name__ == "__main__":
    sys.exit(main())
