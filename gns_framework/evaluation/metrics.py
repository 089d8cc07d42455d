"""Error metrics between a predicted and a true rollout, batched, in PyTorch.

Every function takes a batch of B rollouts whose particles are padded to a common
count N; a boolean ``mask`` marks the real particles. Kinematic particles (those of
the types whose material is kinematic, ``ModelSetup.kinematic_types``) follow prescribed
paths in both rollouts, so they are left out of every error.

A metric is a :class:`~gns_framework.plugin_types.Metric` record (name, unit, function of a :class:`RolloutPair`)
returned by a plugin's ``gns_metrics`` hook; the built-in ones are registered the
same way (``gns_builtins.metrics``), so a new metric is one record in one place.

Units: L is the dataset's length unit (metres in MPM data), s are seconds
(frames are ``dt`` seconds apart). Relative errors (``*_pct``) are in percent of
a stated reference scale.

Shapes: B rollouts, S rolled-out frames, N particles, d spatial dimensions.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass, replace
from functools import cached_property
from typing import cast

import torch
from torch import Tensor

from ..plugin_types import Metric

DEFAULT_HORIZONS = (1, 5, 10, 20, 50, 100)
"""Rollout steps at which position errors are reported (besides the full rollout)."""

DIVERGED = "diverged"
DIVERGED_UNIT = "share of rollouts whose prediction left the finite numbers (their errors are inf)"
"""The one value every scoring has: it decides which errors are inf, so it is no plugin's."""


@dataclass(frozen=True)
class ParticleRollout:
    """Positions of a batch of rollouts and which of their particles count.

    Attributes:
        position: (B, S, N, d) rolled-out positions, L.
        particle_type: (B, N) int64 particle-type ids.
        mask: (B, N) bool, True for real particles (False pads shorter examples).
        start: (B, N, d) the last input frame the rollout starts from, or None.
        kinematic_types: the particle types whose material is kinematic (prescribed,
            left out of every error): ``ModelSetup.kinematic_types``.
    """

    position: Tensor
    particle_type: Tensor
    mask: Tensor
    start: Tensor | None
    kinematic_types: tuple[int, ...]

    @classmethod
    def of(
        cls,
        position: Tensor,
        particle_type: Tensor,
        mask: Tensor | None = None,
        start: Tensor | None = None,
        *,
        kinematic_types: Collection[int],
    ) -> ParticleRollout:
        """Accept one rollout ((S, N, d), (N,), ...) or a batch; check shapes agree."""
        position = torch.as_tensor(position)
        particle_type = torch.as_tensor(particle_type)
        if position.ndim == 3:
            position = position[None]
            particle_type = particle_type[None]
            mask = None if mask is None else torch.as_tensor(mask)[None]
            start = None if start is None else torch.as_tensor(start)[None]
        if position.ndim != 4:
            raise ValueError(f"position: expected (S, N, d) or (B, S, N, d), got {tuple(position.shape)}")
        b, _, n, d = position.shape
        if tuple(particle_type.shape) != (b, n):
            raise ValueError(f"particle_type: expected ({b}, {n}), got {tuple(particle_type.shape)}")
        mask = torch.ones(b, n, dtype=torch.bool, device=position.device) if mask is None else torch.as_tensor(mask)
        if tuple(mask.shape) != (b, n) or mask.dtype != torch.bool:
            raise ValueError(f"mask: expected bool ({b}, {n}), got {mask.dtype} {tuple(mask.shape)}")
        if start is not None and tuple(start.shape) != (b, n, d):
            raise ValueError(f"start: expected ({b}, {n}, {d}), got {tuple(start.shape)}")
        return cls(position, particle_type.long(), mask, start, tuple(sorted(int(t) for t in kinematic_types)))

    @property
    def moving(self) -> Tensor:
        """(B, N) bool: real, non-kinematic particles, the ones errors are taken over."""
        kinematic = torch.as_tensor(
            self.kinematic_types, dtype=self.particle_type.dtype, device=self.particle_type.device
        )
        return self.mask & ~torch.isin(self.particle_type, kinematic)

    def of_types(self, types: Collection[int]) -> Tensor:
        """(B, N) bool: moving particles whose type is in ``types``."""
        wanted = torch.as_tensor(sorted(types), dtype=self.particle_type.dtype, device=self.particle_type.device)
        return self.moving & torch.isin(self.particle_type, wanted)


