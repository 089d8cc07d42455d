"""Dam break of the MLS-MPM water against Martin & Moyce (1952) and Ritter's solution, with and without viscosity.

Usage: python benchmarks/dam_break.py [--viscosity 0 1e-3 0.1 1] [--cells 20] [--floor no_slip|slip]
           [--plot docs/images/ground_truth_dam_break.png] [--runup]

Martin & Moyce's column of width a = 2.25 in (0.05715 m) and height 2a
(n^2 = 2) collapses along a dry floor; their Table 2 gives the surge front
Z = z / a against T = n t sqrt(g / a) = t sqrt(2 g / a). The same column runs
here in 2D with ``--cells`` cells across a (default 20, dx = 2.9 mm), slip
side walls and lid, and a ``--floor`` that is no-slip (default) or slip.
Printed: the front Z(T) of each viscosity (the 99.5th percentile of x, so
one stray particle does not count) beside the experiment and Ritter's
shallow-water front Z = 1 + 2 T (the column is not shallow: Ritter overshoots).
Then Ritter's own case, a shallow reservoir (0.4 m long, 0.05 m deep) on a
frictionless bed: the depth at the dam site, which Ritter holds at 4/9 of the
initial depth until the rarefaction returns from the back wall, and the depth
profile at t = 0.3 s (drawn in the figure's right panel).
``--runup`` prints instead how high the water of scenes/water_dam_break_2d.yaml
climbs the far wall. A few seconds per viscosity on a CPU.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from gns_framework.assembly.ground_truth import build_ground_truth_simulator
from gns_framework.ground_truth.scene_spec import load_scene, parse_scene
from gns_framework.plugins import load_registry

G = 9.81
A = 0.05715
"""Column width, metres (2.25 in); the height is 2 a."""
MARTIN_MOYCE_T = np.array([0.41, 0.84, 1.19, 1.43, 1.63, 1.83, 1.98, 2.20, 2.32, 2.51, 2.65, 2.83, 2.98, 3.11, 3.33])
MARTIN_MOYCE_Z = np.array([1.11, 1.22, 1.44, 1.67, 1.89, 2.11, 2.33, 2.56, 2.78, 3.00, 3.22, 3.44, 3.67, 3.89, 4.11])
"""Martin & Moyce (1952), Phil. Trans. R. Soc. A 244, Table 2: surge front of the a = 2.25 in, n^2 = 2 column."""
TIME_SCALE = np.sqrt(2 * G / A)
"""T = t * TIME_SCALE (1/s)."""


def dam_break(viscosity: float, cells: int, floor: str) -> dict:
    """The Martin & Moyce column in a 7a x 3a tank, ``cells`` cells across a, run to T = 3.5."""
    dx = A / cells
    frame_dt = 0.1 / TIME_SCALE  # frames every 0.1 in T
    wave_speed = 21.6  # m/s, the Tait sound speed at 10 % compression (K = 2e5 Pa)
    limits = [0.5 * dx / wave_speed] + ([1000 * dx**2 / (4 * viscosity)] if viscosity > 0 else [])
    return {
        "name": f"martin_moyce_eta_{viscosity:g}",
        "dim": 2,
        "domain": {
            "bounds": [[0.0, 7 * A], [0.0, 3 * A]],
            "grid": 7 * cells,
            "walls": {"x_min": "slip", "x_max": "slip", "y_min": floor, "y_max": "slip"},
        },
        "time": {"frame_dt": frame_dt, "substeps": int(np.ceil(frame_dt / min(limits))), "frames": 36},
        "jitter": 0.0,
        "blocks": [
            {"material": "water", "position": [0.0, 0.0], "size": [A, 2 * A], "parameters": {"viscosity": viscosity}}
        ],
    }


def run(viscosity: float, cells: int, floor: str, registry) -> tuple[np.ndarray, np.ndarray]:
    """(T, Z front), one value per frame."""
    scene = parse_scene(dam_break(viscosity, cells, floor))
    position = build_ground_truth_simulator(scene, registry, "<dam break>").simulate(scene, 0).position
    T = np.arange(scene.time.frames) * scene.time.frame_dt * TIME_SCALE
    return T, np.quantile(position[:, :, 0], 0.995, axis=1) / A


RITTER_H0, RITTER_L = 0.05, 0.4
"""Shallow reservoir of Ritter's comparison: depth h0 and length L = 8 h0, metres."""


