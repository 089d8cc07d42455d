"""The built-in rollout metrics: each one's value from what a rollout pair measured, by hand.

A rollout pair is stood in for by a record holding what the metrics read from
``RolloutPair`` (its per-step MSE, runouts, final extents and heights, ...), so each
formula here is checked alone; ``tests/evaluation/test_metrics.py`` measures those
inputs on constructed rollouts.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest
import torch

from gns_builtins import metrics as builtin
from gns_builtins.metrics import BUILTIN_METRICS

BY_NAME = {metric.name: metric for metric in BUILTIN_METRICS}


def value(name: str, **pair):
    return BY_NAME[name].function(SimpleNamespace(**pair))


def tensor(*values: float) -> torch.Tensor:
    return torch.tensor(values, dtype=torch.float64)


def test_whole_rollout_and_final_frame_position_errors():
    # Two rollouts of three steps; the MSE of a step is in L^2.
    per_step = torch.tensor([[1.0, 2.0, 6.0], [0.0, 0.0, 0.03]], dtype=torch.float64)
    torch.testing.assert_close(value("mse_full", mse_per_step=per_step), tensor(3.0, 0.01))
    torch.testing.assert_close(value("mse_final", mse_per_step=per_step), tensor(6.0, 0.03))
    # sqrt(3) and sqrt(0.01) = 0.1 as a share of a domain 2 L wide.
    torch.testing.assert_close(
        value("rmse_full_pct", mse_per_step=per_step, domain_size=2.0), tensor(100 * math.sqrt(3) / 2, 5.0)
    )


@pytest.mark.parametrize("name", ["mse_full", "mse_final", "rmse_full_pct"])
def test_position_errors_are_missing_without_particle_correspondence(name):
    assert value(name, mse_per_step=None, domain_size=1.0) is None


def test_per_material_errors_need_particle_correspondence(monkeypatch):
    calls = []
    monkeypatch.setattr(
        builtin, "per_material_mse", lambda *args: calls.append(args) or {"mse_full[sand]": tensor(0.5)}
    )
    pair = dict(predicted="p", target="t", material_names={6: "sand"})
    assert value("mse_full[<material>]", same_particles=False, **pair) == {}
    assert calls == []
    assert value("mse_full[<material>]", same_particles=True, **pair) == {"mse_full[sand]": tensor(0.5)}
    assert calls == [("p", "t", {6: "sand"})]


def test_runout_error_and_its_share_of_the_true_runout():
    runouts = (tensor(0.25, 0.5, 0.1), tensor(0.3, 0.4, 0.0))
    torch.testing.assert_close(value("runout_error", runouts=runouts), tensor(0.05, 0.1, 0.1))
    percent = value("runout_error_pct", runouts=runouts)
    torch.testing.assert_close(percent[:2], tensor(100 * 0.05 / 0.3, 100 * 0.1 / 0.4))
    # A true runout of 0 is no reference to be a share of: NaN, not inf or 0.
    assert math.isnan(percent[2])
    assert value("runout_error", runouts=None) is None and value("runout_error_pct", runouts=None) is None


def test_final_extent_height_and_deposit_errors():
    pair = dict(
        final_extents=(tensor(0.45, 0.6), tensor(0.5, -0.5)), final_heights=(tensor(0.1, 0.2), tensor(0.1, 0.25))
    )
    extent, height = value("extent_error_pct", **pair), value("height_error_pct", **pair)
    # |0.45 - 0.5| / 0.5 = 10 %, |0.6 + 0.5| / |-0.5| = 220 %; heights 0 % and 0.05 / 0.25 = 20 %.
    torch.testing.assert_close(extent, tensor(10.0, 220.0))
    torch.testing.assert_close(height, tensor(0.0, 20.0))
    torch.testing.assert_close(value("deposit_error_pct", **pair), tensor(5.0, 120.0))


@pytest.mark.parametrize(
    "extents, heights", [(None, (tensor(0.1), tensor(0.1))), ((tensor(0.1), tensor(0.1)), None), (None, None)]
)
def test_the_deposit_error_is_missing_when_either_measure_is(extents, heights):
    assert value("deposit_error_pct", final_extents=extents, final_heights=heights) is None


def test_cloud_energy_and_profile_metrics_read_their_measure():
    pair = dict(
        sinkhorn_final=tensor(0.02),
        domain_size=4.0,
        kinetic_energy_error=(tensor(1.5), tensor(30.0)),
        profile_error=(tensor(0.01), tensor(4.0)),
    )
    torch.testing.assert_close(value("sinkhorn_final", **pair), tensor(0.02))
    torch.testing.assert_close(value("sinkhorn_final_pct", **pair), tensor(0.5))
    torch.testing.assert_close(value("kinetic_energy_error", **pair), tensor(1.5))
    torch.testing.assert_close(value("kinetic_energy_error_pct", **pair), tensor(30.0))
    torch.testing.assert_close(value("profile_error", **pair), tensor(0.01))
    torch.testing.assert_close(value("profile_error_pct", **pair), tensor(4.0))
    assert value("profile_error", profile_error=None) is None and value("profile_error_pct", profile_error=None) is None


def test_position_errors_are_pairwise_and_cloud_metrics_are_not():
    # Pairwise metrics see the raw prediction and must be None without correspondence (tested above).
    pairwise = {m.name for m in BUILTIN_METRICS if m.pairwise}
    assert pairwise == {"mse_{h}", "mse_full", "rmse_full_pct", "mse_final", "mse_full[<material>]"}


def test_the_metrics_tracked_in_training_and_the_report_order():
    tracked = {m.name: m.validation for m in BUILTIN_METRICS if m.validation}
    assert tracked == {
        "mse_full": "mse",
        "sinkhorn_final_pct": "sinkhorn_pct",
        "runout_error_pct": "runout_error_pct",
        "extent_error_pct": "extent_error_pct",
        "height_error_pct": "height_error_pct",
        "deposit_error_pct": "deposit_error_pct",
    }
    # The order of the report's columns: horizons first, then whole-rollout errors; the hook gives them all.
    assert [m.name for m in BUILTIN_METRICS][:3] == ["mse_{h}", "mse_full", "rmse_full_pct"]
    assert builtin.gns_metrics() == list(BUILTIN_METRICS)
    assert all(m.unit.split(",")[0] in {"L", "L^2", "%", "L^2/s^2", "flag"} for m in BUILTIN_METRICS)
