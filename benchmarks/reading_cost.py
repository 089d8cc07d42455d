"""What a reader opens to follow one training step and one rollout step: files and lines.

Runs one training step (the trainer's step room, ``training/step.py``, where the tree
has one, else ``Trainer.train_step``, after a first step has made every lazy choice) and one rollout step (``rollout``
of one frame) of the reference model (interaction network, 10 steps, latent 128) on a small dataset made here, under
``sys.settrace``, and records every project source file whose code ran (``gns_framework/`` and
``plugins/gns_builtins/``). It prints per step the files, their total lines (what a reader opens) and the lines that
ran, then the files.

The project's reading goal (issue 28): the files and lines of one training step at
most half of what they were before the redesign; with the default (fused) edge block at
most 1,700 lines (issue 49). Modules that declare ``IMPLEMENTS`` (the chunked, C and Triton
forms of the interaction network's edge block, ``gns_builtins/_kernels``) run on the default
path but implement code already on it, the paper's three lines, which their mirror tests hold
them equal to: a reader follows those, so they are listed and counted apart (as PyG keeps a
fused ``message_and_aggregate`` off the ``message``/``aggregate`` path a reader follows).

To measure an older tree, put it first on the path; the script measures whatever
``gns_framework`` it imports::

    git worktree add /tmp/before 944aa1f^
    PYTHONPATH=/tmp/before:/tmp/before/plugins python benchmarks/reading_cost.py
    python benchmarks/reading_cost.py --edge-block plain     # the paper's form of the step
    python benchmarks/reading_cost.py --json                  # one JSON line as well
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import tempfile
from collections import defaultdict
from pathlib import Path

import numpy as np
import torch


def project_roots() -> list[Path]:
    """The source folders of the imported gns_framework and gns_builtins (wherever they were imported from)."""
    import gns_builtins
    import gns_framework

    return [Path(gns_framework.__file__).parent, Path(gns_builtins.__file__).parent]


class LineTrace:
    """Every line run in the project's files while active: ``{file: {line numbers}}``."""

    def __init__(self, roots: list[Path]):
        self.roots = tuple(str(root) + "/" for root in roots)
        self.lines: dict[str, set[int]] = defaultdict(set)

    def _global(self, frame, event, arg):
        if not frame.f_code.co_filename.startswith(self.roots):
            return None  # no line events outside the project: cheap, and not counted
        return self._local

    def _local(self, frame, event, arg):
        if event in ("call", "line"):
            self.lines[frame.f_code.co_filename].add(frame.f_lineno)
        return self._local

    def __enter__(self):
        sys.settrace(self._global)
        return self

    def __exit__(self, *exc):
        sys.settrace(None)


def write_dataset(path: Path, particles: int = 64, frames: int = 20) -> None:
    """A small random-walk sand dataset (train 2, valid 1, test 1): values do not matter, the code path does."""
    from gns_framework.data.metadata import DatasetMetadata, compute_statistics
    from gns_framework.data.trajectory import Trajectory
    from gns_framework.plugins import load_registry

    rng = np.random.default_rng(0)
    side = int(np.sqrt(particles))
    lattice = np.stack(np.meshgrid(np.arange(side), np.arange(side), indexing="ij"), -1).reshape(-1, 2) * 0.02 + 0.3

    def trajectory(key: str) -> Trajectory:
        steps = rng.normal(0, 1e-3, (frames, len(lattice), 2)).cumsum(0)
        position = (lattice + steps).astype(np.float32)
        return Trajectory(position, np.full(len(lattice), 6, np.int64), None, None, key)

    splits = {
        split: [trajectory(f"{split}_{i}") for i in range(count)]
        for split, count in (("train", 2), ("valid", 1), ("test", 1))
    }
    registry = load_registry()
    metadata = DatasetMetadata(
        bounds=[(0.0, 1.0), (0.0, 1.0)],
        sequence_length=frames,
        default_connectivity_radius=0.03,
        dim=2,
        dt=0.005,
        **compute_statistics(splits["train"], registry.kinematic_types()),
    )
    registry.get("dataset", "safe").write(path, metadata, splits)


