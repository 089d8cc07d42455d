"""The ground-truth simulator contract: a particle solver that runs scene files."""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import TYPE_CHECKING, ClassVar

from .material import Material
from .params import ComponentParams, Params

if TYPE_CHECKING:
    from ..data.trajectory import Trajectory
    from ..ground_truth.scene_spec import SceneSpec


class GroundTruthSimulator(ABC):
    """A particle solver that generates ground-truth trajectories from a scene spec.

    The default is MLS-MPM; a user's own solver (or a converter of its output
    files) plugs in the same way and feeds ``gns generate``.
    """

    name: ClassVar[str]
    Params: ClassVar[type[Params]] = Params
    dims: ClassVar[tuple[int, ...]] = (2, 3)
    constitutive_models: ClassVar[tuple[str, ...]] = ()
    """The :attr:`Material.constitutive_model` values this simulator can move."""

    def __init__(self, params: ComponentParams, materials: dict[str, type[Material]]):
        self.params = params
        self.materials = materials

    def check(self, scene: SceneSpec) -> list[tuple[str, str]]:
        """Problems (location, message) of this simulator's own that stop it from running ``scene``.

        Stability limits (time step versus wave speed) and the like. The checks every
        simulator shares (dimension, materials and their constitutive models,
        obstacles, properties) are made before, by
        :func:`gns_framework.ground_truth.scene_checks.scene_problems`; none here by default.
        """
        return []

    @abstractmethod
    def simulate(self, scene: SceneSpec, seed: int) -> Trajectory:
        """Run ``scene`` with randomness drawn from ``seed``; the same seed gives the same bits.

        Returns a trajectory of ``scene.time.frames`` frames: position (T, N, d)
        float32 inside the scene's bounds, particle_type (N,), material_property
        (N, P) only when the scene sets properties.
        """

    def simulate_at_resolution(self, scene: SceneSpec, seed: int, variant: SceneSpec) -> Trajectory:
        """Run the scene ``simulate(scene, seed)`` runs, as drawn, at ``variant``'s grid and time stepping.

        The yardstick of a reduced-resolution simulator: the same box, walls, bodies
        and properties refilled at the coarser spacing
        (:func:`~gns_framework.ground_truth.sampling.at_resolution`). A simulator that
        does not draw its scenes with :func:`~gns_framework.ground_truth.sampling.sample_scene`
        raises NotImplementedError, and ``gns evaluate`` says its rows are scenes drawn anew.
        """
        raise NotImplementedError(f"{self.name} cannot run a drawn scene at another resolution")
