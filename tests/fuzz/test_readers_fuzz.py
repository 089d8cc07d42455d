"""Every reader of outside input fed damaged files: each is read or refused in one line, never a traceback, a death
by signal, a hang or an allocation beyond the limits (issue 47).

The seeds are real files of each kind: a small dataset in the safe, geoelements ``npz``,
``tfrecord`` and LagrangeBench layouts (``gns convert``), a checkpoint of a short
training, a recipe, a scene file and an invert config. Each trial copies a seed, damages
one of its files (truncation, flipped, overwritten, inserted or deleted bytes) with a
seeded generator, and has a worker process (:mod:`reader_worker`) read it whole; the
worker's address space is capped, so an allocation beyond it shows as ``MemoryError``.
The budget is ``GNS_FUZZ_SECONDS`` (default 60) for all readers together, so CI runs a
fixed time; the trials come in a fixed order, so a longer budget runs more of the same
sequence. A failing input is saved (its path is in the failure) with the reader and trial.
"""

from __future__ import annotations

import os
import random
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
from synthetic import write_synthetic_dataset
from tiny import tiny_recipe_mapping

from gns_framework.cli import main

ROOT = Path(__file__).resolve().parents[2]
WORKER = Path(__file__).with_name("reader_worker.py")
ANSWER_SECONDS = 60
"""Longest a worker may take on one input before it counts as a hang."""


class Worker:
    """One reader worker; restarted after a death."""

    def __init__(self):
        self.process: subprocess.Popen | None = None

    def start(self) -> None:
        env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(ROOT)}
        self.process = subprocess.Popen(
            [sys.executable, str(WORKER)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            text=True,
            env=env,
        )
        assert self.process.stdout.readline().strip() == "ready"

    def read(self, reader: str, path: Path) -> str:
        if self.process is None or self.process.poll() is not None:
            self.start()
        assert self.process is not None and self.process.stdin is not None and self.process.stdout is not None
        self.process.stdin.write(f"{reader} {path}\n")
        self.process.stdin.flush()
        line = _readline(self.process, ANSWER_SECONDS)
        if line is None:
            self.process.kill()
            self.process.wait()
            code = self.process.returncode
            self.process = None
            return f"hang (no answer in {ANSWER_SECONDS} s; killed, exit {code})"
        if line == "":
            code = self.process.wait()
            self.process = None
            return f"died (exit {code}{', signal ' + str(-code) if code < 0 else ''})"
        return line.rstrip("\n")

    def close(self) -> None:
        if self.process is not None and self.process.poll() is None:
            self.process.stdin.close()
            self.process.wait(timeout=30)


def _readline(process: subprocess.Popen, seconds: float) -> str | None:
    import selectors

    with selectors.DefaultSelector() as selector:
        selector.register(process.stdout, selectors.EVENT_READ)
        if not selector.select(timeout=seconds):
            return None
    return process.stdout.readline()


def damage(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    """``data`` damaged one way, and how."""
    if not data:
        return b"\0", "an empty file given one byte"
    at = rng.randrange(len(data))
    kind = rng.choice(["truncate", "flip", "overwrite", "insert", "delete", "flip"])
    if kind == "truncate":
        return data[:at], f"truncated at byte {at}"
    if kind == "flip":
        mask = rng.randrange(1, 256)
        return data[:at] + bytes([data[at] ^ mask]) + data[at + 1 :], f"byte {at} xor {mask:#04x}"
    if kind == "overwrite":
        count = rng.randrange(1, 9)
        fill = rng.choice([b"\xff", b"\x00", b"\x7f", bytes([rng.randrange(256)])]) * count
        return data[:at] + fill + data[at + count :], f"{count} bytes at {at} set to {fill[:1].hex()}"
    if kind == "insert":
        extra = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 17)))
        return data[:at] + extra + data[at:], f"{len(extra)} bytes inserted at {at}"
    count = rng.randrange(1, 17)
    return data[:at] + data[at + count :], f"{count} bytes deleted at {at}"


@pytest.fixture(scope="module")
def seeds(tmp_path_factory) -> dict[str, Path]:
    """reader -> a real input it reads (a file, or a dataset folder)."""
    root = tmp_path_factory.mktemp("seeds")
    safe = write_synthetic_dataset(root / "safe", train=2, valid=1, test=1, frames=8)
    found = {"safe": safe}
    for layout in ("npz", "tfrecord", "lagrangebench"):
        out = root / layout
        assert main(["convert", str(safe), "--from", "safe", "--to", layout, "--out", str(out)]) == 0
        found[layout] = out
    raw = tiny_recipe_mapping(safe)
    recipe = root / "tiny.yaml"
    recipe.write_text(yaml.safe_dump(raw))
    run = root / "run"
    assert main(["train", str(recipe), "--out", str(run), "--steps", "1", "--no-tracking", "--no-progress"]) == 0
    found["checkpoint"] = run / "checkpoints" / "checkpoint-000000001.pt"
    found["recipe"] = ROOT / "recipes" / "sand2d_fast.yaml"
    found["scene"] = ROOT / "scenes" / "sand_general_2d.yaml"
    found["invert_config"] = ROOT / "inversions" / "sand_friction.yaml"
    return found


def test_every_reader_reads_or_refuses_damaged_input_in_one_line(seeds, tmp_path):
    budget = float(os.environ.get("GNS_FUZZ_SECONDS", "60"))
    saved = Path(os.environ.get("GNS_FUZZ_SAVE", tmp_path / "failures"))
    worker = Worker()
    failures, trials = [], {}
    try:
        for reader, seed in seeds.items():  # the unharmed seeds read as they are
            answer = worker.read(reader, seed)
            assert answer.startswith("ok "), f"{reader}: the seed {seed} itself: {answer}"
        deadline_each = budget / len(seeds)
        for reader, seed in seeds.items():
            rng = random.Random(f"gns-fuzz-{reader}")
            stop, trial = time.monotonic() + deadline_each, 0
            while time.monotonic() < stop:
                trial += 1
                case = tmp_path / "case"
                shutil.rmtree(case, ignore_errors=True)
                if seed.is_dir():
                    shutil.copytree(seed, case)
                    target = rng.choice(sorted(p for p in case.iterdir() if p.is_file()))
                    path = case
                else:
                    case.mkdir()
                    target = path = case / seed.name
                    shutil.copy(seed, target)
                damaged, how = damage(target.read_bytes(), rng)
                target.write_bytes(damaged)
                answer = worker.read(reader, path)
                if not answer.startswith(("ok ", "refused ")) or (answer.startswith("refused ") and "\n" in answer):
                    keep = saved / f"{reader}-trial{trial}"
                    shutil.rmtree(keep, ignore_errors=True)
                    shutil.copytree(case, keep)
                    failures.append(f"{reader} trial {trial} ({target.name} {how}; saved in {keep}): {answer}")
            trials[reader] = trial
    finally:
        worker.close()
    print("fuzz trials per reader:", trials)
    assert not failures, f"{len(failures)} of {sum(trials.values())} damaged inputs failed:\n" + "\n".join(
        failures[:20]
    )
