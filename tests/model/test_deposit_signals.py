"""gns_framework.model.deposit_signals: the particle spacing, the two outer fronts (run, share, gap, held by a
wall, motion at the end), the energy ratio and the other signals, on small synthetic scenes whose answers are derived
by hand.

Lengths are multiples of 1/8 m where a comparison sits exactly on a threshold, so the binary floats are exact there.
Elsewhere the coordinates are of order 1 m: float64 rounding leaves about 1e-15 of them, far below the 1e-9
relative tolerance used.
"""

from __future__ import annotations

import numpy as np
import pytest

from gns_framework.model.deposit_signals import (
    Front,
    deposit_signals,
    energy_ratio,
    fronts,
    other_signals,
    spacing,
)

REL = 1e-9
"""Relative tolerance: metre-scale float64 sums and quotients are exact to ~1e-15."""
H = 0.125
"""Particle spacing of the synthetic sand, m (a power of two: thresholds in spacings are hit exactly)."""


def lattice(columns: int, rows: int, dx: float, dy: float, x0: float = 0.0) -> np.ndarray:
    """A regular ``columns`` x ``rows`` block of particles (N, 2) with steps ``dx``, ``dy``, m."""
    x, y = np.meshgrid(x0 + dx * np.arange(columns), dy * np.arange(rows))
    return np.stack([x.ravel(), y.ravel()], axis=1)


def spread_path(start: np.ndarray, left: float, right: float, frames: int = 20) -> np.ndarray:
    """A sand path (S, N, 2) moving each particle linearly in time from ``start`` to a final deposit whose x runs
    from ``left`` to ``right`` (the start's x stretched affinely), heights kept."""
    lo, hi = start[:, 0].min(), start[:, 0].max()
    final = start.copy()
    final[:, 0] = left + (start[:, 0] - lo) / (hi - lo) * (right - left)
    t = np.linspace(0.0, 1.0, frames)[:, None, None]
    return start[None] + t * (final - start)[None]


def by_side(fronts: list[Front]) -> dict[str, Front]:
    return {f.side: f for f in fronts}


# A 5 x 5 column of sand on x in [0, 0.5] m that spreads to [-0.125, 1.25] m: the left front runs 1 spacing, the
# right one 6 (0.75 m) over a final extent of 1.375 m, so its run share is 0.75 / 1.375 = 6/11 > 0.5.
START = lattice(5, 5, H, H)
PATH = spread_path(START, left=-0.125, right=1.25)
EXTENT = 1.375
WIDE = np.array([[-1.0, 3.0], [0.0, 2.0]])
"""Walls far from the sand on both sides: x in [-1, 3] m, y in [0, 2] m."""
NO_OBSTACLE = np.zeros((0, 2))


def block(x0: float, x1: float) -> np.ndarray:
    """An obstacle of particles one spacing apart covering x in [x0, x1], m, two spacings tall."""
    return lattice(round((x1 - x0) / H) + 1, 3, H, H, x0=x0)


# --- spacing ---------------------------------------------------------------------------------------------------


def test_spacing_of_a_square_lattice_is_its_step():
    step = 0.1
    assert spacing(lattice(6, 4, step, step)) == pytest.approx(step, rel=REL)


def test_spacing_of_a_rectangular_lattice_is_its_shorter_step():
    # Every particle's nearest neighbour lies along the shorter step; the longer one never enters.
    assert spacing(lattice(6, 4, 0.1, 0.15)) == pytest.approx(0.1, rel=REL)


def test_spacing_is_the_median_so_a_stray_particle_does_not_move_it():
    # 25 particles 0.1 m apart and one 10 m away: the mean of the nearest distances would be ~0.48 m, the median
    # stays at the lattice step.
    start = np.vstack([lattice(5, 5, 0.1, 0.1), [[10.0, 0.0]]])
    assert spacing(start) == pytest.approx(0.1, rel=REL)


# --- fronts ----------------------------------------------------------------------------------------------------


