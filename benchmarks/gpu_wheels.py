"""Wheels for a GPU machine that lacks them: made here by ``gpu_check.sh --prepare``, installed there by
``gpu_check.sh``.

The lent GPU machine (docs/performance.md, "GPUs") has Python 3.12 and torch, numpy,
pluggy, PyYAML, tqdm, scipy, h5py and matplotlib, but no pydantic, no gns-framework
and no registry to install from. ``prepare`` (run here, with network) writes

    gpu_wheels/cp312/   the project's wheel and every wheel the check needs that the
                        machine lacks, for CPython 3.12 manylinux x86_64 (the device)
    gpu_wheels/cp311/   the same versions for the local Python (the rehearsal,
                        benchmarks/gpu_rehearsal.sh), one folder per ``--python``
    gpu_wheels/manifest.json   what was made, from which pyproject.toml

``install`` (run there, with the machine's own interpreter; it needs only the
standard library and ``packaging``, which pip carries) works out which of the
project's requirements the interpreter lacks or has in a version that does not
satisfy them, and installs exactly those wheels, the project's own included, with
``pip install --no-index --no-deps --target TARGET``. Put TARGET on PYTHONPATH
after that: its ``gns_framework-*.dist-info`` holds the entry points through which
the registry finds the built-in plugins. warp-lang (the MPM) and torch-geometric
(only the ``graph_attention`` processor) may be missing: the parts that need them
say ``skipped``. torch is never carried: the machine's is used (pyproject.toml says
which versions the project supports).

Usage:
    python benchmarks/gpu_wheels.py prepare --out gpu_wheels [--python 3.12 --python 3.11] [--limit-mib 64]
    python benchmarks/gpu_wheels.py install --wheels gpu_wheels --target /tmp/site
"""

from __future__ import annotations

import argparse
import email.parser
import hashlib
import importlib.metadata
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
import zipfile
from pathlib import Path

try:
    from packaging.requirements import Requirement
    from packaging.utils import canonicalize_name
    from packaging.version import Version
except ImportError:  # an interpreter without packaging still has pip's copy
    from pip._vendor.packaging.requirements import Requirement  # type: ignore[no-redef]
    from pip._vendor.packaging.utils import canonicalize_name  # type: ignore[no-redef]
    from pip._vendor.packaging.version import Version  # type: ignore[no-redef]

REPO = Path(__file__).resolve().parents[1]
PROJECT = "gns-framework"
DEVICE_PYTHON = "3.12"
DEVICE_PLATFORMS = (
    "manylinux_2_28_x86_64",
    "manylinux_2_27_x86_64",
    "manylinux_2_17_x86_64",
    "manylinux2014_x86_64",
    "manylinux1_x86_64",
)
"""The ``pip download --platform`` flags of the device tool's README for its GPU machine."""
CHECK_EXTRAS = ("eval",)
"""Extras whose requirements the check needs besides the project's own: geomloss (the
CUDA tests' evaluation metrics). Of an extra, only what DEVICE_HAS lacks is carried."""
EXTRA_NEEDED = {"geomloss"}
"""The requirements of CHECK_EXTRAS the check uses (matplotlib is on the device; meshio is not used)."""
OPTIONAL = {
    "warp-lang": "the MLS-MPM simulator (mpm part, MPM CUDA test)",
    "torch-geometric": "only the graph_attention processor, which the check does not use",
}
"""Requirements the check runs without: the parts that need them report ``skipped``."""
NEVER_CARRIED = {"torch"}
"""The machine's own torch is used: a carried one would be GBs and the wrong CUDA build."""
DEVICE_HAS = {
    "numpy",
    "pluggy",
    "pyyaml",
    "tqdm",
    "scipy",
    "h5py",
    "matplotlib",
    "packaging",
    "pytest",
    "hypothesis",
    "torch-geometric",
    "filelock",
    "jinja2",
    "sympy",
    "networkx",
    "fsspec",
}
"""Installed on the lent machine's image (device tool, KINDS.md, read 2026-11-17) and large: not
carried. A version there that does not satisfy a requirement is reported by ``install``."""
MiB = 2**20


