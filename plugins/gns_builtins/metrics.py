"""Built-in rollout metrics, registered through the same ``gns_metrics`` hook as a plugin's.

L is the dataset's length unit, s seconds; ``*_pct`` are percent of the stated
scale. The order here is the order of the report's columns.
"""

from __future__ import annotations

import torch

from gns_framework.api import Metric, RolloutPair, free_deposits, hookimpl, horizon_mse, per_material_mse


def _mse_full(pair: RolloutPair):
    return None if pair.mse_per_step is None else pair.mse_per_step.mean(-1)


def _rmse_full_pct(pair: RolloutPair):
    mse = _mse_full(pair)
    return None if mse is None else 100 * mse.sqrt() / pair.domain_size


def _mse_final(pair: RolloutPair):
    return None if pair.mse_per_step is None else pair.mse_per_step[:, -1]


def _per_material(pair: RolloutPair):
    return per_material_mse(pair.predicted, pair.target, pair.material_names) if pair.same_particles else {}


def _relative(error, scale):
    """``100 * error / |scale|``, NaN where the scale is 0 (no reference to be a share of)."""
    return 100 * error / torch.where(scale.abs() > 0, scale.abs(), torch.nan)


def _runout_error(pair: RolloutPair):
    if pair.runouts is None:
        return None
    predicted, true = pair.runouts
    return (predicted - true).abs()


def _runout_error_pct(pair: RolloutPair):
    return None if pair.runouts is None else _relative(_runout_error(pair), pair.runouts[1])


def _final_error_pct(values):
    """``|predicted - true| / |true|`` in % of a (predicted, true) pair of final measures; None when absent."""
    if values is None:
        return None
    predicted, true = values
    return _relative((predicted - true).abs(), true)


def _extent_error_pct(pair: RolloutPair):
    return _final_error_pct(pair.final_extents)


def _height_error_pct(pair: RolloutPair):
    return _final_error_pct(pair.final_heights)


def _deposit_error_pct(pair: RolloutPair):
    """The mean of the final extent and height errors, the deposit a geotechnical user reads off.

    Chosen to pick the best checkpoint of a model of many scenes: a final-cloud Sinkhorn
    error averaged over scenes is dominated by boxes full of sand that hardly move, and
    can be small while single columns stop too early or slide too far.
    """
    extent, height = _extent_error_pct(pair), _height_error_pct(pair)
    return None if extent is None or height is None else (extent + height) / 2


def _free_deposit(pair: RolloutPair):
    """1 where the true deposit stops short of a side wall (its extent is the flow's to set), else 0; None without
    granular types."""
    if not pair.granular_types:
        return None
    truth = pair.target
    start = truth.start if truth.start is not None else truth.position[:, 0]
    sand = truth.of_types(pair.granular_types)
    return free_deposits(truth.position[:, -1], start, sand, pair.bounds, pair.runout_axis).to(start.dtype)


BUILTIN_METRICS = (
    Metric("mse_{h}", "L^2, position MSE averaged over rollout steps 1..h", horizon_mse, pairwise=True),
    Metric("mse_full", "L^2, position MSE averaged over the whole rollout", _mse_full, pairwise=True, validation="mse"),
    Metric("rmse_full_pct", "%, sqrt(mse_full) as a share of the domain size", _rmse_full_pct, pairwise=True),
    Metric("mse_final", "L^2, position MSE at the last frame", _mse_final, pairwise=True),
    Metric(
        "mse_full[<material>]",
        "L^2, mse_full and mse_final of one moving material's particles (also mse_final[<material>])",
        _per_material,
        pairwise=True,
    ),
    Metric(
        "sinkhorn_final",
        "L, Sinkhorn distance sqrt(2 S_eps) between final particle clouds (~ W2)",
        lambda pair: pair.sinkhorn_final,
    ),
    Metric(
        "sinkhorn_final_pct",
        "%, sinkhorn_final as a share of the domain size",
        lambda pair: 100 * pair.sinkhorn_final / pair.domain_size,
        validation="sinkhorn_pct",
    ),
    Metric(
        "kinetic_energy_error",
        "L^2/s^2, mean |error| of the kinetic energy per unit mass, averaged per particle",
        lambda pair: pair.kinetic_energy_error[0],
    ),
    Metric(
        "kinetic_energy_error_pct",
        "%, kinetic_energy_error as a share of the mean true kinetic energy",
        lambda pair: pair.kinetic_energy_error[1],
    ),
    Metric("runout_error", "L, |predicted - true| runout distance of the granular particles", _runout_error),
    Metric(
        "runout_error_pct",
        "%, runout_error as a share of the true runout distance",
        _runout_error_pct,
        validation="runout_error_pct",
    ),
    Metric(
        "extent_error_pct",
        "%, |predicted - true| final horizontal extent (front - back) of the granular particles, of the true one",
        _extent_error_pct,
        validation="extent_error_pct",
    ),
    Metric(
        "height_error_pct",
        "%, |predicted - true| final pile height (highest granular particle above the floor), of the true one",
        _height_error_pct,
        validation="height_error_pct",
    ),
    Metric(
        "deposit_error_pct",
        "%, mean of extent_error_pct and height_error_pct: the deposit's shape in one figure",
        _deposit_error_pct,
        validation="deposit_error_pct",
    ),
    Metric(
        "free_deposit",
        "flag, 1 where the true final deposit ends more than a particle spacing from a side wall (its extent is set "
        "by the flow), 0 where it reaches both walls (set by the box)",
        _free_deposit,
    ),
    Metric(
        "profile_error",
        "L, RMS error of the final pile surface height over occupied bins",
        lambda pair: None if pair.profile_error is None else pair.profile_error[0],
    ),
    Metric(
        "profile_error_pct",
        "%, profile_error as a share of the true maximum pile height",
        lambda pair: None if pair.profile_error is None else pair.profile_error[1],
    ),
)


@hookimpl
def gns_metrics():
    return list(BUILTIN_METRICS)
