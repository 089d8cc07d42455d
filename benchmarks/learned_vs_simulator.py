"""Time per stored frame against particle count: the learned simulator beside the MLS-MPM that makes its data.

The scene is the demo's granular column (scenes/demo_sand_2d.yaml, column 0.15 m x 0.25 m,
tan phi 0.7) refined to about ``--particles`` particles: the grid grows as sqrt(N) and,
to keep the simulator's CFL number, its substeps per frame grow with the grid
(40 at grid 48, the data's setting). The learned models see the same particles with
their connectivity radius scaled to the spacing (the same ~13 neighbours each, self included):

    fast       the shipped model's architecture (5 x 64, one step per 2 stored frames)
    grid       the shipped grid-processor model (models/sand2d_fast_grid.pt: grid_cnn, 32 wide, stride 2)
    reference  the paper's (10 x 128, one step per stored frame)

Each learned case times full rollout steps (graph, features, model, integration) on the
MPM's initial particles, median of ``--repeats`` after one warm-up; the MPM times
``--frames`` frames after a warm-up frame (kernels compiled before). Cases of one size
run back to back, so load from other processes hits them alike; the table gives the
time per stored frame and the MPM / learned ratio (above 1: the learned one is faster).

Usage::

    python benchmarks/learned_vs_simulator.py --particles 1000 10000 100000 --threads 2
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
DATA_GRID, DATA_SUBSTEPS = 48, 40


def refined_scene(particles: int):
    """The demo scene with a fixed column, its grid chosen for ~``particles`` particles, CFL kept."""
    from gns_framework.ground_truth.sampling import sample_scene
    from gns_framework.ground_truth.scene_spec import Range, load_scene

    scene = load_scene(ROOT / "scenes" / "demo_sand_2d.yaml")
    block = scene.blocks[0].model_copy(
        update={
            "size": [Range(range=(0.15, 0.15)), Range(range=(0.25, 0.25))],
            "properties": {"friction": Range(range=(0.7, 0.7))},
        }
    )
    # Particle count ~ (0.15 x 0.25 m) x (particles per cell / dx)^2 = 0.15 grid^2 for 2 per cell on a 1 m box.
    grid = max(DATA_GRID, round(math.sqrt(particles / (0.15 * 0.25 * scene.particles_per_cell**2))))
    substeps = math.ceil(DATA_SUBSTEPS * grid / DATA_GRID)
    scene = scene.model_copy(
        update={
            "blocks": [block],
            "domain": scene.domain.model_copy(update={"grid": grid}),
            "time": scene.time.model_copy(update={"substeps": substeps, "frames": 2}),
        }
    )
    return scene, sample_scene(scene, 0)


def time_mpm(scene, sample, registry, frames: int) -> float:
    """Seconds per stored frame of the MPM on ``scene`` (after one untimed frame)."""
    from gns_builtins.simulators._mpm.solver import MpmSolver
    from gns_framework.assembly.ground_truth import build_ground_truth_simulator

    simulator = build_ground_truth_simulator(scene, registry, "benchmark scene")
    solver = MpmSolver(
        scene,
        position=np.concatenate([b.position for b in sample.blocks]),
        velocity=np.zeros((sample.num_particles, scene.dim)),
        particles=simulator._particle_arrays(scene, sample),
        obstacles=sample.obstacles,
        device="cpu",
    )
    solver.advance_frame()
    started = time.perf_counter()
    for _ in range(frames):
        solver.advance_frame()
    solver.position()
    return (time.perf_counter() - started) / frames


def learned_model(kind: str, registry, radius_scale: float):
    """(simulator, frames per step) of the shipped architecture or the reference's, radius scaled."""
    from gns_framework.assembly.learned import build_learned_simulator
    from gns_framework.assembly.trained import load_trained
    from gns_framework.config.recipe import load_recipe

    model_file = "sand2d_fast_grid.pt" if kind == "grid" else "sand2d_fast.pt"
    shipped = load_trained(ROOT / "models" / model_file, registry)
    scene = replace(
        shipped.simulator.setup, connectivity_radius=shipped.simulator.setup.connectivity_radius * radius_scale
    )
    if kind in ("fast", "grid"):
        simulator = build_learned_simulator(scene, shipped.metadata, shipped.recipe.model, registry)
        simulator.load_state_dict(shipped.simulator.state_dict())
        return simulator.eval(), shipped.recipe.dataset.frame_stride
    reference = load_recipe(ROOT / "recipes" / "sand2d.yaml", registry)
    # Weights do not change the cost: the reference architecture with its initial parameters.
    return build_learned_simulator(scene, shipped.metadata, reference.model, registry).eval(), 1


