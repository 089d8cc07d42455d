"""One piece of a split scene (decomposition/piece.py): the batch a process predicts on, the graph the model builds
from it, and the step a process with nothing to predict skips or stands in for."""

from __future__ import annotations

from dataclasses import replace

import torch
from decomposition_cases import case_simulator, case_trajectory

from gns_framework.data.batch import window
from gns_framework.decomposition.exchange import Routing
from gns_framework.decomposition.halo import Halo
from gns_framework.decomposition.particles import Particles
from gns_framework.decomposition.piece import on_piece, piece_batch


def _piece(window_batch, owned_rows: list[int]) -> Halo:
    """A piece of ``window_batch``'s particles: the rows ``owned_rows`` owned, the others a halo (one process)."""
    n = window_batch.num_particles
    local = Particles(
        torch.arange(n), window_batch.position_sequence, window_batch.particle_type, window_batch.material_property
    )
    halo_rows = [i for i in range(n) if i not in owned_rows]
    nothing = torch.zeros(0, dtype=torch.long)
    return Halo(
        local, torch.tensor(owned_rows), torch.tensor(halo_rows, dtype=torch.long), nothing, Routing.of(nothing, 1)
    )


def _scene(name: str = "2d_walls"):
    return window(case_trajectory(name), 0, 6, with_target=False)


def test_a_piece_of_latents_carries_its_owned_particles_and_exchange_into_the_batch():
    scene = _scene()
    piece = _piece(scene, [0, 2, 5])
    shared = replace(scene, ahead=torch.zeros(scene.num_particles, 1, 2))
    batch = piece_batch(shared, piece, "latents")
    assert batch.owned.nonzero()[:, 0].tolist() == [0, 2, 5] and batch.exchange == piece.refresh
    assert torch.equal(batch.position_sequence, piece.local.sequence) and batch.ahead is None
    assert batch.batch.tolist() == [0] * scene.num_particles and batch.walls is scene.walls
    positions = piece_batch(shared, piece, "positions")
    assert positions.owned is None and positions.exchange is None


def test_the_model_builds_edges_into_owned_particles_only_from_a_piece_of_latents():
    simulator, scene = case_simulator("2d_walls"), _scene()
    owned = [i for i in range(scene.num_particles) if i % 3 == 0]
    whole = simulator.build_graph(scene.position_sequence, scene)
    piece = _piece(scene, owned)
    graph = simulator.build_graph(scene.position_sequence, piece_batch(scene, piece, "latents"))
    into_owned = torch.isin(whole.receivers, torch.tensor(owned))
    assert 0 < graph.num_edges < whole.num_edges
    assert torch.equal(graph.senders, whole.senders[into_owned])
    assert torch.equal(graph.receivers, whole.receivers[into_owned])
    assert graph.exchange == piece.refresh and whole.exchange is None


def test_a_process_that_owns_nothing_skips_a_step_with_a_halo_of_positions():
    simulator, scene = case_simulator("2d_walls"), _scene()
    ran = []
    assert on_piece(simulator, _piece(scene, []), "positions", scene, ran.append) is None and ran == []
    result = on_piece(simulator, _piece(scene, [1]), "positions", scene, lambda batch: batch.num_particles)
    assert result == scene.num_particles


def test_a_process_without_particles_stands_in_for_each_exchange_of_a_halo_of_latents(monkeypatch):
    simulator, scene = case_simulator("2d_walls"), _scene()
    whole = _piece(scene, [])
    nothing = torch.zeros(0, dtype=torch.long)
    empty = Halo(whole.local.select(nothing), nothing, nothing, nothing, whole.routing)
    refreshes = []
    original = Halo.refresh

    def counted(self, latent):
        refreshes.append(latent.requires_grad)
        return original(self, latent)

    monkeypatch.setattr(Halo, "refresh", counted)
    assert on_piece(simulator, empty, "latents", scene, lambda batch: 1 / 0, backward=True) is None
    assert refreshes == [True]  # 2 message-passing steps: one exchange between them, with a backward
