"""benchmarks/energy_warning.py: the scene features of synthetic columns (aspect, hinge, floor over tan phi, the
runout cut off by a wall, an obstacle or another column, the wall behind, the potential-energy weights), the ridge
fit and its cross-validation on exactly linear data, and the warning's flag, with answers derived by hand.

The sand lies on a lattice of spacing 1/8 m, so every edge, height and gap below is exact in binary floats.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

import energy_warning

REL = 1e-9
H = 0.125
"""Particle spacing of the synthetic sand, m."""
BOX = np.array([[0.0, 4.0], [0.0, 2.0]])
"""A 4 m x 2 m box."""
WALLS = np.array([[0.3, 0.0], [0.0, 0.0], [0.4, 0.0], [0.0, 0.0]])
"""Rough left wall (mu 0.3), slip right wall, rough floor (mu 0.4), slip top."""
NONE = np.zeros((0, 2))


def column(x0: float, width: float, height: float) -> np.ndarray:
    """Sand particles (N, 2) filling x in [x0, x0 + width], y in [0, height], m, one per cell of side ``H``."""
    x, y = np.meshgrid(x0 + H / 2 + H * np.arange(round(width / H)), H / 2 + H * np.arange(round(height / H)))
    return np.stack([x.ravel(), y.ravel()], axis=1)


def features(start, friction, blockers=NONE, walls=WALLS):
    return energy_warning.scene_features(start, np.asarray(friction, float), blockers, BOX, walls, H)


def test_a_column_against_a_wall_flows_one_way_with_its_aspect_and_the_wall_behind():
    # 0.5 m wide, 1 m tall against the rough left wall: a = 1 / 0.5 = 2, below the hinge; the runout the scaling
    # predicts, 1.2 * 0.5 * 2 = 1.2 m, ends well before the right wall 3.5 m away: nothing is cut off.
    start = column(0.0, 0.5, 1.0)
    f = features(start, np.full(len(start), 0.8))
    assert f["log_aspect"] == pytest.approx(np.log(2.0), rel=REL)
    assert f["hinge"] == 0.0
    assert f["log_floor_over_tan_phi"] == pytest.approx(np.log(0.4 / 0.8), rel=REL)
    assert f["log_tan_phi"] == pytest.approx(np.log(0.8), rel=REL)
    assert f["cut_off"] == 0.0
    assert f["back_wall"] == pytest.approx(0.3, rel=REL)
    assert f["free"] == 0.0
    assert f["columns"] == 1.0


def test_an_obstacle_ahead_cuts_off_the_share_of_the_runout_it_stands_in():
    # An obstacle particle (a cell of side H) whose near side is 0.6 m past the column's right edge (0.5 m): half of
    # the predicted 1.2 m runout is cut off.
    start = column(0.0, 0.5, 1.0)
    f = features(start, np.full(len(start), 0.8), blockers=np.array([[1.1 + H / 2, 0.0625]]))
    assert f["cut_off"] == pytest.approx(0.5, rel=REL)
    # An obstacle behind the column (none ahead of it) leaves the runout free.
    assert features(start, np.full(len(start), 0.8), blockers=np.array([[-0.5, 0.0]]))["cut_off"] == 0.0


def test_a_no_slip_wall_behind_counts_as_fully_rough():
    start = column(0.0, 0.5, 1.0)
    walls = WALLS.copy()
    walls[0] = [0.0, 1.0]
    assert features(start, np.full(len(start), 0.8), walls=walls)["back_wall"] == 1.0


def test_a_free_standing_tall_column_spreads_both_ways_beyond_the_hinge():
    # 0.5 m wide, 1.5 m tall, standing free: each side spreads from half the width, a = 1.5 / 0.25 = 6 > 2.5. The
    # runout 1.2 * 0.25 * 2.5^(1/3) * 6^(2/3) = 1.34 m; the left wall 0.5 m away cuts off 1 - 0.5 / 1.34 of the
    # left side's runout, the right one 1 m away 1 - 1 / 1.34 of the right side's.
    start = column(0.5, 0.5, 1.5)
    box = np.array([[0.0, 2.0], [0.0, 2.0]])
    f = energy_warning.scene_features(start, np.full(len(start), 0.6), NONE, box, WALLS, H)
    runout = 1.2 * 0.25 * 2.5 ** (1 / 3) * 6 ** (2 / 3)
    assert f["log_aspect"] == pytest.approx(np.log(6.0), rel=REL)
    assert f["hinge"] == pytest.approx(np.log(6.0 / 2.5), rel=REL)
    assert f["cut_off"] == pytest.approx((2.0 - 1.5 / runout) / 2, rel=REL)
    assert f["free"] == 1.0
    assert f["back_wall"] == 0.0


def test_two_columns_are_weighted_by_potential_energy_and_block_each_other():
    # Left: 0.5 x 1 m against the left wall (32 particles, weight 32 * 1), tan phi 0.8. Right: a free 0.5 x 0.5 m
    # column at x in [1.0, 1.5] (16 particles, weight 16 * 0.5), tan phi 0.6: weights 0.8 and 0.2.
    left, right = column(0.0, 0.5, 1.0), column(1.0, 0.5, 0.5)
    start = np.vstack([left, right])
    friction = np.concatenate([np.full(len(left), 0.8), np.full(len(right), 0.6)])
    f = features(start, friction)
    assert f["columns"] == 2.0
    assert f["log_tan_phi"] == pytest.approx(0.8 * np.log(0.8) + 0.2 * np.log(0.6), rel=REL)
    # Left column: a = 2; right column: a = 0.5 / 0.25 = 2 on each side.
    assert f["log_aspect"] == pytest.approx(np.log(2.0), rel=REL)
    # Other columns' particles are cells of side H, like obstacles'. The left column's runout (1.2 m) meets the right
    # column 0.5 m ahead: 1 - 0.5 / 1.2 cut off. The right column's
    # left side (runout 1.2 * 0.25 * 2 = 0.6 m) meets the left column 0.5 m away: 1 - 0.5 / 0.6; its right side runs
    # free to the wall 2.5 m away.
    expected = 0.8 * (1 - 0.5 / 1.2) + 0.2 * (1 - 0.5 / 0.6) / 2
    assert f["cut_off"] == pytest.approx(expected, rel=REL)
    assert f["free"] == pytest.approx(0.2, rel=REL)
    assert f["back_wall"] == pytest.approx(0.8 * 0.3, rel=REL)


def test_the_fit_recovers_exactly_linear_data_and_ignores_a_constant_feature():
    rng = np.random.default_rng(0)
    x = np.column_stack([rng.normal(size=40), rng.normal(size=40), np.full(40, 3.0)])
    y = 0.5 + 0.2 * x[:, 0] - 0.1 * x[:, 1]
    predictor = energy_warning.fit(x, y, ridge=0.0)
    assert predictor.log_ratio(x) == pytest.approx(y, rel=REL, abs=1e-12)
    assert predictor.coef[2] == 0.0
    # Cross-validated on the same exact data, every held-out scene is predicted exactly too.
    assert np.abs(energy_warning.cross_validated(x, y, folds=4, ridge=0.0)).max() < 1e-12


def test_the_ridge_shrinks_the_coefficients_toward_the_mean():
    rng = np.random.default_rng(1)
    x = rng.normal(size=(30, 1))
    y = 2.0 * x[:, 0]
    free, shrunk = energy_warning.fit(x, y, ridge=0.0), energy_warning.fit(x, y, ridge=30.0)
    # Standardised z has z.T @ z = 30, so the penalty 30 halves the coefficient.
    assert shrunk.coef[0] == pytest.approx(free.coef[0] / 2, rel=REL)


def row(learned: float, predicted: float) -> dict:
    return {"signals": {"energy_ratio": learned}, "predicted_energy_ratio": predicted}


def test_the_warning_flags_a_misfit_above_the_threshold_and_a_rollout_without_a_ratio():
    assert energy_warning.misfit(row(1.1, 1.0)) == pytest.approx(np.log(1.1), rel=REL)
    assert energy_warning.misfit(row(1.0, 1.1)) == pytest.approx(np.log(1.1), rel=REL)
    assert energy_warning.flagged(row(1.2, 1.0), 0.1)
    assert not energy_warning.flagged(row(1.05, 1.0), 0.1)
    assert energy_warning.flagged(row(float("nan"), 1.0), 0.1)
