"""Extreme inputs for the learned simulator, and a check that forward and backward passes stay finite.

Every case is one window of C positions in the unit box (walls at 0 and 1,
connectivity radius R = 0.1, velocity and acceleration statistics of order 1e-3
like the public datasets), built by a function of the dimension and a seed.
The check runs the training computation (prediction, target, loss), its backward
pass to the parameters and to the input positions, and a second-order pass (the
gradient of the squared input-gradient norm, as gradient penalties and
differentiable-rollout optimisers take).
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import Tensor

from ..assembly.learned import build_learned_simulator
from ..config.recipe import REFERENCE_NOISE_STD, ModelSpec
from ..contracts import ModelSetup
from ..data.batch import ParticleBatch
from ..data.metadata import DatasetMetadata
from ..model.learned_simulator import LearnedSimulator
from ..model.loss import masked_acceleration_loss
from ..plugins import Registry

RADIUS = 0.1
HISTORY = 6
TYPES = (3, 5, 6)
"""Kinematic (3), water (5) and sand (6): the type embedding and the kinematic path are exercised."""


def extreme_scene(dim: int) -> ModelSetup:
    return ModelSetup(
        dim=dim,
        bounds=((0.0, 1.0),) * dim,
        connectivity_radius=RADIUS,
        particle_types=TYPES,
        kinematic_types=(3,),
        history=HISTORY,
    )


def extreme_metadata(dim: int, zero_std: bool = False) -> DatasetMetadata:
    """Statistics like the public datasets' (std ~1e-3), or all-zero std (a dataset of particles at rest)."""
    std = [0.0] * dim if zero_std else [1e-3] * dim
    return DatasetMetadata(
        bounds=[(0.0, 1.0)] * dim,
        sequence_length=10,
        default_connectivity_radius=RADIUS,
        dim=dim,
        dt=0.01,
        vel_mean=[0.0] * dim,
        vel_std=std,
        acc_mean=[0.0] * dim,
        acc_std=std,
    )


def tiny_simulator(
    registry: Registry, dim: int, processor: str = "interaction_network", zero_std: bool = False, seed: int = 0
) -> LearnedSimulator:
    """A small model (latent 16, 2 message-passing steps) on the extreme scene; ``zero_std`` also drops the noise."""
    torch.manual_seed(seed)
    model = ModelSpec(
        latent_size=16,
        mlp_hidden_size=16,
        mlp_hidden_layers=1,
        type_embedding_size=4,
        noise_std=0.0 if zero_std else REFERENCE_NOISE_STD,
        processor={"name": processor, "message_passing_steps": 2},
    )
    return build_learned_simulator(extreme_scene(dim), extreme_metadata(dim, zero_std), model, registry)


def _batch(last: Tensor, velocity: Tensor, particle_type: Tensor | None = None) -> ParticleBatch:
    """A window ending at ``last`` (N, d) with constant ``velocity`` (N, d) per frame; next position continues it."""
    steps = torch.arange(-(HISTORY - 1), 1, dtype=torch.float32)[None, :, None]
    sequence = last[:, None] + steps * velocity[:, None]
    n = last.shape[0]
    if particle_type is None:
        particle_type = torch.tensor(TYPES[1:], dtype=torch.long).repeat(n)[:n]
    return ParticleBatch(
        position_sequence=sequence,
        particle_type=particle_type,
        batch=torch.zeros(n, dtype=torch.long),
        num_examples=1,
        next_position=last + velocity,
    )


def _uniform(n: int, dim: int, generator: torch.Generator, low: float = 0.1, high: float = 0.9) -> Tensor:
    return low + (high - low) * torch.rand(n, dim, generator=generator)


def _slow(n: int, dim: int, generator: torch.Generator) -> Tensor:
    return 1e-3 * torch.randn(n, dim, generator=generator)


def on_and_beyond_walls(dim: int, generator: torch.Generator) -> ParticleBatch:
    """Particles exactly on each wall, and 0.05 to 10 box lengths outside."""
    inside = _uniform(2 * dim, dim, generator)
    on_wall = inside.clone()
    for k in range(dim):
        on_wall[2 * k, k], on_wall[2 * k + 1, k] = 0.0, 1.0
    outside = _uniform(4, dim, generator)
    outside[:, 0] = torch.tensor([-0.05, 1.05, -10.0, 11.0])
    last = torch.cat([on_wall, outside])
    return _batch(last, _slow(len(last), dim, generator))


def coincident(dim: int, generator: torch.Generator) -> ParticleBatch:
    """Groups of particles at exactly the same position: zero-length edges besides the self-edges."""
    centres = _uniform(3, dim, generator)
    last = centres.repeat_interleave(4, dim=0)
    return _batch(last, torch.zeros_like(last))