def test_a_front_running_toward_an_obstacle_has_its_run_share_and_gap_in_spacings():
    # Block from 1.5 m: 0.25 m = 2 spacings ahead of the right front at 1.25 m (the wall at 3 m is 14 away).
    sides = by_side(fronts(PATH, START, block(1.5, 1.75), WIDE, H))
    right, left = sides["right"], sides["left"]
    assert right.run == pytest.approx(0.75, rel=REL)
    assert right.share == pytest.approx(0.75 / EXTENT, rel=REL)
    assert right.gap == pytest.approx(2.0, rel=REL)
    assert not right.at_wall
    # The block is behind the left front: only the left wall, 0.875 m = 7 spacings away, is ahead of it.
    assert left.run == pytest.approx(0.125, rel=REL)
    assert left.share == pytest.approx(0.125 / EXTENT, rel=REL)
    assert left.gap == pytest.approx(7.0, rel=REL)
    assert not left.at_wall
    # 20 frames: the tail is the last round(0.1 * 20) = 2 steps, 2/19 of each run, in spacings.
    assert right.tail == pytest.approx(2 / 19 * 0.75 / H, rel=REL)
    assert left.tail == pytest.approx(2 / 19 * 0.125 / H, rel=REL)


def test_without_obstacles_the_gap_is_to_the_wall_ahead():
    right = by_side(fronts(PATH, START, NO_OBSTACLE, WIDE, H))["right"]
    assert right.gap == pytest.approx((3.0 - 1.25) / H, rel=REL)  # 14 spacings
    assert not right.at_wall


def test_a_front_on_an_obstacle_or_just_past_one_has_gap_zero():
    # An obstacle particle half a spacing behind the front is under it (the front is on the obstacle), not passed.
    under = np.array([[1.25 - H / 2, 0.0]])
    assert by_side(fronts(PATH, START, under, WIDE, H))["right"].gap == 0.0
    # Obstacle reaching both sides of the front: on it.
    assert by_side(fronts(PATH, START, block(1.0, 1.5), WIDE, H))["right"].gap == 0.0


def test_an_obstacle_the_front_has_passed_is_not_ahead_of_it():
    # Exactly one spacing behind and further: passed (the comparison is strict), so the wall sets the gap.
    passed = block(0.75, 1.25 - H)
    right = by_side(fronts(PATH, START, passed, WIDE, H))["right"]
    assert right.gap == pytest.approx(14.0, rel=REL)


def test_a_front_within_one_spacing_of_a_wall_is_held():
    # Right wall exactly one spacing past the final front (1.375 m): held by it (<=), whatever its run share.
    walls = np.array([[-1.0, 1.25 + H], [0.0, 2.0]])
    right = by_side(fronts(PATH, START, NO_OBSTACLE, walls, H))["right"]
    assert right.at_wall
    assert right.gap == pytest.approx(1.0, rel=REL)
    assert right.share == pytest.approx(0.75 / EXTENT, rel=REL)


def test_a_front_two_spacings_before_a_wall_is_not_held():
    walls = np.array([[-1.0, 1.25 + 2 * H], [0.0, 2.0]])
    right = by_side(fronts(PATH, START, NO_OBSTACLE, walls, H))["right"]
    assert not right.at_wall
    assert right.gap == pytest.approx(2.0, rel=REL)


def test_mirroring_the_scene_swaps_the_left_and_right_fronts():
    # x -> -x turns the right front into the left one: the same run, share, gap and tail on the other side.
    obstacle = block(1.5, 1.75)
    walls = np.array([[-1.0, 1.25 + H], [0.0, 2.0]])

    def mirror(points):
        return points * np.array([-1.0, 1.0])

    mirrored_walls = np.array([[-walls[0, 1], -walls[0, 0]], walls[1]])
    for bounds, mirrored_bounds in ((WIDE, np.array([[-3.0, 1.0], [0.0, 2.0]])), (walls, mirrored_walls)):
        original = by_side(fronts(PATH, START, obstacle, bounds, H))
        flipped = by_side(fronts(mirror(PATH), mirror(START), mirror(obstacle), mirrored_bounds, H))
        for side, other in (("left", "right"), ("right", "left")):
            a, b = original[side], flipped[other]
            assert (a.run, a.share, a.gap, a.tail) == pytest.approx((b.run, b.share, b.gap, b.tail), rel=REL)
            assert a.at_wall == b.at_wall


# --- energy_ratio ----------------------------------------------------------------------------------------------


