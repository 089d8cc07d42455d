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
