"""VTK frames and .pvd collections load back with meshio, in 2D and 3D."""

from __future__ import annotations

import dataclasses

import meshio
import numpy as np
import pytest

from gns_framework.io.vtk import frame_velocities, read_pvd, write_rollout_vtk, write_vtk_series


@pytest.mark.parametrize("dim", [2, 3])
def test_rollout_vtk_loads_back_with_meshio(make_rollout, tmp_path, dim):
    rollout = make_rollout(dim=dim, steps=4, particles=12, history=6)
    seen = []
    collections = write_rollout_vtk(
        rollout, tmp_path, property_names=["friction_angle", "density"], progress=lambda *a: seen.append(a)
    )
    assert seen == [(k, 20) for k in range(1, 21)], "both series of 10 frames counted as one"
    for name, trajectory in (
        ("predicted", rollout.predicted_trajectory()),
        ("ground_truth", rollout.ground_truth_trajectory()),
    ):
        frames = read_pvd(collections[name])
        assert [t for t, _ in frames] == pytest.approx([0.01 * k for k in range(10)])
        for t, (_, file) in enumerate(frames):
            mesh = meshio.read(file)
            assert mesh.points.shape == (12, 3)
            np.testing.assert_allclose(mesh.points[:, :dim], trajectory[t])
            if dim == 2:
                assert (mesh.points[:, 2] == 0).all()
            assert mesh.cells[0].type == "vertex" and len(mesh.cells[0].data) == 12
            np.testing.assert_array_equal(mesh.point_data["particle_type"], rollout.particle_type)
            np.testing.assert_allclose(mesh.point_data["friction_angle"], rollout.material_property[:, 0])
            np.testing.assert_allclose(mesh.point_data["density"], rollout.material_property[:, 1])
            assert mesh.point_data["velocity"].shape == (12, 3)
        last = meshio.read(frames[-1][1])
        expected = (trajectory[-1] - trajectory[-2]) / 0.01
        np.testing.assert_allclose(last.point_data["velocity"][:, :dim], expected, rtol=1e-4, atol=1e-6)


def test_velocity_of_the_first_frame_is_the_forward_difference():
    positions = np.array([[[0.0, 0.0]], [[0.1, 0.0]], [[0.3, 0.0]]])
    velocity = frame_velocities(positions, dt=0.1)
    np.testing.assert_allclose(velocity[:, 0, 0], [1.0, 1.0, 2.0])


def test_series_without_material_properties_and_default_names(tmp_path):
    positions = np.zeros((2, 3, 2), dtype=np.float32)
    pvd = write_vtk_series(tmp_path, "scene", positions, 0.5, np.array([0, 1, 3]), np.ones((3, 1)))
    mesh = meshio.read(read_pvd(pvd)[1][1])
    assert set(mesh.point_data) == {"velocity", "particle_type", "material_property_0"}
    with pytest.raises(ValueError, match="2 names for 1 properties"):
        write_vtk_series(tmp_path, "bad", positions, 0.5, np.zeros(3), np.ones((3, 1)), ["a", "b"])


def test_materials_are_named_and_properties_take_the_datasets_names(make_rollout, tmp_path):
    """ParaView shows ``material:sand`` (1 on sand particles) and ``friction``, not type ids and column numbers."""
    rollout = make_rollout(dim=2, steps=2, particles=12, history=6)
    metadata = rollout.metadata.model_copy(update={"material_properties": ["friction", "density"]})
    rollout = dataclasses.replace(rollout, metadata=metadata)
    names = {int(t): f"m{int(t)}" for t in np.unique(rollout.particle_type)}
    pvd = write_rollout_vtk(rollout, tmp_path, material_names=names)["predicted"]
    mesh = meshio.read(read_pvd(pvd)[0][1])
    for type_id, name in names.items():
        np.testing.assert_array_equal(mesh.point_data[f"material:{name}"], rollout.particle_type == type_id)
    np.testing.assert_allclose(mesh.point_data["friction"], rollout.material_property[:, 0])
    assert "material_property_0" not in mesh.point_data
