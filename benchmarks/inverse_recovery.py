"""Recovery, cost and memory of ``gns invert`` on MPM trajectories whose parameters are known.

Three measurements, each printed as a table, and one JSON object on the last line:

``recovery``  For each of the first ``--cases`` trajectories of a ``gns generate``
    dataset, invert the learned model for the unknown and compare with the truth:
    ``friction`` (tan of the friction angle) with the value the scene drew for that
    trajectory (from its seed, which ``gns generate`` records in the trajectory key);
    ``initial_velocity`` with the block's launch velocity when it starts in free flight
    (``--gravity``: its input frames are exactly ballistic), else with its mean velocity
    over the model's C input frames in the data (:func:`input_frame_velocity`).
    Relative error per case (of the vector's norm) and its median.

``--mpm-baseline``  The same friction recovered without the learned model, by a
    derivative-free golden-section search over the bounds whose every evaluation is one
    MPM simulation of the trajectory (the simulator that made the data, at its
    settings). It stops once its estimate is as close to the truth as the learned
    inversion's; the table gives both times and their ratio.

``--memory``  Peak resident memory of one loss-and-gradient evaluation of a
    full-length rollout, with and without gradient checkpointing, each in a fresh
    process (ru_maxrss), beside a process that only loads the model and data.

Usage::

    python benchmarks/inverse_recovery.py --model models/sand2d_fast.pt --data data/invert_heldout \\
        --unknown friction --cases 6 --mpm-baseline --memory --threads 1
    python benchmarks/inverse_recovery.py --model models/sand2d_throw.pt --data data/throw_heldout \\
        --unknown initial_velocity --gravity 0 -9.81 --cases 6 --threads 1
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch

GOLDEN = (math.sqrt(5) - 1) / 2
RECORDED = ("key", "truth", "recovered", "error_pct", "seconds", "iterations", "launch")


def seed_of(key: str) -> int:
    if not key.startswith("seed_"):
        raise SystemExit(f"trajectory {key!r}: not written by gns generate (its key holds no seed)")
    return int(key.removeprefix("seed_"))


def drawn_truth(scene, key: str, unknown: str) -> list[float]:
    """The value the scene drew for this trajectory: friction of block 0, or its launch velocity."""
    from gns_framework.ground_truth.sampling import sample_scene

    block = sample_scene(scene, seed_of(key)).blocks[0]
    if unknown == "friction":
        return [float(block.values["friction"][0])]
    return [float(v) for v in block.velocity]


def input_frame_velocity(position: np.ndarray, history: int, dt: float) -> list[float]:
    """Mean velocity of the moving body over the model's C input frames, (p[C-1] - p[0]) / ((C-1) dt).

    What an unknown initial velocity stands for: the rollout starts from C frames of
    uniform motion. A block launched along a frictional floor slows and settles
    within them, so this is below its launch velocity.
    """
    return [float(v) for v in (position[history - 1] - position[0]).mean(0) / ((history - 1) * dt)]


def unknown_spec(args) -> dict:
    if args.unknown == "friction":
        return {"friction": {"bounds": args.bounds}}
    spec = {"particle_type": args.sand_type, "bounds": [args.bounds, args.bounds_y]}
    if args.gravity:
        spec["gravity"] = args.gravity
    return {"initial_velocity": spec}


def invert_case(args, index: int, registry) -> dict:
    from gns_framework.inverse.config import parse_invert_config
    from gns_framework.inverse.solve import prepare, solve

    raw = {
        "model": str(args.model),
        "observed": {"dataset": str(args.data), "split": args.split, "trajectory": index, "frames": args.frames},
        "unknowns": unknown_spec(args),
        "optimizer": {"name": args.optimizer, "lr": args.lr, "iterations": args.iterations},
        "loss": args.loss,
        "checkpoint_every": args.checkpoint_every,
    }
    config, unknowns = parse_invert_config(raw, "benchmark")
    inversion = prepare(config, unknowns, "benchmark", registry)
    result = solve(inversion)
    value = result.unknowns[args.unknown]
    return {
        "key": inversion.trajectory.key,
        "recovered": value if isinstance(value, list) else [value],
        "seconds": result.seconds,
        "loss": result.loss,
        "iterations": result.iterations,
        "inversion": inversion,
        "result": result,
    }


def golden_section_mpm(
    scene, simulator, key: str, observed: np.ndarray, stride: int, truth: float, target: float, bounds: list[float]
) -> dict:
    """Golden-section search of block 0's friction by MPM runs, until within ``target`` relative error of the truth."""
    from gns_framework.ground_truth.scene_spec import Range

    seed = seed_of(key)
    evaluations, started = 0, time.perf_counter()

    def misfit(friction: float) -> float:
        nonlocal evaluations
        evaluations += 1
        block = scene.blocks[0].model_copy(
            update={"properties": {**scene.blocks[0].properties, "friction": Range(range=(friction, friction))}}
        )
        variant = scene.model_copy(update={"blocks": [block, *scene.blocks[1:]]})
        final = simulator.simulate(variant, seed).position[::stride][len(observed) - 1]
        return float(((final - observed[-1]) ** 2).mean())

    low, high = bounds
    a, b = high - GOLDEN * (high - low), low + GOLDEN * (high - low)
    fa, fb = misfit(a), misfit(b)
    while abs(0.5 * (low + high) - truth) / truth > target and high - low > 1e-6:
        if fa < fb:
            high, b, fb = b, a, fa
            a = high - GOLDEN * (high - low)
            fa = misfit(a)
        else:
            low, a, fa = a, b, fb
            b = low + GOLDEN * (high - low)
            fb = misfit(b)
    estimate = 0.5 * (low + high)
    return {
        "estimate": estimate,
        "evaluations": evaluations,
        "seconds": time.perf_counter() - started,
        "error_pct": 100 * abs(estimate - truth) / truth,
    }