def normalize(name: str) -> str:
    return str(canonicalize_name(name))


# --------------------------------------------------------------------------- wheels


def wheel_name_version(path: Path) -> tuple[str, str]:
    name, version = path.name.split("-")[:2]
    return normalize(name), version


def wheel_metadata(path: Path):
    """The METADATA of a wheel, as an email message (``get_all('Requires-Dist')``)."""
    with zipfile.ZipFile(path) as archive:
        member = next(n for n in archive.namelist() if re.fullmatch(r"[^/]+\.dist-info/METADATA", n))
        return email.parser.Parser().parsestr(archive.read(member).decode("utf-8"))


def marker_environment(python: str) -> dict[str, str]:
    """PEP 508 marker values of CPython ``python`` on x86-64 Linux (the device, or the local one)."""
    major, minor = python.split(".")[:2]
    return {
        "python_version": f"{major}.{minor}",
        "python_full_version": f"{major}.{minor}.0",
        "implementation_name": "cpython",
        "platform_python_implementation": "CPython",
        "sys_platform": "linux",
        "platform_system": "Linux",
        "platform_machine": "x86_64",
        "os_name": "posix",
        "implementation_version": f"{major}.{minor}.0",
        "extra": "",
    }


def applies(requirement: Requirement, environment: dict[str, str], extras: tuple[str, ...] = ()) -> bool:
    """Whether ``requirement`` applies in ``environment``, with ``extras`` asked for."""
    if requirement.marker is None:
        return True
    return any(requirement.marker.evaluate({**environment, "extra": extra}) for extra in ("", *extras))


def requirements_of(metadata, environment: dict[str, str], extras: tuple[str, ...] = ()) -> list[Requirement]:
    found = []
    for line in metadata.get_all("Requires-Dist") or []:
        requirement = Requirement(line)
        if not applies(requirement, environment, extras):
            continue
        is_extra = requirement.marker is not None and "extra" in str(requirement.marker)
        if is_extra and normalize(requirement.name) not in EXTRA_NEEDED:
            continue
        found.append(requirement)
    return found


def python_tag(python: str) -> str:
    major, minor = python.split(".")[:2]
    return f"cp{major}{minor}"


# --------------------------------------------------------------------------- prepare


def _pip_download(spec: str, python: str, folder: Path) -> Path:
    """One wheel of ``spec`` for CPython ``python`` on manylinux x86_64 (no dependencies), its path."""
    before = set(folder.iterdir())
    command = [
        sys.executable,
        "-m",
        "pip",
        "download",
        "-q",
        "--no-deps",
        "--only-binary=:all:",
        "--python-version",
        python,
        "--implementation",
        "cp",
        "--abi",
        python_tag(python),
        *[flag for platform in DEVICE_PLATFORMS for flag in ("--platform", platform)],
        "-d",
        str(folder),
        spec,
    ]
    _run(command)
    new = set(folder.iterdir()) - before
    name = normalize(Requirement(spec).name)
    matches = [p for p in (new or folder.iterdir()) if p.suffix == ".whl" and wheel_name_version(p)[0] == name]
    if len(matches) != 1:
        raise SystemExit(f"gpu_wheels: pip download {spec} for Python {python} gave {sorted(p.name for p in matches)}")
    return matches[0]


def _run(command: list[str], **kwargs) -> None:
    """``command``, its output shown only when it fails (pip's warnings about this machine's indexes are noise)."""
    result = subprocess.run(command, capture_output=True, text=True, **kwargs)
    if result.returncode != 0:
        sys.stderr.write(result.stdout + result.stderr)
        raise SystemExit(f"gpu_wheels: {' '.join(command)} failed (exit {result.returncode})")


