"""The harmonic oscillator x'' = -x that the integrators' physical forms (``advance``) are judged on."""

from __future__ import annotations

import math

import torch


def oscillator_energy(advance, omega_dt: float, steps: int = 2000) -> list[float]:
    """Energy after each of ``steps`` of x'' = -omega^2 x (omega = 1) from x = 1, v = 0, relative to the start."""
    x, v = torch.tensor([1.0], dtype=torch.float64), torch.tensor([0.0], dtype=torch.float64)
    energies = []
    for _ in range(steps):
        x, v = advance(x, v, lambda p: -p, omega_dt)
        energies.append(float(0.5 * v**2 + 0.5 * x**2) / 0.5)
    return energies


def position_error(advance, dt: float) -> float:
    """|x(1) - cos(1)| after integrating x'' = -x from x = 1, v = 0 to t = 1 in steps of ``dt``."""
    x, v = torch.tensor([1.0], dtype=torch.float64), torch.tensor([0.0], dtype=torch.float64)
    for _ in range(round(1.0 / dt)):
        x, v = advance(x, v, lambda p: -p, dt)
    return abs(float(x) - math.cos(1.0))


def observed_order(advance) -> float:
    """log2 of the error ratio when the step is halved from 0.02 to 0.01: the global order of accuracy."""
    return math.log2(position_error(advance, 0.02) / position_error(advance, 0.01))


def frames_of_force_law(advance, steps: int = 8) -> tuple[torch.Tensor, torch.Tensor]:
    """(steps + 1, 1, 2) positions of two coupled springs a(x) = A x advanced with dt = 1 frame, and A.

    A non-diagonal A makes the acceleration differ between frames and components, so a
    history form that takes the acceleration of the wrong frame shows.
    """
    matrix = torch.tensor([[-0.1, 0.03], [0.02, -0.05]], dtype=torch.float64)
    x = torch.tensor([[0.7, -0.4]], dtype=torch.float64)
    v = torch.tensor([[0.05, 0.1]], dtype=torch.float64)
    frames = [x]
    for _ in range(steps):
        x, v = advance(x, v, lambda p: p @ matrix.T, 1.0)
        frames.append(x)
    return torch.stack(frames), matrix
