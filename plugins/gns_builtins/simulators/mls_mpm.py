"""The default ground-truth simulator: MLS-MPM (Hu et al. 2018) in NVIDIA Warp, 2D and 3D.

Sand (Drucker-Prager), water (weakly compressible), goop (von Mises
plasticity) and kinematic rigid obstacles with Coulomb friction. Warp is
imported only when a scene is simulated, never on import of this plugin.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
from pydantic import Field, ValidationError

from gns_framework.api import BodySample, SceneSample, SceneSpec, Trajectory, at_resolution, sample_scene
from gns_framework.contracts import ComponentParams, GroundTruthSimulator

from ._mpm.models import MODELS, RIGID, ConstitutiveModel


class MlsMpm(GroundTruthSimulator):
    """Moving least squares material point method with APIC transfers, explicit in time."""

    name = "mls_mpm"
    dims = (2, 3)
    constitutive_models = (*MODELS, RIGID)

    class Params(ComponentParams):
        device: str = Field(default="auto", description="Warp device: 'cpu', 'cuda', 'cuda:0' or 'auto'")
        cfl: float = Field(default=0.5, gt=0, le=1, description="substep dt must stay below cfl * dx / wave speed")

    params: Params  # the validated Params above (the base class assigns it)

    def check(self, scene: SceneSpec) -> list[tuple[str, str]]:
        """Adds constitutive-parameter validation, the elastic-wave CFL limit and the viscous limit
        to the generic checks."""
        problems = super().check(scene)
        fastest, fastest_where = 0.0, ""
        viscous, viscous_where = math.inf, ""
        for i, block in enumerate(scene.blocks):
            where = f"blocks[{i}]"
            material = self.materials.get(block.material)
            if material is None or material.constitutive_model not in MODELS:
                continue  # already reported by the generic checks
            model = MODELS[material.constitutive_model]
            for name in block.parameters:
                if name not in model.model_fields:
                    problems.append(
                        (
                            f"{where}.parameters.{name}",
                            f"model {model.name!r} has no parameter {name!r} (it has: {', '.join(model.model_fields)})",
                        )
                    )
            ranged = {
                name: (value.low, value.high)
                for name, value in {**block.properties, **block.parameters}.items()
                if name in model.model_fields
            }
            # Every constraint and the wave speed are monotone in each parameter: the corners bound them.
            for corner in itertools.product(*ranged.values()):
                try:
                    params = model(**{**material.physical_parameters, **dict(zip(ranged, corner, strict=True))})
                except ValidationError as exc:
                    problems += [
                        (f"{where}.{'.'.join(str(p) for p in err['loc'])}", err["msg"]) for err in exc.errors()
                    ]
                    break
                if params.wave_speed() > fastest:
                    fastest, fastest_where = params.wave_speed(), where
                if params.viscous_substep_limit(scene.domain.cell_size, scene.dim) < viscous:
                    viscous, viscous_where = params.viscous_substep_limit(scene.domain.cell_size, scene.dim), where
        if fastest > 0:
            limit = self.params.cfl * scene.domain.cell_size / fastest
            if scene.time.substep_dt > limit:
                needed = math.ceil(scene.time.frame_dt / limit)
                problems.append(
                    (
                        "time.substeps",
                        f"substep dt {scene.time.substep_dt:.3g} s exceeds the stable {limit:.3g} s "
                        f"(cfl {self.params.cfl} x dx {scene.domain.cell_size:.3g} m / wave speed {fastest:.3g} m/s "
                        f"in {fastest_where}): use at least {needed} substeps",
                    )
                )
        if scene.time.substep_dt > viscous:
            problems.append(
                (
                    "time.substeps",
                    f"substep dt {scene.time.substep_dt:.3g} s exceeds the viscous limit {viscous:.3g} s "
                    f"(rho dx^2 / (2 d eta) in {viscous_where}): use at least "
                    f"{math.ceil(scene.time.frame_dt / viscous)} substeps",
                )
            )
        return problems

    def _particle_arrays(self, scene: SceneSpec, sample: SceneSample) -> dict[str, np.ndarray]:
        """Per-particle kernel inputs of the blocks (N_free,), float32 / int32."""
        volume = scene.particle_spacing**scene.dim
        parts: dict[str, list[np.ndarray]] = {}
        for block in sample.blocks:
            constitutive_model = self.materials[block.material].constitutive_model
            assert constitutive_model is not None  # scene_problems checks every block's material has one
            model: type[ConstitutiveModel] = MODELS[constitutive_model]
            n = block.num_particles
            defaults = model(**self.materials[block.material].physical_parameters).model_dump()
            values = {
                name: np.asarray(block.values.get(name, np.full(n, default)), dtype=np.float64)
                for name, default in defaults.items()
            }
            arrays = {
                "model": np.full(n, model.kernel_id),
                "mass": values["density"] * volume,
                "volume": np.full(n, volume),
                **model.kernel_parameters(values),
            }
            for name, array in arrays.items():
                parts.setdefault(name, []).append(np.broadcast_to(array, (n,)))
        return {
            name: np.concatenate(chunks).astype(np.int32 if name == "model" else np.float32)
            for name, chunks in parts.items()
        }

    def simulate(self, scene: SceneSpec, seed: int) -> Trajectory:
        return self._run(sample_scene(scene, seed), seed)

    def simulate_at_resolution(self, scene: SceneSpec, seed: int, variant: SceneSpec) -> Trajectory:
        return self._run(at_resolution(sample_scene(scene, seed), scene, variant, seed), seed)

    def _run(self, sample: SceneSample, seed: int) -> Trajectory:
        """The trajectory of a drawn scene (``sample.scene``: its domain, grid and time stepping)."""
        from ._mpm.solver import MpmSolver

        assert sample.scene is not None  # sample_scene draws it
        scene = sample.scene  # this trajectory's domain: extent and face conditions drawn
        solver = MpmSolver(
            scene,
            position=np.concatenate([b.position for b in sample.blocks]),
            velocity=np.concatenate([np.broadcast_to(b.velocity, b.position.shape) for b in sample.blocks]),
            particles=self._particle_arrays(scene, sample),
            obstacles=sample.obstacles,
            device=self.params.device,
        )
        frames = [solver.position()]
        for _ in range(scene.time.frames - 1):
            solver.advance_frame()
            frames.append(solver.position())
        position = np.stack(frames)
        if sample.obstacles:
            position = np.concatenate([position, _kinematic_positions(sample.obstacles, scene)], axis=1)
        return Trajectory(
            position=position.astype(np.float32),
            particle_type=sample.particle_type(self.materials),
            material_property=sample.material_property(self.materials),
            key=f"seed_{seed}",
            bounds=sample.bounds,
            walls=sample.walls,
        )


def _kinematic_positions(obstacles: list[BodySample], scene: SceneSpec) -> np.ndarray:
    """(T, N_kinematic, d) obstacle particles moving at their constant velocities."""
    times = np.arange(scene.time.frames) * scene.time.frame_dt
    return np.concatenate([o.position[None] + times[:, None, None] * o.velocity[None, None] for o in obstacles], axis=1)
