"""Names from data are never paths: every file name made from a trajectory key, label, recipe name, experiment
name or split is one safe component inside its output folder, and nothing lands outside it."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from tiny import tiny_recipe, tiny_recipe_mapping, tiny_trainer

from gns_framework.cli import main
from gns_framework.cli.evaluate import model_labels
from gns_framework.config.recipe import validate_recipe
from gns_framework.safe_names import (
    MAX_COMPONENT,
    UnsafePathError,
    ensure_inside,
    require_component,
    safe_component,
    unique_components,
)

pytestmark = pytest.mark.usefixtures("one_torch_thread")

SAFE = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$")

HOSTILE = [
    "/abs/path/name",
    "../../../../x",
    "..",
    ".",
    "",
    "-rf",
    "--help",
    ".hidden",
    "a\x00b",
    "a\\..\\b",
    "C:\\x",
    "con",
    "NUL.txt",
    "x" * 500,
    "é/ü",
    "a/b",
    "trailing.",
    " ",
    "\n",
    "~",
    "$HOME",
    "a" * 99 + "/",
]


def assert_one_safe_component(component: str) -> None:
    assert SAFE.match(component), component
    assert component not in (".", "..") and "\x00" not in component and "/" not in component and "\\" not in component
    assert len(component) <= MAX_COMPONENT and not component.endswith(".")
    assert Path(component).name == component and len(Path(component).parts) == 1


# --- the helper ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["simulation_trajectory_0", "train", "sand2d_fast", "a.b-c", "case_0001", "Water2D"])
def test_a_safe_name_is_kept_as_it_is(name):
    assert safe_component(name) == name
    assert require_component(name, "split") == name


@pytest.mark.parametrize("name", HOSTILE, ids=repr)
def test_any_name_becomes_one_safe_component_with_a_hash_of_the_original(name, tmp_path):
    component = safe_component(name)
    assert_one_safe_component(component)
    assert re.search(r"-[0-9a-f]{8}$", component), "a changed name carries a hash of the original"
    assert ensure_inside(tmp_path / component, tmp_path) == tmp_path / component
    with pytest.raises(UnsafePathError, match="must be a plain name"):
        require_component(name, "split")


def test_names_that_clean_to_the_same_text_stay_apart():
    cleaned = [safe_component(name) for name in ("a/b", "a\\b", "a b", "a_b", "../a_b", "/a_b")]
    assert len(set(cleaned)) == len(cleaned) and cleaned[3] == "a_b"
    assert safe_component("x" * 500) != safe_component("x" * 499)


@settings(max_examples=300, deadline=None, database=None, derandomize=True)
@given(st.text(max_size=300))
def test_safe_component_of_any_text(text):
    component = safe_component(text)
    assert_one_safe_component(component)
    assert safe_component(component) == component, "idempotent"
    assert (component == text) == bool(
        SAFE.match(text)
        and len(text) <= MAX_COMPONENT
        and not text.endswith(".")
        and text.split(".")[0].lower() not in {"con", "prn", "aux", "nul"}
        and not re.match(r"(?i)(com|lpt)[1-9]$", text.split(".")[0])
    )


def test_unique_components_never_repeat_in_one_folder_ignoring_case():
    names = ["a", "A", "a", "a/b", "a_b", "a_b", "../x", "../x"]
    components = unique_components(names)
    assert len({c.casefold() for c in components}) == len(names)
    assert components[:3] == ["a", "A-2", "a-3"] and components[4:6] == ["a_b", "a_b-2"]
    assert unique_components(["a"], taken=["A"]) == ["a-2"]
    assert all(len(c) <= MAX_COMPONENT for c in unique_components(["y" * 300] * 12))


def test_ensure_inside_refuses_every_way_out_naming_path_and_folder(tmp_path):
    out = tmp_path / "out"
    (out / "sub").mkdir(parents=True)
    (tmp_path / "elsewhere").mkdir()
    (out / "link").symlink_to(tmp_path / "elsewhere")
    for path in (
        out / ".." / "x.npz",
        out / "sub" / ".." / ".." / "x",
        Path("/etc/passwd"),
        out / "link" / "x.npz",
        out,
        out / "sub" / "..",
    ):
        with pytest.raises(UnsafePathError) as info:
            ensure_inside(path, out)
        assert str(path) in str(info.value) and f"outside its output folder {out}" in str(info.value)
    assert ensure_inside(out / "sub" / "x.npz", out) == out / "sub" / "x.npz"
    # A link as the file itself is replaced by the write (atomic rename), not followed: that stays inside.
    (out / "file.npz").symlink_to(tmp_path / "elsewhere" / "victim.npz")
    assert ensure_inside(out / "file.npz", out) == out / "file.npz"
    # Relative paths and a folder reached through a link of its own are fine.
    (tmp_path / "alias").symlink_to(out)
    assert ensure_inside(tmp_path / "alias" / "x.npz", out) == tmp_path / "alias" / "x.npz"


def test_model_labels_are_safe_components(tmp_path):
    labels = model_labels(
        ["..", "-x", "a/b", "a/b"], [tmp_path / f"{n}/checkpoints/best.pt" for n in ("..", ".", "c", "c")]
    )
    for label in labels:
        assert_one_safe_component(label)
    assert len(set(labels)) == 4
    assert model_labels([".."], [tmp_path / "m.pt"]) == ["model"]


# --- every source of names, end to end -------------------------------------------------------------------------


def tree(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (links not followed) with its content."""
    return {
        str(p.relative_to(folder)): p.read_bytes()
        for p in sorted(folder.rglob("*"))
        if p.is_file() and not p.is_symlink()
    }


