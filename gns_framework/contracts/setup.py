"""The learned model's setup (:class:`ModelSetup`) and the sizes its networks follow (:class:`ModelSizes`)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class ModelSetup:
    """The setup a learned model is built for: what it must know of the scenes it simulates; its sizes follow from it.

    Derived from the training data (:mod:`gns_framework.assembly.scene`) and stored in
    every checkpoint. A scene *file* (``scenes/*.yaml``, read into
    :class:`gns_framework.ground_truth.scene_spec.SceneSpec`) is what the ground-truth
    simulator runs; this is the learned model's summary of the scenes in its data. (Called
    ``Scene`` until 0.2: that name still imports, with a DeprecationWarning.)

    Attributes:
        dim: spatial dimensions d (2 or 3).
        bounds: (d, 2) lower and upper walls, dataset units.
        connectivity_radius: R; particles closer than R (strict) are connected.
        particle_types: sorted type ids the model handles (one per material).
        kinematic_types: the subset of ``particle_types`` that is prescribed.
        property_names: per-particle material properties, in node-feature column order.
        context_size: width of the per-frame global context (0: none).
        history: C, positions per input window (C - 1 velocities).
        walls: whether wall-distance features are built (for the non-periodic dimensions).
        boundary_clamp_limit: wall distances / R are clipped to +-this.
        periodic: per dimension, whether the domain wraps around there (minimum-image
            displacements, no walls); empty means no periodic dimension.
        wall_conditions: whether each walled face's Coulomb friction coefficient is a node
            feature (from the data's per-trajectory ``walls``), so one model learns rough
            and slip walls.
    """

    dim: int
    bounds: tuple[tuple[float, float], ...]
    connectivity_radius: float
    particle_types: tuple[int, ...]
    kinematic_types: tuple[int, ...] = ()
    property_names: tuple[str, ...] = ()
    context_size: int = 0
    history: int = 6
    walls: bool = True
    boundary_clamp_limit: float = 1.0
    periodic: tuple[bool, ...] = ()
    wall_conditions: bool = False

    @property
    def num_particle_types(self) -> int:
        return len(self.particle_types)

    @property
    def uses_type_embedding(self) -> bool:
        return len(self.particle_types) > 1

    @property
    def periodic_dims(self) -> tuple[int, ...]:
        """Indices of the dimensions that wrap around."""
        return tuple(k for k, wraps in enumerate(self.periodic) if wraps)

    @property
    def wall_dims(self) -> tuple[int, ...]:
        """Indices of the dimensions bounded by walls (none when ``walls`` is False)."""
        if not self.walls:
            return ()
        return tuple(k for k in range(self.dim) if k not in self.periodic_dims)


@dataclass(frozen=True)
class ModelSizes:
    """Sizes shared by encoder, processor and decoder, derived from the scene and recipe."""

    node_in: int
    edge_in: int
    latent: int
    mlp_hidden: int
    mlp_hidden_layers: int
    output: int
    dim: int
    connectivity_radius: float = 1.0
    """R, the length unit of ``Graph.displacement`` for processors that use geometry."""
