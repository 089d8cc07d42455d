"""The interaction network's edge block as Triton kernels against the chunked torch path, in one run, on one device.

Usage:
    python benchmarks/edge_kernels.py [--device cuda] [--sizes 10000 100000] [--precisions float32 bfloat16]
                                      [--repeat 5] [--profile-rows 15] [--small]

For each scene size and precision, one rollout step (inference) and one training step
(forward, loss, backward) of the paper's model (latent 128, 10 steps) on the 3D lattice
scene, with the kernels (``triton``) and without (``GNS_TRITON=0``: ``chunked``),
interleaved repeat by repeat; the median times, the speed-up, and the largest
difference of the predicted accelerations between the two paths relative to their
largest magnitude. Then: whether two training steps with the kernels give the same
gradients bit for bit (sums in a fixed order), and a torch.profiler table of one
rollout step per path at the first size (top kernels by device time, kernels per step).

Output: ``gpu_check: kernels ...`` lines (benchmarks/gpu_check.sh runs this as its
``kernels`` part; docs/performance.md reads them). On the CPU the kernels run only
under Triton's interpreter (``TRITON_INTERPRET=1``, set before triton is imported):
with ``--small`` (latent 16, 2 steps, 150 particles) that checks the script runs; the
figures mean nothing there.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from contextlib import contextmanager
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from gpu_check import emit, left, part_deadline, skipped

PATHS = ("chunked", "triton")


@contextmanager
def edge_path(path: str):
    """The edge block's implementation while inside: ``chunked`` sets ``GNS_TRITON=0``, ``triton`` unsets it
    (``interpret`` on the CPU)."""
    before = os.environ.get("GNS_TRITON")
    os.environ["GNS_TRITON"] = "0" if path == "chunked" else os.environ.get("GNS_EDGE_KERNELS_TRITON", "")
    try:
        yield
    finally:
        if before is None:
            os.environ.pop("GNS_TRITON", None)
        else:
            os.environ["GNS_TRITON"] = before


class Case:
    """The paper's model (or a small one) on a lattice scene: one rollout step, one training step's gradients."""

    def __init__(self, particles: int, precision: str, device, small: bool):
        import torch
        from lattice_scene import lattice_scene

        from gns_framework.assembly.learned import build_learned_simulator
        from gns_framework.config.recipe import ModelSpec
        from gns_framework.model.loss import masked_acceleration_loss
        from gns_framework.model.noise import random_walk_noise
        from gns_framework.plugins import load_registry
        from gns_framework.runtime.precision import autocast, backward_precision

        scene = lattice_scene(particles, dim=3)
        spec = ModelSpec()
        if small:
            spec = ModelSpec(
                latent_size=16,
                mlp_hidden_size=16,
                processor={"name": "interaction_network", "message_passing_steps": 2},
            )
        torch.manual_seed(0)
        self.device = device
        self.simulator = build_learned_simulator(scene.setup, scene.metadata, spec, load_registry()).to(device)
        self.batch = scene.batch.to(device)
        self.mask = self.simulator.predicted_mask(self.batch.particle_type)
        generator = torch.Generator().manual_seed(0)
        self.noise = random_walk_noise(scene.batch.position_sequence, 6.7e-4, generator).to(device)
        self.noise = self.noise * self.mask[:, None, None]
        self.autocast = lambda: autocast(precision, device)
        self.backward_precision = lambda: backward_precision(precision, device)
        self.loss = masked_acceleration_loss

    def edges(self) -> int:
        import torch

        with torch.no_grad():
            return int(self.simulator.build_graph(self.batch.position_sequence, self.batch).num_edges)

    def rollout(self):
        """One rollout step's predicted accelerations."""
        import torch

        with torch.inference_mode(), self.autocast():
            return self.simulator.predict_next_position(self.batch)

    def train(self):
        """One training step's parameter gradients (noise fixed), as one flat float32 tensor."""
        import torch

        self.simulator.zero_grad(set_to_none=True)
        with self.autocast():
            prediction, target = self.simulator(self.batch, self.noise)
        loss = self.loss(prediction.to(target.dtype), target, self.mask)
        with self.backward_precision():
            loss.backward()
        return torch.cat([p.grad.float().reshape(-1) for p in self.simulator.parameters() if p.grad is not None])


def timed(function, device) -> float:
    from gns_framework.runtime.device import synchronize

    synchronize(device)
    started = time.perf_counter()
    function()
    synchronize(device)
    return time.perf_counter() - started