@pytest.fixture(scope="module")
def checkpoint(dataset_2d, tmp_path_factory) -> Path:
    trainer = tiny_trainer(tiny_recipe(dataset_2d), tmp_path_factory.mktemp("model") / "run")
    trainer.train(1)
    path = trainer.checkpoints.save()
    trainer.close()
    return path


def hostile_keyed_dataset(folder: Path, source: Path, keys: list[str], registry) -> Path:
    """``source``'s test trajectory under each of ``keys`` (its other splits as they are)."""
    cls = registry.get("dataset", "safe")
    dataset = cls(cls.Params(), source)
    splits = {split: list(dataset.split(split)) for split in dataset.splits()}
    splits["test"] = [dataclasses.replace(splits["test"][0], key=key) for key in keys]
    cls.write(folder, dataset.metadata(), splits)
    return folder


def test_trajectory_keys_through_evaluate_gif_and_vtk_stay_inside_out(
    checkpoint, dataset_2d, tmp_path, registry, capsys
):
    """The reported attack: keys ``/abs/path/name`` and ``../../../../x`` overwrote a user's files."""
    victim = tmp_path / "victim"
    victim.mkdir()
    absolute_key = str(victim / "name")
    out = tmp_path / "w" / "report"
    # Where the keys pointed: <out>/rollouts/tiny/<key>.npz
    targets = [victim / "name.npz", tmp_path / "x.npz"]
    for target in targets:
        target.write_bytes(b"the user's file")
    keys = [absolute_key, "../../../../x", ".."]
    data = hostile_keyed_dataset(tmp_path / "data", dataset_2d, keys, registry)
    before = {k: v for k, v in tree(tmp_path).items() if not k.startswith(("w/", "data/"))}

    code = main(
        [
            "evaluate",
            "--outside-envelope",
            str(checkpoint),
            "--dataset",
            str(data),
            "--out",
            str(out),
            "--no-simulator",
            "--repeats",
            "1",
            "--warmup",
            "0",
            "--gif",
            "--vtk",
        ]
    )

    assert code == 0, capsys.readouterr().err
    after = {k: v for k, v in tree(tmp_path).items() if not k.startswith(("w/", "data/"))}
    assert after == before, "nothing outside --out was written or changed"
    assert all(t.read_bytes() == b"the user's file" for t in targets)
    rollouts = sorted(p.relative_to(out / "rollouts").as_posix() for p in (out / "rollouts").rglob("*.npz"))
    expected = [f"tiny/{c}.npz" for c in unique_components(keys)]
    assert rollouts == sorted(expected) and len(rollouts) == 3, "one file per trajectory, none overwritten"
    assert (out / "tiny.gif").is_file() and (out / "vtk" / "tiny" / "predicted.pvd").is_file()
    for path in out.rglob("*"):
        assert path.resolve().is_relative_to(out.resolve())


