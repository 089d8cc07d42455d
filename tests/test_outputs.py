"""Outputs are never silently replaced (issue 30, item 4): convert, generate, rollout, evaluate and render refuse a
non-empty output that is not their own earlier result, naming what is there, unless given --overwrite; a dataset is
replaced whole, never left a mix of two. End to end through each command, then gns_framework.outputs' functions
one by one (markers, the description of a folder, the folder and file checks, the whole replacement)."""

from __future__ import annotations

import json

import pytest
import yaml
from scene_builders import mixed
from synthetic import soft_sphere_trajectory, synthetic_metadata, write_synthetic_dataset
from tiny import tiny_recipe, tiny_trainer

from gns_framework import outputs
from gns_framework.cli import generate as generate_command
from gns_framework.cli import main
from gns_framework.errors import GnsError
from gns_framework.io.rollout_file import save_rollout
from gns_framework.outputs import MARKER
from gns_framework.plugins import load_registry


def tree(folder):
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def no_temporary_siblings(folder):
    return not [p for p in folder.parent.iterdir() if p.name.startswith(f".{folder.name}.")]


@pytest.fixture
def foreign(tmp_path):
    """A folder of the user's, holding a file that is no output of gns."""
    folder = tmp_path / "mine"
    folder.mkdir()
    (folder / "notes.txt").write_text("precious")
    return folder


# ---- convert ----------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def two_sources(tmp_path_factory):
    root = tmp_path_factory.mktemp("sources")
    first = write_synthetic_dataset(root / "first", train=2, valid=1, test=1)
    trajectories = [soft_sphere_trajectory(20 + i, key=f"second_{i}") for i in range(3)]
    second = root / "second"
    splits = {"train": trajectories[:2], "valid": trajectories[2:]}  # no test split
    load_registry().get("dataset", "safe").write(second, synthetic_metadata(splits["train"], 2), splits)
    return first, second


def convert(source, out, *extra):
    return main(["convert", str(source), "--from", "safe", "--to", "safe", "--out", str(out), *extra])


def test_convert_refuses_a_folder_of_the_users_naming_what_is_there(two_sources, foreign, capsys):
    assert convert(two_sources[0], foreign) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1
    assert f"{foreign}: not empty and not an earlier result of gns convert: it holds 1 entry: notes.txt" in err
    assert "--overwrite" in err
    assert tree(foreign) == {"notes.txt": b"precious"}


def test_convert_onto_another_dataset_never_leaves_a_mix(two_sources, tmp_path, capsys):
    """The attack: the old dataset's test split stayed beside the new one's train and valid."""
    first, second = two_sources
    out = tmp_path / "out"
    assert convert(first, out) == 0
    assert (out / "test.npz").exists()
    assert convert(second, out) == 0  # its own earlier result: replaced whole
    assert "replaced the earlier contents" in capsys.readouterr().out
    assert not (out / "test.npz").exists()
    assert {p.name for p in out.iterdir()} == {p.name for p in second.iterdir()} | {MARKER}
    assert no_temporary_siblings(out)


def test_convert_overwrite_replaces_a_foreign_folder_whole(two_sources, foreign):
    assert convert(two_sources[0], foreign, "--overwrite") == 0
    assert not (foreign / "notes.txt").exists() and (foreign / "metadata.json").is_file()


def test_a_convert_that_fails_leaves_the_earlier_dataset_as_it_was(two_sources, tmp_path, registry, monkeypatch):
    first, second = two_sources
    out = tmp_path / "out"
    assert convert(first, out) == 0
    before = tree(out)
    layout = registry.get("dataset", "safe")
    original = layout.write.__func__

    def failing(cls, path, metadata, splits):
        original(cls, path, metadata, {"train": splits["train"]})
        raise GnsError("disk full")

    monkeypatch.setattr(layout, "write", classmethod(failing))
    assert convert(second, out) == 2
    assert tree(out) == before and no_temporary_siblings(out)


# ---- generate ---------------------------------------------------------------------------------------------------