def _local_version(name: str, requirement: Requirement) -> str | None:
    """The version installed here, when it satisfies ``requirement``: the combination the tests ran with."""
    try:
        version = importlib.metadata.version(name)
    except importlib.metadata.PackageNotFoundError:
        return None
    return version if requirement.specifier.contains(version, prereleases=True) else None


def build_project_wheel(folder: Path) -> Path:
    """``pip wheel --no-deps`` of the repository (built-in plugins included: one distribution).

    Built from a copy of what travels to the device (tracked and untracked-not-ignored
    files), so nothing is written into the checkout (its ``build/`` and ``*.egg-info``).
    """
    with tempfile.TemporaryDirectory() as build:
        source = Path(build) / "src"
        for name in _working_tree_files():
            target = source / name
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(REPO / name, target)
        # Without build isolation when setuptools is here: no download, the backend this interpreter has.
        flags = ["--no-build-isolation"] if _has("setuptools") else []
        _run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", *flags, "-w", build, str(source)], cwd=build)
        wheel = next(Path(build).glob("gns_framework-*.whl"))
        target = folder / wheel.name
        shutil.copy2(wheel, target)
    return target


def _has(module: str) -> bool:
    import importlib.util

    return importlib.util.find_spec(module) is not None


def prepare(out: Path, pythons: list[str], limit_mib: float) -> int:
    started = time.perf_counter()
    pythons = list(dict.fromkeys([DEVICE_PYTHON, *pythons]))
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    staging = out / ".project"
    staging.mkdir()
    project = build_project_wheel(staging)
    metadata = wheel_metadata(project)
    pins: dict[str, str] = {}  # name -> version, the same for every Python
    carried: dict[str, list[str]] = {}
    for python in pythons:
        folder = out / python_tag(python)
        folder.mkdir()
        shutil.copy2(project, folder / project.name)
        environment = marker_environment(python)
        queue = requirements_of(metadata, environment, CHECK_EXTRAS)
        seen: set[str] = set()
        while queue:
            requirement = queue.pop(0)
            name = normalize(requirement.name)
            if name in seen or name in NEVER_CARRIED or name in OPTIONAL or name in DEVICE_HAS:
                continue
            seen.add(name)
            version = pins.get(name) or _local_version(requirement.name, requirement)
            spec = f"{requirement.name}=={version}" if version else f"{requirement.name}{requirement.specifier}"
            wheel = _pip_download(spec, python, folder)
            pins[name] = wheel_name_version(wheel)[1]
            queue.extend(requirements_of(wheel_metadata(wheel), environment))
        carried[python_tag(python)] = sorted(p.name for p in folder.iterdir())
    shutil.rmtree(staging)
    manifest = {
        "pyproject_sha256": _pyproject_sha256(),
        "made": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "pythons": pythons,
        "wheels": carried,
    }
    (out / "manifest.json").write_text(json.dumps(manifest, indent=1) + "\n")
    size = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
    travel = size + _working_tree_bytes(out)
    for tag, names in carried.items():
        print(f"gpu_check: prepare python={tag} wheels={len(names)} names={','.join(names)}")
    print(
        f"gpu_check: prepare folder={out} size_mib={size / MiB:.2f} travel_mib={travel / MiB:.2f} "
        f"limit_mib={limit_mib:g} seconds={time.perf_counter() - started:.1f}"
    )
    if size > limit_mib * MiB or travel > limit_mib * MiB:
        largest = ", ".join(f"{folder} {bytes_ / MiB:.1f} MiB" for folder, bytes_ in _largest_folders(out))
        print(
            f"gpu_wheels: {out} ({size / MiB:.1f} MiB) with the working tree ({travel / MiB:.1f} MiB) is over "
            f"the {limit_mib:g} MiB that travels to the device; the largest folders that travel: {largest}. "
            "Move what the check does not need (models/in_training/: checkpoints of runs in progress) out of "
            "the tree for the call, and back after it",
            file=sys.stderr,
        )
        return 1
    return 0


