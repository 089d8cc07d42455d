"""The graph a builder returns and processors pass messages over."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

from torch import Tensor


@dataclass(frozen=True)
class Graph:
    """Directed connectivity of one batch of particles.

    Attributes:
        senders: (E,) int64 (or int32, which a builder may give on accelerators) index of the particle each
            edge comes from; processors index with either.
        receivers: (E,) the same dtype, index of the particle each edge points to (messages
            are summed at receivers). Built-in builders sort edges by
            (receiver, sender).
        displacement: (E, d) float, ``p_sender - p_receiver`` in dataset units
            (minimum image in periodic domains).
        num_nodes: N, or more where ``node_particle`` is given.
        position: (N, d) float, each particle's current position in dataset units, for
            processors that work on space itself (a grid) rather than on edges; the
            learned simulator attaches it, builders need not (None: not given).
        batch: (N,) int64 example index of each particle (non-decreasing), or None
            (one example), so such processors keep the examples of a batch apart.
        num_examples: B.
        receivers_sorted: the builder guarantees ``receivers`` non-decreasing (every built-in builder does), so
            sums at receivers can run over contiguous runs of edges without sorting or a read-back to check;
            keeping a subset of the edges keeps it.
        node_particle: (num_nodes,) int64 the particle whose features and position each node takes, where a
            graph has more nodes than particles: a fixed-size graph's padding edges join a sink node after the
            particles, so that no particle receives their messages; the learned simulator drops the sinks'
            outputs. None: node i is particle i.
        exchange: in a domain-decomposed step with a halo of latents, refreshes the (N, L) node latents of
            the particles other processes own; a processor that declares ``exchanges_latents`` calls it
            between message-passing steps. None otherwise.
    """

    senders: Tensor
    receivers: Tensor
    displacement: Tensor
    num_nodes: int
    position: Tensor | None = None
    batch: Tensor | None = None
    num_examples: int = 1
    receivers_sorted: bool = False
    node_particle: Tensor | None = None
    exchange: Callable[[Tensor], Tensor] | None = None

    @property
    def num_edges(self) -> int:
        return int(self.senders.shape[0])

    def received_by(self, owned: Tensor, exchange: Callable[[Tensor], Tensor] | None) -> Graph:
        """The edges whose receiver is ``owned`` ((N,) bool), with ``exchange`` attached.

        A process of a domain-decomposed step computes messages into its own particles
        only; its halo particles just send, their latents refreshed by ``exchange``.
        """
        keep = owned[self.receivers].nonzero()[:, 0]
        return replace(
            self,
            senders=self.senders[keep],
            receivers=self.receivers[keep],
            displacement=self.displacement[keep],
            exchange=exchange,
        )
