"""The measuring parts of benchmarks/gpu_check.sh: the device, step time and peak memory by scene size and precision, the MPM.

Usage:
    python benchmarks/gpu_check.py info --device cuda
    python benchmarks/gpu_check.py scale --device cuda [--sizes 10000 100000 1000000] [--precisions ...] [--repeat 5]
    python benchmarks/gpu_check.py mpm --device cuda [--grid 96] [--frames 10]
    python benchmarks/gpu_check.py data OUT_FOLDER          # the small synthetic dataset the CLI parts train on

Every figure is one line ``gpu_check: <part> key=value ...`` on stdout (format in
docs/performance.md). ``scale`` times the paper's model (latent 128, 10 steps) on
the 3D lattice benchmark scene (~20 neighbours per particle): one rollout step
(inference) and one training step (noise, forward, loss, backward, Adam), each the
median of ``--repeat`` after one warm-up, with the device synchronised around every
timed step. Peak memory is ``torch.cuda.max_memory_allocated`` during the step
(on the CPU: the process's peak resident size). A case that runs out of GPU
memory is reported ``status=oom`` and retried for training with
``recompute_activations``; it is a measurement, not a failure. Cases not
started within ``--budget-s`` are reported ``status=over_budget``.
"""

from __future__ import annotations

import argparse
import resource
import statistics
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from lattice_scene import lattice_scene  # noqa: E402

from gns_framework.assembly.learned import build_learned_simulator  # noqa: E402
from gns_framework.config.recipe import ModelSpec, OptimizerSpec  # noqa: E402
from gns_framework.model.loss import masked_acceleration_loss  # noqa: E402
from gns_framework.model.noise import random_walk_noise  # noqa: E402
from gns_framework.plugins import load_registry  # noqa: E402
from gns_framework.runtime.activation_memory import set_recompute_activations  # noqa: E402
from gns_framework.runtime.precision import PRECISIONS, autocast, backward_precision  # noqa: E402
from gns_framework.training.optim import make_optimizer  # noqa: E402
from gns_framework.training.trainer import synchronize  # noqa: E402


def emit(part: str, **figures) -> None:
    """One output line: ``gpu_check: <part> key=value ...`` (floats with 4 significant digits)."""
    text = " ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in figures.items())
    print(f"gpu_check: {part} {text}", flush=True)


def peak_bytes(device: torch.device) -> int:
    if device.type == "cuda":
        return torch.cuda.max_memory_allocated(device)
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def info(args) -> None:
    device = torch.device(args.device)
    if device.type == "cuda":
        if not torch.cuda.is_available():
            raise SystemExit("gpu_check: --device cuda but torch sees no GPU")
        props = torch.cuda.get_device_properties(device)
        emit("device", name=props.name.replace(" ", "_"), count=torch.cuda.device_count(),
             memory_gb=props.total_memory / 2**30, capability=f"{props.major}.{props.minor}",
             torch=torch.__version__, cuda=torch.version.cuda)
    else:
        emit("device", name="cpu", threads=torch.get_num_threads(), torch=torch.__version__)


def _timed(step, device: torch.device, repeat: int) -> tuple[float, int]:
    """Median seconds of ``step`` after one warm-up, and the peak memory of the timed steps."""
    step()
    synchronize(device)
    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats(device)
    seconds = []
    for _ in range(repeat):
        synchronize(device)
        started = time.perf_counter()
        step()
        synchronize(device)
        seconds.append(time.perf_counter() - started)
    return statistics.median(seconds), peak_bytes(device)


def _case(particles: int, precision: str, phase: str, device: torch.device, repeat: int, recompute: bool) -> dict:
    scene = lattice_scene(particles, dim=3)
    torch.manual_seed(0)
    simulator = build_learned_simulator(scene.scene, scene.metadata, ModelSpec(), load_registry()).to(device)
    batch = scene.batch.to(device)
    mask = simulator.predicted_mask(batch.particle_type)
    set_recompute_activations(recompute)
    if device.type == "cuda":
        torch.cuda.empty_cache()
        torch.cuda.reset_peak_memory_stats(device)
    base = peak_bytes(device)
    edges = int(simulator.build_graph(batch.position_sequence, batch).num_edges)

    if phase == "rollout":
        def step():
            with torch.inference_mode(), autocast(precision, device):
                simulator.predict_next_position(batch)
    else:
        optimizer, scheduler = make_optimizer(simulator.parameters(), OptimizerSpec(), total_steps=1)
        generator = torch.Generator().manual_seed(0)

        def step():
            noise = random_walk_noise(scene.batch.position_sequence, 6.7e-4, generator).to(device) * mask[:, None, None]
            with autocast(precision, device):
                prediction, target = simulator(batch, noise)
            loss = masked_acceleration_loss(prediction.to(target.dtype), target, mask)
            optimizer.zero_grad(set_to_none=True)
            with backward_precision(precision, device):
                loss.backward()
            optimizer.step()
            scheduler.step()

    seconds, peak = _timed(step, device, repeat)
    return {"edges": edges, "step_s": seconds, "peak_gb": peak / 2**30,
            "bytes_per_edge": (peak - base) / max(edges, 1) if device.type == "cuda" else "n/a"}