@pytest.fixture
def generate(sim_registry, monkeypatch, tmp_path):
    monkeypatch.setattr(generate_command, "load_registry", lambda: sim_registry)
    scene = tmp_path / "scene.yaml"
    scene.write_text(yaml.safe_dump(mixed(frames=6)))
    return lambda out, *extra: main(["generate", str(scene), "--out", str(out), "--no-progress", *extra])


def test_generate_refuses_another_dataset_and_a_folder_of_the_users(generate, two_sources, foreign, tmp_path, capsys):
    assert generate(foreign, "--trajectories", "3") == 2
    assert "not empty and not an earlier result of gns generate: it holds 1 entry: notes.txt" in capsys.readouterr().err
    assert tree(foreign) == {"notes.txt": b"precious"}
    converted = tmp_path / "converted"
    assert convert(two_sources[0], converted) == 0
    before = tree(converted)
    assert generate(converted, "--trajectories", "3") == 2
    assert "(written by gns convert)" in capsys.readouterr().err
    assert tree(converted) == before
    assert generate(converted, "--trajectories", "3", "--overwrite") == 0
    assert json.loads((converted / "metadata.json").read_text())["generated_from"]


def test_generate_replaces_its_own_earlier_dataset_whole_and_still_skips_an_identical_one(generate, tmp_path, capsys):
    out = tmp_path / "data"
    assert generate(out, "--trajectories", "3") == 0
    assert (out / "valid.npz").exists() and (out / "test.npz").exists()
    written = (out / "train.npz").stat().st_mtime_ns
    assert generate(out, "--trajectories", "3") == 0
    assert "already holds this dataset" in capsys.readouterr().out
    assert (out / "train.npz").stat().st_mtime_ns == written
    assert generate(out, "--trajectories", "2", "--valid", "0", "--test", "1") == 0
    metadata = json.loads((out / "metadata.json").read_text())
    assert metadata["generated_from"]["trajectories"] == {"train": 1, "valid": 0, "test": 1}
    valid = out / "valid.npz"
    assert not valid.exists() or valid.stat().st_mtime_ns > written  # never the old dataset's valid split
    assert no_temporary_siblings(out)


def test_generate_recognises_a_dataset_it_wrote_before_folders_were_marked(generate, tmp_path):
    out = tmp_path / "data"
    assert generate(out, "--trajectories", "3") == 0
    (out / MARKER).unlink()
    assert generate(out, "--trajectories", "4") == 0


# ---- render -----------------------------------------------------------------------------------------------------


def test_render_refuses_an_existing_gif_and_a_foreign_vtk_folder(make_rollout, tmp_path, foreign, capsys):
    path = save_rollout(tmp_path / "rollout.npz", make_rollout(dim=2, steps=3))
    gif = tmp_path / "anim.gif"
    gif.write_bytes(b"my own animation")
    assert main(["render", str(path), "--gif", str(gif)]) == 2
    assert f"{gif}: --gif: the file exists (16 bytes)" in capsys.readouterr().err
    assert gif.read_bytes() == b"my own animation"
    assert main(["render", str(path), "--vtk", str(foreign)]) == 2
    assert "not an earlier result of gns render" in capsys.readouterr().err
    assert tree(foreign) == {"notes.txt": b"precious"}
    assert main(["render", str(path), "--gif", str(gif), "--overwrite"]) == 0
    assert gif.read_bytes()[:3] == b"GIF"
    vtk = tmp_path / "vtk"
    assert main(["render", str(path), "--vtk", str(vtk)]) == 0
    assert main(["render", str(path), "--vtk", str(vtk)]) == 0  # its own earlier frames
    assert "writing over the earlier contents" in capsys.readouterr().err


# ---- rollout and evaluate ---------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def checkpoint(dataset_2d, tmp_path_factory):
    trainer = tiny_trainer(tiny_recipe(dataset_2d), tmp_path_factory.mktemp("run") / "run")
    trainer.train(2)
    path = trainer.checkpoints.save()
    trainer.close()
    return path


