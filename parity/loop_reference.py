"""The GNS of Sanchez-Gonzalez et al. 2020 restated with plain loops, to check the built-ins against.

One particle or one edge at a time, in float64, with no graph library and no
vectorised gather or scatter: slow on purpose, and readable next to the paper.
Concatenation orders are ours (DeepMind's): edge MLP ``[e, x_receiver, x_sender]``,
node MLP ``[x, aggregate]``.

Notation: N particles, C positions of history (C - 1 velocities), d dimensions,
R the connectivity radius, x node latents, e edge latents.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

Layers = list[tuple[Tensor, Tensor]]
"""An MLP as (weight (out, in), bias (out,)) per Linear; ReLU between them."""


@dataclass
class NormedMLP:
    layers: Layers
    gamma: Tensor
    beta: Tensor


@dataclass
class Weights:
    """Every learned parameter, by role (float64)."""

    type_embedding: dict[int, Tensor] | None
    encoder_node: NormedMLP
    encoder_edge: NormedMLP
    steps: list[tuple[NormedMLP, NormedMLP]]
    """(edge MLP, node MLP) per message-passing step."""
    decoder: Layers


@dataclass
class Statistics:
    """Normalisation statistics; ``std`` already combined with the training noise."""

    vel_mean: Tensor
    vel_std: Tensor
    acc_mean: Tensor
    acc_std: Tensor


def combined_std(std: list[float], noise_std: float) -> Tensor:
    """Inputs are noisy during training, so their spread is sqrt(std^2 + noise^2)."""
    return torch.tensor([math.sqrt(s * s + noise_std * noise_std) for s in std], dtype=torch.float64)


def connect(position: Tensor, example: list[int], radius: float) -> list[tuple[int, int]]:
    """(sender, receiver) for every ordered pair of one example closer than R, self-pairs included."""
    pairs = []
    for receiver in range(len(position)):
        for sender in range(len(position)):
            if example[sender] != example[receiver]:
                continue
            d2 = sum(float(position[sender, k] - position[receiver, k]) ** 2 for k in range(position.shape[1]))
            if d2 < radius * radius:
                pairs.append((sender, receiver))
    return pairs


def node_features(
    history: Tensor,
    particle_type: list[int],
    properties: Tensor | None,
    bounds: list[tuple[float, float]],
    radius: float,
    clamp: float,
    stats: Statistics,
    weights: Weights,
) -> list[Tensor]:
    """Per particle: normalised velocities (time-major), clipped wall distances / R, type embedding, properties."""
    features = []
    for i in range(history.shape[0]):
        parts = []
        for t in range(history.shape[1] - 1):
            velocity = history[i, t + 1] - history[i, t]
            parts.append((velocity - stats.vel_mean) / stats.vel_std)
        current = history[i, -1]
        lower = torch.stack([current[k] - bounds[k][0] for k in range(len(bounds))])
        upper = torch.stack([bounds[k][1] - current[k] for k in range(len(bounds))])
        parts.append(torch.clamp(torch.cat([lower, upper]) / radius, -clamp, clamp))
        if weights.type_embedding is not None:
            parts.append(weights.type_embedding[particle_type[i]])
        if properties is not None:
            parts.append(properties[i])
        features.append(torch.cat(parts))
    return features


def edge_features(position: Tensor, pairs: list[tuple[int, int]], radius: float) -> list[Tensor]:
    """Per edge: (p_sender - p_receiver) / R and its length."""
    features = []
    for sender, receiver in pairs:
        relative = (position[sender] - position[receiver]) / radius
        features.append(torch.cat([relative, torch.sqrt((relative * relative).sum()).reshape(1)]))
    return features


def mlp(layers: Layers, v: Tensor) -> Tensor:
    for index, (weight, bias) in enumerate(layers):
        if index > 0:
            v = torch.clamp(v, min=0.0)
        v = weight @ v + bias
    return v


def layer_norm(v: Tensor, gamma: Tensor, beta: Tensor, eps: float = 1e-5) -> Tensor:
    mean = v.mean()
    variance = ((v - mean) ** 2).mean()
    return (v - mean) / torch.sqrt(variance + eps) * gamma + beta


def normed_mlp(block: NormedMLP, v: Tensor) -> Tensor:
    return layer_norm(mlp(block.layers, v), block.gamma, block.beta)


def interaction_step(
    x: list[Tensor], e: list[Tensor], pairs: list[tuple[int, int]], edge_block: NormedMLP, node_block: NormedMLP
) -> tuple[list[Tensor], list[Tensor]]:
    """Edge update from (edge, receiver, sender), sum at receivers, node update, residuals on both."""
    edge_update = [normed_mlp(edge_block, torch.cat([e[k], x[r], x[s]])) for k, (s, r) in enumerate(pairs)]
    aggregate = [torch.zeros_like(x[0]) for _ in x]
    for k, (_, receiver) in enumerate(pairs):
        aggregate[receiver] = aggregate[receiver] + edge_update[k]
    node_update = [normed_mlp(node_block, torch.cat([x[i], aggregate[i]])) for i in range(len(x))]
    return [x[i] + node_update[i] for i in range(len(x))], [e[k] + edge_update[k] for k in range(len(e))]


@dataclass
class ModelSetup:
    bounds: list[tuple[float, float]]
    radius: float
    clamp: float
    kinematic_types: set[int]


def normalized_acceleration(
    history: Tensor,
    particle_type: list[int],
    properties: Tensor | None,
    example: list[int],
    scene: ModelSetup,
    stats: Statistics,
    weights: Weights,
) -> tuple[Tensor, list[tuple[int, int]]]:
    """Encode, process, decode: (N, d) normalised accelerations, and the graph's (sender, receiver) pairs."""
    position = history[:, -1]
    pairs = connect(position, example, scene.radius)
    nodes = node_features(history, particle_type, properties, scene.bounds, scene.radius, scene.clamp, stats, weights)
    x = [normed_mlp(weights.encoder_node, v) for v in nodes]
    e = [normed_mlp(weights.encoder_edge, v) for v in edge_features(position, pairs, scene.radius)]
    for edge_block, node_block in weights.steps:
        x, e = interaction_step(x, e, pairs, edge_block, node_block)
    return torch.stack([mlp(weights.decoder, v) for v in x]), pairs


