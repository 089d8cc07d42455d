"""The measuring parts of benchmarks/gpu_check.sh: imports, the device, tests, DDP, node sums, step time and memory, the
MPM.

Usage:
    python benchmarks/gpu_check.py imports                  # import seconds; the registry lists the built-ins
    python benchmarks/gpu_check.py info --device cuda
    python benchmarks/gpu_check.py tests TEST_FILE...       # pytest, one line per test as it ends
    python benchmarks/gpu_check.py ddp --device cuda        # a real process group of one rank, DDP steps
    python benchmarks/gpu_check.py sums --device cuda [--rows 4194304]
    python benchmarks/gpu_check.py chunks --device cuda [--particles 10000]
    python benchmarks/gpu_check.py scale --device cuda [--sizes 10000 100000 1000000] [--precisions ...] [--repeat 5]
    python benchmarks/gpu_check.py mpm --device cuda [--grid 96] [--frames 10]
    python benchmarks/gpu_check.py data OUT_FOLDER          # the small synthetic dataset the CLI parts train on

Every figure is one line ``gpu_check: <part> key=value ...`` on stdout, printed (and
flushed) as soon as it is measured, so a part killed at its limit loses nothing it
printed (format in docs/performance.md). A part that cannot run here prints
``skipped: <why>`` and exits with :data:`SKIP` (77). gpu_check.sh gives every part
its time limit in ``GPU_CHECK_PART_LIMIT_S``; parts that loop (``scale``, ``sums``)
watch that deadline themselves, inside a case too, and report what did not fit as
``status=over_budget``.

``scale`` times the paper's model (latent 128, 10 steps) on the 3D lattice benchmark
scene (~20 neighbours per particle): one rollout step (inference) and one training
step (noise, forward, loss, backward, Adam), each the median of ``--repeat`` after one
warm-up, with the device synchronised around every timed step; then one more step
synchronised between its phases (graph build, forward, backward, optimizer). Peak
memory is ``torch.cuda.max_memory_allocated`` (on the CPU: the process's peak RSS).
On CUDA a case whose memory, predicted from the CPU table of bytes per edge
(docs/performance.md), exceeds the GPU's is reported ``status=predicted_oom`` and not
tried; at 1M particles the configuration expected to fit (bfloat16 + recompute) runs
first. One that runs out anyway is ``status=oom``: measurements, not failures.
"""

from __future__ import annotations

import time

STARTED = time.monotonic()  # before torch's import: the part's clock starts with the process

import argparse  # noqa: E402
import contextlib  # noqa: E402
import dataclasses  # noqa: E402
import importlib.util  # noqa: E402
import os  # noqa: E402
import resource  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402
from unittest import mock  # noqa: E402

SKIP = 77
"""Exit status of a part that cannot run here (it printed ``skipped: <why>``)."""
REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "benchmarks"))
sys.path.insert(0, str(REPO / "tests"))

CPU_BYTES_PER_EDGE = {
    ("rollout", "float32", "stored"): 2123,
    ("rollout", "tf32", "stored"): 2123,
    ("rollout", "bfloat16", "stored"): 1515,
    ("train", "float32", "stored"): 24108,
    ("train", "tf32", "stored"): 24108,
    ("train", "float32", "recompute"): 7713,
    ("train", "tf32", "recompute"): 7713,
    ("train", "bfloat16", "stored"): 15735,
    ("train", "bfloat16", "recompute"): 5016,
}
"""Peak bytes per edge measured on the CPU (docs/performance.md, benchmarks/memory_per_edge.py)."""
RESERVED_GIB = 4.0
"""CUDA context, model, Adam state and allocator slack, as the CPU table's "largest scene" assumes."""


def is_cuda(device) -> bool:
    """runtime.device.is_cuda, imported when first asked (the imports part times torch's import)."""
    from gns_framework.runtime.device import is_cuda as on_cuda

    return on_cuda(device)


def emit(part: str, **figures) -> None:
    """One output line: ``gpu_check: <part> key=value ...`` (floats with 4 significant digits), flushed."""
    text = " ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in figures.items())
    print(f"gpu_check: {part} {text}", flush=True)


def skipped(why: str) -> None:
    """End a part that cannot run here: one ``skipped: <why>`` line, exit status :data:`SKIP`."""
    print(f"skipped: {why}", flush=True)
    raise SystemExit(SKIP)


def part_deadline(margin_s: float = 5.0) -> float:
    """``time.monotonic()`` by which this part must have printed its last line (its limit less ``margin_s``)."""
    limit = float(os.environ.get("GPU_CHECK_PART_LIMIT_S", "1e9"))
    return STARTED + max(limit - margin_s, 1.0)


def left(deadline: float) -> float:
    return deadline - time.monotonic()


# --------------------------------------------------------------------------- imports, info, tests


