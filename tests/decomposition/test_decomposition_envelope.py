"""The envelope check of a scene split over processes (decomposition/envelope.py), and its rollout read in parts:
each process measures and checks its own run of the particles, and together they equal one process reading the
whole scene; bad data in one run stops every process."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
from decomposition_cases import case_metadata, case_simulator, case_trajectory, in_parts_worker
from spawned import free_loopback_port, run_processes

from gns_framework.data.lazy import TrajectorySequence
from gns_framework.decomposition.envelope import measured_in_parts
from gns_framework.model.envelope import scene_measures
from gns_framework.model.rollout import rollout
from gns_framework.runtime.processes import Processes

pytestmark = pytest.mark.usefixtures("one_torch_thread")
NAME = "2d_walls"


def _results(tmp_path, bad_particle: int) -> list[dict]:
    run_processes(in_parts_worker, (2, free_loopback_port(), str(tmp_path), NAME, bad_particle), 2)
    return [pickle.loads((tmp_path / f"in-parts-{rank}.pkl").read_bytes()) for rank in range(2)]


def test_one_process_measures_the_whole_scene():
    scene, metadata, setup = case_trajectory(NAME), case_metadata(NAME), case_simulator(NAME).setup
    split = TrajectorySequence([scene.key], lambda key: scene, "f", scene.dim)
    whole = scene_measures(scene.validated("f"), metadata, setup.history, setup.kinematic_types)
    assert measured_in_parts(split, 1, metadata, setup, Processes()) == [whole]


def test_two_processes_measure_and_roll_out_a_scene_read_in_parts_as_one_process_does(tmp_path):
    scene, metadata = case_trajectory(NAME), case_metadata(NAME)
    setup = case_simulator(NAME).setup
    whole = scene_measures(scene.validated("f"), metadata, setup.history, setup.kinematic_types)
    first, second = _results(tmp_path, bad_particle=-1)
    assert first["measures"] == second["measures"] == [whole]
    expected = rollout(case_simulator(NAME), scene, steps=3).predicted
    np.testing.assert_allclose(first["rollout"], expected, rtol=0, atol=1e-6 * np.abs(expected).max())
    assert second["rollout"] is None  # gathered on rank 0


def test_a_bad_value_in_one_process_s_run_stops_both_and_that_one_names_it(tmp_path):
    particles = case_trajectory(NAME).num_particles
    found = _results(tmp_path, bad_particle=particles - 1)  # the last particle: the second process's run
    detail = f"non-finite value at frame 3, particle {particles - 1}"
    assert detail in found[1]["measures"] and detail in found[1]["rollout"]
    assert found[0]["measures"].startswith("another process refused the data: ") and detail in found[0]["measures"]
    assert "another process refused its particles (its error says why)" in found[0]["rollout"]
