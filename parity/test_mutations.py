"""Deliberately wrong variants of the model must fail parity, so the suite is known to be able to fail.

Each test breaks one component the way public ports have (or easily could), runs the
forward stages on the smallest reference case, and expects failed quantities.
"""

from __future__ import annotations

import pytest
import torch

from gns_builtins.graph_builders.radius import RadiusGraphBuilder
from gns_builtins.processors.interaction_network import InteractionStep
from gns_framework.contracts import Graph
from gns_framework.importers import geoelements_layout
from gns_framework.model import normalization

from .harness import compare_case

FORWARD = ("features", "latents", "outputs")


def failed_quantities(case) -> list[str]:
    return [d.quantity for d in compare_case(case, case.import_model(), FORWARD) if not d.ok]


def drop_self_edges(monkeypatch) -> None:
    """The radius graph without the (i, i) edges the reference includes."""
    original = RadiusGraphBuilder.build

    def without_self_edges(self, position, batch, num_examples):
        graph = original(self, position, batch, num_examples)
        keep = graph.senders != graph.receivers
        return Graph(graph.senders[keep], graph.receivers[keep], graph.displacement[keep], graph.num_nodes)

    monkeypatch.setattr(RadiusGraphBuilder, "build", without_self_edges)


def test_the_unmutated_model_passes_the_same_checks(smallest_case):
    assert failed_quantities(smallest_case) == []


def test_edge_concatenation_in_the_reference_order_fails(smallest_case, monkeypatch):
    """Reading [receiver, sender, edge] columns as if they were ours ([edge, receiver, sender])."""
    monkeypatch.setattr(geoelements_layout, "edge_inputs_to_ours", lambda weight, latent: weight)
    failed = failed_quantities(smallest_case)
    assert "processor node latents" in failed and "normalised acceleration" in failed


def test_node_concatenation_in_the_reference_order_fails(smallest_case, monkeypatch):
    """Reading [aggregate, node] columns as if they were ours ([node, aggregate])."""
    monkeypatch.setattr(geoelements_layout, "node_inputs_to_ours", lambda weight, latent: weight)
    failed = failed_quantities(smallest_case)
    assert "processor node latents" in failed and "normalised acceleration" in failed


def test_no_residual_on_edges_fails(smallest_case, monkeypatch):
    """Edge latents replaced by their update (the residual kept on nodes only)."""
    original = InteractionStep.forward

    def without_edge_residual(self, x, e, senders, receivers, order=None):
        x_new, e_new = original(self, x, e, senders, receivers, order)
        return x_new, e_new - e

    monkeypatch.setattr(InteractionStep, "forward", without_edge_residual)
    failed = failed_quantities(smallest_case)
    assert "processor edge latents (subset, matched by pair)" in failed and "normalised acceleration" in failed


def test_std_not_combined_with_noise_fails(smallest_case, monkeypatch):
    """Normalising with the data's std alone instead of sqrt(std^2 + noise^2)."""
    monkeypatch.setattr(normalization, "noise_combined_std", lambda std, noise_std: torch.tensor(std))
    failed = failed_quantities(smallest_case)
    assert "node features" in failed and "next position (moving particles)" in failed


def test_missing_self_edges_fail(smallest_case, monkeypatch):
    drop_self_edges(monkeypatch)
    failed = failed_quantities(smallest_case)
    assert "input graph: edges in only one graph" in failed and "normalised acceleration" in failed


@pytest.mark.parametrize("stage", ["rollout", "training"])
def test_missing_self_edges_fail_rollout_and_training(smallest_case, monkeypatch, stage):
    """The later stages fail too, so they are not vacuous."""
    drop_self_edges(monkeypatch)
    deviations = compare_case(smallest_case, smallest_case.import_model(), [stage])
    assert [d for d in deviations if not d.ok]