def test_candidate_labels_and_case_keys_in_the_report_api_stay_inside_rollout_dir(tmp_path):
    from rollouts import small_metadata

    from gns_framework.data.trajectory import Trajectory
    from gns_framework.evaluation.report import Candidate, Prediction, evaluate

    rng = np.random.default_rng(0)
    position = rng.random((8, 5, 2)).astype(np.float32) * 0.5 + 0.25
    cases = [Trajectory(position, np.full(5, 5), key=key) for key in ("../../up", "/abs/x", "ok")]

    def still(case):
        return Prediction(np.repeat(case.position[5:6], len(case.position) - 5, axis=0))

    names = ["../../../model", "/tmp/model", "a/b"]
    report = evaluate(
        [Candidate(n, "learned", still) for n in names],
        cases,
        small_metadata(),
        5,
        repeats=1,
        warmup=0,
        rollout_dir=tmp_path / "out" / "rollouts",
    )
    written = [p for e in report.entries for p in e.rollout_files]
    assert len(set(written)) == 9 and all(p.parent.parent == tmp_path / "out" / "rollouts" for p in written)
    assert sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*") if p.is_file()) == sorted(
        p.relative_to(tmp_path).as_posix() for p in written
    )


def test_a_recipe_named_dot_dot_trains_in_its_own_folder_under_runs(
    dataset_2d, tmp_path, monkeypatch, registry, capsys
):
    """``name: ".."`` wrote into the working directory and overwrote the user's recipe.yaml."""
    monkeypatch.chdir(tmp_path)
    raw = tiny_recipe_mapping(dataset_2d)
    raw["name"] = ".."
    (tmp_path / "recipe.yaml").write_text(yaml.safe_dump(raw))
    mine = (tmp_path / "recipe.yaml").read_bytes()
    recipe = validate_recipe(raw, registry)
    assert recipe.run_dir.parent == Path("runs") and recipe.run_dir.name == safe_component("..") != ".."

    code = main(["train", "recipe.yaml", "--steps", "1", "--no-progress", "--no-tracking"])

    assert code == 0, capsys.readouterr().err
    assert (tmp_path / "recipe.yaml").read_bytes() == mine
    assert sorted(p.name for p in tmp_path.iterdir()) == ["recipe.yaml", "runs"]
    assert list((tmp_path / "runs").iterdir()) == [tmp_path / recipe.run_dir]
    assert (tmp_path / recipe.run_dir / "checkpoints").is_dir()


@pytest.mark.parametrize("experiment", ["../../x", "/abs/store", ".."])
def test_an_experiment_name_never_puts_artifacts_outside_the_store(experiment, tmp_path):
    from gns_framework.training.mlflow_tracker import ARTIFACTS_FOLDER, _local_artifact_root

    store = tmp_path / "store"
    uri = _local_artifact_root(f"sqlite:///{store / 'mlflow.db'}", experiment)
    folder = Path(uri.removeprefix("file://"))
    assert folder.parent == (store / ARTIFACTS_FOLDER).resolve() and folder.name == safe_component(experiment)


