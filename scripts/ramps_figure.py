"""Draw frames of the ramps scenes for docs/ground_truth.md.

Usage: python scripts/ramps_figure.py [--out docs/images/ground_truth_ramps.png] [--seed 1]

Simulates one trajectory of scenes/sand_ramps_2d.yaml (two seeds),
scenes/water_ramps_2d.yaml and scenes/sand_ramps_3d.yaml (seen from the
front, x-y) on the CPU and draws four frames of each: the ramps are the
recorded kinematic boundary particles (grey). About 15 s on 2 cores.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from gns_framework.assembly.ground_truth import build_ground_truth_simulator
from gns_framework.ground_truth.scene_spec import load_scene
from gns_framework.plugins import load_registry

ROOT = Path(__file__).resolve().parents[1]
COLOURS = {3: "0.45", 5: "tab:blue", 6: "goldenrod"}
"""Particle type -> colour: boundary, water, sand."""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "images" / "ground_truth_ramps.png")
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    registry = load_registry()
    runs = [
        ("sand_ramps_2d", args.seed),
        ("sand_ramps_2d", args.seed + 1),
        ("water_ramps_2d", args.seed),
        ("sand_ramps_3d", args.seed),
    ]
    times = (0.0, 0.2, 0.4, 0.6)
    fig, axes = plt.subplots(len(runs), len(times), figsize=(2.4 * len(times), 2.4 * len(runs)))
    for row, (name, seed) in zip(axes, runs, strict=True):
        scene = load_scene(ROOT / "scenes" / f"{name}.yaml")
        trajectory = build_ground_truth_simulator(scene, registry, name).simulate(scene, seed)
        bounds = np.array(scene.domain.bounds)
        for ax, t in zip(row, times, strict=True):
            frame = min(round(t / scene.time.frame_dt), scene.time.frames - 1)
            position = trajectory.position[frame]
            for kind, colour in COLOURS.items():
                mine = trajectory.particle_type == kind
                ax.scatter(
                    position[mine, 0], position[mine, 1], s=0.6 if scene.dim == 2 else 0.2, c=colour, linewidths=0
                )
            ax.set_xlim(*bounds[0])
            ax.set_ylim(*bounds[1])
            ax.set_aspect("equal")
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_title(f"{name} seed {seed}\nt = {frame * scene.time.frame_dt:.2f} s", fontsize=7)
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
