"""How far an obstacle's surface friction moves the simulator's deposit: an input a model must see.

``scenes/sand_general_2d.yaml`` draws each obstacle's Coulomb friction (0.3-0.5) per trajectory, and the MPM applies it
at the obstacle's surface, but the data did not record it (the obstacles' particles read 0): a model trained on it
cannot tell a hump the sand slides over from one that holds it. This runs the MPM again on the held-out scenes of
the given seeds with every obstacle's friction set to each end of that range (``--frictions``; the draws otherwise the
same: frame 0 is checked to be the data's, particle for particle) and prints, per scene with an obstacle, the extent
and height difference of each run's deposit from the data's. Where those differ by more than the worst-case goal,
a model blind to the friction cannot meet it there, whatever it learns.

Usage::

    python benchmarks/obstacle_friction.py --seed 12 13 --out runs/obstacle_friction --threads 1 [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from generalization import ROOT

KEEP_DRAWS = 1e-9
"""Width of the range an obstacle's friction is pinned to: a range of zero width draws nothing, which would shift
every later draw of the trajectory (and so every body after it); a range this narrow draws as the data's did."""


def pinned(scene, friction: float | None):
    """``scene`` with every obstacle's friction drawn from ``[friction, friction + KEEP_DRAWS]`` (None: as it is)."""
    from gns_framework.ground_truth.scene_values import Range

    if friction is None:
        return scene
    obstacles = [
        o.model_copy(update={"friction": Range(range=(friction, friction + KEEP_DRAWS))}) for o in scene.obstacles
    ]
    return scene.model_copy(update={"obstacles": obstacles})


def generated(scene, scene_path: Path, out: Path, held_out: int, registry) -> Path:
    """``out`` holding ``held_out`` test trajectories of ``scene`` (and the one training trajectory statistics need)."""
    from gns_framework.assembly.ground_truth import build_ground_truth_simulator
    from gns_framework.ground_truth.generate import generate_dataset, is_up_to_date, provenance

    simulator = build_ground_truth_simulator(scene, registry, scene_path)
    counts = {"train": 1, "valid": 0, "test": held_out}
    if not is_up_to_date(out, provenance(scene, simulator, counts)):
        generate_dataset(scene, simulator, out, registry.get("dataset", "safe"), counts, progress=False)
    return out


def deposit(position: np.ndarray, sand: np.ndarray, floor: float) -> tuple[float, float]:
    """(extent, height) of the ``sand`` particles of a (N, d) frame, m."""
    x = position[sand, 0]
    return float(x.max() - x.min()), float(position[sand, 1].max() - floor)


def scene_rows(scene_path: Path, seed: int, out: Path, held_out: int, frictions, registry) -> list[dict]:
    """Per held-out scene with an obstacle: the drawn frictions and each pinned run's extent and height difference
    from the data's deposit, %."""
    from gns_framework.ground_truth.drawn import read_drawn
    from gns_framework.ground_truth.scene_spec import load_scene

    scene = load_scene(scene_path).model_copy(update={"seed": seed})
    kinematic = list(registry.kinematic_types())
    runs = {f: generated(pinned(scene, f), scene_path, out / f"friction_{f:g}", held_out, registry) for f in frictions}
    data = generated(scene, scene_path, out / "data", held_out, registry)
    rows = []
    with np.load(data / "test.npz") as truth:
        stored = {f: np.load(path / "test.npz") for f, path in runs.items()}
        for key in sorted({name.split("/")[0] for name in truth.files}):
            types = truth[f"{key}/particle_type"]
            if not np.isin(types, kinematic).any():
                continue
            granular = [t for t in np.unique(types) if registry.material_by_type(int(t)).cls.granular]
            sand, floor = np.isin(types, granular), float(truth[f"{key}/bounds"][1, 0])
            position = truth[f"{key}/position"]
            extent, height = deposit(position[-1], sand, floor)
            row = {"scene": key, "seed": seed, "drawn": _drawn_frictions(read_drawn(data, key)), "runs": {}}
            for f, run in stored.items():
                other = run[f"{key}/position"]
                if not np.array_equal(other[0], position[0]):
                    raise SystemExit(f"{key}: friction {f:g} drew another scene (frame 0 differs): not comparable")
                e, h = deposit(other[-1], sand, floor)
                row["runs"][f"{f:g}"] = {"extent": 100 * (e - extent) / extent, "height": 100 * (h - height) / height}
            rows.append(row)
        for run in stored.values():
            run.close()
    return rows


def _drawn_frictions(record: dict | None) -> list[float]:
    return [float(v["friction"]) for k, v in (record or {}).items() if k.startswith("obstacles")]


def span(row: dict) -> float:
    """The largest extent or height difference between two of the row's deposits (the data's among them), %."""
    values = {name: [0.0] + [run[name] for run in row["runs"].values()] for name in ("extent", "height")}
    return max(max(v) - min(v) for v in values.values())


def report(rows: list[dict], goal: float) -> dict:
    frictions = list(rows[0]["runs"]) if rows else []
    print(f"{'scene':<18} {'seed':>4} {'drawn friction':>15} " + " ".join(f"{'friction ' + f:>22}" for f in frictions))
    print(f"{'':<18} {'':>4} {'':>15} " + " ".join(f"{'extent / height, %':>22}" for _ in frictions))
    for row in rows:
        runs = " ".join(f"{r['extent']:>+10.1f} / {r['height']:>+9.1f}" for r in row["runs"].values())
        print(f"{row['scene']:<18} {row['seed']:>4} {', '.join(f'{f:.2f}' for f in row['drawn']):>15} {runs}")
    spans = [span(row) for row in rows]
    summary = {
        "scenes_with_obstacles": len(rows),
        "span_over_10_pct": sum(s > 10 for s in spans),
        f"span_over_{goal:g}_pct": sum(s > goal for s in spans),
        "largest_span_pct": max(spans, default=0.0),
    }
    print(
        f"{len(rows)} scenes with an obstacle: the deposit moves by more than 10 % across the frictions on "
        f"{summary['span_over_10_pct']}, by more than {goal:g} % on {summary[f'span_over_{goal:g}_pct']}; "
        f"largest {summary['largest_span_pct']:.1f} %"
    )
    return summary


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", type=Path, default=ROOT / "scenes" / "sand_general_2d.yaml")
    parser.add_argument("--seed", type=int, nargs="+", default=[12, 13], help="scene seeds of the held-out scenes")
    parser.add_argument("--held-out", type=int, default=20, help="scenes per seed")
    parser.add_argument("--frictions", type=float, nargs="+", default=[0.3, 0.5], help="obstacle frictions to run")
    parser.add_argument("--out", type=Path, required=True, help="datasets are kept here, per seed and friction")
    parser.add_argument("--goal", type=float, default=15.0, help="worst-case goal, %%")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--json", action="store_true", help="also print the rows and summary as one JSON line")
    args = parser.parse_args(argv)
    import torch

    torch.set_num_threads(args.threads)
    from gns_framework.plugins import load_registry

    registry = load_registry()
    rows = []
    for seed in args.seed:
        rows += scene_rows(args.scene, seed, args.out / f"s{seed}", args.held_out, args.frictions, registry)
    summary = report(rows, args.goal)
    if args.json:
        print(json.dumps({"rows": rows, **summary}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