def imports(args) -> None:
    """Seconds to import torch and the project and to discover the plugins; the built-ins must be there."""
    started = time.perf_counter()
    import torch

    torch_s = time.perf_counter() - started
    started = time.perf_counter()
    import gns_framework
    from gns_framework.plugins import load_registry

    registry = load_registry()
    project_s = time.perf_counter() - started
    import importlib.metadata

    distribution = importlib.metadata.distribution("gns-framework")
    entries = registry.entries()
    builtins = [e for e in entries if e.distribution == "gns-framework" and e.plugin.startswith("builtin-")]
    emit(
        "imports",
        torch=torch.__version__,
        torch_s=torch_s,
        gns_s=project_s,
        components=len(entries),
        builtins=len(builtins),
        kinds=len(registry.kinds()),
        gns_framework=Path(gns_framework.__file__).parent,
        dist_info=Path(str(distribution.locate_file(""))),
    )
    required = {
        "processor": "interaction_network",
        "graph_builder": "radius",
        "dataset": "safe",
        "integrator": "semi_implicit_euler",
        "simulator": "mls_mpm",
    }
    missing = [f"{kind}:{name}" for kind, name in required.items() if name not in registry.names(kind)]
    if missing:
        raise SystemExit(
            f"gpu_check: the registry lacks the built-ins {missing}: gns-framework's entry points are "
            "not installed (gpu_check.sh installs them from gpu_wheels/)"
        )
    import subprocess

    listed = subprocess.run([sys.executable, "-m", "gns_framework.cli", "plugins"], capture_output=True, text=True)
    if listed.returncode != 0 or "interaction_network" not in listed.stdout:
        raise SystemExit(f"gpu_check: `gns plugins` failed or lists no built-ins:\n{listed.stdout}{listed.stderr}")
    emit("imports", gns_plugins="ok", lines=len(listed.stdout.splitlines()) - 1)


def info(args) -> None:
    import torch

    device = torch.device(args.device)
    if is_cuda(device):
        if not torch.cuda.is_available():
            raise SystemExit("gpu_check: --device cuda but torch sees no GPU")
        props = torch.cuda.get_device_properties(device)
        emit(
            "device",
            name=props.name.replace(" ", "_"),
            count=torch.cuda.device_count(),
            memory_gb=props.total_memory / 2**30,
            capability=f"{props.major}.{props.minor}",
            torch=torch.__version__,
            cuda=torch.version.cuda,
            python=sys.version.split()[0],
        )
    else:
        emit(
            "device",
            name="cpu",
            threads=torch.get_num_threads(),
            torch=torch.__version__,
            python=sys.version.split()[0],
        )
    for module in ("pydantic", "warp", "mlflow", "geomloss", "torch_geometric", "pytest"):
        spec = importlib.util.find_spec(module)
        emit("module", name=module, present=spec is not None)


def tests(args) -> None:
    """pytest on ``args.files``; one ``gpu_check: test`` line per test as it ends, exit status pytest's."""
    if importlib.util.find_spec("pytest") is None:
        skipped("pytest is not installed here")
    import pytest

    class Lines:
        def pytest_runtest_logreport(self, report):
            if report.when == "call" or report.outcome != "passed":
                name = report.nodeid.split("::", 1)[-1].replace(" ", "_")
                emit("test", name=name, phase=report.when, outcome=report.outcome, seconds=float(report.duration))

    code = pytest.main(["-q", "-p", "no:cacheprovider", "-o", "addopts=", *args.files], plugins=[Lines()])
    raise SystemExit(int(code))


# --------------------------------------------------------------------------- ddp


def ddp(args) -> None:
    """A real process group of one rank (NCCL on CUDA, gloo on the CPU), DDP training steps and collectives."""
    import tempfile
    from datetime import timedelta

    import torch
    import torch.distributed as dist

    from gns_framework.training.distributed import backend_for, process_group_timeout

    device = torch.device(args.device)
    if is_cuda(device):
        if not torch.cuda.is_available():
            raise SystemExit("gpu_check: --device cuda but torch sees no GPU")
        if device.index is None:  # set_device and the group's device_id need an index
            device = torch.device("cuda", torch.cuda.current_device())
    backend = backend_for(device)
    if not dist.is_backend_available(backend):
        skipped(f"torch {torch.__version__} has no {backend} backend")
    timeout = min(process_group_timeout(), timedelta(seconds=60))
    with tempfile.TemporaryDirectory() as folder:
        store = dist.FileStore(str(Path(folder) / "store"), 1)
        started = time.perf_counter()
        if is_cuda(device):
            torch.cuda.set_device(device)
        dist.init_process_group(
            backend=backend,
            store=store,
            rank=0,
            world_size=1,
            timeout=timeout,
            device_id=device if is_cuda(device) else None,
        )
        try:
            group_s = time.perf_counter() - started
            torch.manual_seed(0)
            model = torch.nn.Sequential(torch.nn.Linear(64, 128), torch.nn.ReLU(), torch.nn.Linear(128, 3)).to(device)
            wrapped = torch.nn.parallel.DistributedDataParallel(
                model, device_ids=[device.index] if is_cuda(device) else None
            )
            optimizer = torch.optim.Adam(wrapped.parameters(), lr=1e-3)
            inputs = torch.randn(4096, 64, device=device)
            seconds = []
            for _ in range(args.steps):
                started = time.perf_counter()
                loss = wrapped(inputs).square().mean()
                optimizer.zero_grad(set_to_none=True)
                loss.backward()  # DDP's reducer all-reduces the gradients through the backend
                optimizer.step()
                if is_cuda(device):
                    torch.cuda.synchronize(device)
                seconds.append(time.perf_counter() - started)
            total = torch.ones(8, device=device)
            dist.all_reduce(total)
            box = [{"rank": 0}]
            dist.broadcast_object_list(box, src=0)
            dist.barrier()
            ok = bool(total.eq(1).all()) and box == [{"rank": 0}] and bool(torch.isfinite(loss))
            emit(
                "ddp",
                ranks=dist.get_world_size(),
                backend=dist.get_backend(),
                group_s=group_s,
                timeout_s=timeout.total_seconds(),
                steps=args.steps,
                step_ms=1e3 * statistics.median(seconds),
                collectives="ok" if ok else "wrong",
            )
            if not ok:
                raise SystemExit("gpu_check: a collective of the one-rank group gave a wrong result")
        finally:
            dist.destroy_process_group()


