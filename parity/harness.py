"""Running the built-in simulator on a reference case and measuring every deviation.

Each check yields a :class:`Deviation` (measured value, tolerance, where the worst
one is). Checks are grouped in stages so a test can ask for the cheap forward
ones only. Our radius graph sorts edges by (receiver, sender), so order-dependent
outputs are compared with the reference's ``canon/`` arrays (its outputs with that
edge order); edges are compared as sets and edge latents matched by (sender, receiver).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from gns_framework.importers.geoelements import ImportedCheckpoint
from gns_framework.importers.geoelements_layout import EMBEDDING_KEY
from gns_framework.model.loss import masked_acceleration_loss
from gns_framework.model.rollout import rollout

from . import tolerances as tol
from .cases import ReferenceCase

STAGES = ("features", "latents", "outputs", "rollout", "training")


@dataclass(frozen=True)
class Deviation:
    """One compared quantity: measured deviation against its tolerance."""

    quantity: str
    value: float
    tolerance: float
    worst: str = ""

    @property
    def ok(self) -> bool:
        return not math.isnan(self.value) and self.value <= self.tolerance

    def __str__(self) -> str:
        where = f" ({self.worst})" if self.worst else ""
        return f"{self.quantity}: {self.value:.3g} vs tolerance {self.tolerance:.3g}{where}"


def max_abs(ours: Tensor, reference: Tensor) -> float:
    if ours.shape != reference.shape:
        return math.inf
    return float((ours.double() - reference.double()).abs().max()) if ours.numel() else 0.0


def edge_keys(senders: Tensor, receivers: Tensor, num_nodes: int) -> np.ndarray:
    """One integer per directed edge, for set comparison and pair matching."""
    return (senders.long() * num_nodes + receivers.long()).numpy()


def edge_set_difference(senders: Tensor, receivers: Tensor, reference_index: np.ndarray, num_nodes: int) -> Deviation:
    """Edges in exactly one of the two graphs (``reference_index``: (2, E) [senders; receivers])."""
    ours = set(edge_keys(senders, receivers, num_nodes).tolist())
    theirs = set(
        edge_keys(torch.from_numpy(reference_index[0]), torch.from_numpy(reference_index[1]), num_nodes).tolist()
    )
    only = sorted(ours ^ theirs)
    worst = f"e.g. (sender, receiver) = {divmod(only[0], num_nodes)}" if only else f"{len(ours)} edges"
    return Deviation("", float(len(only)), 0.0, worst)


def matched_rows(ours: Tensor, senders: Tensor, receivers: Tensor, pairs: np.ndarray, num_nodes: int) -> Tensor:
    """Rows of ``ours`` (E, k) for the edges ``pairs`` (2, K) [senders; receivers]; NaN rows where absent."""
    position = {key: i for i, key in enumerate(edge_keys(senders, receivers, num_nodes).tolist())}
    wanted = edge_keys(torch.from_numpy(pairs[0]), torch.from_numpy(pairs[1]), num_nodes).tolist()
    rows = torch.full((len(wanted), ours.shape[1]), math.nan, dtype=ours.dtype)
    for k, key in enumerate(wanted):
        if key in position:
            rows[k] = ours[position[key]]
    return rows


def compare_case(case: ReferenceCase, imported: ImportedCheckpoint, stages: Iterable[str] = STAGES) -> list[Deviation]:
    """Every deviation of ``imported.simulator`` from ``case`` for the chosen stages."""
    stages = set(stages)
    unknown = stages - set(STAGES)
    if unknown:
        raise ValueError(f"unknown stages {sorted(unknown)}; choose from {STAGES}")
    found: list[Deviation] = []
    if stages & {"features", "latents", "outputs"}:
        found += _forward(case, imported, stages)
    if "rollout" in stages:
        found += _rollout(case, imported)
    if "training" in stages:
        found += _training(case, imported)
    return found


def _named(quantity: str, deviation: Deviation) -> Deviation:
    return Deviation(quantity, deviation.value, deviation.tolerance, deviation.worst)


@torch.no_grad()
def _forward(case: ReferenceCase, imported: ImportedCheckpoint, stages: set[str]) -> list[Deviation]:
    simulator = imported.simulator
    batch = case.batch()
    n = batch.num_particles
    node_features, edge_features, graph = simulator.encode_inputs(batch.position_sequence, batch)
    s, r = graph.senders, graph.receivers
    found = []
    if "features" in stages:
        reference_index = case.arrays["pre/edge_index"]
        found += [
            Deviation("node features", max_abs(node_features, case.tensor("pre/node_features")), tol.EXACT),
            _named("input graph: edges in only one graph", edge_set_difference(s, r, reference_index, n)),
            Deviation(
                "edge features (matched by pair)",
                max_abs(matched_rows(edge_features, s, r, reference_index, n), case.tensor("pre/edge_features")),
                tol.EXACT,
            ),
        ]
    if "latents" in stages:
        node_latent, edge_latent = simulator.encoder(node_features, edge_features)
        processed_nodes, processed_edges = simulator.processor(node_latent, edge_latent, graph)
        pairs = case.arrays["enc/latent_edges_subset_senders_receivers"]
        for stage, nodes, edges, bound in (
            ("encoder", node_latent, edge_latent, tol.EXACT),
            ("processor", processed_nodes, processed_edges, tol.PROCESSOR_LATENT),
        ):
            prefix = "enc" if stage == "encoder" else "proc"
            found += [
                Deviation(f"{stage} node latents", max_abs(nodes, case.tensor(f"{prefix}/latent_nodes")), bound),
                Deviation(
                    f"{stage} edge latents (subset, matched by pair)",
                    max_abs(matched_rows(edges, s, r, pairs, n), case.tensor(f"{prefix}/latent_edges_subset")),
                    bound,
                ),
                # Each of the E summed rows may differ by the per-row tolerance.
                Deviation(
                    f"{stage} edge latent column sums (float64, all edges)",
                    max_abs(edges.double().sum(0), case.tensor(f"{prefix}/latent_edges_colsum")),
                    bound * graph.num_edges,
                ),
            ]
    if "outputs" in stages:
        acceleration = simulator.normalized_prediction(batch.position_sequence, batch)
        moving = simulator.predicted_mask(batch.particle_type)
        found += [
            Deviation(
                "normalised acceleration",
                max_abs(acceleration, case.tensor("canon/out/normalized_acceleration")),
                tol.NORMALIZED_ACCELERATION,
            ),
            # Kinematic particles are prescribed, never integrated: only moving rows are comparable.
            Deviation(
                "next position (moving particles)",
                max_abs(simulator.predict_next_position(batch)[moving], case.tensor("canon/out/next_position")[moving]),
                tol.NEXT_POSITION,
            ),
        ]
    return found


def _rollout(case: ReferenceCase, imported: ImportedCheckpoint) -> list[Deviation]:
    """The reference's rollout: per example, kinematic particles set to the ground truth each step."""
    reference = case.tensor("canon/rollout/predicted")
    steps = reference.shape[0]
    predicted, losses = [], []
    for example in case.examples:
        result = rollout(imported.simulator, case.trajectory(example), steps)
        predicted.append(torch.from_numpy(result.predicted))
        # The reference's loss_mean averages over every particle, kinematic ones included.
        losses.append(float(((result.predicted.astype(np.float64) - result.ground_truth) ** 2).mean()))
    predicted_all = torch.cat(predicted, dim=1)
    per_step = (predicted_all.double() - reference.double()).abs().amax(dim=(1, 2))
    first = tol.ROLLOUT_FIRST_STEP_COUNT
    worst_step = int(per_step.argmax())
    loss_reference = case.arrays["canon/rollout/loss_mean"].astype(np.float64)
    loss_error = np.abs(np.array(losses) - loss_reference)
    # mean((e + D)^2) - mean(e^2) <= 2 sqrt(mean e^2) max|D| + max|D|^2 when positions agree within max|D|.
    loss_bound = 2 * np.sqrt(loss_reference) * tol.ROLLOUT_ALL_STEPS + tol.ROLLOUT_ALL_STEPS**2
    return [
        Deviation(
            f"rollout positions, steps 1-{first}",
            float(per_step[:first].max()),
            tol.ROLLOUT_FIRST_STEPS,
            f"per step {[f'{v:.2g}' for v in per_step[:first].tolist()]}",
        ),
        Deviation(
            f"rollout positions, all {steps} steps",
            float(per_step.max()),
            tol.ROLLOUT_ALL_STEPS,
            f"worst at step {worst_step + 1}",
        ),
        Deviation(
            "rollout loss_mean per example", float((loss_error / loss_bound).max()), 1.0, f"abs {loss_error.tolist()}"
        ),
    ]