def ritter_depth(x: np.ndarray, t: float) -> np.ndarray:
    """Ritter (1892): depth over a dry frictionless bed after the dam at x = L is removed, for an endless reservoir.

    h = h0 upstream of the rarefaction x < L - c t, (2 c - (x - L) / t)^2 / (9 g) up to the front
    x = L + 2 c t, and 0 beyond; c = sqrt(g h0).
    """
    c = np.sqrt(G * RITTER_H0)
    xi = np.clip((x - RITTER_L) / t, -c, 2 * c)
    depth = (2 * c - xi) ** 2 / (9 * G)
    return np.where((x - RITTER_L) / t > 2 * c, 0.0, depth)


def ritter_run(viscosity: float, registry, cells: int = 10) -> tuple[np.ndarray, np.ndarray, float]:
    """(x bin centres, MPM surface height) at ``RITTER_TIME`` and the mean depth at the dam site over
    [0.15, 0.45] s, before the rarefaction comes back from the far wall; frictionless bed, ``cells`` across h0."""
    dx = RITTER_H0 / cells
    frame_dt = 0.01
    scene = parse_scene(
        {
            "name": "ritter",
            "dim": 2,
            "domain": {
                "bounds": [[0.0, 4 * RITTER_L], [0.0, 2 * RITTER_H0]],
                "grid": round(4 * RITTER_L / dx),
                "wall_friction": 0.0,
            },
            "time": {"frame_dt": frame_dt, "substeps": int(np.ceil(frame_dt / (0.5 * dx / 21.6))), "frames": 46},
            "jitter": 0.0,
            "blocks": [
                {
                    "material": "water",
                    "position": [0.0, 0.0],
                    "size": [RITTER_L, RITTER_H0],
                    "parameters": {"viscosity": viscosity},
                }
            ],
        }
    )
    position = build_ground_truth_simulator(scene, registry, "<ritter>").simulate(scene, 0).position
    times = np.arange(scene.time.frames) * frame_dt

    def surface(frame: int, centres: np.ndarray) -> np.ndarray:
        """Height of the top particle in each bin plus half a particle spacing (particles are cell centres)."""
        x, y = position[frame, :, 0], position[frame, :, 1]
        tops = [y[np.abs(x - c) < dx] for c in centres]
        return np.array([top.max() + scene.particle_spacing / 2 if top.size else 0.0 for top in tops])

    at_dam = np.array([surface(f, np.array([RITTER_L]))[0] for f in range(scene.time.frames)])
    window = (times >= 0.15) & (times <= 0.45)
    centres = np.arange(0.5 * dx, 4 * RITTER_L, 2 * dx)
    return centres, surface(round(RITTER_TIME / frame_dt), centres), float(at_dam[window].mean())


RITTER_TIME = 0.3
"""Seconds after the release at which the depth profile is compared."""


