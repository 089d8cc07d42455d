"""Limits checked before anything is allocated (issue 30, item 5).

A scene, a dataset's metadata or a file's own length fields can ask for more
memory than any machine has: a scene of 6.4e10 particles, a grid of 4096^3 nodes,
a ``sequence_length`` of 1e12, a tfrecord record of 2^40 bytes. Each is estimated
from the numbers alone and refused with the estimate, before the allocation that
would fail with ``MemoryError`` (or succeed and swap the machine to a halt).

The stated limits are the constants below; memory estimates are also compared
with this machine's physical memory (``os.sysconf``).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

from .errors import GnsError

MAX_PARTICLES = 100_000_000
"""Particles of one trajectory of a generated scene (blocks and obstacles together)."""
MAX_GRID_NODES = 1 << 30
"""Nodes of a simulator's background grid."""
MAX_SEQUENCE_LENGTH = 1_000_000
"""Frames of one trajectory a dataset's metadata may promise."""
MAX_RECORD_BYTES = 1 << 34
"""Bytes of one tfrecord record (16 GiB); a record is also never longer than the rest of its file."""

MAX_MEMBER_BYTES = 1 << 34
"""Bytes one member of a zip archive (an ``.npz`` array) may inflate to (16 GiB)."""
MAX_INFLATE_RATIO = 200
"""How many times its stored size a large archive member may inflate to. Particle positions compress 1-5x;
a member of zeros that inflates 1,000x from a few MB is a zip bomb, refused before it is inflated."""
INFLATE_RATIO_ABOVE = 1 << 26
"""Members that inflate to less than this (64 MiB) are not held to MAX_INFLATE_RATIO: a small constant array may
compress as well as it likes."""

MAX_MODEL_PARAMETERS = 2_000_000_000
"""Learned parameters a recipe may ask for (the paper's model has 1.6 million; 2e9 is 32 GB to train with Adam)."""
TRAINING_BYTES_PER_PARAMETER = 16
"""Weights, gradients and Adam's two moments, float32."""

PARTICLE_STATE_BYTES = {2: 4 * (2 * 2 + 2 * 4 + 4), 3: 4 * (2 * 3 + 2 * 9 + 4)}
"""Simulator state per particle, bytes: position, velocity, affine and deformation matrices, material (float32)."""
GRID_NODE_BYTES = {2: 8 * 3, 3: 8 * 4}
"""Grid state per node, bytes: mass and momentum, twice (scatter and update)."""


class LimitError(GnsError):
    """A size asked for is beyond a stated limit or this machine's memory."""


def physical_memory() -> int | None:
    """Bytes of physical memory of this machine, None where the system does not say."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        return None


def gib(nbytes: float) -> str:
    return f"{nbytes / 2**30:.3g} GiB"


def check_memory(where: str, nbytes: float, what: str) -> None:
    """Refuse ``nbytes`` when it exceeds this machine's physical memory."""
    memory = physical_memory()
    if memory is not None and nbytes > memory:
        raise LimitError(f"{where}: {what} needs about {gib(nbytes)}, more than this machine's {gib(memory)} of memory")


def _cells(length: float, spacing: float) -> float:
    return max(1.0, round(length / spacing))


def _domain_extents(scene) -> list[float]:
    return [hi - lo for lo, hi in scene.domain.bounds]


def body_particles(body, scene) -> float:
    """Upper bound of the particles one block or obstacle of ``scene`` is filled with (its largest draw)."""
    spacing = scene.particle_spacing
    extents = _domain_extents(scene)
    if body.shape == "plane":
        across = [_cells(e, spacing) + 1 for axis, e in enumerate(extents) if axis != 1]
        return scene.particles_per_cell * math.prod(across)
    if body.shape == "polygon":
        xs = [v[0] for v in body.vertices or [(0.0, 0.0)]]
        ys = [v[1] for v in body.vertices or [(0.0, 0.0)]]
        return _cells(max(xs) - min(xs), spacing) * _cells(max(ys) - min(ys), spacing)
    sizes = [value.high for value in body.size or []]
    return math.prod(_cells(s, spacing) for s in sizes) if sizes else 1.0


