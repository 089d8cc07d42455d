"""``gns render`` end to end, and the promise that plain imports stay light."""

from __future__ import annotations

import json
import subprocess
import sys

import meshio
from PIL import Image

from gns_framework.io.rollout_file import save_rollout
from gns_framework.io.vtk import read_pvd

HEAVY = ("matplotlib", "meshio", "geomloss", "mlflow")


def gns(*args: str) -> subprocess.CompletedProcess:
    entry_point = "import sys; from gns_framework.cli import main; sys.exit(main())"
    return subprocess.run(
        [sys.executable, "-c", entry_point, *args], check=False, capture_output=True, text=True, timeout=120
    )


def test_render_writes_vtk_and_gif(make_rollout, tmp_path):
    path = save_rollout(tmp_path / "rollout.npz", make_rollout(dim=2, steps=4))
    result = gns(
        "render", str(path), "--vtk", str(tmp_path / "vtk"), "--gif", str(tmp_path / "anim.gif"), "--every", "3"
    )
    assert result.returncode == 0, result.stderr
    frames = read_pvd(tmp_path / "vtk" / "predicted.pvd")
    assert len(frames) == 10 and meshio.read(frames[0][1]).points.shape == (12, 3)
    assert (tmp_path / "vtk" / "ground_truth.pvd").is_file()
    with Image.open(tmp_path / "anim.gif") as gif:
        assert gif.n_frames == 4
    # Drawing takes time: both steps show how far they are (20 VTK frames: 10 per series; 4 GIF frames).
    assert "render VTK frames" in result.stderr and "20/20" in result.stderr
    assert "render GIF frames" in result.stderr and "4/4" in result.stderr
    quiet = gns("render", str(path), "--gif", str(tmp_path / "quiet.gif"), "--no-progress")
    assert quiet.returncode == 0 and "render" not in quiet.stderr


def test_render_reports_bad_input_by_file_and_field(make_rollout, tmp_path):
    result = gns("render", str(tmp_path / "absent.npz"), "--gif", str(tmp_path / "a.gif"))
    assert result.returncode == 2 and "absent.npz: rollout file not found" in result.stderr
    result = gns("render", str(tmp_path / "absent.npz"), "--gif", str(tmp_path / "a.mp4"))
    assert result.returncode == 2 and "written as .gif" in result.stderr
    result = gns("render", str(tmp_path / "absent.npz"))
    assert result.returncode == 2 and "nothing to do" in result.stderr


def test_help_and_plain_imports_load_no_heavy_optional_package():
    code = (
        "import contextlib, io, json, sys\n"
        "import gns_framework.evaluation.metrics, gns_framework.evaluation.report\n"
        "import gns_framework.io.vtk, gns_framework.viz.animation, gns_framework.cli.render\n"
        "from gns_framework.cli import main\n"
        "with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):\n"
        "    main(['--help'])\n"
        f"print(json.dumps([m for m in {list(HEAVY)!r} if m in sys.modules]))\n"
    )
    result = subprocess.run([sys.executable, "-c", code], check=False, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout) == []