def test_energy_ratio_of_particles_dropping_and_sliding_is_drop_over_friction_times_slide():
    # Each particle drops 0.5 m and slides 2 m (half to each side: |dx| counts) with tan(phi) = 0.5:
    # R = m g h / (mu m g L) = 0.5 / (0.5 * 2) = 0.5.
    start = lattice(4, 2, 0.1, 0.1)
    start[:, 1] += 1.0
    final = start.copy()
    final[:, 1] -= 0.5
    final[:, 0] += np.where(np.arange(len(start)) % 2 == 0, 2.0, -2.0)
    friction = np.full(len(start), 0.5)
    assert energy_ratio(start, final, friction) == pytest.approx(0.5, rel=REL)


def test_energy_ratio_of_a_block_sliding_down_a_slope_of_its_friction_angle_is_one():
    # Down a slope with tan = mu: the drop is mu * dx, so the released energy equals the friction work.
    mu, dx = 0.6, 1.5
    start = np.array([[0.0, 2.0], [0.1, 2.0], [0.0, 2.1]])
    final = start + np.array([dx, -mu * dx])
    assert energy_ratio(start, final, np.full(3, mu)) == pytest.approx(1.0, rel=REL)


def test_energy_ratio_weighs_each_particle_by_its_own_friction_and_counts_a_rise_against_the_drop():
    # Particle 1: drops 1 m, slides 1 m, tan(phi) 1 -> work 1. Particle 2: rises 0.5 m, slides 2 m, tan(phi) 0.25
    # -> work 0.5. R = (1 - 0.5) / (1 + 0.5) = 1/3 (a mean friction, 0.625 * 3, would give 0.27 instead).
    start = np.array([[0.0, 1.0], [0.0, 0.0]])
    final = np.array([[1.0, 0.0], [-2.0, 0.5]])
    friction = np.array([1.0, 0.25])
    assert energy_ratio(start, final, friction) == pytest.approx(1 / 3, rel=REL)


def test_energy_ratio_without_horizontal_motion_is_nan():
    start = lattice(3, 3, 0.1, 0.1)
    final = start - np.array([0.0, 0.05])  # a pure settling: no friction work to divide by
    assert np.isnan(energy_ratio(start, final, np.full(len(start), 0.5)))


# --- other_signals, deposit_signals ----------------------------------------------------------------------------


def test_the_tallest_columns_aspect_and_friction_and_the_runout_ratio_are_the_columns_own():
    # Two columns two spacings apart with different frictions: a 2 x 6 one (tan phi 0.5) and a 4 x 2 one (0.8).
    # Widths count one spacing more than the particles span (each particle stands for a cell); heights are measured
    # from the floor (y = 0) to the top particle plus half a spacing.
    tall = lattice(2, 6, H, H)
    low = lattice(4, 2, H, H, x0=0.75)
    start = np.vstack([tall, low])
    friction = np.r_[np.full(len(tall), 0.5), np.full(len(low), 0.8)]
    path = np.stack([start, start])  # nothing moves
    bounds = np.array([[-1.0, 3.0], [0.0, 2.0]])
    signals = other_signals(path, start, friction, NO_OBSTACLE, bounds, H)
    tall_aspect = (5 * H + H / 2) / (2 * H)
    assert signals["aspect"] == pytest.approx(tall_aspect, rel=REL)
    assert signals["tan_phi"] == 0.5
    assert signals["aspect_over_tan_phi"] == pytest.approx(tall_aspect / 0.5, rel=REL)
    assert signals["runout_ratio"] == pytest.approx(1.0, rel=REL)
    assert np.isnan(signals["energy_ratio"]), "nothing slid: no friction work"
    assert signals["touching"] == 0.0


def test_deposit_signals_carry_the_fronts_the_held_particles_and_the_sand_count():
    signals = deposit_signals(PATH, START, np.full(len(START), 0.6), block(1.5, 1.75), WIDE, held=3)
    assert [f.side for f in signals.fronts] == ["left", "right"]
    assert signals.leading().side == "right"
    assert signals.signals["held"] == 3.0
    assert signals.signals["sand_particles"] == len(START)
    assert signals.fronts == fronts(PATH, START, block(1.5, 1.75), WIDE, spacing(START))


def test_a_deposit_that_did_not_spread_has_run_share_zero_not_a_division_by_zero():
    line = np.array([[0.0, 0.0], [0.0, H], [0.0, 2 * H]])  # one particle wide: extent 0
    path = np.stack([line, line])
    assert all(f.share == 0.0 for f in fronts(path, line, NO_OBSTACLE, WIDE, H))