def _masked_mean(values: Tensor, weight: Tensor) -> Tensor:
    """Mean of ``values`` (B, ..., N) over particles where ``weight`` (B, N) is True.

    NaN where an example has no such particle: an error over nothing is unknown, not 0.
    """
    while weight.ndim < values.ndim:
        weight = weight.unsqueeze(1)
    # where, not multiply: a left-out particle's inf must not turn into 0 * inf = NaN.
    return torch.where(weight, values, 0).sum(-1) / weight.sum(-1).to(values.dtype)


def squared_error_per_particle(predicted: Tensor, target: Tensor) -> Tensor:
    """(..., N, d) positions -> (..., N) squared distance averaged over the d components, L^2.

    A non-finite prediction has an infinite error (never NaN, which averaging
    could mistake for "no particles").
    """
    return (predicted - target).square().mean(-1).nan_to_num(nan=torch.inf)


def mse_per_step(predicted: ParticleRollout, target: ParticleRollout, weight: Tensor | None = None) -> Tensor:
    """(B, S) position MSE of every frame over moving particles (or ``weight``), L^2.

    Needs particle correspondence: both rollouts hold the same particles in the
    same order (a learned model's rollout does; a simulator run at another
    resolution does not, and has no position MSE).
    """
    if predicted.position.shape != target.position.shape:
        raise ValueError(
            f"position MSE needs the same particles in both rollouts: "
            f"{tuple(predicted.position.shape)} vs {tuple(target.position.shape)}"
        )
    weight = target.moving if weight is None else weight
    return _masked_mean(squared_error_per_particle(predicted.position, target.position), weight)


def mse_at_horizons(per_step: Tensor, horizons: Sequence[int] = DEFAULT_HORIZONS) -> dict[str, Tensor | None]:
    """Position MSE averaged over the first h rollout steps, for every horizon h.

    Args:
        per_step: (B, S) MSE of each frame, from :func:`mse_per_step`.
        horizons: rollout steps h >= 1.

    Returns:
        ``{"mse_h": (B,) tensor}`` for each h, ``None`` where the rollout is shorter
        than h (missing, never clamped to S), and ``"mse_full"`` over all S frames.
    """
    steps = per_step.shape[-1]
    result: dict[str, Tensor | None] = {}
    for h in horizons:
        if h < 1:
            raise ValueError(f"horizons must be >= 1, got {h}")
        result[f"mse_{h}"] = per_step[..., :h].mean(-1) if h <= steps else None
    result["mse_full"] = per_step.mean(-1)
    return result


def sinkhorn_distance(
    x: Tensor,
    y: Tensor,
    x_weight: Tensor,
    y_weight: Tensor,
    blur: float,
    diameter: float | None = None,
    scaling: float = 0.8,
) -> Tensor:
    """Debiased Sinkhorn distance between two batches of particle clouds, L.

    Each cloud is a uniform measure on the particles its weight marks; the
    clouds need not have the same particles (nor the same count). Returns
    ``sqrt(2 S_eps)`` where ``S_eps`` is geomloss's Sinkhorn divergence with cost
    ``|x - y|^2 / 2`` and ``eps = blur^2``: it is 0 for identical clouds and equals
    the shift for a translated copy, like the Wasserstein-2 distance it approximates
    for blur below the particle spacing.

    Shapes:
        x: (B, N, d), y: (B, M, d), x_weight: (B, N) bool, y_weight: (B, M) bool -> (B,).
    """
    try:
        from geomloss import SamplesLoss
    except ImportError:
        raise ImportError("the Sinkhorn metric needs geomloss: pip install 'gns-framework[eval]'") from None
    # Padded particles get zero mass; they are also moved onto the origin so that
    # garbage or inf in padding never enters the cost matrix (0 mass * inf cost = NaN).
    x = torch.where(x_weight[..., None], x, torch.zeros((), dtype=x.dtype, device=x.device)).contiguous()
    y = torch.where(y_weight[..., None], y, torch.zeros((), dtype=y.dtype, device=y.device)).contiguous()
    a = x_weight.to(x.dtype) / x_weight.sum(-1, keepdim=True).to(x.dtype)
    b = y_weight.to(y.dtype) / y_weight.sum(-1, keepdim=True).to(y.dtype)
    loss = SamplesLoss(
        "sinkhorn", p=2, blur=blur, scaling=scaling, debias=True, diameter=diameter, backend="tensorized"
    )
    divergence = loss(a, x, b, y)
    # The debiased divergence is >= 0 in exact arithmetic; round-off can dip below.
    return torch.sqrt(2 * divergence.clamp_min(0))


