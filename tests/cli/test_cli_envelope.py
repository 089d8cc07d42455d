"""``gns envelope MODEL [SCENE.yaml]`` (``gns_framework.cli.envelope``): the training envelope printed in scene-file
terms; a scene file checked against it (exit 0 inside, 1 outside, 2 for a bad scene file)."""

from __future__ import annotations

from pathlib import Path

from gns_framework.cli import main


def test_it_prints_the_envelope_in_scene_file_terms(capsys):
    assert main(["envelope", "models/sand2d_general.pt"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("models/sand2d_general.pt was trained on (step 17000):\n")
    assert "domain.grid 96 over the largest box" in out and "box x: 0.75 .. 2 m" in out


def test_a_scene_file_is_checked_field_by_field(tmp_path, capsys):
    assert main(["envelope", "models/sand2d_general.pt", "scenes/canonical/two_frictions.yaml"]) == 0
    assert "inside the envelope of models/sand2d_general.pt" in capsys.readouterr().out
    tall = tmp_path / "tall.yaml"
    tall.write_text(
        Path("scenes/canonical/tall_column_long_domain.yaml")
        .read_text()
        .replace("size: [0.2, 0.5]", "size: [0.2, 0.7]")
    )
    assert main(["envelope", "models/sand2d_general.pt", str(tall)]) == 1
    out = capsys.readouterr().out
    assert f"{tall}: 1 field(s) outside the envelope of models/sand2d_general.pt:" in out
    assert "  blocks[0].size[1]: 0.7 m along y; trained sand blocks 0.1 .. 0.5 m" in out


def test_a_bad_scene_file_is_one_line(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\n")
    assert main(["envelope", "models/sand2d_general.pt", str(bad)]) == 2
    assert capsys.readouterr().err.startswith(f"gns envelope: error: {bad}")