def recipe_for(data: Path, run: Path, edge_block: str | None):
    from gns_framework.config.recipe import validate_recipe
    from gns_framework.plugins import load_registry

    processor = {"name": "interaction_network", "message_passing_steps": 10}
    if edge_block is not None:
        processor["edge_block"] = edge_block
    raw = {
        "name": "reading-cost",
        "dataset": {"name": "safe", "path": str(data)},
        "model": {"processor": processor},
        "training": {
            "steps": 2,
            "batch_size": 1,
            "threads": 1,
            "log_every": 1000,
            "validate_every": 1000,
            "checkpoint_every": 1000,
        },
    }
    return validate_recipe(raw, load_registry())


def measure(edge_block: str | None) -> dict:
    from gns_framework.assembly.data import open_dataset
    from gns_framework.model.rollout import rollout
    from gns_framework.plugins import load_registry
    from gns_framework.training.trainer import Trainer

    torch.set_num_threads(1)
    roots = project_roots()
    with tempfile.TemporaryDirectory() as scratch:
        data, run = Path(scratch) / "data", Path(scratch) / "run"
        write_dataset(data)
        recipe = recipe_for(data, run, edge_block)
        trainer = Trainer(recipe, load_registry(), run_dir=run, progress=False)
        trainer.train_step()  # the first step makes every lazy choice (kernels, plans)
        # The step's own room where the tree has one (training/step.py); before it, the trainer's method.
        room, step = getattr(trainer, "optimisation", None), trainer.step
        with LineTrace(roots) as training:
            if room is not None:
                room(step)
            else:
                trainer.train_step()
        trajectory = open_dataset(recipe.dataset, load_registry(), data).split("test")[0]
        simulator = trainer.simulator.eval()
        with torch.no_grad():
            rollout(simulator, trajectory, steps=1)
            with LineTrace(roots) as rolling:
                rollout(simulator, trajectory, steps=1)
        trainer.close()
    return {"training_step": summary(training, roots), "rollout_step": summary(rolling, roots)}


IMPLEMENTS = re.compile(r'^IMPLEMENTS = "([^"]+)"', re.MULTILINE)
"""A module's top-level ``IMPLEMENTS = "<the plain code it implements faster>"`` (see gns_builtins/_kernels)."""


def summary(trace: LineTrace, roots: list[Path]) -> dict:
    """The files a step ran, their lines, and the lines that ran; modules that declare ``IMPLEMENTS`` (a faster
    form of code the reader follows instead, held equal to it by their mirror tests) are counted apart."""
    files = {}
    for name, lines in sorted(trace.lines.items()):
        path = Path(name)
        root = next(r for r in roots if path.is_relative_to(r))
        text = path.read_text()
        declared = IMPLEMENTS.search(text)
        files[f"{root.name}/{path.relative_to(root)}"] = {
            "lines": len(text.splitlines()),
            "ran": len(lines),
            "implements": declared.group(1) if declared else None,
        }
    read = {name: f for name, f in files.items() if f["implements"] is None}
    behind = {name: f for name, f in files.items() if f["implements"] is not None}
    return {
        "files": len(read),
        "lines": sum(f["lines"] for f in read.values()),
        "lines_ran": sum(f["ran"] for f in read.values()),
        "implementation_files": len(behind),
        "implementation_lines": sum(f["lines"] for f in behind.values()),
        "per_file": files,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--edge-block",
        choices=["fused", "plain"],
        help="the interaction step's form (trees before it existed take no choice)",
    )
    parser.add_argument("--json", action="store_true", help="also print the figures as one JSON line")
    args = parser.parse_args()
    result = measure(args.edge_block)
    import gns_framework

    print(f"gns_framework from {Path(gns_framework.__file__).parent}; edge block: {args.edge_block or 'default'}")
    for step, figures in result.items():
        print(
            f"\n{step}: {figures['files']} files, {figures['lines']} lines to open, {figures['lines_ran']} lines ran"
            f" (and {figures['implementation_lines']} lines in {figures['implementation_files']} faster forms of"
            " code on the path, read there instead)"
        )
        for name, counts in figures["per_file"].items():
            behind = f"  implements {counts['implements']}" if counts["implements"] else ""
            print(f"  {name:60s} {counts['lines']:5d} lines, {counts['ran']:4d} ran{behind}")
    if args.json:
        print(
            json.dumps(
                {step: {k: v for k, v in figures.items() if k != "per_file"} for step, figures in result.items()}
            )
        )


if __name__ == "__main__":
    main()
