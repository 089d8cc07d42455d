"""Synthetic geoelements/gns checkpoints for the importer's tests: random tensors under geoelements' keys and
shapes, the metadata of their dataset and a batch to run them on."""

from __future__ import annotations

import torch

from gns_framework.data.batch import ParticleBatch
from gns_framework.importers.geoelements_layout import Architecture

METADATA = {
    "bounds": [[0.0, 1.0], [0.0, 1.0]],
    "sequence_length": 50,
    "default_connectivity_radius": 0.3,
    "dim": 2,
    "dt": 0.0025,
    "vel_mean": [0.0, -1e-3],
    "vel_std": [2e-3, 2e-3],
    "acc_mean": [0.0, 0.0],
    "acc_std": [3e-4, 3e-4],
}


def geoelements_state_dict(
    latent=6, hidden=5, layers=2, steps=2, types=9, embedding=4, properties=0, dim=2, seed=0
) -> dict[str, torch.Tensor]:
    """Random tensors under geoelements' keys and shapes (its ``LearnedSimulator`` with these sizes)."""
    node_in = 7 * dim + (embedding if types > 1 else 0) + properties
    arch = Architecture(latent, hidden, layers, steps, types, embedding, node_in, dim + 1)
    generator = torch.Generator().manual_seed(seed)
    widths = {"_encoder.node_fn": node_in, "_encoder.edge_fn": dim + 1, "edge_fn": 3 * latent, "node_fn": 2 * latent}
    state = {}
    for key in arch.keys():  # noqa: SIM118 - an Architecture is no dict: keys() lists its state-dict keys
        if key.startswith("_particle_type_embedding"):
            shape = (types, embedding)
        elif "NN-" not in key:
            shape = (latent,)
        else:
            k = int(key.split("NN-")[1].split(".")[0])
            block = None if "_decoder" in key else next(b for b in widths if b in key)
            fan_in = (widths[block] if block else latent) if k == 0 else hidden
            fan_out = (dim if "_decoder" in key else latent) if k == layers else hidden
            shape = (fan_out, fan_in) if key.endswith("weight") else (fan_out,)
        state[key] = torch.randn(shape, generator=generator) * 0.3
    return state


def batch_of(types, dim=2, n=12, seed=1, with_property=False) -> ParticleBatch:
    generator = torch.Generator().manual_seed(seed)
    start = torch.rand(n, 1, dim, generator=generator) * 0.8 + 0.1
    sequence = start + torch.cumsum(torch.randn(n, 6, dim, generator=generator) * 2e-3, dim=1)
    return ParticleBatch(
        position_sequence=sequence,
        particle_type=torch.tensor(types)[torch.arange(n) % len(types)],
        batch=torch.zeros(n, dtype=torch.long),
        num_examples=1,
        material_property=torch.full((n, 1), 0.6) if with_property else None,
    )