def test_rollout_refuses_a_foreign_folder_and_rewrites_its_own(checkpoint, foreign, tmp_path, capsys):
    args = ["rollout", str(checkpoint), "--split", "test", "--no-progress", "--device", "cpu", "--outside-envelope"]
    assert main([*args, "--out", str(foreign)]) == 2
    assert (
        f"{foreign}: not empty and not an earlier result of gns rollout: it holds 1 entry: notes.txt"
        in capsys.readouterr().err
    )
    assert tree(foreign) == {"notes.txt": b"precious"}
    out = tmp_path / "rollouts"
    assert main([*args, "--out", str(out)]) == 0
    assert main([*args, "--out", str(out)]) == 0
    assert "writing over the earlier contents" in capsys.readouterr().err
    (out / MARKER).unlink()  # a folder written before markers: rollout files only
    assert main([*args, "--out", str(out)]) == 0
    assert main([*args, "--out", str(foreign), "--overwrite"]) == 0
    assert (foreign / "notes.txt").read_text() == "precious" and (foreign / "test_0000.npz").is_file()


def test_evaluate_refuses_a_foreign_folder_before_any_work(checkpoint, foreign, capsys):
    assert (
        main(
            [
                "evaluate",
                "--outside-envelope",
                str(checkpoint),
                "--out",
                str(foreign),
                "--no-simulator",
                "--repeats",
                "1",
            ]
        )
        == 2
    )
    assert "not an earlier result of gns evaluate: it holds 1 entry: notes.txt" in capsys.readouterr().err
    assert tree(foreign) == {"notes.txt": b"precious"}


def test_evaluate_rewrites_its_own_report(checkpoint, tmp_path, capsys):
    out = tmp_path / "report"
    args = [
        "evaluate",
        "--outside-envelope",
        str(checkpoint),
        "--out",
        str(out),
        "--no-simulator",
        "--repeats",
        "1",
        "--warmup",
        "0",
        "--device",
        "cpu",
        "--outside-envelope",
    ]
    assert main(args) == 0
    assert main(args) == 0
    assert "writing over the earlier contents" in capsys.readouterr().err


# ---- the functions themselves -----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "content, command",
    [
        ('{"command": "convert"}', "convert"),
        ("not json", None),
        ('["convert"]', None),  # JSON, but no object
        ('{"command": 3}', None),  # an object, but no command name
        (b"\xff\xfe", None),  # no text
    ],
)
def test_the_recorded_command_is_read_from_a_well_formed_marker_only(tmp_path, content, command):
    marker = tmp_path / MARKER
    marker.write_bytes(content if isinstance(content, bytes) else content.encode())
    assert outputs.recorded_command(tmp_path) == command


def test_a_folder_without_marker_records_no_command(tmp_path):
    assert outputs.recorded_command(tmp_path) is None
    assert outputs.recorded_command(tmp_path / "absent") is None


def test_the_description_names_the_first_entries_sorted_the_count_and_the_writer(tmp_path):
    for name in ["g", "c", "a", "e", "f", "d"]:
        (tmp_path / name).write_text("")
    (tmp_path / "b").mkdir()
    outputs.write_marker(tmp_path, "rollout")
    # The marker is no entry of the user's: 7 entries, not 8.
    assert outputs.describe_contents(tmp_path) == "7 entries (written by gns rollout): a, b/, c, d, e and 2 more"
    assert outputs.describe_contents(tmp_path, most=7) == "7 entries (written by gns rollout): a, b/, c, d, e, f, g"


def test_the_description_of_one_unmarked_entry(foreign):
    assert outputs.describe_contents(foreign) == "1 entry: notes.txt"


def test_an_absent_or_empty_folder_is_free(tmp_path):
    assert outputs.check_folder(tmp_path / "new", "convert", overwrite=False) is False
    outputs.write_marker(tmp_path, "generate")  # a marker alone: nothing to replace, whoever wrote it
    assert outputs.check_folder(tmp_path, "convert", overwrite=False) is False


