"""Friction of an inclined plane in the MLS-MPM ground truth: where does a sand block start to slide?

Usage: python benchmarks/inclined_plane.py [--friction 0.5] [--angles 20 33] [--dim 2]

A block of sand rests on a plane obstacle of Coulomb coefficient mu tilted
by theta. Its internal friction is high (tan(phi) = 3) so that it slides on
its base rather than shearing inside (a Drucker-Prager block of tan(phi) = 1
already flows at 24 degrees in plane strain). A rigid block stays for
tan(theta) <= mu and slides with acceleration g (sin theta - mu cos theta)
above it, so the analytical threshold is atan(mu). The script scans theta in
1-degree steps and prints the block's mean downhill speed over the last
0.1 s of 0.6 s against the rigid block's, then the measured threshold: the
first angle whose block still moves faster than 2 cm/s (a block that holds
only settles by a few millimetres into the staircase of grid nodes, then
stops). Each run is 160 particles (2D) for 2,400 substeps: seconds on a CPU.
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from gns_framework.assembly.ground_truth import build_ground_truth_simulator
from gns_framework.ground_truth.scene_spec import parse_scene
from gns_framework.plugins import load_registry

G = 9.81
DURATION = 0.6
"""Seconds of simulated time per run."""
WINDOW = 0.1
"""Seconds at the end over which the sliding speed is measured."""
SLIDING_SPEED = 0.02
"""m/s: a block moving faster than this at the end slides (a rigid one reaches 0.05 m/s 1 degree past the threshold)."""
SAND_FRICTION = 3.0
"""tan(phi) of the block: high, so that it slides on its base instead of shearing inside."""


def block_on_plane(angle: float, friction: float, dim: int = 2) -> dict:
    """Scene: a 0.1 m x 0.04 m sand block lying on a plane through (0.3, 0.2) tilted by ``angle`` degrees.

    The plane rises along +x, so the block slides towards -x. dx = 10 mm; in 3D
    the block is 0.06 m deep between slip walls.
    """
    theta = math.radians(angle)
    size = np.array([0.1, 0.04])
    point = np.array([0.3, 0.2])
    centre = point + size[1] / 2 * np.array([-math.sin(theta), math.cos(theta)])
    lower = centre - size / 2
    frames = round(DURATION / 0.01) + 1
    bounds = [[0.0, 0.6], [0.0, 0.45]]
    position, extent = list(lower), list(size)
    walls = {}
    if dim == 3:
        bounds.append([0.0, 0.1])
        position.append(0.02)
        extent.append(0.06)
        walls = {"z_min": "slip", "z_max": "slip"}
    return {
        "name": f"block_on_plane_{angle:g}deg",
        "dim": dim,
        "domain": {"bounds": bounds, "grid": 60, "walls": walls},
        "time": {"frame_dt": DURATION / (frames - 1), "substeps": 40, "frames": frames},
        "jitter": 0.0,
        "blocks": [
            {
                "material": "sand",
                "position": position,
                "size": extent,
                "angle": angle,
                "parameters": {"friction": SAND_FRICTION},
            }
        ],
        "obstacles": [
            {
                "material": "rigid",
                "shape": "plane",
                "position": [*point, 0.05][:dim],
                "angle": angle,
                "friction": friction,
            }
        ],
    }


def sliding_speed(angle: float, friction: float, registry, dim: int = 2) -> float:
    """Mean downhill speed of the block over the last ``WINDOW`` s of ``DURATION``, m/s."""
    scene = parse_scene(block_on_plane(angle, friction, dim))
    trajectory = build_ground_truth_simulator(scene, registry, "<inclined plane>").simulate(scene, 0)
    sand = trajectory.particle_type != 3
    frames = round(WINDOW / scene.time.frame_dt)
    moved = trajectory.position[-1, sand, :2].mean(0) - trajectory.position[-1 - frames, sand, :2].mean(0)
    theta = math.radians(angle)
    return float(-(moved @ np.array([math.cos(theta), math.sin(theta)]))) / WINDOW


def rigid_block_speed(angle: float, friction: float) -> float:
    """Analytical speed of a rigid block at the middle of the window: g (sin - mu cos) t, or 0 when it holds."""
    theta = math.radians(angle)
    return max(0.0, G * (math.sin(theta) - friction * math.cos(theta))) * (DURATION - WINDOW / 2)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--friction", type=float, default=0.5, help="Coulomb coefficient mu of the plane")
    parser.add_argument("--angles", type=float, nargs=2, default=(20.0, 33.0), help="first and last angle, degrees")
    parser.add_argument("--dim", type=int, default=2, choices=(2, 3))
    args = parser.parse_args()
    registry = load_registry()
    analytical = math.degrees(math.atan(args.friction))
    print(f"plane mu = {args.friction}: analytical threshold atan(mu) = {analytical:.2f} deg")
    print(f"{'angle':>6} {'MPM m/s':>9} {'rigid block m/s':>16}  state")
    first_slide = None
    for angle in np.arange(args.angles[0], args.angles[1] + 0.5, 1.0):
        speed = sliding_speed(float(angle), args.friction, registry, args.dim)
        state = "slides" if speed > SLIDING_SPEED else "stays"
        print(f"{angle:6.1f} {speed:9.4f} {rigid_block_speed(angle, args.friction):16.4f}  {state}")
        if state == "slides" and first_slide is None:
            first_slide = float(angle)
    if first_slide is None:
        print("no angle in the range slides")
    else:
        print(
            f"measured threshold: between {first_slide - 1:g} and {first_slide:g} deg "
            f"(analytical {analytical:.2f} deg; midpoint off by {first_slide - 0.5 - analytical:+.1f} deg)"
        )


if __name__ == "__main__":
    main()
