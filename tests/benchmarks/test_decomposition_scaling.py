"""benchmarks/decomposition_scaling.py: the lattice scene in 2D and 3D, and each measured run recorded with the
figures issue 50 asks for (particles, processes, absolute peak memory per process, seconds per step)."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

import decomposition_scaling


def test_the_lattice_is_aspect_times_as_long_as_its_other_sides():
    for dim, particles, aspect in ((2, 1000, 8.0), (3, 20_000, 4.0)):
        sites = decomposition_scaling.scene_sites(particles, aspect, dim)
        assert len(sites) == dim and math.prod(sites) >= particles
        assert abs(sites[0] / sites[1] - aspect) / aspect < 0.35 and len(set(sites[1:])) == 1


def test_a_run_appends_its_records(tmp_path, capsys):
    results = tmp_path / "decomposition_results.json"
    argv = ["--particles", "400", "--processes", "1", "2", "--dim", "3", "--aspect", "2", "--steps", "1"]
    argv += ["--train-steps", "1", "--halo", "latents", "--hops", "2", "--latent", "8", "--json"]
    argv += ["--project-particles", "20000", "--project-gpus", "1", "8"]  # a small projection: quick
    for _ in range(2):
        assert decomposition_scaling.main([*argv, "--results", str(results)]) == 0
    runs = json.loads(results.read_text())
    assert [run["processes"] for run in runs] == [1, 2, 1, 2]
    for run in runs:
        assert run["particles"] == 400 and run["dim"] == 3 and run["peak_rss_mb_per_process"] > 50
        assert run["seconds_per_step"] > 0 and run["commit"] and run["date"]
    # Each process writes its own shard: two processes' shards are each about half of one process's output.
    assert 0.35 < runs[1]["output_mb_per_process"] / runs[0]["output_mb_per_process"] < 0.75
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["rows"][1]["partition"].startswith("2 slabs")


def test_the_projection_takes_its_gpu_times_from_the_newest_device_run(tmp_path):
    assert decomposition_scaling.gpu_terms(tmp_path / "none.json") == (
        decomposition_scaling.H200,
        "H200, 2026-12-04, 1,000,000 particles (docs/performance.md)",
    )
    runs = [
        {"device": "old", "date": "d1", "commit": "a" * 40, "rollout_ms": {"1000000": 3310.0}, "training_ms": {}},
        {
            "device": "NVIDIA H200",
            "date": "2026-12-09",
            "commit": "b" * 40,
            "rollout_ms": {"10000": 2.0, "100000": 15.0},
            "training_ms": {"10000": 6.0, "100000": 50.0, "1000000": 600.0},
        },
    ]
    (tmp_path / "gpu_results.json").write_text(json.dumps(runs))
    terms, source = decomposition_scaling.gpu_terms(tmp_path / "gpu_results.json")
    assert source == "NVIDIA H200, 2026-12-09 (bbbbbbb), 100,000 particles, gpu_results.json"
    assert math.isclose(terms["rollout_seconds_per_particle"], 15e-3 / 1e5)
    assert math.isclose(terms["train_seconds_per_particle"], 50e-3 / 1e5)
    assert terms["train_bytes_per_particle"] == decomposition_scaling.H200["train_bytes_per_particle"]
    first = decomposition_scaling.projection(20_000, 2.0, 2, [1, 4])
    faster = decomposition_scaling.projection(20_000, 2.0, 2, [1, 4], terms=terms)
    # Compute scales with the time per particle; the exchanges are the same.
    ratio = terms["rollout_seconds_per_particle"] / decomposition_scaling.H200["rollout_seconds_per_particle"]
    assert math.isclose(faster[0]["rollout_seconds"], first[0]["rollout_seconds"] * ratio, rel_tol=0.05)
    assert faster[1]["halo_fraction"] == first[1]["halo_fraction"]