def scale(args) -> None:
    device = torch.device(args.device)
    started = time.perf_counter()
    for particles in args.sizes:
        repeat = args.repeat if particles < 500_000 else max(1, args.repeat // 3)
        for precision in args.precisions:
            for phase in ("rollout", "train"):
                for recompute in (False, True) if phase == "train" else (False,):
                    label = dict(particles=particles, precision=precision, phase=phase,
                                 memory="recompute" if recompute else "stored")
                    if time.perf_counter() - started > args.budget_s:
                        emit("step", **label, status="over_budget")
                        continue
                    try:
                        figures = _case(particles, precision, phase, device, repeat, recompute)
                    except torch.OutOfMemoryError:
                        emit("step", **label, status="oom")
                        continue
                    finally:
                        set_recompute_activations(False)
                        if device.type == "cuda":
                            torch.cuda.empty_cache()
                    emit("step", **label, status="ok", **figures)
                    if phase == "train" and not recompute:
                        break  # stored activations fit: the recompute mode only when they do not


def mpm(args) -> None:
    """Seconds per frame of the 3D sand column on a ``--grid``-cell-wide grid (particles grow as grid^3), on ``--device``."""
    from scene_builders import column_collapse_3d

    from gns_framework.assembly.ground_truth import build_ground_truth_simulator as build_ground_truth
    from gns_framework.ground_truth.scene_spec import parse_scene

    raw = column_collapse_3d()
    raw["simulator"] = {"name": "mls_mpm", "device": args.device}
    raw["time"]["frames"] = args.frames
    # Cells of 1/grid the box, particles with them, and substeps shortened with the cells (CFL).
    base_grid = raw["domain"]["grid"]
    raw["domain"]["grid"] = args.grid
    raw["time"]["substeps"] = -(-raw["time"]["substeps"] * args.grid // base_grid)
    scene = parse_scene(raw)
    simulator = build_ground_truth(scene, load_registry(), "<gpu_check>")
    simulator.simulate(scene, seed=0)  # kernel build and first launches
    started = time.perf_counter()
    trajectory = simulator.simulate(scene, seed=0)
    seconds = time.perf_counter() - started
    finite = bool(torch.isfinite(torch.from_numpy(trajectory.position)).all())
    emit("mpm", particles=trajectory.num_particles, frames=args.frames, substeps=scene.time.substeps,
         s_per_frame=seconds / args.frames, finite=finite)
    if not finite:
        raise SystemExit("gpu_check: the MPM produced non-finite positions")


def data(args) -> None:
    from synthetic import write_synthetic_dataset

    write_synthetic_dataset(Path(args.out), train=2, valid=1, test=1, kinematic_floor=True, frames=20)
    emit("data", path=args.out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    for name in ("info", "scale", "mpm"):
        command = sub.add_parser(name)
        command.add_argument("--device", default="cuda")
    sub.choices["scale"].add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000, 1_000_000])
    sub.choices["scale"].add_argument("--precisions", nargs="+", choices=PRECISIONS, default=list(PRECISIONS))
    sub.choices["scale"].add_argument("--repeat", type=int, default=5)
    sub.choices["scale"].add_argument("--budget-s", type=float, default=1e9,
                                      help="cases not started within this many seconds are reported status=over_budget")
    sub.choices["mpm"].add_argument("--frames", type=int, default=10)
    sub.choices["mpm"].add_argument("--grid", type=int, default=96, help="grid cells along the box (24: 768 particles)")
    sub.add_parser("data").add_argument("out")
    args = parser.parse_args()
    {"info": info, "scale": scale, "mpm": mpm, "data": data}[args.command](args)


if __name__ == "__main__":
    main()