def runup(viscosity: float, floor: str, registry) -> float:
    """Highest rise of water on the far wall of scenes/water_dam_break_2d.yaml (0.2 x 0.4 m column, 1 m tank),
    metres: the 99.5th percentile height of the particles within 5 cm of the wall, over 0.75 s; 1 m is the lid.
    0 when the water never reaches the wall within the scene's frames (a scene cut short)."""
    scene = load_scene(Path(__file__).resolve().parents[1] / "scenes" / "water_dam_break_2d.yaml")
    raw = scene.model_dump(mode="json", exclude_none=True)
    raw["blocks"][0].update(size=[0.2, 0.4], parameters={"viscosity": viscosity})
    raw["domain"]["walls"] = {"y_min": floor}
    raw["time"]["substeps"] = 40
    position = (
        build_ground_truth_simulator(parse_scene(raw), registry, "<runup>").simulate(parse_scene(raw), 0).position
    )
    near = position[:, :, 0] > raw["domain"]["bounds"][0][1] - 0.05
    return max(
        (float(np.quantile(y[m], 0.995)) for y, m in zip(position[:, :, 1], near, strict=True) if m.sum() > 5),
        default=0.0,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--viscosity",
        type=float,
        nargs="+",
        default=[0.0, 1e-3, 0.1, 1.0],
        help="dynamic viscosities to run, Pa s (water: 1e-3)",
    )
    parser.add_argument("--cells", type=int, default=20, help="grid cells across the column width a")
    parser.add_argument(
        "--floor",
        choices=("no_slip", "slip"),
        default="no_slip",
        help="floor of the Martin & Moyce tank (default no_slip, a real floor)",
    )
    parser.add_argument("--plot", type=Path, help="write the figure (front positions, Ritter profile) to this PNG")
    parser.add_argument(
        "--runup",
        action="store_true",
        help="only print the run-up on the far wall of scenes/water_dam_break_2d.yaml per viscosity, "
        "with a slip and a no-slip floor",
    )
    args = parser.parse_args()
    registry = load_registry()
    if args.runup:
        print(f"{'eta Pa s':>9} {'slip floor m':>13} {'no-slip floor m':>16}   (run-up on the far wall; lid at 1 m)")
        for eta in args.viscosity:
            print(f"{eta:9g} {runup(eta, 'slip', registry):13.3f} {runup(eta, 'no_slip', registry):16.3f}")
        return
    runs = {eta: run(eta, args.cells, args.floor, registry) for eta in args.viscosity}
    header = "".join(f"{f'eta {eta:g}':>10}" for eta in runs)
    print(f"Martin & Moyce column, {args.cells} cells across a, {args.floor} floor; front Z = z / a")
    print(f"{'T':>5} {'Martin&Moyce':>13} {'Ritter':>7}{header}")
    for t, z in zip(MARTIN_MOYCE_T, MARTIN_MOYCE_Z, strict=True):
        row = "".join(f"{np.interp(t, T, front):10.2f}" for T, front in runs.values())
        print(f"{t:5.2f} {z:13.2f} {1 + 2 * t:7.2f}{row}")
    for eta, (T, front) in runs.items():
        error = (np.interp(MARTIN_MOYCE_T, T, front) - MARTIN_MOYCE_Z) / MARTIN_MOYCE_Z
        print(
            f"eta {eta:g} Pa s: front vs Martin & Moyce mean {100 * error.mean():+.1f} %, "
            f"largest {100 * error[np.argmax(np.abs(error))]:+.1f} %"
        )
    centres, surface, at_dam = ritter_run(args.viscosity[0], registry)
    exact = ritter_depth(centres, RITTER_TIME)
    c = np.sqrt(G * RITTER_H0)
    # Ritter holds away from the tip, where the flow is shallow and resistance has not acted: up to 3/4 of the way.
    fan = (centres > RITTER_L - c * RITTER_TIME) & (centres < RITTER_L + 1.5 * c * RITTER_TIME)
    print(
        f"Ritter, h0 = {RITTER_H0} m, reservoir {RITTER_L} m, frictionless, eta {args.viscosity[0]:g}: "
        f"depth at the dam site {at_dam / RITTER_H0:.3f} h0 (Ritter 4/9 = {4 / 9:.3f}); at t = {RITTER_TIME} s "
        f"the surface in the rarefaction fan is off by {100 * np.abs(surface - exact)[fan].mean() / RITTER_H0:.1f} % "
        f"of h0 on average"
    )
    if args.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, (ax, bx) = plt.subplots(1, 2, figsize=(10, 4))
        ax.plot(MARTIN_MOYCE_T, MARTIN_MOYCE_Z, "ko", label="Martin & Moyce 1952 (a = 2.25 in, n² = 2)")
        t = np.linspace(0, 3.5, 50)
        ax.plot(t, 1 + 2 * t, "k--", lw=1, label="Ritter: Z = 1 + 2T")
        for eta, (T, front) in runs.items():
            ax.plot(T, front, label=f"MPM, η = {eta:g} Pa s")
        ax.set_xlabel("T = t √(2g/a)")
        ax.set_ylabel("Z = front / a")
        ax.set_xlim(0, 3.5)
        ax.set_ylim(1, 6)
        ax.legend(fontsize=7)
        ax.set_title(f"Surge front, {args.cells} cells across a, {args.floor} floor", fontsize=9)
        bx.plot(centres, exact, "k--", lw=1, label="Ritter")
        bx.plot(centres, surface, label=f"MPM, η = {args.viscosity[0]:g} Pa s")
        bx.set_xlim(0, 4 * RITTER_L)
        bx.set_xlabel("x (m), dam at 0.4 m")
        bx.set_ylabel("depth (m)")
        bx.legend(fontsize=7)
        bx.set_title(f"Depth at t = {RITTER_TIME} s, reservoir {RITTER_L} m x {RITTER_H0} m, frictionless", fontsize=9)
        fig.tight_layout()
        args.plot.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(args.plot, dpi=110)
        print(f"wrote {args.plot}")


if __name__ == "__main__":
    main()