def kinetic_energy(rollout: ParticleRollout, dt: float, weight: Tensor | None = None) -> Tensor:
    """Kinetic energy per unit mass, averaged over moving particles, per frame, L^2/s^2.

    Velocities are backward differences ``(p[t] - p[t-1]) / dt``; the first frame
    uses ``rollout.start``. Returns (B, S) with a start, else (B, S - 1) for frames 1..S-1.
    """
    position = rollout.position
    if rollout.start is not None:
        position = torch.cat([rollout.start[:, None], position], dim=1)
    velocity = position.diff(dim=1) / dt
    weight = rollout.moving if weight is None else weight
    return _masked_mean(0.5 * velocity.square().sum(-1), weight)


def kinetic_energy_error(predicted_energy: Tensor, true_energy: Tensor) -> tuple[Tensor, Tensor]:
    """Mean absolute kinetic-energy error (L^2/s^2) and its % of the mean true energy.

    Frames are aligned at the end, so a rollout without ``start`` (one frame fewer)
    is compared on the frames both have. The % is NaN when the truth is at rest.

    Shapes: (B, S) and (B, S') -> (B,), (B,).
    """
    frames = min(predicted_energy.shape[-1], true_energy.shape[-1])
    predicted_energy, true_energy = predicted_energy[..., -frames:], true_energy[..., -frames:]
    error = (predicted_energy - true_energy).abs().mean(-1)
    scale = true_energy.mean(-1)
    return error, 100 * error / torch.where(scale > 0, scale, torch.nan)


def horizontal_extent(position: Tensor, weight: Tensor, axis: int = 0) -> Tensor:
    """(B, N, d) positions -> (B,) span ``max - min`` along ``axis`` of the weighted particles, L."""
    along = position[..., axis]
    high = torch.where(weight, along, -torch.inf).amax(-1)
    low = torch.where(weight, along, torch.inf).amin(-1)
    return high - low


def runout_distance(rollout: ParticleRollout, weight: Tensor, axis: int = 0) -> Tensor:
    """(B,) growth of the horizontal extent from the start to the final frame, L.

    The extent is ``max - min`` along ``axis`` of the particles ``weight`` marks
    (the granular ones); the start is ``rollout.start``, else frame 0. Divided by
    the initial extent it is the normalised runout ``(L_f - L_0) / L_0`` of
    granular column collapse.
    """
    initial = rollout.start if rollout.start is not None else rollout.position[:, 0]
    return horizontal_extent(rollout.position[:, -1], weight, axis) - horizontal_extent(initial, weight, axis)


def pile_profile(
    position: Tensor, weight: Tensor, bounds: Sequence[Sequence[float]], bins: int = 50, vertical_axis: int = -1
) -> Tensor:
    """Height of the pile surface above the floor in each horizontal bin, L.

    The horizontal axes (all but ``vertical_axis``) of the domain ``bounds`` are cut
    into ``bins`` equal bins each; a bin's height is the highest weighted particle
    in it, measured from the lower bound of the vertical axis, and NaN when the
    bin holds no particle.

    Shapes: position (B, N, d), weight (B, N) -> (B, bins) in 2D, (B, bins**2) in 3D.
    """
    b, n, d = position.shape
    vertical_axis = vertical_axis % d
    horizontal = [a for a in range(d) if a != vertical_axis]
    cell = torch.zeros(b, n, dtype=torch.long, device=position.device)
    for a in horizontal:
        low, high = bounds[a]
        index = ((position[..., a] - low) / (high - low) * bins).floor().long().clamp(0, bins - 1)
        cell = cell * bins + index
    floor = bounds[vertical_axis][0]
    height = torch.where(weight, position[..., vertical_axis] - floor, -torch.inf)
    profile = torch.full((b, bins ** len(horizontal)), -torch.inf, dtype=position.dtype, device=position.device)
    profile = profile.scatter_reduce(1, cell, height, reduce="amax")
    return torch.where(torch.isinf(profile), torch.nan, profile)


def profile_error(predicted_profile: Tensor, true_profile: Tensor) -> tuple[Tensor, Tensor]:
    """RMS height error over bins occupied in either profile (L), and its % of the true peak.

    A bin empty in one profile counts as height 0 there, so material that lands
    where there should be none (or is missing) is an error; bins empty in both are
    left out so a wide domain does not dilute the error.

    Shapes: (B, K) and (B, K) -> (B,), (B,).
    """
    occupied = ~(predicted_profile.isnan() & true_profile.isnan())
    difference = predicted_profile.nan_to_num(0.0) - true_profile.nan_to_num(0.0)
    error = _masked_mean(difference.square(), occupied).sqrt()
    peak = true_profile.nan_to_num(0.0).amax(-1)
    return error, 100 * error / torch.where(peak > 0, peak, torch.nan)


