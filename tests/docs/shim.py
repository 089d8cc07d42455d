"""What ``gns``, ``python`` and ``torchrun`` are inside a documented-commands sandbox.

The test puts this script first on the sandbox's PATH (and at ``.venv/bin/``) under
those names. It runs the real command with the arguments the document gives,
scaled down where a command would take minutes (``GNS_DOCS_SCALE=full`` runs them as
written), then checks that the files the command names as its outputs exist. Each
call appends one JSON line to ``$GNS_DOCS_LOG``: the command as written, as run,
and what was scaled or not run and why.

    python shim.py TOOL ARG...
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

PYTHON = os.environ.get("GNS_DOCS_PYTHON", sys.executable)
FULL = os.environ.get("GNS_DOCS_SCALE", "ci") == "full"

# Per gns command: flag -> the most it may ask for in CI (an int caps a number; a list replaces a list).
GNS_CAPS: dict[str, dict[str, object]] = {
    "train": {"--steps": 4},
    "demo": {"--steps": 4, "--held-out": 1, "--repeats": 1},
    "evaluate": {"--repeats": 1, "--grid-scales": ["0.5"]},
}
GNS_ADD: dict[str, tuple[str, ...]] = {"demo": ("--steps", "--held-out", "--repeats")}
"""Capped flags also given, at their cap, when the command leaves them to a larger default."""
SCRIPT_CAPS: dict[str, dict[str, object]] = {
    "learned_vs_simulator.py": {"--particles": [1000], "--repeats": 1, "--frames": 20},
    "rollout_profile.py": {"--particles": [300], "--repeats": 1},
    "batched_rollout.py": {"--scenes": 2, "--batch": [2]},
    "time_to_accuracy.py": {"--budget-minutes": 0.05, "--points": 2, "--trajectories": 1, "--seeds": 1, "--late": 1},
    "generalization.py": {"--held-out": 1},
    "invert_starts.py": {"--starts": [1], "--repeats": 1},
    "inverse_recovery.py": {"--cases": 1, "--iterations": 2},
    "step_time.py": {"--particles": [1000], "--repeat": 1, "--warmup": 0},
    "decomposition_scaling.py": {
        "--particles": 2000,
        "--processes": [1, 2],
        "--steps": 2,
        "--train-steps": 1,
        "--project-particles": 20000,
        "--project-gpus": [8],
    },
}
SCRIPT_ADD: dict[str, tuple[str, ...]] = {
    "time_to_accuracy.py": ("--points", "--trajectories", "--seeds"),
    "step_time.py": ("--particles", "--repeat", "--warmup"),
    "decomposition_scaling.py": ("--steps", "--train-steps", "--project-particles", "--project-gpus"),
    "learned_vs_simulator.py": ("--repeats", "--frames"),
}
GOAL_VERDICT = {"generalization.py": "NOT met"}
"""Benchmarks that exit 1 when the model misses its goal: at any scale that is a verdict, not a failure to run."""
ENVELOPE_CHECKED = ("rollout", "evaluate")
"""Commands that refuse data outside a model's envelope: a model trained here, for a few steps on one trajectory,
has an envelope of that trajectory, so its rollouts on other scaled-down data run with --outside-envelope."""
NOT_RUN = {
    ("-m", "pytest"): "the test suite this test belongs to (CI runs it)",
}
OUTPUT_FLAGS = ("--out", "--gif", "--vtk", "--plot", "--gifs", "--record")
CHECKPOINT = re.compile(r"checkpoint-(\d{9})\.pt$")


def log(entry: dict) -> None:
    path = os.environ.get("GNS_DOCS_LOG")
    if path:
        with open(path, "a", encoding="utf-8") as out:
            out.write(json.dumps(entry) + "\n")


def _value_count(args: list[str], index: int) -> int:
    """How many values follow the flag at ``index`` (up to the next flag)."""
    count = 0
    for arg in args[index + 1 :]:
        if arg.startswith("--"):
            break
        count += 1
    return count


def capped(args: list[str], caps: dict[str, object], add: Sequence[str] = ()) -> tuple[list[str], list[str]]:
    """``args`` with every capped flag's value at most its cap, the ``add`` flags given at their cap when absent,
    and what changed."""
    out, notes, seen = [], [], set()
    i = 0
    while i < len(args):
        arg = args[i]
        flag, _, inline = arg.partition("=")
        if flag in caps:
            seen.add(flag)
            cap = caps[flag]
            n = 1 if inline else _value_count(args, i)
            values = [inline] if inline else args[i + 1 : i + 1 + n]
            if isinstance(cap, list):
                new = [str(v) for v in cap]
            else:
                new = [str(min(type(cap)(float(values[0])), cap))] if values else [str(cap)]
            if new != values:
                notes.append(f"{flag} {' '.join(values)} -> {' '.join(new)}")
            out += [flag, *new]
            i += 1 + (0 if inline else n)
            continue
        out.append(arg)
        i += 1
    for flag in add:
        if flag not in seen:
            cap = caps[flag]
            given = [str(v) for v in cap] if isinstance(cap, list) else [str(cap)]
            out += [flag, *given]
            notes.append(f"{flag} {' '.join(given)} added")
    return out, notes


def scaled_generate(args: list[str]) -> tuple[list[str], list[str]]:
    """``gns generate``: 1 train, at most 1 valid and 1 test trajectory."""

    def value(flag: str) -> int | None:
        return int(args[args.index(flag) + 1]) if flag in args else None

    valid, test = value("--valid"), value("--test")
    out, notes = capped(args, {"--valid": 1, "--test": 1})
    total = 1 + (1 if valid is None else min(valid, 1)) + (1 if test is None else min(test, 1))
    out, more = capped(out, {"--trajectories": total})
    added = [f"{flag} 1" for flag, given in (("--valid", valid), ("--test", test)) if given is None]
    for flag in added:
        out += flag.split()
    return out, notes + more + [f"{flag} added" for flag in added]


def newest_checkpoints(args: list[str]) -> tuple[list[str], list[str]]:
    """A checkpoint named by its step that a scaled-down training never reached: the newest one of its folder."""
    out, notes = [], []
    for arg in args:
        match = CHECKPOINT.search(arg)
        path = Path(arg)
        if match and not path.exists() and path.parent.is_dir():
            found = sorted(path.parent.glob("checkpoint-*.pt"))
            if found:
                notes.append(f"{arg} -> {found[-1]} (the scaled training's last step)")
                arg = str(found[-1])
        out.append(arg)
    return out, notes


def cached_generate(args: list[str], run) -> int:
    """Generation is deterministic: the same scene and counts are copied from the cache of earlier documents."""
    cache = os.environ.get("GNS_DOCS_DATA_CACHE")
    if not cache or "--out" not in args:
        return run()
    scene = Path(args[1]) if len(args) > 1 else None
    out = Path(args[args.index("--out") + 1])
    others = [a for i, a in enumerate(args) if a != "--out" and (i == 0 or args[i - 1] != "--out")]
    key = hashlib.sha256(json.dumps([others, scene.read_bytes().hex() if scene and scene.is_file() else ""]).encode())
    kept = Path(cache) / key.hexdigest()[:16]
    if kept.is_dir() and not out.exists():
        shutil.copytree(kept, out)
        print(f"docs-test: {out} copied from an identical generation earlier in this test session")
        return 0
    code = run()
    if code == 0 and out.is_dir() and not kept.exists():
        shutil.copytree(out, kept)
    return code


def trained_here(path: str) -> bool:
    """A checkpoint this sandbox's scaled-down training wrote (not a model the repository ships)."""
    file = Path(path)
    if file.suffix != ".pt" or not file.is_file():
        return False
    shipped = Path(os.environ.get("GNS_DOCS_REPO", ".")) / "models" / file.name
    return not (shipped.is_file() and shipped.read_bytes() == file.read_bytes())


