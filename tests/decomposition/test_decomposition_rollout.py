"""A rollout split over 2 and 4 gloo processes equals the single-process rollout (decomposition/rollout.py)."""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest
from decomposition_cases import (
    CASES,
    case_simulator,
    case_trajectory,
    narrow_guard,
    partitioned_worker,
    reading_worker,
)
from spawned import free_loopback_port, run_processes

from gns_framework.decomposition.rollout import partitioned_rollout
from gns_framework.io.rollout_file import load_rollout
from gns_framework.model.rollout import rollout
from gns_framework.runtime.processes import Processes

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def single_process() -> dict[str, np.ndarray]:
    return {name: rollout(case_simulator(name), case_trajectory(name)).predicted for name in CASES}


def _partitioned(
    tmp_path,
    processes: int,
    halo: str,
    depth_scale: float = 1.0,
    cases: tuple[str, ...] = tuple(CASES),
    cut: str = "slabs",
    rebalance: float | None = 1.25,
    sharded: bool = False,
    narrow: bool = False,
) -> dict[str, np.ndarray]:
    options = (depth_scale, halo, cut, rebalance, sharded, narrow)
    arguments = (processes, free_loopback_port(), str(tmp_path), list(cases), *options)
    run_processes(partitioned_worker, arguments, processes)
    return {name: np.load(tmp_path / f"{name}.npy") for name in cases}


def _tolerance(reference: np.ndarray) -> float:
    """One float32 rounding of positions of this size per step of the rollout.

    The processes' smaller matrix products may round differently on other CPUs (here
    the results are bitwise equal). A halo one hop short is off by 8e-5 to 5e-4 in
    these scenes, 58x or more above this.
    """
    return np.finfo(np.float32).eps * float(np.abs(reference).max()) * reference.shape[0]


@pytest.mark.parametrize("halo", ["positions", "latents"])
@pytest.mark.parametrize("processes", [2, 4])
def test_a_partitioned_rollout_equals_the_single_process_one(tmp_path, single_process, processes, halo):
    """2D and 3D, walls and periodic boundaries, kinematic particles and material properties; particles migrate."""
    partitioned = _partitioned(tmp_path, processes, halo)
    for name, reference in single_process.items():
        np.testing.assert_allclose(partitioned[name], reference, rtol=0, atol=_tolerance(reference), err_msg=name)
        summary = json.loads((tmp_path / f"{name}.json").read_text())
        assert summary["kind"] == halo
        assert summary["migrations"] > 0, f"{name}: no particle crossed a slab face; the test would miss migration"
        assert 0 < summary["halo_fraction"] < processes, name


@pytest.mark.parametrize("halo", ["positions", "latents"])
def test_a_rollout_cut_into_blocks_equals_the_single_process_one(tmp_path, single_process, halo):
    """Four blocks by recursive bisection: halos across corners, and through periodic faces in 2D and 3D."""
    partitioned = _partitioned(tmp_path, 4, halo, cut="blocks")
    for name, reference in single_process.items():
        np.testing.assert_allclose(partitioned[name], reference, rtol=0, atol=_tolerance(reference), err_msg=name)
        summary = json.loads((tmp_path / f"{name}.json").read_text())
        assert summary["partition"] == "4 blocks (recursive bisection)" and summary["migrations"] > 0, name


@pytest.mark.parametrize("cut", ["slabs", "blocks"])
@pytest.mark.parametrize("halo", ["positions", "latents"])
def test_a_halo_too_shallow_gives_different_positions(tmp_path, single_process, halo, cut):
    """The equality above is not luck: half the halo each kind needs changes the owned particles' predictions."""
    partitioned = _partitioned(tmp_path, 2 if cut == "slabs" else 4, halo, depth_scale=0.5, cut=cut)
    for name, reference in single_process.items():
        assert np.abs(partitioned[name] - reference).max() > 10 * _tolerance(reference), name


