"""GIF animations: prediction beside ground truth, one GIF frame per drawn frame."""

from __future__ import annotations

import dataclasses

import pytest
from PIL import Image

from gns_framework.plugins import load_registry
from gns_framework.viz.animation import animate_rollout, frame_indices


def test_frame_indices_always_end_on_the_last_frame():
    assert frame_indices(10, 3) == [0, 3, 6, 9]
    assert frame_indices(11, 3) == [0, 3, 6, 9, 10]
    assert frame_indices(1, 5) == [0]
    with pytest.raises(ValueError):
        frame_indices(10, 0)


@pytest.mark.parametrize("dim, every, frames", [(2, 1, 10), (2, 4, 4), (3, 3, 4)])
def test_gif_has_one_frame_per_drawn_frame(make_rollout, tmp_path, dim, every, frames):
    rollout = make_rollout(dim=dim, steps=4, history=6)
    seen = []
    path = animate_rollout(
        rollout, tmp_path / "anim.gif", every=every, material_names={6: "sand"}, progress=lambda *a: seen.append(a)
    )
    assert seen == [(k, frames) for k in range(1, frames + 1)], "progress after each drawn frame"
    with Image.open(path) as gif:
        assert gif.format == "GIF"
        assert gif.n_frames == frames
        # Two panels side by side: wider than tall.
        assert gif.size[0] > gif.size[1]


def test_only_gif_is_written(make_rollout, tmp_path):
    with pytest.raises(ValueError, match=r"written as \.gif"):
        animate_rollout(make_rollout(), tmp_path / "anim.mp4")


@pytest.mark.parametrize("generated, unit", [(True, "x (m)"), (False, "x (dataset units)")])
def test_particles_are_named_by_material_and_axes_carry_units(make_rollout, tmp_path, monkeypatch, generated, unit):
    """Legends say the material, not ``type 6``; positions are in metres when our simulators made the data."""
    from matplotlib.axes import Axes

    rollout = make_rollout(dim=2, steps=2, history=6)
    if generated:
        metadata = rollout.metadata.model_copy(update={"generated_from": {"scene": {}, "simulator": "mls_mpm"}})
        rollout = dataclasses.replace(rollout, metadata=metadata)
    labels, axis_labels = set(), set()
    scatter, set_xlabel = Axes.scatter, Axes.set_xlabel
    monkeypatch.setattr(Axes, "scatter", lambda self, *a, **k: labels.add(k.get("label")) or scatter(self, *a, **k))
    monkeypatch.setattr(
        Axes, "set_xlabel", lambda self, text, **k: axis_labels.add(text) or set_xlabel(self, text, **k)
    )
    names = load_registry().material_names(rollout.particle_type)
    animate_rollout(rollout, tmp_path / "anim.gif", every=8, material_names=names)
    assert labels == {names[t] for t in set(rollout.particle_type.tolist())}
    assert not any(label.startswith("type ") for label in labels)
    assert axis_labels == {unit}


def test_material_names_fall_back_to_the_type_id_where_no_material_is_installed():
    registry = load_registry()
    names = registry.material_names([6, 6, 5, 99])
    assert names[6] == registry.material_by_type(6).cls.name and names[99] == "type 99"
    assert list(names) == [5, 6, 99]
