"""Scenes and a worker for the domain-decomposed tests: each case is rebuilt from its name in every process."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import torch

from gns_framework.assembly.learned import build_learned_simulator
from gns_framework.config.recipe import ModelSpec
from gns_framework.contracts import ModelSetup
from gns_framework.data.metadata import DatasetMetadata
from gns_framework.data.trajectory import Trajectory
from gns_framework.model.learned_simulator import LearnedSimulator
from gns_framework.plugins import load_registry

HOPS = 2
TYPES = (3, 5, 6)  # kinematic, water, sand
FRAMES = 18  # 6 inputs, 12 predicted
CASES = {
    # name: (dim, periodic dims, particles, material property, connectivity radius): about 12 and 8 neighbours
    "2d_walls": (2, (), 320, True, 0.1),
    "2d_periodic": (2, (0,), 320, False, 0.1),
    "3d_walls": (3, (), 420, False, 0.15),
    "3d_periodic": (3, (0, 2), 420, False, 0.15),
}
DRIFT = {"2d_drift": (2, (), 200, False, 0.1)}
"""A scene whose particles all drift along x by 0.04 per frame, in a band spread farthest along x (so slabs are cut
across x): the first slab empties within a few steps."""
FEW = {"2d_few": (2, (), 3, False, 0.5)}
"""Three particles for four processes: one process owns none (slabs cut at particle-count quantiles)."""


def case_simulator(name: str) -> LearnedSimulator:
    """A randomly initialised model of the case's scene (latent 16, 2 message-passing steps), the same every call."""
    dim, periodic, _, with_property, radius = {**CASES, **DRIFT, **FEW}[name]
    scene = ModelSetup(
        dim=dim,
        bounds=((0.0, 1.0),) * dim,
        connectivity_radius=radius,
        particle_types=TYPES,
        kinematic_types=(3,),
        property_names=("friction",) if with_property else (),
        periodic=tuple(k in periodic for k in range(dim)),
    )
    model = ModelSpec(
        latent_size=16,
        mlp_hidden_size=16,
        mlp_hidden_layers=1,
        type_embedding_size=4,
        graph_builder={"name": "periodic_radius" if periodic else "radius"},
        processor={"name": "interaction_network", "message_passing_steps": HOPS},
    )
    torch.manual_seed(0)
    return build_learned_simulator(scene, case_metadata(name), model, load_registry()).eval()


def case_metadata(name: str) -> DatasetMetadata:
    """The statistics the case's model normalises with (velocities of about 0.01 per frame)."""
    dim, _, _, _, radius = {**CASES, **DRIFT, **FEW}[name]
    return DatasetMetadata(
        bounds=[(0.0, 1.0)] * dim,
        sequence_length=FRAMES,
        default_connectivity_radius=radius,
        dim=dim,
        dt=0.01,
        vel_mean=[0.0] * dim,
        vel_std=[0.01] * dim,
        acc_mean=[0.0] * dim,
        acc_std=[1e-3] * dim,
    )


def narrow_guard(name: str):
    """A guard whose walls stand at 0.2 and 0.8 (the scene's are 0 and 1) with no margin, clamping: it holds
    particles back at most steps, on every process's piece."""
    from gns_framework.model.rollout_guard import RolloutGuard

    simulator = case_simulator(name)
    guard = RolloutGuard(simulator.setup, margin=0.0, on_violation="clamp")
    return guard.with_bounds(np.array([[0.2, 0.8]] * simulator.setup.dim))


def case_trajectory(name: str) -> Trajectory:
    """Particles drifting fast enough (up to 0.03 per frame) to cross slab faces, with kinematic ones among them.

    Periodic dimensions wrap the stored positions into the box.
    """
    dim, periodic, n, with_property, _ = {**CASES, **DRIFT, **FEW}[name]
    rng = np.random.default_rng(7)
    start = rng.uniform(0.05, 0.95, (n, dim))
    velocity = rng.uniform(-0.03, 0.03, (n, dim))
    if name in DRIFT:
        start[:, 0] *= 0.4
        start[:, 1] = 0.1 + 0.2 * start[:, 1]
        velocity[:, 0] = 0.04
        velocity[:, 1] *= 0.2
    position = np.stack([start + t * velocity for t in range(FRAMES)])
    for k in periodic:
        position[..., k] = np.mod(position[..., k], 1.0)
    types = np.array([TYPES[i % len(TYPES)] for i in range(n)], dtype=np.int64)
    friction = rng.uniform(0.2, 0.8, (n, 1)).astype(np.float32) if with_property else None
    return Trajectory(position.astype(np.float32), types, material_property=friction, key=name)