def peak_rss_child(args, checkpoint_every: int | None) -> float:
    """Peak RSS (MiB) of a fresh process that evaluates one loss and gradient (None: loads only)."""
    code = f"""
import resource, sys, torch
torch.set_num_threads({args.threads})
sys.argv = ['x']
from gns_framework.inverse.config import parse_invert_config
from gns_framework.inverse.solve import prepare
from gns_framework.runtime.activation_memory import activations_recomputed
from gns_framework.plugins import load_registry
raw = {{"model": {str(args.model)!r}, "observed": {{"dataset": {str(args.data)!r}, "split": {args.split!r},
       "trajectory": 0, "frames": "all"}}, "unknowns": {{"friction": {{"bounds": {list(args.bounds)!r}}}}},
       "checkpoint_every": {checkpoint_every or 0}}}
config, unknowns = parse_invert_config(raw, "memory")
problem = prepare(config, unknowns, "memory", load_registry()).problem
if {checkpoint_every is not None}:
    with activations_recomputed(problem.checkpoint_every > 0):
        u = torch.tensor(problem.start, requires_grad=True)
        torch.autograd.grad(problem.loss(u), u)
print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return float(out.stdout.strip().splitlines()[-1])


def trained_friction(model: Path) -> list[float]:
    """The range of friction ``model`` trained on: the widest bounds ``gns invert`` searches without a warning."""
    from gns_framework.assembly.trained import load_trained
    from gns_framework.plugins import load_registry

    envelope = load_trained(model, load_registry()).envelope
    if envelope is None or "friction" not in envelope.properties:
        return [0.4, 1.0]
    return [float(v) for v in envelope.properties["friction"]]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", type=Path, default=Path("models/sand2d_fast.pt"))
    parser.add_argument(
        "--data", type=Path, required=True, help="gns generate output of the model's scene, unseen seeds"
    )
    parser.add_argument("--split", default="test")
    parser.add_argument("--unknown", choices=("friction", "initial_velocity"), default="friction")
    parser.add_argument(
        "--bounds",
        type=float,
        nargs=2,
        default=None,
        help="default: the friction range the model trained on (gns invert refuses wider), 0 1.2 (velocity x)",
    )
    parser.add_argument("--bounds-y", type=float, nargs=2, default=[-0.2, 1.2], help="velocity y bounds (2D scenes)")
    parser.add_argument(
        "--gravity",
        type=float,
        nargs=2,
        help="gx gy: the block starts in free flight; its input "
        "frames are rebuilt ballistically and the truth is its launch velocity",
    )
    parser.add_argument("--sand-type", type=int, default=6)
    parser.add_argument("--cases", type=int, default=5)
    parser.add_argument("--optimizer", choices=("adam", "lbfgs"), default="adam")
    parser.add_argument("--lr", type=float, default=0.05)
    parser.add_argument("--iterations", type=int, default=40)
    parser.add_argument("--loss", choices=("positions", "runout", "sinkhorn"), default="positions")
    parser.add_argument("--frames", default="all", help="last, all, or comma-separated frame indices (6,8,10)")
    parser.add_argument("--checkpoint-every", type=int, default=10)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--mpm-baseline", action="store_true")
    parser.add_argument("--memory", action="store_true")
    parser.add_argument("--picture", type=Path, help="write the first case's convergence plot and GIF into this folder")
    parser.add_argument(
        "--record",
        type=Path,
        help="JSON-lines file of finished cases: each case is appended when "
        "done, and cases already there are read instead of inverted again (a stopped run continues)",
    )
    parser.add_argument("--json", action="store_true", help="(the JSON line is always printed last)")
    args = parser.parse_args()
    if args.frames not in ("last", "all"):
        args.frames = [int(frame) for frame in args.frames.split(",")]
    torch.set_num_threads(args.threads)
    if args.bounds is None:
        args.bounds = trained_friction(args.model) if args.unknown == "friction" else [0.0, 1.2]

    from gns_framework.assembly.data import open_dataset
    from gns_framework.assembly.ground_truth import build_ground_truth_simulator
    from gns_framework.ground_truth.scene_spec import SceneSpec
    from gns_framework.plugins import load_registry

    registry = load_registry()
    metadata = json.loads((args.data / "metadata.json").read_text())
    scene = SceneSpec.model_validate(metadata["generated_from"]["scene"])
    cases = []
    print(f"{'case':<18}{'truth':>18}{'recovered':>18}{'error %':>9}{'seconds':>9}{'iterations':>11}")
    recorded = (
        [json.loads(line) for line in args.record.read_text().splitlines()]
        if args.record and args.record.exists()
        else []
    )
    for index in range(args.cases):
        if index < len(recorded):
            case = recorded[index]
            cases.append(case)
            truth, error = case["truth"], case["error_pct"]
        else:
            case = invert_case(args, index, registry)
            truth = drawn_truth(scene, case["key"], args.unknown)
            if args.unknown == "initial_velocity" and not args.gravity:
                problem = case["inversion"].problem
                case["launch"] = truth
                truth = input_frame_velocity(
                    case["inversion"].trajectory.position, problem.simulator.setup.history, problem.metadata.dt
                )
            error = 100 * float(np.linalg.norm(np.subtract(case["recovered"], truth)) / np.linalg.norm(truth))
            case.update(truth=truth, error_pct=error)
            cases.append(case)
            if args.record:
                with args.record.open("a") as record:
                    record.write(json.dumps({k: case[k] for k in RECORDED if k in case}) + "\n")
        fmt = lambda v: ", ".join(f"{x:.3f}" for x in v)  # noqa: E731
        print(
            f"{case['key']:<18}{fmt(truth):>18}{fmt(case['recovered']):>18}{error:>9.2f}{case['seconds']:>9.1f}"
            f"{case['iterations']:>11}"
        )
        if index == 0 and args.picture and "inversion" in case:
            from gns_framework.inverse.solve import write_outputs

            args.picture.mkdir(parents=True, exist_ok=True)
            write_outputs(case["inversion"], case["result"], args.picture)
    errors = [c["error_pct"] for c in cases]
    summary = {
        "unknown": args.unknown,
        "loss": args.loss,
        "frames": args.frames,
        "optimizer": args.optimizer,
        "iterations": args.iterations,
        "cases": len(cases),
        "median_error_pct": float(np.median(errors)),
        "worst_error_pct": float(max(errors)),
        "median_seconds": float(np.median([c["seconds"] for c in cases])),
    }
    print(
        f"median error {summary['median_error_pct']:.2f} %, worst {summary['worst_error_pct']:.2f} %, "
        f"median {summary['median_seconds']:.1f} s per inversion"
    )

    if args.mpm_baseline and args.unknown == "friction":
        from gns_framework.assembly.trained import load_trained

        model_recipe = load_trained(args.model, registry).recipe
        dataset = open_dataset(model_recipe.dataset, registry, args.data)
        stride = model_recipe.dataset.frame_stride
        simulator = build_ground_truth_simulator(scene, registry, "metadata.json: generated_from")
        print(
            f"\n{'case':<18}{'learned s':>10}{'MPM search s':>13}{'MPM runs':>9}{'MPM error %':>12}{'learned/MPM':>12}"
        )
        ratios = []
        for index, case in enumerate(cases):
            observed = dataset.split(args.split)[index].position
            target = max(case["error_pct"], 0.05) / 100
            search = golden_section_mpm(
                scene, simulator, case["key"], observed, stride, case["truth"][0], target, args.bounds
            )
            ratios.append(case["seconds"] / search["seconds"])
            case["mpm"] = search
            print(
                f"{case['key']:<18}{case['seconds']:>10.1f}{search['seconds']:>13.1f}{search['evaluations']:>9}"
                f"{search['error_pct']:>12.2f}{ratios[-1]:>12.1f}"
            )
        summary["time_ratio_learned_over_mpm_median"] = float(np.median(ratios))
        print(
            "median time ratio learned / MPM search at equal error: "
            f"{summary['time_ratio_learned_over_mpm_median']:.1f}"
        )

    if args.memory:
        base = peak_rss_child(args, None)
        whole = peak_rss_child(args, 0)
        checkpointed = peak_rss_child(args, args.checkpoint_every)
        summary["memory_mib"] = {
            "load_only": base,
            "no_checkpointing": whole,
            f"checkpoint_every_{args.checkpoint_every}": checkpointed,
        }
        print(
            f"\npeak RSS, one full-length loss and gradient: load only {base:.0f} MiB, without checkpointing "
            f"{whole:.0f} MiB (+{whole - base:.0f}), checkpoint every {args.checkpoint_every} steps "
            f"{checkpointed:.0f} MiB (+{checkpointed - base:.0f})"
        )
    summary["per_case"] = [{k: c[k] for k in (*RECORDED, "mpm") if k in c} for c in cases]
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