def next_position(history: Tensor, acceleration: Tensor) -> Tensor:
    """Semi-implicit Euler with dt = 1: v' = (p_t - p_{t-1}) + a, p' = p_t + v'."""
    return history[:, -1] + (history[:, -1] - history[:, -2]) + acceleration


def training_loss(
    history: Tensor,
    label: Tensor,
    noise: Tensor,
    particle_type: list[int],
    properties: Tensor | None,
    example: list[int],
    scene: ModelSetup,
    stats: Statistics,
    weights: Weights,
) -> tuple[Tensor, Tensor]:
    """Target (N, d) and loss of one training step on noisy inputs (Sec. 3 of the paper).

    The label moves with the last input's noise, so the target corrects the velocity
    noise only; kinematic particles add nothing to the mean over particles.
    """
    noisy = history + noise
    predicted, _ = normalized_acceleration(noisy, particle_type, properties, example, scene, stats, weights)
    adjusted = label + noise[:, -1]
    target = []
    total, count = torch.zeros((), dtype=torch.float64), 0
    for i in range(len(particle_type)):
        acceleration = (adjusted[i] - noisy[i, -1]) - (noisy[i, -1] - noisy[i, -2])
        target.append((acceleration - stats.acc_mean) / stats.acc_std)
        if particle_type[i] not in scene.kinematic_types:
            total = total + ((predicted[i] - target[i]) ** 2).sum()
            count += 1
    return torch.stack(target), total / max(count, 1)