def _join(rank: int, world: int, port: int):
    """Join a gloo process group of ``world`` processes on the loopback as ``rank``, one thread; its Processes."""
    from gns_framework.training.distributed import processes_from_environment, start

    os.environ.update(
        MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port), RANK=str(rank), WORLD_SIZE=str(world), LOCAL_RANK=str(rank)
    )
    torch.set_num_threads(1)
    processes = processes_from_environment()
    start(processes, torch.device("cpu"))
    return processes


def _scale_halo_depth(depth_scale: float) -> None:
    """In this process, halos ``depth_scale`` times as deep as each kind needs (< 1: a broken decomposition)."""
    from gns_framework.decomposition import halo as halos

    if depth_scale != 1.0:
        depth = halos.halo_depth
        halos.halo_depth = lambda simulator, kind: depth_scale * depth(simulator, kind)  # type: ignore[assignment]


def partitioned_worker(
    rank: int,
    world: int,
    port: int,
    out: str,
    cases: list[str],
    depth_scale: float = 1.0,
    halo: str = "positions",
    cut: str = "auto",
    rebalance: float | None = 1.25,
    sharded: bool = False,
    narrow: bool = False,
) -> None:
    """Roll every case out over ``world`` gloo processes; rank 0 saves ``<case>.npy`` and ``<case>.json``.

    With ``sharded`` every process writes its shard into ``<case>.rollout`` and rank 0 saves what reads back
    from it, with the guard's clamps; ``narrow``: under :func:`narrow_guard`. ``depth_scale`` < 1 shrinks the
    halo below what ``halo`` needs: a broken decomposition.
    """
    from gns_framework.decomposition import rollout as decomposed
    from gns_framework.io.rollout_file import load_rollout
    from gns_framework.training.distributed import stop

    processes = _join(rank, world, port)
    _scale_halo_depth(depth_scale)
    try:
        for name in cases:
            options = dict(halo=halo, cut=cut, rebalance=rebalance, guard=narrow_guard(name) if narrow else None)
            if sharded:
                folder = Path(out) / f"{name}.rollout"
                simulator, trajectory, metadata = case_simulator(name), case_trajectory(name), case_metadata(name)
                written, stats = decomposed.sharded_rollout(
                    simulator,
                    trajectory,
                    processes,
                    folder,
                    metadata,
                    **options,  # type: ignore[arg-type]
                )
                result = load_rollout(folder) if rank == 0 else None
                clamps = [v.describe() for v in written.guard_violations]
            else:
                result, stats = decomposed.partitioned_rollout(
                    case_simulator(name),
                    case_trajectory(name),
                    processes,
                    **options,  # type: ignore[arg-type]
                )
                clamps = None if result is None else [v.describe() for v in result.guard_violations]
            if rank == 0:
                assert result is not None
                np.save(Path(out) / f"{name}.npy", result.predicted)
                summary = {
                    "migrations": stats.migrations,
                    "halo_fraction": stats.halo_fraction,
                    "kind": stats.halo_kind,
                    "partition": stats.partition.describe(),
                    "rebalances": stats.rebalances,
                    "clamps": clamps,
                    "read_back_clamps": [v.describe() for v in result.guard_violations],
                }
                (Path(out) / f"{name}.json").write_text(json.dumps(summary))
    finally:
        stop()


def training_window(name: str):
    """The case's first training window and its noise, in float64 (the test compares gradients at float64 round-off).

    Kinematic particles get no noise, as in training.
    """
    from gns_framework.data.batch import window

    trajectory = case_trajectory(name)
    batch = window(trajectory, 0, 6, with_target=True)
    batch = batch._map_tensors(lambda t: t.double() if t.is_floating_point() else t)
    generator = torch.Generator().manual_seed(3)
    noise = 1e-3 * torch.randn(batch.position_sequence.shape, generator=generator, dtype=torch.float64)
    noise[batch.particle_type == 3] = 0.0
    return batch, noise


def single_process_gradients(name: str) -> tuple[float, dict[str, torch.Tensor]]:
    """The whole scene's loss and gradients in one process (the reference)."""
    from gns_framework.model.loss import masked_acceleration_loss

    simulator = case_simulator(name).double().train()
    batch, noise = training_window(name)
    prediction, target = simulator(batch, noise)
    loss = masked_acceleration_loss(prediction, target, simulator.predicted_mask(batch.particle_type))
    loss.backward()
    return float(loss.detach()), {k: p.grad.clone() for k, p in simulator.named_parameters() if p.grad is not None}