def domain_size(bounds: Sequence[Sequence[float]]) -> float:
    """Largest side of the domain box, L: the length relative errors are taken against."""
    return max(float(high) - float(low) for low, high in bounds)


@dataclass(frozen=True)
class RolloutPair:
    """A batch of predicted rollouts beside the true ones, and what metrics need to compare them.

    The intermediate results several metrics share (the per-step position error, the
    final Sinkhorn distance, runouts, pile profiles) are computed once, on first use.

    Attributes:
        predicted, target: the rollouts, with the same B and S.
        dt: seconds between frames (the dataset's ``dt``).
        bounds: (d, 2) domain walls, L.
        same_particles: whether particle i of one rollout is particle i of the other.
        horizons: rollout steps for ``mse_h``; those beyond S are None.
        granular_types: particle types whose runout and pile profile are measured.
        material_names: names for per-material keys (``mse_full[sand]``), else ``type=<id>``.
        vertical_axis: the axis gravity acts along (the last one in the public datasets).
        runout_axis: the horizontal axis the runout is measured along.
        profile_bins: bins per horizontal axis of the pile profile.
        blur_fraction: Sinkhorn blur as a fraction of the domain size.
    """

    predicted: ParticleRollout
    target: ParticleRollout
    dt: float
    bounds: Sequence[Sequence[float]]
    same_particles: bool = True
    horizons: Sequence[int] = DEFAULT_HORIZONS
    granular_types: Collection[int] = ()
    material_names: Mapping[int, str] | None = None
    vertical_axis: int = -1
    runout_axis: int = 0
    profile_bins: int = 50
    blur_fraction: float = 1e-3

    @property
    def domain_size(self) -> float:
        return domain_size(self.bounds)

    @cached_property
    def mse_per_step(self) -> Tensor | None:
        """(B, S) position MSE of every frame, L^2; None when the rollouts hold different particles."""
        return mse_per_step(self.predicted, self.target) if self.same_particles else None

    @cached_property
    def sinkhorn_final(self) -> Tensor:
        size = self.domain_size
        return sinkhorn_distance(
            self.predicted.position[:, -1],
            self.target.position[:, -1],
            self.predicted.moving,
            self.target.moving,
            blur=self.blur_fraction * size,
            diameter=math.sqrt(len(self.bounds)) * size,
        )

    @cached_property
    def kinetic_energy_error(self) -> tuple[Tensor, Tensor]:
        return kinetic_energy_error(kinetic_energy(self.predicted, self.dt), kinetic_energy(self.target, self.dt))

    @cached_property
    def runouts(self) -> tuple[Tensor, Tensor] | None:
        """(predicted, true) runout distances of the granular particles, (B,) each, L; None without granular types."""
        if not self.granular_types:
            return None
        return (
            runout_distance(self.predicted, self.predicted.of_types(self.granular_types), self.runout_axis),
            runout_distance(self.target, self.target.of_types(self.granular_types), self.runout_axis),
        )

    @cached_property
    def final_extents(self) -> tuple[Tensor, Tensor] | None:
        """(predicted, true) final horizontal extent of the granular particles, (B,) each, L; None without them."""
        if not self.granular_types:
            return None
        return cast(
            "tuple[Tensor, Tensor]",
            tuple(
                horizontal_extent(r.position[:, -1], r.of_types(self.granular_types), self.runout_axis)
                for r in (self.predicted, self.target)
            ),
        )

    @cached_property
    def final_heights(self) -> tuple[Tensor, Tensor] | None:
        """(predicted, true) final pile height: the highest granular particle above the floor, (B,) each, L."""
        if not self.granular_types:
            return None
        axis = self.vertical_axis % len(self.bounds)
        floor = float(self.bounds[axis][0])
        return cast(
            "tuple[Tensor, Tensor]",
            tuple(
                torch.where(r.of_types(self.granular_types), r.position[:, -1, :, axis] - floor, -torch.inf).amax(-1)
                for r in (self.predicted, self.target)
            ),
        )

    @cached_property
    def profile_error(self) -> tuple[Tensor, Tensor] | None:
        """:func:`profile_error` of the final granular piles; None without granular types."""
        if not self.granular_types:
            return None
        return profile_error(
            *(
                pile_profile(
                    rollout.position[:, -1],
                    rollout.of_types(self.granular_types),
                    self.bounds,
                    self.profile_bins,
                    self.vertical_axis,
                )
                for rollout in (self.predicted, self.target)
            )
        )


