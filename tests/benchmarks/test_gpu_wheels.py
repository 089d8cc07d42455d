"""benchmarks/gpu_wheels.py installs, of the prepared wheels, exactly what the interpreter lacks or has too old.

Planned on small wheels made here (a METADATA file each), against a made-up set of
installed versions: no network, no pip.
"""

from __future__ import annotations

import zipfile
from pathlib import Path

import pytest
from load_script import load_script

REPO = Path(__file__).resolve().parents[2]
gpu_wheels = load_script("benchmarks/gpu_wheels.py")

PROJECT_REQUIRES = [
    "torch>=2.11,<2.14",
    "torch-geometric<2.9,>=2.8",
    "pluggy>=1.5",
    "pydantic>=2.7",
    "numpy>=1.26",
    "warp-lang==1.19.0",
    'pytest>=8; extra == "test"',
    'geomloss>=0.3.1; extra == "eval"',
    'meshio>=5.3; extra == "eval"',
    'mlflow>=3; extra == "tracking"',
]
DEVICE = {
    "torch": "2.11.0+cu130",
    "torch-geometric": "2.8.0.post1",
    "pluggy": "1.6.0",
    "numpy": "2.5.2",
    "typing-extensions": "4.12.2",
    "scipy": "1.16.0",
}
"""Versions as on the lent GPU machine, but for typing-extensions: older than pydantic-core needs."""


def _wheel(folder: Path, filename: str, requires: list[str]) -> Path:
    name, version = filename.split("-")[:2]
    path = folder / filename
    metadata = f"Metadata-Version: 2.1\nName: {name}\nVersion: {version}\n" + "".join(
        f"Requires-Dist: {r}\n" for r in requires
    )
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr(f"{name}-{version}.dist-info/METADATA", metadata)
    return path


@pytest.fixture
def folder(tmp_path) -> Path:
    _wheel(tmp_path, "gns_framework-0.1.0-py3-none-any.whl", PROJECT_REQUIRES)
    _wheel(
        tmp_path,
        "pydantic-2.14.4-py3-none-any.whl",
        [
            "annotated-types>=0.6.0",
            "pydantic-core==2.50.5",
            "typing-extensions>=4.14.1",
            "typing-inspection>=0.4.2",
            'email-validator>=2.0.0; extra == "email"',
        ],
    )
    _wheel(
        tmp_path,
        "pydantic_core-2.50.5-cp312-cp312-manylinux2014_x86_64.manylinux_2_17_x86_64.whl",
        ["typing-extensions>=4.14.1"],
    )
    _wheel(tmp_path, "annotated_types-0.8.0-py3-none-any.whl", ['typing-extensions>=4.0.0; python_version < "3.9"'])
    _wheel(tmp_path, "typing_inspection-0.4.5-py3-none-any.whl", ["typing-extensions>=4.12.0"])
    _wheel(tmp_path, "typing_extensions-4.16.0-py3-none-any.whl", [])
    _wheel(tmp_path, "geomloss-0.3.1-py3-none-any.whl", ["numpy", "scipy", "torch"])
    return tmp_path


def _plan(folder, installed: dict[str, str]):
    versions = {gpu_wheels.normalize(k): v for k, v in installed.items()}
    chosen, optional, problems = gpu_wheels.plan(
        folder, lambda name: versions.get(gpu_wheels.normalize(name)), gpu_wheels.marker_environment("3.12")
    )
    return sorted(gpu_wheels.wheel_name_version(p)[0] for p in chosen), optional, problems


def test_on_the_device_it_installs_the_project_pydantic_and_a_newer_typing_extensions(folder):
    chosen, optional, problems = _plan(folder, DEVICE)
    assert problems == []
    assert chosen == [
        "annotated-types",
        "geomloss",
        "gns-framework",
        "pydantic",
        "pydantic-core",
        "typing-extensions",
        "typing-inspection",
    ]
    assert sorted(optional) == ["warp-lang"], "torch-geometric 2.8.0.post1 is there; warp-lang is optional"