def _training(case: ReferenceCase, imported: ImportedCheckpoint) -> list[Deviation]:
    """One training step with the stored noise: target, prediction, loss, every gradient and the Adam step."""
    simulator = imported.simulator
    batch = case.batch()
    noise = case.tensor("train/position_noise")
    mask = simulator.predicted_mask(batch.particle_type)
    found = [
        Deviation("non-kinematic mask: mismatches", float((mask != case.tensor("train/non_kinematic_mask")).sum()), 0.0)
    ]
    with torch.no_grad():
        graph = simulator.build_graph(batch.position_sequence + noise, batch)
    found.append(
        _named(
            "noisy training graph: edges in only one graph",
            edge_set_difference(graph.senders, graph.receivers, case.arrays["train/edge_index"], batch.num_particles),
        )
    )
    simulator.zero_grad(set_to_none=True)
    prediction, target = simulator(batch, noise)
    loss = masked_acceleration_loss(prediction, target, mask)
    loss.backward()
    reference_loss = float(case.arrays["canon/train/loss"])
    found += [
        Deviation(
            "training target", max_abs(target.detach(), case.tensor("train/target_normalized_acceleration")), tol.EXACT
        ),
        Deviation(
            "training prediction",
            max_abs(prediction.detach(), case.tensor("canon/train/pred_normalized_acceleration")),
            tol.NORMALIZED_ACCELERATION,
        ),
        Deviation(
            "training loss (relative)",
            abs(float(loss.detach()) - reference_loss) / abs(reference_loss),
            tol.LOSS_RELATIVE,
        ),
    ]
    found += _gradients(case, imported)
    found += _adam_step(case, imported)
    return found