def rollout_metrics(pair: RolloutPair, metrics: Sequence[Metric]) -> dict[str, Tensor | None]:
    """Every metric of ``metrics`` for a batch, by name, plus ``mse_per_step`` and ``diverged``.

    Position MSEs need particle correspondence: when the rollouts hold different
    particles (a simulator run at another resolution, ``pair.same_particles`` False)
    they are None, and the metrics that compare clouds (Sinkhorn, kinetic energy,
    runout, pile profile) still compare the two.

    Returns:
        name -> (B,) tensor, or None when missing; ``"mse_per_step"`` is (B, S) (None
        without correspondence). A prediction with a non-finite moving particle has
        ``diverged`` 1, an ``inf`` position error in each frame where a particle is
        non-finite (and in every horizon that includes such a frame), and every other
        error ``inf``, so averaging over rollouts cannot hide it.
    """
    predicted, target = pair.predicted, pair.target
    if predicted.position.shape[:2] != target.position.shape[:2]:
        raise ValueError(
            f"rollouts must have the same batch size and frame count: "
            f"{tuple(predicted.position.shape[:2])} vs {tuple(target.position.shape[:2])}"
        )
    finite = torch.isfinite(predicted.position).all(-1) | ~predicted.moving[:, None]
    diverged = ~finite.flatten(1).all(-1)
    # A diverged rollout has no meaningful cloud, energy or pile: compute on finite
    # stand-in values (so no NaN reaches the solvers), then mark those errors inf.
    stand_in = replace(
        pair,
        predicted=replace(predicted, position=torch.nan_to_num(predicted.position, nan=0.0, posinf=0.0, neginf=0.0)),
    )
    values: dict[str, Tensor | None] = {"mse_per_step": pair.mse_per_step}
    for metric in metrics:
        value = metric.function(pair if metric.pairwise else stand_in)
        family = value if isinstance(value, Mapping) else {metric.name: value}
        for name, result in family.items():
            if result is not None and not metric.pairwise:
                result = torch.where(diverged, torch.inf, result)
            values[name] = result
    values[DIVERGED] = diverged.to(predicted.position.dtype)
    return values


def metric_units(metrics: Sequence[Metric]) -> dict[str, str]:
    """Name (or family pattern) -> unit and meaning, of every value :func:`rollout_metrics` gives."""
    return {DIVERGED: DIVERGED_UNIT, **{m.name: m.unit for m in metrics}}


def horizon_mse(pair: RolloutPair) -> dict[str, Tensor | None]:
    """``mse_h`` for every horizon of ``pair``: None without correspondence or beyond the rollout."""
    if pair.mse_per_step is None:
        return {f"mse_{h}": None for h in pair.horizons}
    return {
        name: value for name, value in mse_at_horizons(pair.mse_per_step, pair.horizons).items() if name != "mse_full"
    }


def per_material_mse(
    predicted: ParticleRollout, target: ParticleRollout, material_names: Mapping[int, str] | None = None
) -> dict[str, Tensor]:
    """Full-rollout and final-frame position MSE per moving particle type, L^2.

    Keys are ``mse_full[<name>]`` and ``mse_final[<name>]`` with the material's
    name from ``material_names`` or ``type=<id>``; NaN for an example without
    particles of that type.
    """
    result: dict[str, Tensor] = {}
    for particle_type in torch.unique(target.particle_type[target.moving]).tolist():
        label = (material_names or {}).get(particle_type, f"type={particle_type}")
        per_step = mse_per_step(predicted, target, target.of_types([particle_type]))
        result[f"mse_full[{label}]"] = per_step.mean(-1)
        result[f"mse_final[{label}]"] = per_step[:, -1]
    return result


def summarise(metrics: Mapping[str, Tensor | None]) -> dict[str, float | None]:
    """Average each (B,) metric over the batch, ignoring NaN; per-step curves are skipped.

    A metric that is ``None`` or NaN for every example stays ``None`` (missing).
    """
    summary: dict[str, float | None] = {}
    for name, value in metrics.items():
        if name == "mse_per_step":
            continue
        if value is None:
            summary[name] = None
            continue
        mean = value.double().nanmean()
        summary[name] = None if mean.isnan() else float(mean)
    return summary
