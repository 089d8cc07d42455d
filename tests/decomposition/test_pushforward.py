"""Push-forward of a batch whose scenes are split over 2 and 4 gloo processes equals the single process's
(decomposition/pushforward.py)."""

from __future__ import annotations

import pytest
import torch
from decomposition_cases import CASES, DRIFT, FEW, pushforward_batch, pushforward_worker, single_process_pushed_forward
from spawned import free_loopback_port, run_processes

pytestmark = pytest.mark.usefixtures("one_torch_thread")

SCENES = [*CASES, *DRIFT]
ABSOLUTE = 1e-12
"""Positions of order 1 in float64, three unrolled steps whose sums may round in another order: about 1e-16 each.
A halo half as deep moves particles by 1e-6 or more (test below)."""


@pytest.fixture(scope="module")
def single_process() -> dict[str, torch.Tensor]:
    return {name: single_process_pushed_forward(name).position_sequence for name in SCENES}


def _decomposed(
    tmp_path, processes: int, halo: str, depth_scale: float = 1.0, scenes: list[str] = SCENES, cut: str = "auto"
) -> dict[str, list[dict]]:
    run_processes(
        pushforward_worker, (processes, free_loopback_port(), str(tmp_path), scenes, depth_scale, halo, cut), processes
    )
    return {
        name: [torch.load(tmp_path / f"{name}-rank{rank}.pt", weights_only=True) for rank in range(processes)]
        for name in scenes
    }


@pytest.mark.parametrize("cut", ["slabs", "blocks"])
@pytest.mark.parametrize("halo", ["positions", "latents"])
@pytest.mark.parametrize("processes", [2, 4])
def test_split_push_forward_equals_the_single_process_push_forward(tmp_path, single_process, processes, halo, cut):
    """2D and 3D, walls and periodic boundaries, kinematic particles, material properties, two windows in the batch,
    and a scene that drifts out of its first slab; every process ends with the same batch."""
    for name, ranks in _decomposed(tmp_path, processes, halo, cut=cut).items():
        batch = pushforward_batch(name)
        reference = single_process[name]
        for saved in ranks:
            assert torch.equal(saved["sequence"], ranks[0]["sequence"]), name
            assert torch.equal(saved["target"], batch.ahead[:, -1]), name  # the true frame after the unrolled steps
        torch.testing.assert_close(ranks[0]["sequence"], reference, rtol=0, atol=ABSOLUTE, msg=name)
        # The model moved the particles: the windows are not the true ones.
        assert (reference[:, -1] - batch.ahead[:, -2]).abs().max() > 1e3 * ABSOLUTE, name


@pytest.mark.parametrize("halo", ["positions", "latents"])
def test_a_process_that_owns_no_particle_still_takes_part(tmp_path, halo):
    """Three particles over four processes: the first owns none, holds only halo, and still joins every exchange."""
    for name, ranks in _decomposed(tmp_path, 4, halo, scenes=list(FEW)).items():
        reference = single_process_pushed_forward(name).position_sequence
        for saved in ranks:
            torch.testing.assert_close(saved["sequence"], reference, rtol=0, atol=ABSOLUTE, msg=name)


@pytest.mark.parametrize("halo", ["positions", "latents"])
def test_a_halo_too_shallow_pushes_forward_elsewhere(tmp_path, single_process, halo):
    for name, ranks in _decomposed(tmp_path, 2, halo, depth_scale=0.5).items():
        assert (ranks[0]["sequence"] - single_process[name]).abs().max() > 1e3 * ABSOLUTE, name