def scene_particles(scene) -> tuple[float, list[tuple[str, float, float]]]:
    """(particles of the largest trajectory, [(location, largest count, particles of one body)])."""
    parts = []
    for location, body in [(f"blocks[{i}]", b) for i, b in enumerate(scene.blocks)] + [
        (f"obstacles[{i}]", o) for i, o in enumerate(scene.obstacles)
    ]:
        parts.append((location, float(body.count.high), float(body_particles(body, scene))))
    return sum(count * each for _, count, each in parts), parts


def grid_nodes(scene) -> float:
    dx = scene.domain.cell_size
    return math.prod(_cells(e, dx) + 1 for e in _domain_extents(scene))


def check_scene(scene, source: str | Path, trajectories: int = 1) -> None:
    """Refuse ``scene`` (from ``source``) when its particles, grid or memory exceed the limits, before sampling.

    ``trajectories``: how many are generated and held in memory together (their stored frames).
    """
    source = str(source)
    particles, parts = scene_particles(scene)
    spacing = scene.particle_spacing
    if particles > MAX_PARTICLES:
        largest = max(parts, key=lambda p: p[1] * p[2])
        location, count, each = largest
        field = location if count <= 1 else f"{location}.count"
        raise LimitError(
            f"{source}: {field}: the scene asks for about {particles:.3g} particles per trajectory "
            f"({location}: up to {count:.0f} bod{'y' if count == 1 else 'ies'} of {each:.3g} particles at spacing "
            f"{spacing:.3g} m), more than the limit of {MAX_PARTICLES:.3g}: make the bodies smaller or fewer, "
            "or the grid coarser (domain.grid)"
        )
    nodes = grid_nodes(scene)
    if nodes > MAX_GRID_NODES:
        raise LimitError(
            f"{source}: domain.grid: a grid of {scene.domain.grid} cells along the longest axis has about "
            f"{nodes:.3g} nodes in {scene.dim}D, more than the limit of {MAX_GRID_NODES:.3g}: make it coarser"
        )
    d = scene.dim
    stored = trajectories * scene.time.frames * particles * d * 4
    working = particles * PARTICLE_STATE_BYTES[d] + nodes * GRID_NODE_BYTES[d]
    check_memory(
        f"{source}: blocks",
        stored + working,
        f"generating {trajectories} trajectories of {scene.time.frames} frames of about {particles:.3g} particles "
        f"on a grid of {nodes:.3g} nodes",
    )


def check_sequence_length(where: str, length: float) -> None:
    """Refuse a promised trajectory length beyond MAX_SEQUENCE_LENGTH frames."""
    if length > MAX_SEQUENCE_LENGTH:
        raise LimitError(
            f"{where}: sequence_length: {length:.6g} frames, more than the limit of {MAX_SEQUENCE_LENGTH:,}"
        )


def check_record_length(where: str, length: int, remaining: int) -> None:
    """Refuse a record whose stated ``length`` is longer than the ``remaining`` bytes of its file, or the limits."""
    if length > remaining:
        from .errors import DatasetError

        raise DatasetError(
            f"{where}: truncated data: the length field says {length:,} bytes but only {remaining:,} bytes follow "
            "in the file (truncated or corrupt?)"
        )
    if length > MAX_RECORD_BYTES:
        raise LimitError(f"{where}: {length:,} bytes, more than the limit of {MAX_RECORD_BYTES:,} bytes per record")
    check_memory(where, length, "reading the record")


