"""GIF animations: prediction beside ground truth, one GIF frame per drawn frame."""

from __future__ import annotations

import pytest
from PIL import Image

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
    with pytest.raises(ValueError, match="written as .gif"):
        animate_rollout(make_rollout(), tmp_path / "anim.mp4")
