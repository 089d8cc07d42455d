"""Does a sand model hold on the scenes users bring? Per-scene errors against the MPM, and the goal.

For a trained model (default ``models/sand2d_general.pt``) on

- held-out scenes drawn from the general envelope (``scenes/sand_general_2d.yaml`` with a
  scene seed training never used, ``--seed``), and
- the four canonical scenes of ``scenes/canonical/`` (a tall column in a 2 m box, a
  free-standing column, two columns of different friction, slip side walls),

it prints per scene the final sand extent, pile height and runout errors of the learned
rollout against the MPM that made the data (%), its final-cloud Sinkhorn error (% of the
largest domain side), the particles a wall held, whether the deposit is free (the MPM's stops
short of a side wall, so the flow sets its extent), and the Sinkhorn error and time of the MPM
at reduced resolutions (``--grid-scales``, default half) on the same drawn scene, then the
medians and worst cases against the goal: median <= 5 %, worst <= 15 % for extent and
height, median <= 8 % and worst <= 15 % for the extent of free deposits, Sinkhorn below the
half-resolution MPM's, and the summed time against each MPM. Datasets are generated into
``--out`` on the first run (``gns generate``'s code, same seeds: reproducible) and reused
afterwards. The learned model and the two MPMs run on the same scenes in one run.

Usage::

    python benchmarks/generalization.py --model models/sand2d_general.pt --held-out 20 --threads 2 [--json]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
GOAL = {"median": 5.0, "worst": 15.0}
FREE_GOAL = {"median": 8.0, "worst": 15.0}
"""Free deposits (the true one stops short of a side wall: its extent is the flow's, not the box's) reported apart."""
MEASURES = ("extent_error_pct", "height_error_pct", "runout_error_pct", "sinkhorn_final_pct")


def dataset(scene_path: Path, out: Path, test: int, seed: int | None, registry, obstacles: bool = True) -> Path:
    """``out`` holding one training trajectory (statistics need one) and ``test`` cases of the scene (without its
    obstacles unless ``obstacles``)."""
    from gns_framework.assembly.ground_truth import build_ground_truth_simulator
    from gns_framework.ground_truth.generate import generate_dataset, is_up_to_date, provenance
    from gns_framework.ground_truth.scene_spec import load_scene

    scene = load_scene(scene_path)
    if seed is not None:
        scene = scene.model_copy(update={"seed": seed})
    if not obstacles:
        scene = scene.model_copy(update={"obstacles": []})
    simulator = build_ground_truth_simulator(scene, registry, scene_path)
    counts = {"train": 1, "valid": 0, "test": test}
    if not is_up_to_date(out, provenance(scene, simulator, counts)):
        layout = registry.get("dataset", "safe")
        generate_dataset(scene, simulator, out, layout, counts, progress=False)
    return out


def evaluate(
    model_path: Path, data: Path, registry, device, gif: Path | None = None, grid_scales=(0.5,)
) -> dict[str, dict[str, dict]]:
    """case key -> {"learned": metrics, "mpm_<scale>": metrics} on the test split of ``data``; each metrics
    mapping holds the case's ``seconds_per_rollout`` and the learned one ``wall_held_particles``.

    With ``gif``, the learned rollout of the first case is drawn there beside the MPM's (every 4th frame).
    """
    from gns_framework.assembly.data import open_dataset
    from gns_framework.assembly.trained import load_trained
    from gns_framework.evaluation.candidates import cases_from_split, compare
    from gns_framework.model.envelope import outside_envelope

    model = load_trained(model_path, registry, device)
    data_set = open_dataset(model.recipe.dataset, registry, data)
    cases = cases_from_split(data_set.split("test"))
    if model.envelope is not None:
        setup = model.simulator.setup
        for line in outside_envelope(model.envelope, data_set.metadata(), cases, setup.history, setup.kinematic_types):
            print(f"{data}: outside the model's envelope: {line}", file=sys.stderr)
    with tempfile.TemporaryDirectory() as rollouts:
        report = compare(
            [("learned", model)],
            cases,
            data_set.metadata(),
            registry,
            device,
            grid_scales=grid_scales,
            repeats=1,
            warmup=0,
            rollout_dir=Path(rollouts) if gif else None,
        )
        if gif is not None:
            from gns_framework.io.rollout_file import load_rollout
            from gns_framework.viz.animation import animate_rollout

            learned = next(e for e in report.entries if e.kind == "learned")
            names = registry.material_names(model.simulator.setup.particle_types)
            animate_rollout(load_rollout(learned.rollout_files[0]), gif, every=4, material_names=names)
            print(f"animation: {gif}", file=sys.stderr)
    by_kind = {}
    for entry in report.entries:
        kind = "learned" if entry.kind == "learned" else f"mpm_{grid_scales[len(by_kind) - 1]:g}"
        by_kind[kind] = entry
    return {key: {kind: entry.cases[key] for kind, entry in by_kind.items()} for key in by_kind["learned"].cases}


def against_goal(label: str, values: list[float], goal: dict[str, float], scope: str = "") -> bool:
    """Print ``values``' median and worst case after ``label`` (and ``scope``) against ``goal``; whether it is met."""
    median, worst = statistics.median(values), max(values)
    ok = median <= goal["median"] and worst <= goal["worst"]
    print(
        f"{label}median {median:6.2f} %  worst {worst:6.2f} %{scope}  "
        f"goal <= {goal['median']:g} / {goal['worst']:g} %: {'met' if ok else 'NOT met'}"
    )
    return ok


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", type=Path, default=ROOT / "models" / "sand2d_general.pt")
    parser.add_argument("--held-out", type=int, default=20, help="held-out envelope scenes (default 20)")
    parser.add_argument("--seed", type=int, default=7, help="scene seed of the held-out scenes (training used 0)")
    parser.add_argument(
        "--without-obstacles",
        action="store_true",
        help="draw the held-out scenes without the envelope's rigid obstacles",
    )
    parser.add_argument("--out", type=Path, default=ROOT / "runs" / "generalization", help="datasets are kept here")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument(
        "--grid-scales",
        default="0.5",
        help="grids of the MPM yardsticks, as fractions of the data's (comma-separated; default 0.5): each runs the "
        "data's drawn scene refilled at its spacing",
    )
    parser.add_argument(
        "--scene",
        type=Path,
        default=ROOT / "scenes" / "sand_general_2d.yaml",
        help="the envelope the held-out scenes are drawn from (default: scenes/sand_general_2d.yaml); one drawing the "
        "same scenes but recording more, as scenes/sand_general_2d_obstacle_friction.yaml does, for a model trained "
        "on it",
    )
    parser.add_argument("--json", action="store_true", help="also print the per-scene figures as one JSON line")
    parser.add_argument(
        "--gifs",
        type=Path,
        metavar="DIR",
        help="draw each canonical scene's rollout beside the MPM's as DIR/<scene>.gif",
    )
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    scales = tuple(float(v) for v in args.grid_scales.split(","))

    from gns_framework.plugins import load_registry

    registry = load_registry()
    device = torch.device("cpu")
    groups = {}
    if args.held_out:
        data = dataset(
            args.scene,
            args.out / ("held_out_without_obstacles" if args.without_obstacles else "held_out"),
            args.held_out,
            args.seed,
            registry,
            obstacles=not args.without_obstacles,
        )
        groups["held-out"] = evaluate(args.model, data, registry, device, grid_scales=scales)
    canonical = {}
    for scene_path in sorted((ROOT / "scenes" / "canonical").glob("*.yaml")):
        data = dataset(scene_path, args.out / "canonical" / scene_path.stem, 1, None, registry)
        gif = args.gifs / f"{scene_path.stem}.gif" if args.gifs else None
        (case,) = evaluate(args.model, data, registry, device, gif, scales).values()
        canonical[scene_path.stem] = case
    groups["canonical"] = canonical

    header = f"{'group':<10} {'scene':<26} " + " ".join(
        f"{m.replace('_error_pct', '').replace('_final_pct', ''):>9}" for m in MEASURES
    )
    print(f"{args.model}: errors against the MPM at the data's grid, % (sinkhorn: % of the largest domain side)")
    yardsticks = [f"mpm_{scale:g}" for scale in scales]
    print(
        header
        + " "
        + " ".join(f"{y + ' sinkhorn':>17}" for y in yardsticks)
        + f" {'held':>5} {'free':>4} {'learned s':>9} "
        + " ".join(f"{y + ' s':>9}" for y in yardsticks)
    )
    rows = []
    for group, cases in groups.items():
        for key, case in cases.items():
            learned = case["learned"]
            values = [learned.get(m) for m in MEASURES]
            cells = " ".join(f"{v:>9.2f}" if v is not None else f"{'-':>9}" for v in values)
            sticks = " ".join(f"{case[y].get('sinkhorn_final_pct') or float('nan'):>17.2f}" for y in yardsticks)
            times = " ".join(f"{case[y]['seconds_per_rollout']:>9.2f}" for y in yardsticks)
            held = int(learned.get("wall_held_particles") or 0)
            free = "yes" if learned.get("free_deposit") else "no"
            print(
                f"{group:<10} {key:<26} {cells} {sticks} {held:>5} {free:>4} {learned['seconds_per_rollout']:>9.2f} "
                f"{times}"
            )
            rows.append(
                {
                    "group": group,
                    "scene": key,
                    **{m: learned.get(m) for m in MEASURES},
                    "wall_held_particles": held,
                    "free_deposit": free == "yes",
                    "seconds": learned["seconds_per_rollout"],
                    **{f"{y}_sinkhorn_final_pct": case[y].get("sinkhorn_final_pct") for y in yardsticks},
                    # The yardsticks' own deposit errors: a scene on which a finer or coarser MPM also lands
                    # elsewhere is one whose outcome turns on details (a front that may or may not reach a hump).
                    **{
                        f"{y}_{m}": case[y].get(m) for y in yardsticks for m in ("extent_error_pct", "height_error_pct")
                    },
                    **{f"{y}_seconds": case[y]["seconds_per_rollout"] for y in yardsticks},
                }
            )
    print()
    verdicts = []
    for group in groups:
        chosen = [r for r in rows if r["group"] == group]
        for measure in ("extent_error_pct", "height_error_pct"):
            values = [r[measure] for r in chosen if r[measure] is not None]
            verdicts.append(against_goal(f"{group:<10} {measure:<18} ", values, GOAL))
        free = [r["extent_error_pct"] for r in chosen if r["free_deposit"] and r["extent_error_pct"] is not None]
        if free:
            label = f"{group:<10} {'free deposits':<18} extent "
            verdicts.append(against_goal(label, free, FREE_GOAL, f" on {len(free)} of {len(chosen)}"))
        for y in yardsticks:
            below = sum(r["sinkhorn_final_pct"] < r[f"{y}_sinkhorn_final_pct"] for r in chosen)
            if y == "mpm_0.5":
                verdicts.append(below == len(chosen))
            learned_s, mpm_s = sum(r["seconds"] for r in chosen), sum(r[f"{y}_seconds"] for r in chosen)
            print(
                f"{group:<10} {y}: sinkhorn below it on {below} of {len(chosen)} scenes; time summed "
                f"learned {learned_s:.1f} s against {mpm_s:.1f} s ({mpm_s / learned_s:.2f}x)"
            )
    if args.json:
        print(json.dumps({"model": str(args.model), "rows": rows}))
    return 0 if all(verdicts) else 1


if __name__ == "__main__":
    sys.exit(main())