def test_train_and_compare_with_a_hostile_experiment_name(dataset_2d, tmp_path, monkeypatch, capsys):
    """``--experiment "../../x"`` wrote artifacts outside the store; its compare plot stays in the working directory."""
    pytest.importorskip("mlflow")
    import mlflow

    work = tmp_path / "a" / "b"
    work.mkdir(parents=True)
    monkeypatch.chdir(work)
    uri = f"sqlite:///{tmp_path / 'a' / 'b' / 'store' / 'mlflow.db'}"
    (work / "store").mkdir()
    (work / "recipe.yaml").write_text(yaml.safe_dump(tiny_recipe_mapping(dataset_2d, work / "run")))
    experiment = "../../x"

    code = main(
        ["train", "recipe.yaml", "--steps", "1", "--no-progress", "--tracking-uri", uri, "--experiment", experiment]
    )
    assert code == 0, capsys.readouterr().err
    location = mlflow.MlflowClient(uri).get_experiment_by_name(experiment).artifact_location
    assert Path(location.removeprefix("file://")).is_relative_to((work / "store" / "mlartifacts").resolve())

    assert main(["compare", experiment, "--tracking-uri", uri, "--plot"]) == 0, capsys.readouterr().err
    plot = Path(capsys.readouterr().out.strip().splitlines()[-1].split("plot in ")[-1])
    assert plot.name.startswith("compare-") and plot.parent == Path(".") and (work / plot).is_file()
    assert sorted(p.name for p in tmp_path.rglob("*") if not p.resolve().is_relative_to(work.resolve())) == ["a"]


@pytest.mark.parametrize("split", ["../../x", "/abs/test", "..", "te/st"])
def test_a_split_name_is_never_a_path(split, checkpoint, dataset_2d, tmp_path, capsys):
    """``--split`` names a file of the dataset folder to read and the rollout files to write: a plain name only."""
    out = tmp_path / "out"
    code = main(
        ["rollout", "--outside-envelope", str(checkpoint), "--split", split, "--out", str(out), "--no-progress"]
    )
    err = capsys.readouterr().err
    assert code == 2 and f"--split {split!r}: must be a plain name" in err and err.count("\n") == 1, err
    code = main(
        ["evaluate", "--outside-envelope", str(checkpoint), "--split", split, "--out", str(out), "--no-simulator"]
    )
    err = capsys.readouterr().err
    assert code == 2 and f"--split {split!r}: must be a plain name" in err, err
    assert not out.exists()


def test_rollout_files_of_a_split_stay_inside_out(checkpoint, tmp_path, capsys):
    out = tmp_path / "out"
    assert (
        main(
            [
                "rollout",
                "--outside-envelope",
                str(checkpoint),
                "--split",
                "test",
                "--out",
                str(out),
                "--no-progress",
                "--steps",
                "2",
            ]
        )
        == 0
    )
    assert sorted(p.name for p in out.iterdir() if p.name != ".gns-output.json") == ["test_0000.npz"]


def test_convert_refuses_a_source_split_that_is_a_path(dataset_2d, tmp_path, registry, monkeypatch, capsys):
    cls = registry.get("dataset", "safe")
    monkeypatch.setattr(cls, "splits", lambda self: ["../../escaped"])
    monkeypatch.setattr(cls, "split", lambda self, name: [])
    out = tmp_path / "out"
    code = main(["convert", str(dataset_2d), "--from", "safe", "--to", "npz", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and f"{dataset_2d}: split '../../escaped': must be a plain name" in err, err
    assert not out.exists() and not (tmp_path.parent / "escaped.npz").exists()


def test_a_vtk_series_name_is_one_file_name(tmp_path):
    from gns_framework.io.vtk import write_vtk_series

    with pytest.raises(UnsafePathError, match=r"VTK series name '\.\./x'"):
        write_vtk_series(tmp_path / "vtk", "../x", np.zeros((2, 3, 2)), 0.1, np.zeros(3, int))
    assert not (tmp_path / "x").exists() and not (tmp_path / "x.pvd").exists()
