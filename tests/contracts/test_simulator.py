"""The ground-truth simulator contract: simulate is required; it keeps its params and materials; its defaults."""

from __future__ import annotations

import numpy as np
import pytest

from gns_framework.contracts import GroundTruthSimulator, Material, Params
from gns_framework.data.trajectory import Trajectory


class Dust(Material):
    name = "dust"
    particle_type = 42


def test_a_simulator_without_simulate_cannot_be_built():
    class NoSimulate(GroundTruthSimulator):
        name = "no_simulate"

    with pytest.raises(TypeError, match="abstract method simulate"):
        NoSimulate(Params(), {"dust": Dust})


class Still(GroundTruthSimulator):
    """One particle per material that never moves (only its class facts and defaults are tested here)."""

    name = "still"

    def simulate(self, scene, seed):
        types = np.array([m.particle_type for m in self.materials.values()])
        return Trajectory(np.zeros((2, len(types), 2), np.float32), types)


def test_a_simulator_keeps_its_params_and_the_installed_materials():
    simulator = Still(Params(), {"dust": Dust})
    assert simulator.params == Params() and simulator.materials == {"dust": Dust}
    assert simulator.simulate(scene=None, seed=0).particle_type.tolist() == [42]


def test_by_default_it_runs_2d_and_3d_moves_no_constitutive_model_and_adds_no_check_of_its_own():
    simulator = Still(Params(), {"dust": Dust})
    assert Still.dims == (2, 3) and Still.constitutive_models == ()
    assert simulator.check(scene=None) == []  # the shared checks (scene_checks) come first, not here