def _gradients(case: ReferenceCase, imported: ImportedCheckpoint) -> list[Deviation]:
    """Every parameter's gradient: full tensors where stored, else norm and sum."""
    parameters = dict(imported.simulator.named_parameters())
    mapping = imported.parameter_map
    keys = [str(k) for k in case.arrays["stats/param_keys"]]
    norms = case.arrays["canon/stats/gradnorm"]
    sums = case.arrays["canon/stats/gradsum"]
    full, norm, total, absent, compared = [], [], [], [], set()
    for key, reference_norm, reference_sum, numel in zip(keys, norms, sums, case.arrays["stats/numel"], strict=True):
        name = mapping.name(key)
        if name is None:
            # No counterpart: only the unused embedding of a single-type model, which gets no gradient.
            absent.append((key, 0.0 if math.isnan(reference_norm) else float(reference_norm)))
            continue
        compared.add(name)
        grad = parameters[name].grad
        ours = torch.zeros_like(parameters[name]) if grad is None else grad
        if f"grad/{key}" in case:
            reference = case.tensor(f"grad/{key}")
            scale = float(reference.abs().max()) or 1.0
            full.append((max_abs(ours, mapping.tensor(key, reference)) / scale, key))
            if key == EMBEDDING_KEY:
                others = [t for t in range(reference.shape[0]) if t not in imported.scene.particle_types]
                absent.append((f"{key} rows of absent types", float(reference[others].abs().max()) if others else 0.0))
        if math.isnan(reference_norm):
            absent.append((f"{key} (ours)", float(ours.abs().max())))
            continue
        norm.append((abs(float(ours.double().norm()) - reference_norm) / reference_norm, key))
        # |sum(D)| <= sqrt(numel) |D|_2 (Cauchy-Schwarz), with |D|_2 bounded by the norm tolerance.
        total.append((abs(float(ours.double().sum()) - reference_sum) / (reference_norm * math.sqrt(numel)), key))
    uncovered = sorted(set(parameters) - compared)
    found = [
        Deviation("parameters without a reference gradient", float(len(uncovered)), 0.0, ", ".join(uncovered[:3])),
        _worst("gradients, full tensors (|diff| / max|g|)", full, tol.GRADIENT_RELATIVE_TO_MAX),
        _worst("gradient norms (relative)", norm, tol.GRADIENT_NORM_RELATIVE),
        _worst("gradient sums (/ (norm * sqrt(numel)))", total, tol.GRADIENT_NORM_RELATIVE),
    ]
    if absent:
        found.append(_worst("gradients that must be zero", [(v, k) for k, v in absent], 0.0))
    return found


def _worst(quantity: str, values: list[tuple[float, str]], tolerance: float) -> Deviation:
    if not values:
        return Deviation(quantity, math.nan, tolerance, "nothing compared")
    value, key = max(values, key=lambda vk: math.inf if math.isnan(vk[0]) else vk[0])
    return Deviation(quantity, value, tolerance, f"{key}; {len(values)} tensors")


def _adam_step(case: ReferenceCase, imported: ImportedCheckpoint) -> list[Deviation]:
    """One ``torch.optim.Adam`` step from our gradients against the reference's parameters after it."""
    settings = case.meta["adam"]
    parameters = dict(imported.simulator.named_parameters())
    before = {name: p.detach().clone() for name, p in parameters.items()}
    optimizer = torch.optim.Adam(
        parameters.values(),
        lr=settings["lr"],
        betas=tuple(settings["betas"]),
        eps=settings["eps"],
        weight_decay=settings["weight_decay"],
    )
    optimizer.step()
    mapping = imported.parameter_map
    errors = []
    for key in case.arrays:
        if key.startswith("adam/param_after/"):
            name = mapping.name(key[len("adam/param_after/") :])
            if name is not None:
                after = mapping.tensor(key[len("adam/param_after/") :], case.tensor(key))
                errors.append((max_abs(parameters[name].detach(), after), name))
    with torch.no_grad():
        for name, p in parameters.items():
            p.copy_(before[name])
    return [_worst("parameters after one Adam step", errors, tol.ADAM_STEP)]