def test_a_folder_is_replaced_when_it_is_the_commands_own_or_overwrite_is_given(foreign):
    assert outputs.check_folder(foreign, "render", overwrite=True) is True
    assert outputs.check_folder(foreign, "render", overwrite=False, own=lambda f: (f / "notes.txt").exists()) is True
    outputs.write_marker(foreign, "render")
    assert outputs.check_folder(foreign, "render", overwrite=False) is True


def test_another_commands_folder_is_refused_naming_it(foreign):
    outputs.write_marker(foreign, "convert")
    with pytest.raises(GnsError) as info:
        outputs.check_folder(foreign, "generate", overwrite=False, own=lambda f: False)
    assert str(info.value) == (
        f"{foreign}: not empty and not an earlier result of gns generate: it holds 1 entry (written by gns convert): "
        "notes.txt; choose another folder, or pass --overwrite to write over it"
    )


def test_a_file_where_a_folder_goes_is_refused_even_with_overwrite(tmp_path):
    path = tmp_path / "out"
    path.write_text("x")
    with pytest.raises(GnsError, match="is a file, not a folder: gns rollout writes a folder there"):
        outputs.check_folder(path, "rollout", overwrite=True)


def test_claiming_a_folder_creates_and_marks_it_and_says_when_it_replaces(tmp_path, foreign, capsys):
    claimed = outputs.claim_folder(tmp_path / "a" / "b", "evaluate", overwrite=False)
    assert claimed.is_dir() and outputs.recorded_command(claimed) == "evaluate"
    assert capsys.readouterr().err == ""
    outputs.claim_folder(foreign, "evaluate", overwrite=True)
    assert capsys.readouterr().err == f"gns evaluate: writing over the earlier contents of {foreign}\n"
    assert (foreign / "notes.txt").exists()  # claiming deletes nothing: the command writes over what it must


def test_an_existing_file_output_is_replaced_only_with_overwrite(tmp_path):
    gif = tmp_path / "anim.gif"
    outputs.check_file(gif, "render", overwrite=False, option="--gif")  # absent: free
    gif.write_bytes(b"12345")
    with pytest.raises(GnsError) as info:
        outputs.check_file(gif, "render", overwrite=False, option="--gif")
    assert str(info.value) == (
        f"{gif}: --gif: the file exists (5 bytes); gns render does not replace it unless you pass --overwrite"
    )
    outputs.check_file(gif, "render", overwrite=True, option="--gif")
    with pytest.raises(GnsError, match="--gif: is a folder, not a file"):
        outputs.check_file(tmp_path, "render", overwrite=True, option="--gif")


def test_a_whole_replacement_swaps_the_folder_and_marks_it(tmp_path):
    folder = tmp_path / "data"
    folder.mkdir()
    (folder / "test.npz").write_text("old")
    with outputs.replaced_whole(folder, "convert") as staging:
        assert staging.parent == tmp_path and staging != folder and not any(staging.iterdir())
        (staging / "train.npz").write_text("new")
        assert (folder / "test.npz").read_text() == "old"  # readers still see the old dataset meanwhile
    assert sorted(p.name for p in folder.iterdir()) == [MARKER, "train.npz"]
    assert outputs.recorded_command(folder) == "convert" and no_temporary_siblings(folder)


def test_a_failed_whole_replacement_leaves_the_folder_as_it_was(tmp_path):
    folder = tmp_path / "data"
    folder.mkdir()
    (folder / "test.npz").write_text("old")
    with pytest.raises(OSError, match="disk full"), outputs.replaced_whole(folder, "convert") as staging:
        (staging / "train.npz").write_text("half")
        raise OSError("disk full")
    assert tree(folder) == {"test.npz": b"old"} and no_temporary_siblings(folder)


def test_a_whole_replacement_of_a_new_folder_creates_its_parents(tmp_path):
    folder = tmp_path / "a" / "b" / "data"
    with outputs.replaced_whole(folder, "generate") as staging:
        (staging / "metadata.json").write_text("{}")
    assert tree(folder) == {MARKER: b'{"command": "generate"}\n', "metadata.json": b"{}"}