def huge_velocity(dim: int, generator: torch.Generator) -> ParticleBatch:
    """Velocities of 1e4 box lengths per frame, 1e7 standard deviations."""
    last = _uniform(16, dim, generator)
    return _batch(last, 1e4 * torch.randn(16, dim, generator=generator))


def single_particle(dim: int, generator: torch.Generator) -> ParticleBatch:
    last = _uniform(1, dim, generator)
    return _batch(last, _slow(1, dim, generator))


def isolated(dim: int, generator: torch.Generator) -> ParticleBatch:
    """Particles farther apart than R: each has only its self-edge."""
    grid = torch.stack(torch.meshgrid(*[torch.arange(3.0)] * dim, indexing="ij"), -1).reshape(-1, dim)
    last = 0.2 + 0.3 * grid
    return _batch(last, _slow(len(last), dim, generator))


def dense_cluster(dim: int, generator: torch.Generator) -> ParticleBatch:
    """300 particles within R/4 of a point: every particle has 300 neighbours (90,000 edges)."""
    last = 0.5 + (RADIUS / 4 / math.sqrt(dim)) * (2 * torch.rand(300, dim, generator=generator) - 1)
    return _batch(last, _slow(300, dim, generator))


def only_kinematic(dim: int, generator: torch.Generator) -> ParticleBatch:
    """Every particle prescribed: the loss averages over no particle."""
    last = _uniform(5, dim, generator)
    return _batch(last, _slow(5, dim, generator), torch.full((5,), 3, dtype=torch.long))


CASES: dict[str, Callable[[int, torch.Generator], ParticleBatch]] = {
    "on and beyond walls": on_and_beyond_walls,
    "coincident particles": coincident,
    "huge velocities": huge_velocity,
    "single particle": single_particle,
    "isolated particles": isolated,
    "dense cluster": dense_cluster,
    "only kinematic particles": only_kinematic,
}
"""Case name -> batch builder ``(dim, generator) -> ParticleBatch``."""


@dataclass(frozen=True)
class ExtremeOutcome:
    """What stayed finite in one case, with the figures worth reporting."""

    forward: bool
    parameter_gradient: bool
    position_gradient: bool
    second_order: bool
    num_edges: int
    max_neighbours: int
    max_abs_prediction: float

    @property
    def finite(self) -> bool:
        return self.forward and self.parameter_gradient and self.position_gradient and self.second_order

    @property
    def failures(self) -> list[str]:
        checks = {
            "forward": self.forward,
            "parameter gradient": self.parameter_gradient,
            "position gradient": self.position_gradient,
            "second order": self.second_order,
        }
        return [name for name, ok in checks.items() if not ok]


def _all_finite(tensors) -> bool:
    return all(bool(torch.isfinite(t).all()) for t in tensors if t is not None)


def check_finite(
    simulator: LearnedSimulator, batch: ParticleBatch, dtype: torch.dtype = torch.float32
) -> ExtremeOutcome:
    """Run forward, backward and second-order passes on ``batch``; ``bfloat16`` runs under CPU autocast."""
    simulator.zero_grad(set_to_none=True)
    sequence = batch.position_sequence.clone().requires_grad_(True)
    batch = ParticleBatch(sequence, batch.particle_type, batch.batch, batch.num_examples, batch.next_position)
    autocast = torch.autocast("cpu", dtype=dtype) if dtype != torch.float32 else contextlib.nullcontext()
    with autocast:
        prediction, target = simulator(batch, torch.zeros_like(sequence))
        graph = simulator.build_graph(sequence.detach(), batch)
        loss = masked_acceleration_loss(
            prediction.float(), target.float(), simulator.predicted_mask(batch.particle_type)
        )
    forward = _all_finite([prediction, target, loss])
    parameters = [p for p in simulator.parameters() if p.requires_grad]
    position_grad, *parameter_grads = torch.autograd.grad(
        loss, [sequence, *parameters], create_graph=True, allow_unused=True
    )
    penalty = (position_grad**2).sum()
    second = torch.autograd.grad(penalty, sequence, allow_unused=True)[0] if penalty.requires_grad else None
    neighbours = torch.bincount(graph.receivers, minlength=graph.num_nodes)
    return ExtremeOutcome(
        forward=forward,
        parameter_gradient=_all_finite(parameter_grads),
        position_gradient=_all_finite([position_grad]),
        second_order=_all_finite([second]),
        num_edges=graph.num_edges,
        max_neighbours=int(neighbours.max()),
        max_abs_prediction=float(torch.nan_to_num(prediction.detach().float(), nan=math.inf).abs().max()),
    )
