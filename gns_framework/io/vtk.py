"""VTK output for ParaView and friends: one ``.vtu`` per frame plus a ``.pvd`` collection.

Each frame is an unstructured grid of vertex cells (one per particle) written by
meshio, with point data ``velocity`` (L/s, always 3 components), ``particle_type``,
one array per material property (named as the data names them), and, given the
materials' names, one 0/1 array per material, ``material:<name>`` (ParaView's
Threshold or colour by it: the particles of one material, by name). 2D points get
z = 0, so 2D and 3D scenes open the same way. The ``.pvd`` file lists the frames with their time in seconds.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any
from xml.etree import ElementTree

import numpy as np

from ..data.rollout import Rollout
from ..safe_names import ensure_inside, require_component


def _as_3d(values: np.ndarray) -> np.ndarray:
    """(..., 2) or (..., 3) -> (..., 3), padding the missing z with 0."""
    if values.shape[-1] == 3:
        return values
    return np.concatenate([values, np.zeros((*values.shape[:-1], 1), dtype=values.dtype)], axis=-1)


def frame_velocities(positions: np.ndarray, dt: float) -> np.ndarray:
    """(T, N, d) positions -> (T, N, d) velocities in L/s.

    Backward differences ``(p[t] - p[t-1]) / dt``, the way the model sees velocity;
    frame 0, which has no predecessor, takes the forward difference.
    """
    velocity = np.diff(positions, axis=0) / dt
    return np.concatenate([velocity[:1], velocity]) if len(velocity) else np.zeros_like(positions)


def write_vtk_series(
    directory: str | Path,
    name: str,
    positions: np.ndarray,
    dt: float,
    particle_type: np.ndarray,
    material_property: np.ndarray | None = None,
    property_names: Sequence[str] | None = None,
    progress: Callable[[int, int], None] | None = None,
    material_names: Mapping[int, str] | None = None,
) -> Path:
    """Write ``<directory>/<name>/frame_<t>.vtu`` for every frame and ``<directory>/<name>.pvd``.

    Args:
        positions: (T, N, d) with d = 2 or 3, L.
        dt: seconds between frames.
        particle_type: (N,) int.
        material_property: (N, P) or None.
        property_names: P point-data names; ``material_property_<k>`` by default.
        progress: called as ``progress(frames_written, num_frames)`` after each frame.
        material_names: type id -> material name (:meth:`Registry.material_names`); each becomes a
            ``material:<name>`` array, 1 on that material's particles.

    Returns the path of the ``.pvd`` collection.
    """
    import meshio

    positions = np.asarray(positions, dtype=np.float32)
    if positions.ndim != 3 or positions.shape[2] not in (2, 3):
        raise ValueError(f"positions: expected (T, N, d) with d = 2 or 3, got {positions.shape}")
    num_frames, num_particles, _ = positions.shape
    point_data: dict[str, np.ndarray] = {"particle_type": np.asarray(particle_type, dtype=np.int32)}
    if material_property is not None:
        material_property = np.asarray(material_property, dtype=np.float32).reshape(num_particles, -1)
        names = list(property_names or [f"material_property_{k}" for k in range(material_property.shape[1])])
        if len(names) != material_property.shape[1]:
            raise ValueError(f"property_names: {len(names)} names for {material_property.shape[1]} properties")
        point_data.update({n: material_property[:, k] for k, n in enumerate(names)})
    for type_id, material in (material_names or {}).items():
        point_data[f"material:{material}"] = (np.asarray(particle_type) == type_id).astype(np.uint8)
    velocities = _as_3d(frame_velocities(positions, dt))
    points = _as_3d(positions)
    cells = [("vertex", np.arange(num_particles, dtype=np.int64)[:, None])]

    directory = Path(directory)
    # ``name`` is one file name: the frames and the collection stay inside ``directory``.
    frames = ensure_inside(directory / require_component(name, "VTK series name"), directory)
    frames.mkdir(parents=True, exist_ok=True)
    width = max(5, len(str(num_frames - 1)))
    collection = ElementTree.Element("VTKFile", type="Collection", version="0.1", byte_order="LittleEndian")
    datasets = ElementTree.SubElement(collection, "Collection")
    for t in range(num_frames):
        relative = f"{name}/frame_{t:0{width}d}.vtu"
        mesh = meshio.Mesh(points[t], cells, point_data={"velocity": velocities[t], **point_data})
        mesh.write(directory / relative)
        ElementTree.SubElement(datasets, "DataSet", timestep=repr(t * dt), group="", part="0", file=relative)
        if progress is not None:
            progress(t + 1, num_frames)
    pvd = directory / f"{name}.pvd"
    ElementTree.ElementTree(collection).write(pvd, xml_declaration=True, encoding="utf-8")
    return pvd


def _named_properties(rollout: Rollout) -> list[str] | None:
    """The dataset's names of the rollout's material property columns, when it names each of them."""
    names = getattr(rollout.metadata, "material_properties", None)
    columns = (
        None
        if rollout.material_property is None
        else np.asarray(rollout.material_property).reshape(len(rollout.particle_type), -1).shape[1]
    )
    return list(names) if names and columns == len(names) else None


def write_rollout_vtk(
    rollout: Rollout,
    directory: str | Path,
    property_names: Sequence[str] | None = None,
    progress: Callable[[int, int], None] | None = None,
    material_names: Mapping[int, str] | None = None,
) -> dict[str, Path]:
    """Write the predicted and the true trajectory of a rollout with its metadata (input frames included).

    The property arrays take the names the dataset gives its material properties
    (``metadata.material_properties``) unless ``property_names`` says otherwise.
    Returns ``{"predicted": <pvd>, "ground_truth": <pvd>}``; frame times count from
    the first input frame. ``progress(frames_written, frames_in_all)`` counts both series.
    """
    assert rollout.metadata is not None  # a rollout file always has it
    common: dict[str, Any] = {
        "dt": rollout.metadata.dt,
        "particle_type": rollout.particle_type,
        "material_property": rollout.material_property,
        "property_names": property_names or _named_properties(rollout),
        "material_names": material_names,
    }
    series = {"predicted": rollout.predicted_trajectory(), "ground_truth": rollout.ground_truth_trajectory()}
    total = sum(len(positions) for positions in series.values())
    written, done = {}, 0
    for name, positions in series.items():
        offset = done
        own = None if progress is None else (lambda frames, _, offset=offset: progress(offset + frames, total))
        written[name] = write_vtk_series(directory, name, positions, progress=own, **common)
        done += len(positions)
    return written


def read_pvd(path: str | Path) -> list[tuple[float, Path]]:
    """(time in s, frame file) of every dataset a ``.pvd`` collection lists, in order."""
    path = Path(path)
    root = ElementTree.parse(path).getroot()
    return [(float(d.get("timestep", "0")), path.parent / d.get("file", "")) for d in root.iter("DataSet")]