def _pyproject_sha256() -> str:
    return hashlib.sha256((REPO / "pyproject.toml").read_bytes()).hexdigest()


def _working_tree_files() -> list[str]:
    """Paths (relative) of what travels with the working tree: tracked and untracked-not-ignored files."""
    listed = subprocess.run(
        ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        cwd=REPO,
        capture_output=True,
        check=True,
    ).stdout
    return [name for name in listed.decode().split("\0") if name and (REPO / name).is_file()]


def _largest_folders(exclude: Path, count: int = 3, depth: int = 2) -> list[tuple[str, int]]:
    """The ``count`` folders (``depth`` levels down) holding the most bytes of what travels, less ``exclude``."""
    exclude = exclude.resolve()
    totals: dict[str, int] = {}
    for name in _working_tree_files():
        if exclude in (REPO / name).resolve().parents:
            continue
        folder = "/".join(Path(name).parts[:-1][:depth]) or "."
        totals[folder] = totals.get(folder, 0) + (REPO / name).stat().st_size
    return sorted(totals.items(), key=lambda item: -item[1])[:count]


def _working_tree_bytes(exclude: Path) -> int:
    """Bytes of what travels with the working tree, less ``exclude``."""
    exclude = exclude.resolve()
    return sum(
        (REPO / name).stat().st_size for name in _working_tree_files() if exclude not in (REPO / name).resolve().parents
    )


# --------------------------------------------------------------------------- install


def _installed_version(name: str) -> str | None:
    try:
        return importlib.metadata.version(name)
    except importlib.metadata.PackageNotFoundError:
        return None


def _already_complete(installed=_installed_version) -> bool:
    """Whether this interpreter has the project and every requirement the check needs, in versions that fit."""
    if installed(PROJECT) is None:
        return False
    environment = marker_environment(f"{sys.version_info.major}.{sys.version_info.minor}")
    for requirement in requirements_of(importlib.metadata.metadata(PROJECT), environment, CHECK_EXTRAS):
        have = installed(requirement.name)
        if normalize(requirement.name) in OPTIONAL:
            continue
        if have is None or not requirement.specifier.contains(Version(have).public, prereleases=True):
            return False
    return True


def plan(folder: Path, installed=_installed_version, environment: dict[str, str] | None = None):
    """What to install from ``folder`` for this interpreter.

    Returns (wheels to install, {name: why} optional ones missing, [problems]). A
    problem is a requirement that neither the interpreter nor the folder satisfies.
    """
    environment = environment or marker_environment(f"{sys.version_info.major}.{sys.version_info.minor}")
    wheels = {wheel_name_version(p)[0]: p for p in folder.glob("*.whl")}
    if PROJECT not in wheels:
        return [], {}, [f"{folder} holds no {PROJECT} wheel: run benchmarks/gpu_check.sh --prepare"]
    chosen: dict[str, Path] = {}
    missing_optional: dict[str, str] = {}
    problems: list[str] = []
    if installed(PROJECT) is None:
        chosen[PROJECT] = wheels[PROJECT]
    queue = [(req, PROJECT) for req in requirements_of(wheel_metadata(wheels[PROJECT]), environment, CHECK_EXTRAS)]
    seen: set[str] = set()
    while queue:
        requirement, wanted_by = queue.pop(0)
        name = normalize(requirement.name)
        have = installed(requirement.name)
        if have is not None and requirement.specifier.contains(Version(have).public, prereleases=True):
            continue
        if name in chosen:
            version = wheel_name_version(chosen[name])[1]
            if not requirement.specifier.contains(version, prereleases=True):
                problems.append(f"{wanted_by} needs {requirement}, the carried wheel is {version}")
            continue
        if name in seen:
            continue
        seen.add(name)
        wheel = wheels.get(name)
        if wheel is not None and requirement.specifier.contains(wheel_name_version(wheel)[1], prereleases=True):
            chosen[name] = wheel
            queue.extend((req, name) for req in requirements_of(wheel_metadata(wheel), environment))
        elif name in OPTIONAL:
            missing_optional[name] = OPTIONAL[name] if have is None else f"{have} installed, {requirement} needed"
        else:
            found = f"{have} is installed" if have is not None else "it is not installed"
            carried = f", the carried wheel is {wheel_name_version(wheel)[1]}" if wheel is not None else ""
            problems.append(f"{wanted_by} needs {requirement}: {found}{carried}")
    return list(chosen.values()), missing_optional, problems


