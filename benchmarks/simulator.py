"""Time the MLS-MPM ground truth on the example scenes and check that a seed gives the same bits.

Usage: python benchmarks/simulator.py [--device cpu|cuda] [--scenes sand_collapse_2d ...]

Prints wall time and process CPU time per scene (CPU time is what a shared
machine cannot steal) after a warm-up run that compiles the kernels, and
whether two runs with one seed agree bit for bit. Reference figures (issue 4,
2 cores): 2D sand 2,048 particles, 80^2 grid, 300 x 40 steps ~4 s; 2D water
dam break ~3 s; 3D sand 4,608 particles, 40^3 grid, 300 x 20 steps ~27 s.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from gns_framework.assembly.ground_truth import build_ground_truth_simulator
from gns_framework.config.recipe import ComponentSpec
from gns_framework.ground_truth.scene_spec import load_scene
from gns_framework.plugins import load_registry

SCENES = Path(__file__).resolve().parents[1] / "scenes"
DEFAULT = ["sand_collapse_2d", "water_dam_break_2d", "sand_collapse_3d"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--scenes", nargs="+", default=DEFAULT)
    args = parser.parse_args()
    registry = load_registry()
    print(f"{'scene':<22} {'particles':>9} {'grid':>5} {'steps':>9} {'wall s':>7} {'cpu s':>7} {'bitwise':>8}")
    for name in args.scenes:
        path = SCENES / f"{name}.yaml"
        scene = load_scene(path)
        chosen = ComponentSpec(name=scene.simulator.name, **{**scene.simulator.params, "device": args.device})
        scene = scene.model_copy(update={"simulator": chosen})
        simulator = build_ground_truth_simulator(scene, registry, path)
        short = scene.model_copy(update={"time": scene.time.model_copy(update={"frames": 3})})
        simulator.simulate(short, 0)  # compiles (or loads) the kernels
        wall, cpu = time.perf_counter(), time.process_time()
        first = simulator.simulate(scene, 0)
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
        same = simulator.simulate(scene, 0).position.tobytes() == first.position.tobytes()
        steps = f"{scene.time.frames}x{scene.time.substeps}"
        print(
            f"{name:<22} {first.num_particles:>9} {scene.domain.grid:>5} {steps:>9} {wall:>7.1f} {cpu:>7.1f} "
            f"{'yes' if same else 'NO':>8}",
            flush=True,
        )


if __name__ == "__main__":
    main()
