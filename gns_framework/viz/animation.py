"""GIF of a rollout: prediction and ground truth side by side, particles coloured by type.

2D scenes are drawn as scatter plots in the domain box; 3D scenes as 3D scatter
plots seen from a fixed camera. matplotlib (Agg backend) and its Pillow writer
do the drawing and encoding, imported only when an animation is made.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..data.rollout import Rollout


def frame_indices(num_frames: int, every: int) -> list[int]:
    """Frames drawn: every ``every``-th from the first, and always the last one."""
    if every < 1:
        raise ValueError(f"every must be >= 1, got {every}")
    indices = list(range(0, num_frames, every))
    if indices[-1] != num_frames - 1:
        indices.append(num_frames - 1)
    return indices


def animate_side_by_side(
    path: str | Path,
    predicted: np.ndarray,
    ground_truth: np.ndarray,
    particle_type: np.ndarray,
    bounds: Sequence[Sequence[float]],
    dt: float,
    *,
    every: int = 1,
    fps: int = 20,
    material_names: Mapping[int, str] | None = None,
    length_unit: str | None = None,
    first_rolled_out_frame: int = 0,
    progress: Callable[[int, int], None] | None = None,
) -> Path:
    """Write a GIF with the prediction on the left and the ground truth on the right.

    Args:
        path: the ``.gif`` to write.
        predicted, ground_truth: (T, N, d) positions, d = 2 or 3, L.
        particle_type: (N,) int; one colour per type.
        bounds: (d, 2) domain walls, the fixed plot limits.
        dt: seconds between frames (shown in the title).
        every: draw every ``every``-th frame (the last is always drawn).
        fps: frames per second of the GIF.
        material_names: legend labels per type id (:meth:`Registry.material_names`), else ``type <id>``.
        length_unit: the positions' unit on the axes (``m`` for data our simulators made); None: the
            dataset's own, unnamed.
        first_rolled_out_frame: frames before it are input frames (labelled as such).
        progress: called as ``progress(frames_drawn, frames_in_all)`` after each frame is drawn
            (drawing dominates: about 0.3 s a frame for a few thousand particles).

    Returns ``path``.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.animation import FuncAnimation, PillowWriter

    path = Path(path)
    if path.suffix.lower() != ".gif":
        raise ValueError(f"{path}: animations are written as .gif")
    predicted, ground_truth = np.asarray(predicted), np.asarray(ground_truth)
    if predicted.shape != ground_truth.shape or predicted.ndim != 3 or predicted.shape[2] not in (2, 3):
        raise ValueError(
            f"predicted and ground_truth must both be (T, N, d) with d = 2 or 3, got {predicted.shape} and "
            f"{ground_truth.shape}"
        )
    dim = predicted.shape[2]
    particle_type = np.asarray(particle_type)
    types = sorted(set(particle_type.tolist()))
    palette = matplotlib.colormaps["tab10"]
    colours = np.array([palette(types.index(t) % 10) for t in particle_type])
    labels = {t: (material_names or {}).get(t, f"type {t}") for t in types}
    marker_size = float(np.clip(4000 / max(len(particle_type), 1), 0.5, 20))

    def axis_label(axis: str) -> str:
        return f"{axis} ({length_unit})" if length_unit else f"{axis} (dataset units)"

    projection = "3d" if dim == 3 else None
    fig = plt.figure(figsize=(10, 5))
    # Axes, or Axes3D for the 3d projection (which matplotlib's types do not tell apart): set_zlim, scatter(x, y, z).
    axes: list[Any] = [fig.add_subplot(1, 2, k + 1, projection=projection) for k in range(2)]

    def draw(t: int) -> list:
        stage = "input" if t < first_rolled_out_frame else "rollout"
        fig.suptitle(f"t = {t * dt:.4g} s (frame {t}, {stage})", fontsize=10)
        for ax, positions, title in ((axes[0], predicted, "prediction"), (axes[1], ground_truth, "ground truth")):
            ax.cla()
            ax.set_title(title, fontsize=10)
            for t_id in types:
                chosen = particle_type == t_id
                ax.scatter(
                    *positions[t, chosen].T, s=marker_size, color=colours[chosen], label=labels[t_id], linewidths=0
                )
            ax.set_xlim(*bounds[0])
            ax.set_ylim(*bounds[1])
            ax.set_xlabel(axis_label("x"), fontsize=8)
            ax.set_ylabel(axis_label("y"), fontsize=8)
            if dim == 3:
                ax.set_zlim(*bounds[2])
                ax.set_zlabel(axis_label("z"), fontsize=8)
            else:
                ax.set_aspect("equal")
        axes[1].legend(loc="upper right", fontsize=7, markerscale=max(1.0, 6 / marker_size))
        return []

    animation = FuncAnimation(fig, draw, frames=frame_indices(len(predicted), every), blit=False)
    path.parent.mkdir(parents=True, exist_ok=True)
    callback = None if progress is None else (lambda drawn, total: progress(drawn + 1, total))
    animation.save(path, writer=PillowWriter(fps=fps), progress_callback=callback)
    plt.close(fig)
    return path


def animate_rollout(
    rollout: Rollout,
    path: str | Path,
    *,
    every: int = 1,
    fps: int = 20,
    material_names: Mapping[int, str] | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> Path:
    """GIF of a rollout with its metadata (as loaded from a file), input frames included (:func:`animate_side_by_side`).

    Positions are labelled in metres when the data came from ``gns generate`` (its
    simulators work in SI units), else in the dataset's own units.
    """
    assert rollout.metadata is not None  # a rollout file always has it
    generated = getattr(rollout.metadata, "generated_from", None) is not None
    return animate_side_by_side(
        path,
        rollout.predicted_trajectory(),
        rollout.ground_truth_trajectory(),
        rollout.particle_type,
        rollout.metadata.bounds if rollout.truth.bounds is None else rollout.truth.bounds.tolist(),  # its own box
        rollout.metadata.dt,
        every=every,
        fps=fps,
        material_names=material_names,
        length_unit="m" if generated else None,
        first_rolled_out_frame=rollout.history,
        progress=progress,
    )
