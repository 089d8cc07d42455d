"""Error metrics between a predicted and a true rollout, batched, in PyTorch.

Every function takes a batch of B rollouts whose particles are padded to a common
count N; a boolean ``mask`` marks the real particles. Kinematic particles (type
:data:`KINEMATIC_PARTICLE_TYPE`) follow prescribed paths in both rollouts, so
they are left out of every error.

Units: L is the dataset's length unit (metres in MPM data), s are seconds
(frames are ``dt`` seconds apart). Relative errors (``*_pct``) are in percent of
a stated reference scale.

Shapes: B rollouts, S rolled-out frames, N particles, d spatial dimensions.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass, replace

import torch
from torch import Tensor

from ..data.metadata import KINEMATIC_PARTICLE_TYPE

DEFAULT_HORIZONS = (1, 5, 10, 20, 50, 100)
"""Rollout steps at which position errors are reported (besides the full rollout)."""

METRIC_UNITS: dict[str, str] = {
    "diverged": "share of rollouts whose prediction left the finite numbers (their errors are inf)",
    "mse_{h}": "L^2, position MSE averaged over rollout steps 1..h",
    "mse_full": "L^2, position MSE averaged over the whole rollout",
    "rmse_full_pct": "%, sqrt(mse_full) as a share of the domain size",
    "mse_final": "L^2, position MSE at the last frame",
    "sinkhorn_final": "L, Sinkhorn distance sqrt(2 S_eps) between final particle clouds (~ W2)",
    "sinkhorn_final_pct": "%, sinkhorn_final as a share of the domain size",
    "kinetic_energy_error": "L^2/s^2, mean |error| of the kinetic energy per unit mass, averaged per particle",
    "kinetic_energy_error_pct": "%, kinetic_energy_error as a share of the mean true kinetic energy",
    "runout_error": "L, |predicted - true| runout distance of the granular particles",
    "runout_error_pct": "%, runout_error as a share of the true runout distance",
    "profile_error": "L, RMS error of the final pile surface height over occupied bins",
    "profile_error_pct": "%, profile_error as a share of the true maximum pile height",
}
"""Unit and meaning of every scalar metric :func:`rollout_metrics` returns."""


@dataclass(frozen=True)
class ParticleRollout:
    """Positions of a batch of rollouts and which of their particles count.

    Attributes:
        position: (B, S, N, d) rolled-out positions, L.
        particle_type: (B, N) int64 particle-type ids.
        mask: (B, N) bool, True for real particles (False pads shorter examples).
        start: (B, N, d) the last input frame the rollout starts from, or None.
    """

    position: Tensor
    particle_type: Tensor
    mask: Tensor
    start: Tensor | None = None

    @classmethod
    def of(
        cls, position: Tensor, particle_type: Tensor, mask: Tensor | None = None, start: Tensor | None = None
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
        return cls(position, particle_type.long(), mask, start)

    @property
    def moving(self) -> Tensor:
        """(B, N) bool: real, non-kinematic particles, the ones errors are taken over."""
        return self.mask & (self.particle_type != KINEMATIC_PARTICLE_TYPE)

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


def one_step_mse(predicted: Tensor, target: Tensor, particle_type: Tensor, mask: Tensor | None = None) -> Tensor:
    """Position MSE of one predicted step from true history, L^2.

    Shapes:
        predicted, target: (N, d) or (B, N, d). particle_type, mask: (N,) or (B, N).
        Returns () or (B,).
    """
    rollout = ParticleRollout.of(predicted.unsqueeze(-3), particle_type, mask)
    truth = ParticleRollout.of(target.unsqueeze(-3), particle_type, mask)
    error = mse_per_step(rollout, truth)[:, 0]
    return error if predicted.ndim == 3 else error[0]


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


def rollout_metrics(
    predicted: ParticleRollout,
    target: ParticleRollout,
    *,
    dt: float,
    bounds: Sequence[Sequence[float]],
    same_particles: bool = True,
    horizons: Sequence[int] = DEFAULT_HORIZONS,
    granular_types: Collection[int] = (),
    material_names: Mapping[int, str] | None = None,
    vertical_axis: int = -1,
    runout_axis: int = 0,
    profile_bins: int = 50,
    blur_fraction: float = 1e-3,
) -> dict[str, Tensor | None]:
    """Every rollout metric of a batch, by name (see :data:`METRIC_UNITS`).

    Position MSEs need particle correspondence: when the rollouts hold
    different particles (a simulator run at another resolution,
    ``same_particles=False``) they are ``None``, and the distribution metrics
    (Sinkhorn, kinetic energy, runout, pile profile) still compare the two. Runout and profile are computed
    only when ``granular_types`` names the granular particle types.

    Args:
        predicted, target: the rollouts to compare, with the same B and S.
        dt: seconds between frames (the dataset's ``dt``).
        bounds: (d, 2) domain walls, L.
        same_particles: whether particle i of one rollout is particle i of the other.
        horizons: rollout steps for ``mse_h``; those beyond S are ``None``.
        granular_types: particle types whose runout and pile profile are measured.
        material_names: names for per-material keys (``mse_full[sand]``), else ``type=<id>``.
        vertical_axis: the axis gravity acts along (the last one in the public datasets).
        runout_axis: the horizontal axis the runout is measured along.
        profile_bins: bins per horizontal axis of the pile profile.
        blur_fraction: Sinkhorn blur as a fraction of the domain size.

    Returns:
        name -> (B,) tensor, or ``None`` when missing; ``"mse_per_step"`` is (B, S).
        A prediction with a non-finite moving particle has ``diverged`` 1, an
        ``inf`` position error in each frame where a particle is non-finite (and
        in every horizon that includes such a frame), and every other error
        ``inf``, so averaging over rollouts cannot hide it.
    """
    if predicted.position.shape[:2] != target.position.shape[:2]:
        raise ValueError(
            f"rollouts must have the same batch size and frame count: "
            f"{tuple(predicted.position.shape[:2])} vs {tuple(target.position.shape[:2])}"
        )
    size = domain_size(bounds)
    metrics: dict[str, Tensor | None] = {}
    if same_particles:
        per_step = mse_per_step(predicted, target)
        metrics["mse_per_step"] = per_step
        metrics.update(mse_at_horizons(per_step, horizons))
        metrics["rmse_full_pct"] = 100 * metrics["mse_full"].sqrt() / size
        metrics["mse_final"] = per_step[:, -1]
        metrics.update(per_material_mse(predicted, target, material_names))
    else:
        metrics["mse_per_step"] = None
        metrics.update({f"mse_{h}": None for h in horizons})
        metrics.update(mse_full=None, rmse_full_pct=None, mse_final=None)

    finite = torch.isfinite(predicted.position).all(-1) | ~predicted.moving[:, None]
    diverged = ~finite.flatten(1).all(-1)
    # A diverged rollout has no meaningful cloud, energy or pile: compute on finite
    # stand-in values (so no NaN reaches the solvers), then mark those errors inf.
    finite_predicted = replace(
        predicted, position=torch.nan_to_num(predicted.position, nan=0.0, posinf=0.0, neginf=0.0)
    )
    distribution = _distribution_errors(
        finite_predicted,
        target,
        dt=dt,
        bounds=bounds,
        granular_types=granular_types,
        vertical_axis=vertical_axis,
        runout_axis=runout_axis,
        profile_bins=profile_bins,
        blur_fraction=blur_fraction,
    )
    for name, value in distribution.items():
        metrics[name] = None if value is None else torch.where(diverged, torch.inf, value)
    metrics["diverged"] = diverged.to(predicted.position.dtype)
    return metrics


def _distribution_errors(
    predicted: ParticleRollout,
    target: ParticleRollout,
    *,
    dt: float,
    bounds: Sequence[Sequence[float]],
    granular_types: Collection[int],
    vertical_axis: int,
    runout_axis: int,
    profile_bins: int,
    blur_fraction: float,
) -> dict[str, Tensor | None]:
    """The metrics that compare particle clouds and need no particle correspondence."""
    size = domain_size(bounds)
    metrics: dict[str, Tensor | None] = {}
    final_distance = sinkhorn_distance(
        predicted.position[:, -1],
        target.position[:, -1],
        predicted.moving,
        target.moving,
        blur=blur_fraction * size,
        diameter=math.sqrt(len(bounds)) * size,
    )
    metrics["sinkhorn_final"] = final_distance
    metrics["sinkhorn_final_pct"] = 100 * final_distance / size

    energy_error, energy_pct = kinetic_energy_error(kinetic_energy(predicted, dt), kinetic_energy(target, dt))
    metrics["kinetic_energy_error"] = energy_error
    metrics["kinetic_energy_error_pct"] = energy_pct

    if not granular_types:
        metrics.update(runout_error=None, runout_error_pct=None, profile_error=None, profile_error_pct=None)
        return metrics
    predicted_granular, true_granular = predicted.of_types(granular_types), target.of_types(granular_types)
    predicted_runout = runout_distance(predicted, predicted_granular, runout_axis)
    true_runout = runout_distance(target, true_granular, runout_axis)
    runout_error = (predicted_runout - true_runout).abs()
    metrics["runout_error"] = runout_error
    metrics["runout_error_pct"] = 100 * runout_error / torch.where(true_runout.abs() > 0, true_runout.abs(), torch.nan)
    metrics["profile_error"], metrics["profile_error_pct"] = profile_error(
        pile_profile(predicted.position[:, -1], predicted_granular, bounds, profile_bins, vertical_axis),
        pile_profile(target.position[:, -1], true_granular, bounds, profile_bins, vertical_axis),
    )
    return metrics


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