def test_what_is_installed_in_a_fitting_version_is_not_installed_again(folder):
    chosen, _, problems = _plan(
        folder,
        {
            **DEVICE,
            "typing-extensions": "4.16.0",
            "pydantic": "2.11.0",
            "pydantic-core": "2.33.2",
            "typing-inspection": "0.4.1",
            "annotated-types": "0.7.0",
        },
    )
    assert problems == [] and chosen == ["geomloss", "gns-framework"]
    chosen, _, _ = _plan(
        folder,
        {
            **DEVICE,
            "gns-framework": "0.1.0",
            "geomloss": "0.3.1",
            "pydantic": "2.11.0",
            "typing-extensions": "4.16.0",
            "typing-inspection": "0.4.1",
            "annotated-types": "0.7.0",
            "pydantic-core": "2.33.2",
        },
    )
    assert chosen == [], "an interpreter with everything (the repository's .venv) installs nothing"


def test_the_rehearsal_venv_lacks_torch_geometric_which_is_optional(folder):
    rehearsal = {k: v for k, v in DEVICE.items() if k != "torch-geometric"} | {"torch": "2.13.0+cpu"}
    chosen, optional, problems = _plan(folder, rehearsal)
    assert problems == [] and "gns-framework" in chosen and sorted(optional) == ["torch-geometric", "warp-lang"]


def test_a_torch_outside_the_supported_range_or_a_missing_wheel_is_a_problem(folder):
    _, _, problems = _plan(folder, {**DEVICE, "torch": "2.10.0"})
    assert any(p.startswith("gns-framework needs torch") and "2.10.0 is installed" in p for p in problems)
    (folder / "pydantic-2.14.4-py3-none-any.whl").unlink()
    _, _, problems = _plan(folder, DEVICE)
    assert any("needs pydantic>=2.7: it is not installed" in p for p in problems)


def test_an_unprepared_folder_says_to_run_prepare(tmp_path):
    chosen, _, problems = gpu_wheels.plan(tmp_path, lambda name: None, gpu_wheels.marker_environment("3.12"))
    assert chosen == [] and "gpu_check.sh --prepare" in problems[0]


def test_only_the_extras_the_check_uses_are_carried(folder):
    metadata = gpu_wheels.wheel_metadata(folder / "gns_framework-0.1.0-py3-none-any.whl")
    names = {
        r.name
        for r in gpu_wheels.requirements_of(metadata, gpu_wheels.marker_environment("3.12"), gpu_wheels.CHECK_EXTRAS)
    }
    assert "geomloss" in names and not names & {"meshio", "pytest", "mlflow"}


def test_the_install_command_fails_without_wheels_for_this_python(tmp_path, capsys, monkeypatch):
    """On the device (the project not installed) the prepared folder is needed."""
    monkeypatch.setattr(gpu_wheels, "_already_complete", lambda: False)
    (tmp_path / "cp399").mkdir()
    assert gpu_wheels.install(tmp_path, tmp_path / "site") == 1
    assert "run benchmarks/gpu_check.sh --prepare" in capsys.readouterr().err


def test_the_projects_own_environment_needs_no_prepared_folder(tmp_path, capsys):
    """Here (and in CI) the project and its requirements are installed: nothing to carry or install."""
    assert gpu_wheels._already_complete()
    assert gpu_wheels.install(tmp_path / "absent", tmp_path / "site") == 0
    assert "installed=none" in capsys.readouterr().out and not (tmp_path / "site").exists()
    assert not gpu_wheels._already_complete(installed=lambda name: None)


def test_the_largest_folders_that_travel_are_named_by_their_bytes(tmp_path, monkeypatch):
    files = {"models/in_training/a.pt": 50, "models/in_training/b.pt": 30, "models/c.pt": 40, "README.md": 5}
    for name, size in files.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_bytes(b"x" * size)
    (tmp_path / "gpu_wheels").mkdir()
    (tmp_path / "gpu_wheels" / "w.whl").write_bytes(b"x" * 100)
    monkeypatch.setattr(gpu_wheels, "REPO", tmp_path)
    monkeypatch.setattr(gpu_wheels, "_working_tree_files", lambda: [*files, "gpu_wheels/w.whl"])
    largest = gpu_wheels._largest_folders(tmp_path / "gpu_wheels")
    assert largest == [("models/in_training", 80), ("models", 40), (".", 5)]
