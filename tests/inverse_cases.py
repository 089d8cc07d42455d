"""Shared cases of the inversion tests (tests/inverse/ and tests/cli/test_invert.py): the shipped model and its
unknowns, inverse problems on a synthetic observation, the gradient check, and inversion config files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
import yaml

from gns_framework.inverse.config import PropertyUnknown, VelocityUnknown
from gns_framework.inverse.problem import InverseProblem

MODEL = Path(__file__).resolve().parents[1] / "models" / "sand2d_fast.pt"
SAND = 6
UNKNOWNS = {
    "friction": PropertyUnknown(bounds=(0.4, 1.0), initial=0.7),
    "initial_velocity": VelocityUnknown(
        particle_type=SAND, bounds=[(-0.5, 0.5), (-0.5, 0.5)], initial=[0.1, -0.05], gravity=[0.0, -9.81]
    ),
}


def problem_of(simulator, observed, loss: str, checkpoint_every: int = 0, frames=(9, 11), unknowns=UNKNOWNS):
    trajectory, metadata = observed
    return InverseProblem(
        simulator,
        trajectory,
        metadata,
        unknowns,
        loss,
        list(frames),
        checkpoint_every=checkpoint_every,
        dtype=torch.float64,
    )


def autograd_and_central_differences(problem: InverseProblem, h: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    u = torch.tensor(problem.start, dtype=torch.float64, requires_grad=True)
    (gradient,) = torch.autograd.grad(problem.loss(u), u)
    differences = []
    with torch.no_grad():
        for i in range(len(problem.start)):
            step = torch.zeros_like(u)
            step[i] = h
            differences.append((problem.loss(u + step).item() - problem.loss(u - step).item()) / (2 * h))
    return gradient.numpy(), np.array(differences)


def config_mapping(model: Path, dataset: Path, **changes) -> dict:
    raw = {
        "model": str(model),
        "observed": {"dataset": str(dataset), "split": "test", "trajectory": 0, "frames": "last"},
        "unknowns": {"friction": {"bounds": [0.4, 1.0], "initial": 0.7}},
        "optimizer": {"name": "adam", "lr": 0.05, "iterations": 2},
        "loss": "positions",
        "checkpoint_every": 3,
        "threads": 1,
    }
    raw.update(changes)
    return raw


def write_config(path: Path, raw: dict) -> Path:
    path.write_text(yaml.safe_dump(raw))
    return path
