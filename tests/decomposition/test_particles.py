"""The particles a process holds: selected, joined and moved field by field (decomposition/particles.py)."""

from __future__ import annotations

import torch

from gns_framework.decomposition.particles import Particles


def _particles(ids: list[int], with_property: bool) -> Particles:
    n = len(ids)
    index = torch.tensor(ids, dtype=torch.float32)
    return Particles(
        ids=torch.tensor(ids),
        sequence=index[:, None, None].expand(n, 3, 2).clone(),
        particle_type=torch.tensor(ids) % 2,
        material_property=index[:, None].clone() if with_property else None,
    )


def test_select_and_cat_keep_every_field_row_by_row_and_none_stays_none():
    first, second = _particles([4, 7, 9], True), _particles([1], True)
    joined = first.cat(second).select(torch.tensor([3, 0]))
    assert joined.ids.tolist() == [1, 4] and joined.count == 2
    assert joined.sequence[:, 0, 0].tolist() == [1.0, 4.0] and joined.material_property[:, 0].tolist() == [1.0, 4.0]
    assert joined.particle_type.tolist() == [1, 0]
    assert joined.next_position is None and joined.noise is None
    bare = _particles([2, 3], False).select(torch.tensor([True, False]))
    assert bare.material_property is None and bare.ids.tolist() == [2]


def test_columns_round_trip():
    particles = _particles([0, 5], True)
    again = Particles.of(particles.columns())
    assert all(
        (a is None and b is None) or torch.equal(a, b)
        for a, b in zip(again.columns(), particles.columns(), strict=True)
    )
    assert len(particles.columns()) == 7  # every field travels