def compare(case: Case, phase: str, repeat: int, deadline: float, label: dict) -> None:
    """Median seconds of ``phase`` on both paths, interleaved, and how far their results are apart."""
    import torch

    step = case.rollout if phase == "rollout" else case.train
    results, seconds = {}, {path: [] for path in PATHS}
    for path in PATHS:  # warm-up: Triton compiles its kernels here
        with edge_path(path):
            warmup = timed(lambda p=path: results.__setitem__(p, step()), case.device)
    for _ in range(repeat):
        if left(deadline) < 3 * warmup:
            break
        for path in PATHS:
            with edge_path(path):
                seconds[path].append(timed(step, case.device))
    chunked, triton = results["chunked"].float(), results["triton"].float()
    scale = float(chunked.abs().max()) or 1.0
    times = {path: statistics.median(s) if s else float("nan") for path, s in seconds.items()}
    emit(
        "kernels",
        **label,
        phase=phase,
        repeats=len(seconds["triton"]),
        chunked_ms=1e3 * times["chunked"],
        triton_ms=1e3 * times["triton"],
        speedup=times["chunked"] / times["triton"],
        max_rel_diff=float((triton - chunked).abs().max()) / scale,
        finite=bool(torch.isfinite(triton).all()),
    )


def bitwise(case: Case, label: dict) -> None:
    """Two training steps with the kernels: the same gradients bit for bit (no atomics in their sums)."""
    import torch

    with edge_path("triton"):
        first, second = case.train(), case.train()
    emit("kernels_bitwise", **label, equal=bool(torch.equal(first, second)), values=first.numel())


def profile(case: Case, rows: int, label: dict) -> None:
    """The top kernels of one rollout step by device time, per path, and the number of kernels per step."""
    import torch
    from torch.profiler import ProfilerActivity
    from torch.profiler import profile as torch_profile

    on_cuda = case.device.type == "cuda"
    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if on_cuda else [])
    for path in PATHS:
        with edge_path(path):
            case.rollout()
            with torch_profile(activities=activities) as profiler:
                case.rollout()
                if on_cuda:
                    torch.cuda.synchronize()
        events = profiler.key_averages()
        time_of = (lambda e: e.self_device_time_total) if on_cuda else (lambda e: e.self_cpu_time_total)
        kernels = [e for e in events if (e.device_type.name == "CUDA") == on_cuda and time_of(e) > 0]
        total = sum(time_of(e) for e in kernels) or 1.0
        emit(
            "kernels_profile",
            **label,
            path=path,
            kernels_per_step=sum(e.count for e in kernels),
            device_ms=total / 1e3,
        )
        for rank, event in enumerate(sorted(kernels, key=time_of, reverse=True)[:rows], 1):
            name = event.key.replace(" ", "_")[:80]
            emit(
                "kernels_top",
                path=path,
                rank=rank,
                share=time_of(event) / total,
                ms=time_of(event) / 1e3,
                calls=event.count,
                name=name,
            )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cuda")
    parser.add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000])
    parser.add_argument("--precisions", nargs="+", default=["float32", "bfloat16"])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--profile-rows", type=int, default=15)
    parser.add_argument("--small", action="store_true", help="latent 16, 2 steps: checks the script runs")
    args = parser.parse_args()
    import torch

    device = torch.device(args.device)
    if device.type == "cuda" and not torch.cuda.is_available():
        skipped("no CUDA device")
    if device.type == "cpu":
        if os.environ.get("TRITON_INTERPRET") != "1":
            skipped("on the CPU the kernels run only under Triton's interpreter (TRITON_INTERPRET=1)")
        os.environ["GNS_EDGE_KERNELS_TRITON"] = "interpret"
    from gns_builtins._kernels import triton_edge_block

    if triton_edge_block.triton_module() is None:
        skipped("triton is not installed")
    deadline = part_deadline()
    for index, particles in enumerate(args.sizes):
        for precision in args.precisions:
            if left(deadline) < 5:
                emit("kernels", particles=particles, precision=precision, status="over_budget")
                continue
            case = Case(particles, precision, device, args.small)
            label = {"particles": particles, "edges": case.edges(), "precision": precision}
            for phase in ("rollout", "train"):
                if left(deadline) > 5:
                    compare(case, phase, args.repeat, deadline, label)
            if index == 0 and left(deadline) > 5:
                bitwise(case, label)
                if precision == args.precisions[0]:
                    profile(case, args.profile_rows, label)
            del case
            if device.type == "cuda":
                torch.cuda.empty_cache()


if __name__ == "__main__":
    main()
