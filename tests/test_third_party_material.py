"""The example clay package adds a material through entry points only; a model trains on it."""

from __future__ import annotations

import numpy as np
import pytest
from synthetic import write_synthetic_dataset
from tiny import tiny_recipe, tiny_trainer

pytest.importorskip("gns_example_clay", reason="install it: pip install -e plugins/examples/gns-clay")


def test_trains_on_clay_with_per_particle_cohesion(tmp_path):
    data = write_synthetic_dataset(
        tmp_path / "data",
        train=2,
        valid=1,
        test=0,
        frames=20,
        particle_types=(8,),
        kinematic_floor=True,
        with_property=True,
    )
    recipe = tiny_recipe(data, materials=["clay", "rigid"], material_properties=["cohesion"])
    trainer = tiny_trainer(recipe, tmp_path / "run")
    scene = trainer.simulator.setup
    assert scene.particle_types == (3, 8) and scene.kinematic_types == (3,)
    assert scene.property_names == ("cohesion",)
    losses = trainer.train(5)
    assert np.isfinite(losses).all()