# --------------------------------------------------------------------------- node sums


def _median_seconds(function, device, repeat: int, deadline: float) -> tuple[float, int]:
    """Median seconds of ``function()`` after one warm-up, as many repeats (up to ``repeat``) as fit."""
    from gns_framework.runtime.device import synchronize

    function()
    synchronize(device)
    seconds: list[float] = []
    while len(seconds) < repeat and (not seconds or left(deadline) > 2 * max(seconds)):
        started = time.perf_counter()
        function()
        synchronize(device)
        seconds.append(time.perf_counter() - started)
    return statistics.median(seconds), len(seconds)


def sums(args) -> None:
    """ms per node-sum call and GB/s: the edge block's ordered sum (and any other path) against ``index_add_``,
    and whether each path gives the same bits twice (the ordered ones sum float32 in a fixed order).

    Each path at ``--chunk-rows`` rows (one call of the edge block: a chunk of edges) and
    then at ``--rows`` (a whole graph), the larger only when the smaller says it fits in
    what is left of the part's time.
    """
    import torch

    from gns_builtins._kernels import segment_sum, triton_edge_block
    from gns_builtins._kernels.edge_order import run_offsets

    deadline = part_deadline()
    device = torch.device(args.device)
    generator = torch.Generator().manual_seed(0)
    for rows_n in dict.fromkeys([min(args.chunk_rows, args.rows), args.rows]):
        nodes = max(rows_n // args.per_node, 1)
        keys = torch.randint(nodes, (rows_n,), generator=generator).to(device)
        rows = torch.randn(rows_n, args.features, generator=generator).to(device)
        out = torch.zeros(nodes, args.features, device=device)
        # Bytes a sum must move at least: the rows and keys read, the node table read and written.
        moved = rows.numel() * rows.element_size() + keys.numel() * 8 + 2 * out.numel() * out.element_size()
        order = torch.argsort(keys, stable=True)
        sorted_keys, sorted_rows = keys[order], rows[order]
        # index_add: the atomic path (training.deterministic: false); ordered: the deterministic CSR segment
        # sum of any keys (a stable sort first, as the senders need); ordered_sorted: of receiver-sorted keys.
        # Each path is called within this iteration; the defaults bind this size's tensors all the same.
        paths = {
            "index_add": lambda out=out, keys=keys, rows=rows: out.zero_().index_add_(0, keys, rows),
            "ordered": lambda out=out, keys=keys, rows=rows: segment_sum.segment_sum_(out.zero_(), keys, rows),
            "ordered_sorted": lambda out=out, keys=sorted_keys, rows=sorted_rows: segment_sum.sorted_segment_sum_(
                out.zero_(), keys, rows
            ),
        }
        if is_cuda(device) and triton_edge_block.triton_module() is not None:
            # triton_sorted: the Triton edge block's own CSR sum (its backward's node-table gradient).
            offsets = run_offsets(sorted_keys, nodes)
            paths["triton_sorted"] = lambda out=out, rows=sorted_rows, offsets=offsets: (
                triton_edge_block.segment_sum_into(out.zero_(), 0, rows, offsets, None)
            )
        reference = paths["index_add"]().clone()
        for name, function in paths.items():
            label = dict(path=name, rows=rows_n, nodes=nodes, features=args.features)
            expected = estimates.get(name, 0.0) * rows_n * 3  # warm-up, one timed call, one for the check
            if left(deadline) < max(2.0, expected):
                emit("sums", **label, status="over_budget")
                continue
            seconds, repeats = _median_seconds(function, device, args.repeat, deadline)
            estimates[name] = seconds / rows_n
            first = function().clone()
            error = float((first - reference).abs().max() / reference.abs().max().clamp(min=1e-30))
            emit(
                "sums",
                **label,
                status="ok",
                repeats=repeats,
                ms=1e3 * seconds,
                gb_s=moved / seconds / 1e9,
                max_rel_diff_vs_index_add=error,
                same_bits_twice=bool(torch.equal(function(), first)),
            )


estimates: dict[str, float] = {}
"""Seconds per row of each node-sum path, from its last size: whether the next size fits."""


# --------------------------------------------------------------------------- the model at scale


def _lattice(particles: int):
    from lattice_scene import lattice_scene

    return lattice_scene(particles, dim=3)


def _lattice_trajectory(particles: int, still: int, key: str):
    """The lattice scene's window, then ``still`` frames at its last positions (its walls fit the lattice tightly):
    a trajectory of 3D water particles to roll out or train on, not kinematic."""
    import numpy as np

    from gns_framework.data.trajectory import Trajectory

    window = _lattice(particles).batch.position_sequence.transpose(0, 1).numpy()
    frames = np.concatenate([window, np.repeat(window[-1:], still, axis=0)])
    return Trajectory(frames, np.full(particles, 5), None, None, key)


def _simulator(scene, device, graph_builder: str = "radius"):
    import torch

    from gns_framework.assembly.learned import build_learned_simulator
    from gns_framework.config.recipe import ModelSpec
    from gns_framework.plugins import load_registry

    torch.manual_seed(0)
    model = ModelSpec(graph_builder={"name": graph_builder})
    return build_learned_simulator(scene.setup, scene.metadata, model, load_registry()).to(device)


def peak_bytes(device) -> int:
    import torch

    if is_cuda(device):
        return torch.cuda.max_memory_allocated(device)
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def _sync_count(step, device) -> int | str:
    """Host synchronisations in one ``step()``, from CUDA's sync debug mode (``n/a`` on the CPU)."""
    import torch

    if not is_cuda(device):
        return "n/a"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        torch.cuda.set_sync_debug_mode("warn")
        try:
            step()
        finally:
            torch.cuda.set_sync_debug_mode("default")
    return sum("synchroniz" in str(w.message) for w in caught)


class _Case:
    """One (size, precision, phase, memory) case on a built scene: the step, and the step split into phases."""

    def __init__(self, scene, precision: str, phase: str, device, recompute: bool):
        import torch

        from gns_framework.config.recipe import OptimizerSpec
        from gns_framework.model.loss import masked_acceleration_loss
        from gns_framework.model.noise import random_walk_noise
        from gns_framework.runtime.precision import autocast, backward_precision
        from gns_framework.training.optim import make_optimizer

        self.device, self.phase = device, phase
        self.simulator = _simulator(scene, device)
        self.batch = scene.batch.to(device)
        self.mask = self.simulator.predicted_mask(self.batch.particle_type)
        self.autocast = lambda: autocast(precision, device)
        self.backward_precision = lambda: backward_precision(precision, device)
        self.loss = masked_acceleration_loss
        if phase == "train":
            self.optimizer, self.scheduler = make_optimizer(self.simulator.parameters(), OptimizerSpec(), total_steps=1)
            generator = torch.Generator().manual_seed(0)
            self.noise = lambda: (
                random_walk_noise(scene.batch.position_sequence, 6.7e-4, generator).to(device)
                * self.mask[:, None, None]
            )
        self.inference = torch.inference_mode

    def edges(self) -> int:
        import torch

        with torch.no_grad():
            return int(self.simulator.build_graph(self.batch.position_sequence, self.batch).num_edges)

    def step(self, mark=lambda phase: None) -> None:
        """One step; ``mark(phase)`` is called at the end of each phase (the split timing synchronises there)."""
        if self.phase == "rollout":
            with self.inference(), self.autocast():
                self.simulator.predict_next_position(self.batch)
            mark("forward")
            return
        noise = self.noise()
        with self.autocast():
            prediction, target = self.simulator(self.batch, noise)
        loss = self.loss(prediction.to(target.dtype), target, self.mask)
        mark("forward")
        self.optimizer.zero_grad(set_to_none=True)
        with self.backward_precision():
            loss.backward()
        mark("backward")
        self.optimizer.step()
        self.scheduler.step()
        mark("optimizer")

    def split(self) -> dict[str, float]:
        """Seconds of each phase in one step synchronised between phases; ``graph_s`` is one graph build alone."""
        import torch

        from gns_framework.runtime.device import synchronize

        synchronize(self.device)
        started = time.perf_counter()
        with torch.no_grad():
            self.simulator.build_graph(self.batch.position_sequence, self.batch)
        synchronize(self.device)
        phases = {"graph_s": time.perf_counter() - started}
        last = [time.perf_counter()]

        def mark(phase):
            synchronize(self.device)
            now = time.perf_counter()
            phases[f"{phase}_s"] = now - last[0]
            last[0] = now

        self.step(mark)
        return phases


def _cases(particles: int, precisions: list[str], large: bool) -> list[tuple[str, str, str]]:
    """(precision, phase, memory) in the order they run: at ``large`` sizes the expected fit first."""
    if large and "bfloat16" in precisions:
        first = [("bfloat16", "train", "recompute")]
        rest = [(p, "rollout", "stored") for p in ("bfloat16", *[p for p in precisions if p != "bfloat16"])]
        rest += [(p, "train", m) for p in precisions for m in ("recompute", "stored") if (p, "train", m) != first[0]]
        return first + rest
    return [
        (p, phase, m)
        for p in precisions
        for phase, m in (("rollout", "stored"), ("train", "stored"), ("train", "recompute"))
    ]


def scale(args) -> None:
    import torch

    from gns_framework.runtime.activation_memory import set_recompute_activations
    from gns_framework.runtime.device import synchronize

    deadline = min(part_deadline(), STARTED + args.budget_s)
    device = torch.device(args.device)
    total = torch.cuda.get_device_properties(device).total_memory if is_cuda(device) else None
    best_fit: dict | None = None  # the largest bfloat16 + recompute training case measured
    seconds_per_edge: dict[str, float] = {}  # the slowest warm-up step per edge so far, by phase
    edges_per_particle = 20.6  # the 3D lattice scene's, until measured
    for particles in args.sizes:
        repeat = args.repeat if particles < 500_000 else max(1, args.repeat // 3)
        if left(deadline) < 5:
            emit("step", particles=particles, status="over_budget")
            continue
        scene = _lattice(particles)
        edges = None
        stored_fit: set[str] = set()  # precisions whose training fits with stored activations
        for precision, phase, memory in _cases(particles, args.precisions, particles >= args.large):
            label = dict(particles=particles, precision=precision, phase=phase, memory=memory)
            if phase == "train" and memory == "recompute" and precision in stored_fit and particles < args.large:
                continue  # stored activations fit: the recompute mode only when they do not
            # A case starts only if its warm-up and one timed step are expected to end by the deadline.
            expected_edges = edges if edges is not None else particles * edges_per_particle
            expected_s = 2 * seconds_per_edge.get(phase, 0.0) * expected_edges + 1.0
            if left(deadline) < max(3.0, expected_s):
                emit("step", **label, status="over_budget", expected_s=expected_s, left_s=max(left(deadline), 0.0))
                continue
            cpu_bytes = CPU_BYTES_PER_EDGE[(phase, precision, memory)]
            if total is not None and edges is not None:
                predicted = edges * cpu_bytes + RESERVED_GIB * 2**30
                if predicted > total:
                    emit(
                        "step",
                        **label,
                        status="predicted_oom",
                        edges=edges,
                        predicted_gb=predicted / 2**30,
                        memory_gb=total / 2**30,
                    )
                    continue
            case = None
            try:
                set_recompute_activations(memory == "recompute")
                if is_cuda(device):
                    torch.cuda.empty_cache()
                    torch.cuda.reset_peak_memory_stats(device)
                case = _Case(scene, precision, phase, device, memory == "recompute")
                base = peak_bytes(device)
                edges = case.edges()
                if total is not None and edges * cpu_bytes + RESERVED_GIB * 2**30 > total:
                    emit(
                        "step",
                        **label,
                        status="predicted_oom",
                        edges=edges,
                        predicted_gb=(edges * cpu_bytes + RESERVED_GIB * 2**30) / 2**30,
                        memory_gb=total / 2**30,
                    )
                    continue
                started = time.perf_counter()
                case.step()  # warm-up
                synchronize(device)
                warmup_s = time.perf_counter() - started
                seconds_per_edge[phase] = max(seconds_per_edge.get(phase, 0.0), warmup_s / max(edges, 1))
                edges_per_particle = edges / particles
                if is_cuda(device):
                    torch.cuda.reset_peak_memory_stats(device)
                seconds: list[float] = []
                while len(seconds) < repeat and left(deadline) > 1.5 * (seconds[-1] if seconds else warmup_s):
                    started = time.perf_counter()
                    case.step()
                    synchronize(device)
                    seconds.append(time.perf_counter() - started)
                peak = peak_bytes(device)
                figures = {
                    "status": "ok",
                    "edges": edges,
                    "repeats": len(seconds),
                    "step_s": statistics.median(seconds) if seconds else warmup_s,
                    "warmup_s": warmup_s,
                    "peak_gb": peak / 2**30,
                    "bytes_per_edge": (peak - base) / max(edges, 1) if is_cuda(device) else "n/a",
                    "cpu_table_bytes_per_edge": cpu_bytes,
                }
                if not seconds:
                    figures["status"] = "warmup_only"  # the deadline came before a timed step would fit
                emit("step", **label, **figures)
                if phase == "train" and memory == "stored":
                    stored_fit.add(precision)
                if (phase, precision, memory) == ("train", "bfloat16", "recompute") and is_cuda(device):
                    best_fit = {"particles": particles, "edges": edges, "bytes_per_edge": figures["bytes_per_edge"]}
                if left(deadline) > 1.5 * figures["step_s"] + 1:
                    emit("phases", **label, **case.split())
                else:
                    emit("phases", **label, status="over_budget")
                if particles == args.sizes[0] and left(deadline) > 1.5 * figures["step_s"] + 1:
                    emit("syncs", **label, per_step=_sync_count(case.step, device))
            except torch.OutOfMemoryError:
                emit("step", **label, status="oom", edges=edges if edges is not None else "n/a")
            finally:
                del case
                set_recompute_activations(False)
                if is_cuda(device):
                    torch.cuda.empty_cache()
    if best_fit is not None and total is not None and best_fit["bytes_per_edge"] != "n/a":
        per_particle = best_fit["edges"] / best_fit["particles"] * max(best_fit["bytes_per_edge"], 1.0)
        emit(
            "largest",
            precision="bfloat16",
            memory="recompute",
            phase="train",
            particles_est=int((total - RESERVED_GIB * 2**30) / per_particle),
            from_particles=best_fit["particles"],
            bytes_per_edge=best_fit["bytes_per_edge"],
            memory_gb=total / 2**30,
            method="linear_in_edges",
        )


def chunks(args) -> None:
    """A float32 training step on a graph split into several chunks of edges, against the same step elsewhere.

    On CUDA: the GPU in chunks of ~E/``--chunks`` edges against the CPU. On the CPU (the
    dry run): small chunks against the CPU's own chunking, so the part runs end to end.
    """
    import torch

    import gns_builtins._kernels.chunked as chunked

    device = torch.device(args.device)
    scene = _lattice(args.particles)
    saved = chunked.ROWS_PER_CHUNK_ACCELERATOR, chunked.ROWS_PER_THREAD

    def step(where, rows_per_chunk=None):
        if rows_per_chunk is not None:
            if where.type == "cpu":
                chunked.ROWS_PER_THREAD = max(rows_per_chunk // max(torch.get_num_threads(), 1), 16)
            else:
                chunked.ROWS_PER_CHUNK_ACCELERATOR = rows_per_chunk
        try:
            case = _Case(scene, "float32", "train", where, recompute=False)
            edges = case.edges()
            prediction, target = case.simulator(case.batch, case.noise())
            loss = case.loss(prediction.to(target.dtype), target, case.mask)
            loss.backward()
            grads = torch.cat([p.grad.detach().double().cpu().flatten() for p in case.simulator.parameters()])
            return float(loss.detach()), grads, edges, chunked.chunk_size(where)
        finally:
            chunked.ROWS_PER_CHUNK_ACCELERATOR, chunked.ROWS_PER_THREAD = saved

    edges = _Case(scene, "float32", "rollout", torch.device("cpu"), recompute=False).edges()
    rows = max(-(-edges // args.chunks), 64)
    a_loss, a_grads, _, a_chunk = step(device, rows)
    b_loss, b_grads, _, b_chunk = step(torch.device("cpu"))
    loss_rel = abs(a_loss - b_loss) / max(abs(b_loss), 1e-30)
    grad_rel = float(torch.linalg.norm(a_grads - b_grads) / torch.linalg.norm(b_grads).clamp(min=1e-30))
    ok = loss_rel <= 1e-4 and grad_rel <= 1e-3
    emit(
        "chunks",
        compared=f"{device.type}_chunked_vs_cpu",
        particles=args.particles,
        edges=edges,
        chunks=-(-edges // a_chunk),
        chunk_rows=a_chunk,
        cpu_chunk_rows=b_chunk,
        loss_rel_diff=loss_rel,
        grad_rel_diff=grad_rel,
        status="ok" if ok else "differ",
    )
    if not ok:
        raise SystemExit("gpu_check: the chunked training step differs from the CPU's")


def capture(args) -> None:
    """Rollout steps of the paper's model on the fixed-capacity graph, eager against captured (``gns rollout
    --capture``: a CUDA graph on CUDA, the emulation on the CPU): the same frames, and the time per step.

    Per size: ``steps`` steps each way from the lattice scene (no kinematic particles), timed after one warm-up
    step; ``max_abs_diff`` compares the last frames (TF32 off: the two must run the same float32 kernels).
    """
    import torch

    device = torch.device(args.device)
    deadline = part_deadline()
    for particles in args.sizes:
        if left(deadline) < 10:
            emit("capture", particles=particles, status="over_budget")
            continue
        figures = _capture_case(_lattice(particles), device, args.steps, args.compile_backend)
        ok = figures["max_abs_diff"] <= 1e-4 and figures["compiled_max_abs_diff"] <= 1e-4 and not figures["overflowed"]
        emit("capture", particles=particles, steps=args.steps, **figures, status="ok" if ok else "differ")


def _capture_case(scene, device, steps: int, backend: str = "inductor") -> dict:
    """Eager, captured and compiled-then-captured rollouts of ``steps`` steps of ``scene``: times per step, their
    differences, captures made. ``backend``: torch.compile's for the node side."""
    import torch

    from gns_framework.model.captured_steps import CapturedSteps
    from gns_framework.model.history import advance_window
    from gns_framework.model.rollout import capacity_checks, rollout_step
    from gns_framework.model.rollout_guard import RolloutGuard
    from gns_framework.runtime.compiled import compile_node_side
    from gns_framework.runtime.device import synchronize

    simulator = _simulator(scene, device, "radius_fixed_capacity").eval()
    compiled = _simulator(scene, device, "radius_fixed_capacity").eval()
    compile_node_side(compiled, backend)
    batch = scene.batch.to(device)
    guard = RolloutGuard(simulator.setup)
    kinematic = torch.zeros(0, dtype=torch.long, device=device)
    still = torch.zeros(0, scene.setup.dim, device=device)

    def step_of_model(model):
        return lambda current, kinematic_next: rollout_step(model, guard, current, kinematic, kinematic_next, "float32")

    one_step = step_of_model(simulator)
    captured = CapturedSteps(one_step, batch, simulator.graph_builder)
    # The node side compiled (fused kernels), then the whole step captured: what gns rollout --compile --capture runs.
    captured_compiled = CapturedSteps(step_of_model(compiled), batch, compiled.graph_builder)
    step_of = {
        "eager": lambda sequence: one_step(dataclasses.replace(batch, position_sequence=sequence), still),
        "captured": lambda sequence: captured(sequence, None, still),
        "compiled": lambda sequence: captured_compiled(sequence, None, still),
    }

    def roll(name, count):
        sequence = batch.position_sequence
        for _ in range(count):
            _, continued = step_of[name](sequence)
            sequence = advance_window(sequence, continued)
        return sequence

    last, figures = {}, {}
    with (
        torch.inference_mode(),
        capacity_checks(simulator.graph_builder),
        capacity_checks(compiled.graph_builder),
        _no_tf32(),
    ):
        for name in step_of:
            roll(name, 1)  # warm-up (and the capture)
            synchronize(device)
            started = time.perf_counter()
            last[name] = roll(name, steps)
            synchronize(device)
            figures[f"{name}_ms"] = (time.perf_counter() - started) / steps * 1e3
        figures["overflowed"] = simulator.graph_builder.overflowed() or compiled.graph_builder.overflowed()
    figures["speedup"] = figures["eager_ms"] / figures["captured_ms"]
    figures["compiled_speedup"] = figures["eager_ms"] / figures["compiled_ms"]
    figures["max_abs_diff"] = float((last["eager"] - last["captured"]).abs().max())
    # Fused kernels round differently from the eager ones: float32 rounding of positions ~1 m over the steps.
    figures["compiled_max_abs_diff"] = float((last["eager"] - last["compiled"]).abs().max())
    figures["captures"] = captured.captures
    return figures


def batched(args) -> None:
    """Many small scenes (issue 45, item 5): ``--scenes`` 3D lattice scenes of ``--particles LO HI`` particles,
    ``--steps`` steps each, rolled out one at a time (eager, as ``gns rollout``) and ``--batch`` at a time replaying
    their capacity classes' captures (``gns rollout --capture --batch``), back to back; seconds per scene of each
    (the captures' own cost included), the classes and captures made, and the largest difference of a batched
    scene's frames from its own rollout (TF32 off)."""
    import numpy as np
    import torch

    from gns_framework.model import captured_steps
    from gns_framework.model.batched_rollout import rollout_batch
    from gns_framework.model.capacity_classes import CaptureClasses
    from gns_framework.model.rollout import rollout
    from gns_framework.runtime.device import synchronize

    device = torch.device(args.device)
    sizes = np.random.default_rng(0).integers(args.particles[0], args.particles[1] + 1, args.scenes)
    scenes = []
    scenes = [_lattice_trajectory(int(particles), args.steps, f"lattice_{k}") for k, particles in enumerate(sizes)]
    simulator = _simulator(_lattice(int(sizes.max())), device, "radius_fixed_capacity").eval()
    classes = CaptureClasses(args.batch)
    made = []
    original = captured_steps.CapturedSteps.__init__

    def counted(self, *a, **k):
        original(self, *a, **k)
        made.append(self)

    timed, results = {}, {}
    with _no_tf32(), mock.patch.object(captured_steps.CapturedSteps, "__init__", counted):
        for name in ("alone", "batched"):
            synchronize(device)
            started = time.perf_counter()
            if name == "alone":
                results[name] = [rollout(simulator, scene, args.steps, device) for scene in scenes]
            else:
                groups = [scenes[i : i + args.batch] for i in range(0, len(scenes), args.batch)]
                results[name] = [
                    r for g in groups for r in rollout_batch(simulator, g, args.steps, device, capture=classes)
                ]
            synchronize(device)
            timed[name] = (time.perf_counter() - started) / len(scenes)
    difference = max(
        float(np.abs(a.predicted - b.predicted).max())
        for a, b in zip(results["alone"], results["batched"], strict=True)
    )
    emit(
        "batched",
        scenes=len(scenes),
        particles=f"{int(sizes.min())}-{int(sizes.max())}",
        steps=args.steps,
        batch=args.batch,
        s_per_scene=timed["batched"],
        alone_s_per_scene=timed["alone"],
        speedup=timed["alone"] / timed["batched"],
        classes=len(classes.classes),
        captures=sum(m.captures for m in made),
        max_abs_diff=difference,
        status="ok" if difference <= 1e-4 else "differ",
    )


def train_capture(args) -> None:
    """Training steps of the paper's model on the fixed-capacity graph, eager against captured
    (``training.capture_step``: CUDA graphs on CUDA, the emulation on the CPU): the same weights, and the time
    per step. Two lattice scenes of about ``--particles`` particles (batches of 2 fall in 3 capacity classes);
    ``--warmup`` steps each way (the captures among them), then ``--steps`` timed. ``loss_rel_diff``: the
    largest relative difference of the two runs' losses over all steps (TF32 off; the same fused Adam both
    ways): the padded batches sum in another order, a few float32 ulps. ``weight_diff_lr``: the weights'
    largest difference in learning rates; Adam's first steps move a weight by about one learning rate whatever
    its gradient's size, so a gradient at rounding level may move it either way (up to 2 per step)."""
    import tempfile

    import torch
    from lattice_scene import HISTORY

    from gns_framework.config.recipe import validate_recipe
    from gns_framework.plugins import load_registry
    from gns_framework.runtime.device import synchronize
    from gns_framework.training.captured_step import make_capturable
    from gns_framework.training.trainer import Trainer

    registry = load_registry()
    work = Path(tempfile.mkdtemp(prefix="train_capture."))
    frames = 12
    splits = {}
    for split, seeds in {"train": (0, 1), "valid": (2,), "test": (3,)}.items():
        splits[split] = [
            _lattice_trajectory(int(args.particles * (1.0 - 0.1 * seed)), frames - HISTORY, f"{split}_{seed}")
            for seed in seeds
        ]
    metadata = _lattice(args.particles).metadata.model_copy(update={"sequence_length": frames})
    registry.get("dataset", "safe").write(work / "data", metadata, splits)
    figures, weights, losses = {}, {}, {}
    with _no_tf32():
        for name in ("eager", "captured"):
            recipe = {
                "name": f"train-capture-{name}",
                "seed": 0,
                "dataset": {"path": str(work / "data")},
                "model": {"graph_builder": {"name": "radius_fixed_capacity"}},
                "training": {
                    "steps": args.warmup + args.steps,
                    "batch_size": 2,
                    "device": args.device,
                    "ema_decay": 0.999,
                    "capture_step": name == "captured",
                    "log_every": 10**6,
                    "validate_every": 10**6,
                    "checkpoint_every": 10**6,
                },
            }
            trainer = Trainer(validate_recipe(recipe, registry), registry, run_dir=work / name, progress=False)
            trainer.checkpoints.start_afresh()
            if trainer.captured is None:
                make_capturable(trainer.optimizer)
            kept = [trainer.train_step()[0] for _ in range(args.warmup)]
            synchronize(trainer.device)
            started = time.perf_counter()
            kept += [trainer.train_step()[0] for _ in range(args.steps)]
            synchronize(trainer.device)
            figures[f"{name}_ms"] = (time.perf_counter() - started) / args.steps * 1e3
            losses[name] = torch.stack(kept).cpu()
            lr = trainer.recipe.training.optimizer.lr_init
            weights[name] = torch.cat([p.detach().flatten() for p in trainer.simulator.parameters()])
            if trainer.captured is not None:
                figures["classes"] = len(trainer.captured.classes)
                figures["captures"] = trainer.captured.captures
    loss_difference = float(((losses["eager"] - losses["captured"]).abs() / losses["eager"].abs()).max())
    emit(
        "train_capture",
        particles=args.particles,
        steps=args.steps,
        **figures,
        speedup=figures["eager_ms"] / figures["captured_ms"],
        loss_rel_diff=loss_difference,
        weight_diff_lr=float((weights["eager"] - weights["captured"]).abs().max()) / lr,
        status="ok" if loss_difference <= 1e-4 else "differ",
    )


@contextlib.contextmanager
def _no_tf32():
    import torch

    saved = torch.backends.cuda.matmul.allow_tf32
    torch.backends.cuda.matmul.allow_tf32 = False
    try:
        yield
    finally:
        torch.backends.cuda.matmul.allow_tf32 = saved


def mpm(args) -> None:
    """Seconds per frame of the 3D sand column on a ``--grid``-cell-wide grid (particles grow as grid^3), on
    ``--device``."""
    if importlib.util.find_spec("warp") is None:
        skipped("warp-lang is not installed here (the MLS-MPM runs on NVIDIA Warp)")
    import torch
    from scene_builders import column_collapse_3d

    from gns_framework.assembly.ground_truth import build_ground_truth_simulator as build_ground_truth
    from gns_framework.ground_truth.scene_spec import parse_scene
    from gns_framework.plugins import load_registry

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
    emit(
        "mpm",
        particles=trajectory.num_particles,
        frames=args.frames,
        substeps=scene.time.substeps,
        s_per_frame=seconds / args.frames,
        finite=finite,
    )
    if not finite:
        raise SystemExit("gpu_check: the MPM produced non-finite positions")


def data(args) -> None:
    from synthetic import write_synthetic_dataset

    write_synthetic_dataset(Path(args.out), train=2, valid=1, test=1, kinematic_floor=True, frames=20)
    emit("data", path=args.out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("imports")
    for name in ("info", "ddp", "sums", "chunks", "scale", "capture", "train_capture", "batched", "mpm"):
        command = sub.add_parser(name)
        command.add_argument("--device", default="cuda")
    sub.add_parser("tests").add_argument("files", nargs="+")
    sub.choices["ddp"].add_argument("--steps", type=int, default=5)
    sub.choices["sums"].add_argument("--rows", type=int, default=1 << 22, help="edges of a whole graph (rows summed)")
    sub.choices["sums"].add_argument("--chunk-rows", type=int, default=1 << 18, help="edges of one chunk (the GPU's)")
    sub.choices["sums"].add_argument("--per-node", type=int, default=20, help="edges per node")
    sub.choices["sums"].add_argument("--features", type=int, default=128)
    sub.choices["sums"].add_argument("--repeat", type=int, default=10)
    sub.choices["chunks"].add_argument("--particles", type=int, default=10_000)
    sub.choices["chunks"].add_argument("--chunks", type=int, default=4, help="about this many chunks of edges")
    sub.choices["scale"].add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000, 1_000_000])
    from gns_framework.runtime.precision import PRECISIONS

    sub.choices["scale"].add_argument("--precisions", nargs="+", choices=PRECISIONS, default=list(PRECISIONS))
    sub.choices["scale"].add_argument("--repeat", type=int, default=5)
    sub.choices["scale"].add_argument(
        "--large", type=int, default=500_000, help="from this size on, bfloat16 + recompute training runs first"
    )
    sub.choices["scale"].add_argument(
        "--budget-s",
        type=float,
        default=1e9,
        help="seconds for the whole part (also bounded by GPU_CHECK_PART_LIMIT_S)",
    )
    sub.choices["capture"].add_argument("--sizes", type=int, nargs="+", default=[300, 10_000, 100_000])
    sub.choices["capture"].add_argument("--steps", type=int, default=20)
    sub.choices["capture"].add_argument(
        "--compile-backend", default="inductor", help="torch.compile backend of the node side (eager: trace only)"
    )
    sub.choices["train_capture"].add_argument("--particles", type=int, default=10_000)
    sub.choices["train_capture"].add_argument("--warmup", type=int, default=12, help="untimed steps (captures)")
    sub.choices["train_capture"].add_argument("--steps", type=int, default=20, help="timed steps")
    sub.choices["batched"].add_argument("--scenes", type=int, default=64)
    sub.choices["batched"].add_argument("--particles", type=int, nargs=2, default=[250, 350], help="LO HI per scene")
    sub.choices["batched"].add_argument("--steps", type=int, default=57, help="steps of each scene's rollout")
    sub.choices["batched"].add_argument("--batch", type=int, default=16, help="scenes per batch")
    sub.choices["mpm"].add_argument("--frames", type=int, default=10)
    sub.choices["mpm"].add_argument("--grid", type=int, default=96, help="grid cells along the box (24: 768 particles)")
    sub.add_parser("data").add_argument("out")
    args = parser.parse_args()
    {
        "imports": imports,
        "info": info,
        "tests": tests,
        "ddp": ddp,
        "sums": sums,
        "chunks": chunks,
        "scale": scale,
        "capture": capture,
        "train_capture": train_capture,
        "batched": batched,
        "mpm": mpm,
        "data": data,
    }[args.command](args)


if __name__ == "__main__":
    with contextlib.suppress(BrokenPipeError):
        main()