def scaled_gns(args: list[str]) -> tuple[list[str], list[str]]:
    if not args or FULL:
        return args, []
    command = args[0]
    if command == "generate":
        out, notes = scaled_generate(args)
    else:
        out, notes = capped(args, GNS_CAPS.get(command, {}), GNS_ADD.get(command, ()))
    out, more = newest_checkpoints(out)
    notes += more
    if command in ENVELOPE_CHECKED and "--outside-envelope" not in out and any(trained_here(a) for a in out):
        out.append("--outside-envelope")
        notes.append("--outside-envelope added (a model trained here for a few steps on one trajectory)")
    return out, notes


def check_outputs(args: list[str]) -> list[str]:
    """The outputs the command names that are not there."""
    missing = []
    for i, arg in enumerate(args[:-1]):
        if arg in OUTPUT_FLAGS and not args[i + 1].startswith("-") and not Path(args[i + 1]).exists():
            missing.append(f"{arg} {args[i + 1]}")
    return missing


def run(tool: str, argv: list[str]) -> int:
    entry: dict = {"tool": tool, "as_written": argv}
    notes: list[str] = []
    if tool == "python":
        for key, reason in NOT_RUN.items():
            if tuple(argv[: len(key)]) == key:
                entry["not_run"] = reason
                log(entry)
                print(f"docs-test: not run here: python {' '.join(argv)} ({reason})")
                return 0
        if argv[:2] == ["-m", "gns_framework.cli"]:
            return run("gns", argv[2:])
        script = Path(argv[0]).name if argv else ""
        rest = argv[1:]
        if not FULL and script in SCRIPT_CAPS:
            rest, notes = capped(rest, SCRIPT_CAPS[script], SCRIPT_ADD.get(script, ()))
        command = [PYTHON, *argv[:1], *rest]
    elif tool == "gns":
        rest, notes = scaled_gns(argv)
        command = [PYTHON, "-m", "gns_framework.cli", *rest]
    elif tool == "torchrun":
        split = argv.index("gns_framework.cli") + 1 if "gns_framework.cli" in argv else len(argv)
        rest, notes = scaled_gns(argv[split:])
        command = [PYTHON, "-m", "torch.distributed.run", *argv[:split], *rest]
    else:
        raise SystemExit(f"shim: unknown tool {tool}")
    entry.update(run=command[1:], scaled=notes)
    if notes:
        print(f"docs-test: scaled for CI: {'; '.join(notes)}")
    sys.stdout.flush()

    verdict = GOAL_VERDICT.get(Path(argv[0]).name) if tool == "python" and argv else None

    def execute() -> int:
        if verdict is None:
            return subprocess.run(command).returncode
        done = subprocess.run(command, stdout=subprocess.PIPE, text=True)
        sys.stdout.write(done.stdout)
        if done.returncode == 1 and verdict in done.stdout:
            entry["verdict"] = f"goal {verdict} (exit 1): the command ran"
            print(f"docs-test: the benchmark ran; its goal verdict is '{verdict}' (exit 1), counted as run")
            return 0
        return done.returncode

    code = cached_generate(rest, execute) if tool == "gns" and rest[:1] == ["generate"] else execute()
    missing = check_outputs(rest) if code == 0 else []
    entry.update(exit=code, missing=missing)
    log(entry)
    if missing:
        print(
            f"docs-test: the command succeeded but its stated outputs are missing: {', '.join(missing)}",
            file=sys.stderr,
        )
        return 3
    return code


if __name__ == "__main__":
    raise SystemExit(run(sys.argv[1], sys.argv[2:]))