def training_worker(
    rank: int,
    world: int,
    port: int,
    out: str,
    cases: list[str],
    depth_scale: float = 1.0,
    halo: str = "positions",
    cut: str = "slabs",
) -> None:
    """One decomposed training step of every case over ``world`` gloo processes; rank 0 saves ``<case>.pt``."""
    from gns_framework.decomposition.halo import halo_depth
    from gns_framework.decomposition.partition import balanced_partition
    from gns_framework.decomposition.training_step import owned_share, partitioned_gradients
    from gns_framework.training.distributed import stop

    processes = _join(rank, world, port)
    try:
        for name in cases:
            simulator = case_simulator(name).double().train()
            batch, noise = training_window(name)
            scene = simulator.setup
            partition = balanced_partition(
                batch.position_sequence[:, -1],
                world,
                depth_scale * halo_depth(simulator, halo),  # type: ignore[arg-type]
                cut,  # type: ignore[arg-type]
                periodic_dims=scene.periodic_dims,
                bounds=scene.bounds,
            )
            owned = owned_share(batch, noise, partition, rank)
            loss = partitioned_gradients(simulator, owned, batch, partition, processes, halo)
            grads = {k: p.grad for k, p in simulator.named_parameters() if p.grad is not None}
            if rank == 0:
                torch.save({"loss": float(loss), "grads": grads}, Path(out) / f"{name}.pt")
    finally:
        stop()


PUSHED_STEPS = 3


def pushforward_batch(name: str):
    """Two training windows of the case (frames 0 and 3 on) collated into one batch, with 3 frames ahead, in float64."""
    from gns_framework.data.batch import collate, window

    trajectory = case_trajectory(name)
    windows = [window(trajectory, start, 6, with_target=True, ahead=PUSHED_STEPS) for start in (0, 3)]
    return collate(windows)._map_tensors(lambda t: t.double() if t.is_floating_point() else t)


def single_process_pushed_forward(name: str):
    """The case's batch pushed forward ``PUSHED_STEPS`` steps by the single-process training step (the reference)."""
    from types import SimpleNamespace

    from gns_framework.training.step import TrainingStep

    step = SimpleNamespace(simulator=case_simulator(name).double())
    return TrainingStep.pushed_forward(step, pushforward_batch(name), PUSHED_STEPS)  # type: ignore[arg-type]


def pushforward_worker(
    rank: int,
    world: int,
    port: int,
    out: str,
    cases: list[str],
    depth_scale: float = 1.0,
    halo: str = "positions",
    cut: str = "auto",
) -> None:
    """Every case's batch pushed forward over ``world`` gloo processes; each rank saves ``<case>-rank<r>.pt``."""
    from gns_framework.decomposition.pushforward import partitioned_pushed_forward
    from gns_framework.training.distributed import stop

    processes = _join(rank, world, port)
    _scale_halo_depth(depth_scale)
    try:
        for name in cases:
            simulator = case_simulator(name).double()
            pushed = partitioned_pushed_forward(
                simulator,
                pushforward_batch(name),
                PUSHED_STEPS,
                processes,
                halo,  # type: ignore[arg-type]
                cut,  # type: ignore[arg-type]
            )
            saved = {"sequence": pushed.position_sequence, "target": pushed.next_position}
            torch.save(saved, Path(out) / f"{name}-rank{rank}.pt")
    finally:
        stop()


def validation_worker(rank: int, world: int, port: int, out: str, cases: list[str], halo: str = "positions") -> None:
    """Every case validated over ``world`` gloo processes: the one-step errors of two windows (float64) and the
    rollout positions (float32, as rollouts store them), then those of a model made to diverge; each rank saves
    ``<case>-rank<r>.pt``."""
    from gns_framework.decomposition.validation import partitioned_one_step_errors, partitioned_positions
    from gns_framework.training.distributed import stop

    processes = _join(rank, world, port)
    try:
        for name in cases:
            batch, trajectory = pushforward_batch(name), case_trajectory(name)
            positions = partitioned_positions(processes, "cpu", halo)  # type: ignore[arg-type]
            saved = {
                "one_step": partitioned_one_step_errors(
                    case_simulator(name).double(),
                    batch,
                    processes,
                    halo,  # type: ignore[arg-type]
                ),
                "positions": positions(case_simulator(name), trajectory),
                "diverged": positions(diverging(case_simulator(name)), trajectory),
            }
            torch.save(saved, Path(out) / f"{name}-rank{rank}.pt")
    finally:
        stop()


def diverging(simulator: LearnedSimulator) -> LearnedSimulator:
    """``simulator`` with a decoder whose output is infinite: its first rolled-out frame is not finite."""
    for parameter in simulator.decoder.parameters():
        parameter.data.fill_(float("inf"))
    return simulator


