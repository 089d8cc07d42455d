"""Every command that rolls out a model refuses data outside its training envelope, naming what and by how much.

The shipped models/sand2d_fast.pt was trained on 10.4 mm lattices (8.7 mm median
neighbour distance with jitter) and 10 ms learned steps: data at 6.25 mm and 16 ms
(issue 25's example) is refused by ``gns rollout`` and by ``gns demo``.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[2]
MODEL = REPO / "models" / "sand2d_fast.pt"


def gns(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "gns_framework.cli", *args], capture_output=True, text=True, timeout=900, cwd=cwd
    )


@pytest.fixture(scope="module")
def fine_and_slow_scene(tmp_path_factory) -> Path:
    """The demo scene at 6.25 mm spacing (grid 80) with 8 ms frames: 16 ms per learned step at stride 2."""
    raw = yaml.safe_load((REPO / "scenes" / "demo_sand_2d.yaml").read_text())
    raw["domain"]["grid"] = 80
    raw["time"] = {"frame_dt": 0.008, "substeps": 120, "frames": 16}
    path = tmp_path_factory.mktemp("scene") / "fine.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


@pytest.fixture(scope="module")
def fine_and_slow(fine_and_slow_scene, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("fine") / "data"
    made = gns(
        "generate",
        str(fine_and_slow_scene),
        "--trajectories",
        "3",
        "--valid",
        "1",
        "--test",
        "1",
        "--out",
        str(out),
        "--no-progress",
    )
    assert made.returncode == 0, made.stderr
    return out


def test_rollout_names_the_spacing_and_the_step_and_writes_nothing(fine_and_slow, tmp_path):
    result = gns("rollout", str(MODEL), "--dataset", str(fine_and_slow), "--out", str(tmp_path / "r"), "--no-progress")
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert lines[0].startswith("gns rollout: error: ") and "outside the envelope of" in lines[0]
    assert any(line.startswith("  - learned step 0.016 s (trained: 0.01 s)") for line in lines), result.stderr
    assert any(
        line.startswith("  - nearest-neighbour distance (median) 0.005") and "(trained: 0.008707 m" in line
        for line in lines
    )
    assert "Traceback" not in result.stderr and not (tmp_path / "r").exists()
    allowed = gns(
        "rollout",
        str(MODEL),
        "--dataset",
        str(fine_and_slow),
        "--out",
        str(tmp_path / "r"),
        "--no-progress",
        "--outside-envelope",
        "--on-violation",
        "clamp",
    )
    assert allowed.returncode == 0, allowed.stderr
    assert "warning: outside the envelope of" in allowed.stderr


def test_demo_refuses_a_scene_outside_the_pretrained_model(fine_and_slow_scene, tmp_path):
    result = gns(
        "demo",
        "--scene",
        str(fine_and_slow_scene),
        "--steps",
        "2",
        "--held-out",
        "1",
        "--repeats",
        "1",
        "--out",
        str(tmp_path / "demo"),
        "--no-progress",
    )
    assert result.returncode == 2, result.stderr
    assert "gns demo: error:" in result.stderr and "learned step 0.016 s" in result.stderr
    assert not (tmp_path / "demo" / "report").exists()