@pytest.mark.parametrize("halo", ["positions", "latents"])
def test_a_process_left_without_particles_keeps_taking_part(tmp_path, halo):
    """Every particle drifts out of the first slab (kept, not re-cut): its process then owns none, and the others
    still finish."""
    name = "2d_drift"
    reference = rollout(case_simulator(name), case_trajectory(name)).predicted
    partitioned = _partitioned(tmp_path, 4, halo, cases=(name,), rebalance=None)[name]
    np.testing.assert_allclose(partitioned, reference, rtol=0, atol=_tolerance(reference))
    first_cut = float(np.sort(case_trajectory(name).position[5, :, 0])[len(reference[0]) // 4])
    assert (reference[-1, :, 0] > first_cut + 0.2).all(), "every particle left the first slab, beyond its halo"


@pytest.mark.parametrize("cut", ["slabs", "blocks"])
def test_pieces_cut_afresh_as_the_particles_crowd_give_the_same_rollout(tmp_path, cut):
    """The drifting scene again, re-cut whenever a process holds more than 1.25x its share."""
    name = "2d_drift"
    reference = rollout(case_simulator(name), case_trajectory(name)).predicted
    partitioned = _partitioned(tmp_path, 4, "latents", cases=(name,), cut=cut)[name]
    np.testing.assert_allclose(partitioned, reference, rtol=0, atol=_tolerance(reference))
    summary = json.loads((tmp_path / f"{name}.json").read_text())
    assert summary["rebalances"] >= 1 and summary["migrations"] > 0


@pytest.mark.parametrize("name", ["3d_periodic", "2d_walls"])
def test_a_rollout_written_in_shards_reads_back_as_the_single_process_one(tmp_path, single_process, name):
    """Each process writes its own particles' frames; the shards read back as one rollout equal to one process's."""
    partitioned = _partitioned(tmp_path, 2, "latents", cases=(name,), sharded=True)[name]
    reference = single_process[name]
    np.testing.assert_allclose(partitioned, reference, rtol=0, atol=_tolerance(reference))
    folder = tmp_path / f"{name}.rollout"
    assert sorted(p.name for p in folder.iterdir()) == ["rollout.json", "shard-00000.h5", "shard-00001.h5"]
    particles = reference.shape[1]
    for shard in sorted(folder.glob("*.h5")):
        with h5py.File(shard, "r") as opened:
            offsets = opened["frames/offsets"][()]
            rows = np.diff(offsets)
            assert len(rows) == reference.shape[0] and rows.min() > 0 and rows.max() < particles, shard.name
    read = load_rollout(folder)
    truth = case_trajectory(name).position[6:]
    np.testing.assert_array_equal(read.ground_truth, truth)
    assert read.predicted_particles is not None and read.predicted_particles.sum() == 2 * particles // 3


def test_the_guard_checks_each_process_s_particles_and_its_clamps_add_up_to_one_process_s(tmp_path):
    """Walls narrower than the scene hold particles back at most steps, on both pieces: the clamps the processes
    report (and the shards keep) are those of one process guarding whole frames, particle for particle."""
    name = "2d_walls"
    reference = rollout(case_simulator(name), case_trajectory(name), guard=narrow_guard(name))
    assert len(reference.guard_violations) >= 6, "the narrow walls must hold particles back at several steps"
    for sharded in (False, True):
        partitioned = _partitioned(tmp_path, 2, "latents", cases=(name,), sharded=sharded, narrow=True)[name]
        np.testing.assert_allclose(partitioned, reference.predicted, rtol=0, atol=_tolerance(reference.predicted))
        summary = json.loads((tmp_path / f"{name}.json").read_text())
        expected = [v.describe() for v in reference.guard_violations]
        assert summary["clamps"] == expected and summary["read_back_clamps"] == expected, sharded


def test_each_process_reads_only_its_run_of_the_particles_frames(tmp_path):
    """The pieces are cut from a coarse summary of each process's own run of particles: no process reads the
    whole scene's input frames (the 4 runs of 420 particles hold 105 each)."""
    name = "3d_walls"
    run_processes(reading_worker, (4, free_loopback_port(), str(tmp_path), name), 4)
    particles = case_trajectory(name).num_particles
    for rank in range(4):
        read = json.loads((tmp_path / f"reads-{rank}.json").read_text())
        assert read and max(read) <= -(-particles // 4), (rank, read)


def test_a_rebalance_ratio_of_one_or_less_is_refused():
    with pytest.raises(ValueError, match="rebalance must be more than 1"):
        partitioned_rollout(case_simulator("2d_walls"), case_trajectory("2d_walls"), Processes(), rebalance=1.0)


def test_one_process_is_the_plain_rollout(single_process):
    name = "2d_periodic"
    result, stats = partitioned_rollout(case_simulator(name), case_trajectory(name), Processes())
    assert result is not None and stats.halo == 0 and stats.migrations == 0
    np.testing.assert_array_equal(result.predicted, single_process[name])