def exchange_worker(rank: int, world: int, port: int, out: str) -> None:
    """Rank r sends rows labelled 100 r + i to the ranks listed per row; saves what it received."""
    from gns_framework.decomposition.exchange import send_rows
    from gns_framework.training.distributed import stop

    _join(rank, world, port)
    try:
        destination = torch.tensor([(rank + i) % world for i in range(2 * world)], dtype=torch.long)
        label = 100 * rank + torch.arange(2 * world)
        pairs = torch.stack([label, -label], dim=1).double()
        flags = label % 2 == 0
        got = send_rows(destination, [label, pairs, flags, None], world)
        torch.save({"label": got[0], "pairs": got[1], "flags": got[2], "none": got[3]}, Path(out) / f"rank{rank}.pt")
    finally:
        stop()


def halo_worker(rank: int, world: int, port: int, out: str) -> None:
    """The halo each rank gets of the 2d_walls case's first frame, beside its own particles; saved per rank."""
    from gns_framework.data.batch import window
    from gns_framework.decomposition.halo import receptive_field, with_halo
    from gns_framework.decomposition.particles import Particles
    from gns_framework.decomposition.slabs import SlabPartition
    from gns_framework.training.distributed import stop

    _join(rank, world, port)
    try:
        start = window(case_trajectory("2d_walls"), 0, 6, with_target=False)
        last = start.position_sequence[:, -1]
        partition = SlabPartition.balanced(last, world, receptive_field(case_simulator("2d_walls")))
        everyone = Particles(torch.arange(start.num_particles), start.position_sequence, start.particle_type)
        owned = everyone.select(partition.owner(last) == rank)
        particles = with_halo(owned, partition, world)
        local = particles.local
        saved = {
            "owned": owned.ids,
            "local": local.ids,
            "owned_rows": particles.owned_rows,
            "halo": particles.halo_count,
        }
        saved["local_sequence"] = local.sequence
        # Latents (3 columns) holding each owned particle's id, -1 on the halo rows: the exchange fills those in.
        owned_mask = torch.zeros(local.count, dtype=torch.bool).index_fill(0, particles.owned_rows, True)
        latent = torch.where(owned_mask[:, None], local.ids[:, None].double().expand(-1, 3), -1.0)
        saved["refreshed"] = particles.refresh(latent)
        torch.save(saved, Path(out) / f"rank{rank}.pt")
    finally:
        stop()


def reading_worker(rank: int, world: int, port: int, out: str, name: str) -> None:
    """Roll ``name`` out over ``world`` processes, recording how many particles' frames each process reads at
    once (every whole-scene read of a rollout goes through ``window``); ``<out>/reads-<rank>.json``."""
    from gns_framework.decomposition import rollout as decomposed
    from gns_framework.training.distributed import stop

    processes = _join(rank, world, port)
    read: list[int] = []
    window = decomposed.window

    def recorded(trajectory, *args, **kwargs):
        read.append(trajectory.num_particles)
        return window(trajectory, *args, **kwargs)

    decomposed.window = recorded  # type: ignore[assignment]
    try:
        decomposed.partitioned_rollout(case_simulator(name), case_trajectory(name), processes, halo="latents")
        (Path(out) / f"reads-{rank}.json").write_text(json.dumps(read))
    finally:
        stop()


def in_parts_worker(rank: int, world: int, port: int, out: str, name: str, bad_particle: int) -> None:
    """Open case ``name`` in parts (a lazy split; a NaN at ``bad_particle`` when >= 0), measure it for the envelope
    and roll it out over ``world`` processes; ``<out>/in-parts-<rank>.pkl`` holds the measures and the rollout's
    prediction, or each step's error."""
    import pickle

    from gns_framework.data.in_parts import scene_in_parts
    from gns_framework.data.lazy import TrajectorySequence
    from gns_framework.decomposition.envelope import measured_in_parts
    from gns_framework.decomposition.rollout import partitioned_rollout
    from gns_framework.errors import GnsError
    from gns_framework.training.distributed import stop

    processes = _join(rank, world, port)
    raw = case_trajectory(name)
    if bad_particle >= 0:
        raw.position[3, bad_particle, 0] = np.nan
    metadata, simulator = case_metadata(name), case_simulator(name)
    split = TrajectorySequence([raw.key], lambda key: raw, f"{name}.npz", raw.dim)  # its particles drift out
    found: dict[str, object] = {}
    try:
        try:
            found["measures"] = measured_in_parts(split, 1, metadata, simulator.setup, processes)
        except GnsError as exc:
            found["measures"] = str(exc)
        try:
            rolled, _ = partitioned_rollout(simulator, scene_in_parts(split, 0), processes, steps=3, halo="latents")
            found["rollout"] = None if rolled is None else rolled.predicted
        except GnsError as exc:
            found["rollout"] = str(exc)
        (Path(out) / f"in-parts-{rank}.pkl").write_bytes(pickle.dumps(found))
    finally:
        stop()
