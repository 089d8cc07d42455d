"""How deep a process's halo must be: the distance over which a particle's next position can depend on others."""

from __future__ import annotations

from ..errors import GnsError
from ..model.learned_simulator import LearnedSimulator


def receptive_field(simulator: LearnedSimulator) -> float:
    """Connectivity radius x message-passing hops (dataset length units).

    Each message-passing step carries information one edge further, and no edge is
    longer than the connectivity radius, so a particle's output depends only on the
    particles within ``hops * R``: with that halo, the particles a process owns see
    exactly the inputs they would see in the whole scene. The encoder and decoder act
    on each particle and each edge alone (their contracts), so they add no reach.
    Refuses a graph builder or processor that does not declare such a bound.
    """
    builder, processor = simulator.graph_builder, simulator.processor
    problems = []
    if not type(builder).joins_within_radius:
        problems.append(
            f"graph builder {builder.name!r} joins particles by more than their own distance "
            "(joins_within_radius is False): use radius or periodic_radius"
        )
    hops_param = type(processor).hops_param
    if hops_param is None:
        problems.append(
            f"processor {processor.name!r} does not bound how far a particle's output reaches (hops_param is None)"
        )
    if problems:
        raise GnsError("a domain-decomposed rollout needs a bounded receptive field: " + "; ".join(problems))
    assert hops_param is not None
    return simulator.scene.connectivity_radius * int(getattr(processor.params, hops_param))