def install(wheels: Path, target: Path) -> int:
    started = time.perf_counter()
    tag = python_tag(f"{sys.version_info.major}.{sys.version_info.minor}")
    folder = wheels / tag
    if not folder.is_dir() and _already_complete():
        # The project's own environment (its .venv, CI): nothing to carry, nothing to install.
        print(
            f"gpu_check: install python={tag} installed=none target=none missing_optional=none "
            f"seconds={time.perf_counter() - started:.2f} already=gns-framework_and_its_requirements",
            flush=True,
        )
        return 0
    if not folder.is_dir():
        made = sorted(p.name for p in wheels.iterdir() if p.is_dir()) if wheels.is_dir() else []
        print(
            f"gpu_wheels: no wheels for Python {sys.version.split()[0]} in {folder} (made for: "
            f"{', '.join(made) or 'nothing'}): run benchmarks/gpu_check.sh --prepare",
            file=sys.stderr,
        )
        return 1
    manifest = wheels / "manifest.json"
    if manifest.is_file() and json.loads(manifest.read_text()).get("pyproject_sha256") != _pyproject_sha256():
        print(
            "gpu_check: install warning=pyproject.toml_changed_since_prepare (entry points may be stale: "
            "run gpu_check.sh --prepare again)",
            flush=True,
        )
    chosen, missing_optional, problems = plan(folder)
    for problem in problems:
        print(f"gpu_wheels: {problem}", file=sys.stderr)
    if problems:
        return 1
    if chosen:
        target.mkdir(parents=True, exist_ok=True)
        subprocess.run(
            [
                sys.executable,
                "-m",
                "pip",
                "install",
                "-q",
                "--no-index",
                "--no-deps",
                "--no-compile",
                "--no-cache-dir",
                "--disable-pip-version-check",
                "--upgrade",
                "--target",
                str(target),
                *map(str, chosen),
            ],
            check=True,
        )
    names = ",".join(sorted(wheel_name_version(p)[0] + "==" + wheel_name_version(p)[1] for p in chosen)) or "none"
    print(
        f"gpu_check: install python={tag} installed={names} target={target} "
        f"missing_optional={','.join(sorted(missing_optional)) or 'none'} "
        f"seconds={time.perf_counter() - started:.2f}",
        flush=True,
    )
    for name, why in sorted(missing_optional.items()):
        print(f"gpu_check: install optional={name} skipped: {why}", flush=True)
    return 0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    made = sub.add_parser("prepare")
    made.add_argument("--out", type=Path, default=REPO / "gpu_wheels")
    made.add_argument(
        "--python",
        action="append",
        default=[],
        help=f"also for this CPython (X.Y); {DEVICE_PYTHON} (the device) always",
    )
    made.add_argument("--limit-mib", type=float, default=64.0)
    put = sub.add_parser("install")
    put.add_argument("--wheels", type=Path, default=REPO / "gpu_wheels")
    put.add_argument("--target", type=Path, required=True)
    args = parser.parse_args()
    if args.command == "prepare":
        sys.exit(
            prepare(args.out, args.python or [f"{sys.version_info.major}.{sys.version_info.minor}"], args.limit_mib)
        )
    sys.exit(install(args.wheels, args.target))


if __name__ == "__main__":
    os.environ.setdefault("PIP_DISABLE_PIP_VERSION_CHECK", "1")
    main()
