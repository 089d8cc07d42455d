"""The node side of a learned step compiled, with no graph breaks (issue 45, item 4).

Per particle a step builds node features from the history, encodes them, updates
the node latents after every message-passing step and decodes them: chains of
small elementwise operations (differences, normalisation, clamps, LayerNorm,
residuals) around matrix products over (N, ...) rows. Eagerly each operation is a
kernel that reads and writes all N rows; compiled, a chain is one kernel. The edge
side runs kernels of its own (Triton on CUDA) and stays outside the compiled graphs.

:func:`compile_node_side` compiles what the components declare as their node side
(``node_module_names``: the encoder's node MLP, each step's node MLP, the decoder)
and the node features, each with ``fullgraph=True``: a graph break, which would
split a graph and run its pieces eagerly, is an error at the first call naming its
line, not a silent slowdown. ``dynamic=True``: one graph for every particle count.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch

if TYPE_CHECKING:
    from ..model.learned_simulator import LearnedSimulator


def compile_node_side(simulator: LearnedSimulator, backend: str = "inductor") -> list[str]:
    """Compile ``simulator``'s node side in place; returns what was compiled, by module path.

    ``backend``: ``inductor`` (fused kernels: Triton on CUDA, C++ on the CPU); ``eager`` and
    ``aot_eager`` trace the same graphs without generating code (the tests' way to show that
    nothing breaks a graph, forward and backward). Parameters and checkpoints are unchanged.
    """
    compiled = []
    for part_name in ("encoder", "processor", "decoder"):
        part = getattr(simulator, part_name)
        for path, module in part.named_modules():
            if module in part.node_modules():
                module.compile(fullgraph=True, dynamic=True, backend=backend)
                compiled.append(f"{part_name}.{path}" if path else part_name)
    features = simulator.features
    features.node_features = torch.compile(  # type: ignore[method-assign]
        features.node_features, fullgraph=True, dynamic=True, backend=backend
    )
    compiled.append("features.node_features")
    return compiled