def time_learned(simulator, sample, repeats: int) -> float:
    """Median seconds of one rollout step from the column at rest."""
    from gns_framework.data.batch import ParticleBatch

    position = torch.from_numpy(np.concatenate([b.position for b in sample.blocks])).float()
    n = position.shape[0]
    history = simulator.setup.history
    state = ParticleBatch(
        position_sequence=position[:, None].repeat(1, history, 1),
        particle_type=torch.full((n,), 6, dtype=torch.long),
        batch=torch.zeros(n, dtype=torch.long),
        num_examples=1,
        material_property=torch.full((n, 1), 0.7),
    )
    times = []
    with torch.inference_mode():
        for repeat in range(repeats + 1):
            started = time.perf_counter()
            simulator.predict_next_position(state)
            if repeat:
                times.append(time.perf_counter() - started)
    return float(np.median(times))


def plot(rows: list[dict], path: Path) -> None:
    """Seconds per stored frame against particle count, log-log, one line per simulator."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    particles = [row["particles"] for row in rows]
    figure, axis = plt.subplots(figsize=(6, 4))
    for key, label in (
        ("mpm_s_per_frame", "MLS-MPM (substeps grow with the grid: CFL)"),
        ("fast_s_per_frame", "learned, 5 x 64, stride 2 (shipped)"),
        ("grid_s_per_frame", "learned, grid processor 32 wide, stride 2 (shipped)"),
        ("reference_s_per_frame", "learned, 10 x 128, stride 1 (reference)"),
    ):
        if all(key in row for row in rows):
            axis.loglog(particles, [row[key] for row in rows], marker="o", label=label)
    axis.set_xlabel("particles")
    axis.set_ylabel("seconds per stored frame")
    axis.set_title("2D sand column on 1 CPU thread")
    axis.grid(True, which="both", alpha=0.3)
    axis.legend(fontsize=8)
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--particles", type=int, nargs="+", default=[1000, 10000, 100000])
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--frames", type=int, default=2, help="MPM frames timed per size")
    parser.add_argument("--plot", type=Path, help="also draw time per frame against particles into this PNG")
    parser.add_argument(
        "--replot", type=Path, help="only draw --plot from the JSON line an earlier run printed (in this file)"
    )
    parser.add_argument("--json", action="store_true", help="(the JSON line is always printed last)")
    args = parser.parse_args()
    if args.replot:
        plot(json.loads(args.replot.read_text().strip().splitlines()[-1])["rows"], args.plot)
        return 0
    torch.set_num_threads(args.threads)
    import warp as wp

    wp.config.quiet = True
    from gns_framework.evaluation.timing import hardware_description
    from gns_framework.plugins import load_registry

    registry = load_registry()
    warm_scene, warm_sample = refined_scene(300)
    time_mpm(warm_scene, warm_sample, registry, 1)  # compiles the kernels
    rows = []
    hardware = hardware_description()
    print(
        f"{hardware['cpu']}, {hardware['cpu_cores_usable']} usable cores, torch threads {args.threads}, torch "
        f"{hardware['torch']}"
    )
    print(
        f"{'particles':>9} {'grid':>5} {'substeps':>8} {'MPM s/frame':>12} {'fast s/frame':>13} {'grid s/frame':>13} "
        f"{'ref s/frame':>12} {'MPM/fast':>9} {'MPM/grid':>9} {'MPM/ref':>8}"
    )
    for target in args.particles:
        scene, sample = refined_scene(target)
        mpm = time_mpm(scene, sample, registry, args.frames)
        scale = DATA_GRID / scene.domain.grid
        fast, fast_stride = learned_model("fast", registry, scale)
        reference, _ = learned_model("reference", registry, scale)
        grid, grid_stride = learned_model("grid", registry, scale)
        fast_frame = time_learned(fast, sample, args.repeats) / fast_stride
        grid_frame = time_learned(grid, sample, args.repeats) / grid_stride
        reference_frame = time_learned(reference, sample, args.repeats)
        row = {
            "particles": sample.num_particles,
            "grid": scene.domain.grid,
            "substeps": scene.time.substeps,
            "mpm_s_per_frame": mpm,
            "fast_s_per_frame": fast_frame,
            "grid_s_per_frame": grid_frame,
            "reference_s_per_frame": reference_frame,
        }
        rows.append(row)
        print(
            f"{row['particles']:>9} {row['grid']:>5} {row['substeps']:>8} {mpm:>12.4f} {fast_frame:>13.4f} "
            f"{grid_frame:>13.4f} {reference_frame:>12.4f} {mpm / fast_frame:>9.2f} {mpm / grid_frame:>9.2f} "
            f"{mpm / reference_frame:>8.2f}",
            flush=True,
        )
    if args.plot:
        plot(rows, args.plot)
    print(json.dumps({"threads": args.threads, "rows": rows}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