def check_zip_member(where: str, info) -> None:
    """Refuse a zip member (``zipfile.ZipInfo``) that would inflate beyond the limits, before it is inflated.

    zipfile never returns more than the member's stated size (``file_size``), so the
    stated size bounds what reading it allocates; a member that lies about it fails
    its CRC at the end instead.
    """
    size, stored = int(info.file_size), max(1, int(info.compress_size))
    if size > MAX_MEMBER_BYTES:
        raise LimitError(f"{where}: inflates to {size:,} bytes, more than the limit of {MAX_MEMBER_BYTES:,} per member")
    if size > INFLATE_RATIO_ABOVE and size > MAX_INFLATE_RATIO * stored:
        raise LimitError(
            f"{where}: {stored:,} stored bytes inflate to {size:,} ({size / stored:,.0f}x; a zip bomb?): more than "
            f"the {MAX_INFLATE_RATIO}x any particle data compresses"
        )
    check_memory(where, size, "inflating the member")


def check_array_header(where: str, shape: tuple, dtype, available: int) -> None:
    """Refuse a ``.npy`` header whose shape x itemsize is more than the ``available`` bytes that follow it.

    numpy allocates the whole array from the header before reading a byte of it: a
    header claiming 6.4e10 particles asks for hundreds of GiB from a file of a few KB.
    """
    if getattr(dtype, "hasobject", False):
        return
    if any(not isinstance(n, int) or n < 0 for n in shape):
        raise LimitError(f"{where}: the .npy header's shape {shape} is not a tuple of counts")
    promised = math.prod(shape) * dtype.itemsize
    if promised > available:
        from .errors import DatasetError

        raise DatasetError(
            f"{where}: the .npy header promises {promised:,} bytes of {dtype} {shape}, but only {available:,} follow "
            "(truncated or forged?)"
        )
    check_memory(where, promised, f"the array {shape}")


def mlp_parameters(inputs: float, hidden: float, layers: float, outputs: float) -> float:
    """Weights and biases of an MLP of ``layers`` hidden layers of ``hidden`` units (a linear map when 0)."""
    if layers <= 0:
        return inputs * outputs + outputs
    return inputs * hidden + hidden + (layers - 1) * (hidden * hidden + hidden) + hidden * outputs + outputs


def estimate_model_parameters(latent: float, hidden: float, layers: float, steps: float) -> float:
    """About how many parameters a GNS of this size has: ``steps`` message-passing steps, each an edge MLP
    (sender, receiver and edge latents in) and a node MLP (node latent and the sum of messages in).

    The encoder, decoder and a processor's own extras add less than one step; a grid
    processor's convolutions are of the same order per step. The estimate is for
    refusing sizes no machine can train, from the numbers alone, before anything is built.
    """
    per_step = mlp_parameters(3 * latent, hidden, layers, latent) + mlp_parameters(2 * latent, hidden, layers, latent)
    return max(1.0, steps) * per_step


def model_size_problems(latent: int, hidden: int, layers: int, steps: int | None) -> list[tuple[str, str]]:
    """Recipe problems (field, why) for a model too large to build: beyond MAX_MODEL_PARAMETERS or this machine."""
    parameters = estimate_model_parameters(latent, hidden, layers, steps or 1)
    sizes = f"latent_size {latent}, mlp_hidden_size {hidden}, mlp_hidden_layers {layers}" + (
        f", {steps} message-passing steps" if steps else ""
    )
    # Named after the number that makes it large: steps grow it linearly, widths quadratically.
    if steps and steps > 1000:
        field = "model.processor.message_passing_steps"
    else:
        field = "model.latent_size" if latent >= hidden else "model.mlp_hidden_size"
    if parameters > MAX_MODEL_PARAMETERS:
        return [
            (field, f"{sizes}: about {parameters:.3g} parameters, more than the limit of {MAX_MODEL_PARAMETERS:.3g}")
        ]
    memory = physical_memory()
    needed = parameters * TRAINING_BYTES_PER_PARAMETER
    if memory is not None and needed > memory:
        return [
            (
                field,
                f"{sizes}: about {parameters:.3g} parameters, whose training state (weights, gradients, Adam) needs "
                f"about {gib(needed)}, more than this machine's {gib(memory)} of memory",
            )
        ]
    return []
