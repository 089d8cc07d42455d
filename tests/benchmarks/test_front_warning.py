"""benchmarks/front_warning.py: the particle spacing, the two outer fronts (run, share, gap, held by a wall), the
energy ratio, the rule's flag at its thresholds and its rates over the grid, and the tuned thresholds of the other
candidates, on small synthetic scenes and hand-made rows whose answers are derived by hand.

Lengths are multiples of 1/8 m where a comparison sits exactly on a threshold, so the binary floats are exact there.
Elsewhere the coordinates are of order 1 m: float64 rounding leaves about 1e-15 of them, far below the 1e-9
relative tolerance used.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

import front_warning
from front_warning import Front

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
    assert front_warning.spacing(lattice(6, 4, step, step)) == pytest.approx(step, rel=REL)


def test_spacing_of_a_rectangular_lattice_is_its_shorter_step():
    # Every particle's nearest neighbour lies along the shorter step; the longer one never enters.
    assert front_warning.spacing(lattice(6, 4, 0.1, 0.15)) == pytest.approx(0.1, rel=REL)


def test_spacing_is_the_median_so_a_stray_particle_does_not_move_it():
    # 25 particles 0.1 m apart and one 10 m away: the mean of the nearest distances would be ~0.48 m, the median
    # stays at the lattice step.
    start = np.vstack([lattice(5, 5, 0.1, 0.1), [[10.0, 0.0]]])
    assert front_warning.spacing(start) == pytest.approx(0.1, rel=REL)


# --- fronts ----------------------------------------------------------------------------------------------------


def test_a_front_running_toward_an_obstacle_has_its_run_share_and_gap_in_spacings():
    # Block from 1.5 m: 0.25 m = 2 spacings ahead of the right front at 1.25 m (the wall at 3 m is 14 away).
    fronts = by_side(front_warning.fronts(PATH, START, block(1.5, 1.75), WIDE, H))
    right, left = fronts["right"], fronts["left"]
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
    # With the default rule (share >= 0.5, gap <= 20) the right front is undecided, the left one is not.
    assert right.undecided() and not left.undecided()


def test_without_obstacles_the_gap_is_to_the_wall_ahead():
    right = by_side(front_warning.fronts(PATH, START, NO_OBSTACLE, WIDE, H))["right"]
    assert right.gap == pytest.approx((3.0 - 1.25) / H, rel=REL)  # 14 spacings
    assert not right.at_wall


def test_a_front_on_an_obstacle_or_just_past_one_has_gap_zero():
    # An obstacle particle half a spacing behind the front is under it (the front is on the obstacle), not passed.
    under = np.array([[1.25 - H / 2, 0.0]])
    assert by_side(front_warning.fronts(PATH, START, under, WIDE, H))["right"].gap == 0.0
    # Obstacle reaching both sides of the front: on it.
    assert by_side(front_warning.fronts(PATH, START, block(1.0, 1.5), WIDE, H))["right"].gap == 0.0


def test_an_obstacle_the_front_has_passed_is_not_ahead_of_it():
    # Exactly one spacing behind and further: passed (the comparison is strict), so the wall sets the gap.
    passed = block(0.75, 1.25 - H)
    right = by_side(front_warning.fronts(PATH, START, passed, WIDE, H))["right"]
    assert right.gap == pytest.approx(14.0, rel=REL)


def test_a_front_within_one_spacing_of_a_wall_is_held_and_not_undecided():
    # Right wall exactly one spacing past the final front (1.375 m): held by it (<=), whatever its run share.
    walls = np.array([[-1.0, 1.25 + H], [0.0, 2.0]])
    right = by_side(front_warning.fronts(PATH, START, NO_OBSTACLE, walls, H))["right"]
    assert right.at_wall
    assert right.gap == pytest.approx(1.0, rel=REL)
    assert right.share == pytest.approx(0.75 / EXTENT, rel=REL)
    assert not right.undecided()


def test_a_front_two_spacings_before_a_wall_is_not_held_and_is_undecided():
    walls = np.array([[-1.0, 1.25 + 2 * H], [0.0, 2.0]])
    right = by_side(front_warning.fronts(PATH, START, NO_OBSTACLE, walls, H))["right"]
    assert not right.at_wall
    assert right.gap == pytest.approx(2.0, rel=REL)
    assert right.undecided()


def test_mirroring_the_scene_swaps_the_left_and_right_fronts():
    # x -> -x turns the right front into the left one: the same run, share, gap and tail on the other side.
    obstacle = block(1.5, 1.75)
    walls = np.array([[-1.0, 1.25 + H], [0.0, 2.0]])

    def mirror(points):
        return points * np.array([-1.0, 1.0])

    mirrored_walls = np.array([[-walls[0, 1], -walls[0, 0]], walls[1]])
    for bounds, mirrored_bounds in ((WIDE, np.array([[-3.0, 1.0], [0.0, 2.0]])), (walls, mirrored_walls)):
        original = by_side(front_warning.fronts(PATH, START, obstacle, bounds, H))
        flipped = by_side(front_warning.fronts(mirror(PATH), mirror(START), mirror(obstacle), mirrored_bounds, H))
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
    assert front_warning.energy_ratio(start, final, friction) == pytest.approx(0.5, rel=REL)


def test_energy_ratio_of_a_block_sliding_down_a_slope_of_its_friction_angle_is_one():
    # Down a slope with tan = mu: the drop is mu * dx, so the released energy equals the friction work.
    mu, dx = 0.6, 1.5
    start = np.array([[0.0, 2.0], [0.1, 2.0], [0.0, 2.1]])
    final = start + np.array([dx, -mu * dx])
    assert front_warning.energy_ratio(start, final, np.full(3, mu)) == pytest.approx(1.0, rel=REL)


def test_energy_ratio_weighs_each_particle_by_its_own_friction_and_counts_a_rise_against_the_drop():
    # Particle 1: drops 1 m, slides 1 m, tan(phi) 1 -> work 1. Particle 2: rises 0.5 m, slides 2 m, tan(phi) 0.25
    # -> work 0.5. R = (1 - 0.5) / (1 + 0.5) = 1/3 (a mean friction, 0.625 * 3, would give 0.27 instead).
    start = np.array([[0.0, 1.0], [0.0, 0.0]])
    final = np.array([[1.0, 0.0], [-2.0, 0.5]])
    friction = np.array([1.0, 0.25])
    assert front_warning.energy_ratio(start, final, friction) == pytest.approx(1 / 3, rel=REL)


def test_energy_ratio_without_horizontal_motion_is_nan():
    start = lattice(3, 3, 0.1, 0.1)
    final = start - np.array([0.0, 0.05])  # a pure settling: no friction work to divide by
    assert np.isnan(front_warning.energy_ratio(start, final, np.full(len(start), 0.5)))


# --- flagged, leading, is_bad ----------------------------------------------------------------------------------


def front(side: str = "right", share: float = 0.0, gap: float = 100.0, at_wall: bool = False, tail: float = 0.0):
    """A front as a row stores it (dataclasses.asdict of Front); run is irrelevant to the rule."""
    return {"side": side, "run": share, "share": share, "gap": gap, "at_wall": at_wall, "tail": tail}


def row(*fronts: dict, extent: float = 0.0, height: float = 0.0, **signals: float) -> dict:
    return {"fronts": list(fronts), "error": {"extent": extent, "height": height}, "signals": signals}


def test_the_rule_flags_a_front_exactly_at_both_thresholds():
    # The comparisons are share >= SHARE and gap <= NEAR: the boundary itself is flagged.
    assert front_warning.flagged(row(front(share=front_warning.SHARE, gap=front_warning.NEAR)))


def test_the_rule_does_not_flag_just_below_the_share_or_just_beyond_the_gap():
    below = np.nextafter(front_warning.SHARE, 0.0)
    beyond = np.nextafter(front_warning.NEAR, np.inf)
    assert not front_warning.flagged(row(front(share=below, gap=front_warning.NEAR)))
    assert not front_warning.flagged(row(front(share=front_warning.SHARE, gap=beyond)))


def test_the_rule_does_not_flag_a_front_held_by_a_wall():
    assert not front_warning.flagged(row(front(share=0.9, gap=0.5, at_wall=True)))


def test_one_undecided_front_is_enough_to_flag():
    decided = front("left", share=0.1, gap=3.0)
    undecided = front("right", share=0.6, gap=3.0)
    assert front_warning.flagged(row(decided, undecided))
    assert front_warning.flagged(row(undecided, decided))
    assert not front_warning.flagged(row(decided, decided))


def test_the_rule_uses_the_thresholds_it_is_given():
    r = row(front(share=0.55, gap=15.0))
    assert front_warning.flagged(r)  # defaults 0.5 and 20
    assert not front_warning.flagged(r, share=0.6)
    assert not front_warning.flagged(r, near=10.0)
    assert front_warning.flagged(r, share=0.55, near=15.0)


def test_the_leading_front_is_the_one_with_the_larger_run_share_on_either_side():
    left, right = front("left", share=0.2), front("right", share=0.7)
    assert front_warning.leading(row(left, right)) is right
    assert front_warning.leading(row(front("left", share=0.8), right))["side"] == "left"


def test_a_scene_is_bad_only_above_15_percent_in_either_error():
    assert front_warning.BAD == 15.0
    assert not front_warning.is_bad(row(extent=15.0, height=15.0))  # > BAD: exactly 15 % is good
    assert front_warning.is_bad(row(extent=15.01, height=0.0))
    assert front_warning.is_bad(row(extent=0.0, height=15.01))  # the height error alone suffices
    assert not front_warning.is_bad(row(extent=3.0, height=14.99))


# --- rule_sweep, best_thresholds -------------------------------------------------------------------------------

SWEEP_ROWS = [
    row(front(share=0.55, gap=8.0), extent=30.0),  # bad: flagged for share <= 0.5 and near >= 10
    row(front(share=0.75, gap=30.0), height=20.0),  # bad: flagged for every share and near >= 40
    row(front(share=0.45, gap=3.0), extent=5.0),  # good: flagged for share <= 0.4, every near
    row(front(share=0.9, gap=0.5, at_wall=True), extent=1.0),  # good: held by a wall, never flagged
]


def test_rule_sweep_rates_over_the_grid_match_the_hand_count():
    sweep = front_warning.rule_sweep(SWEEP_ROWS)
    # Rows: SHARES (0.3 .. 0.7); columns: NEARS (5, 10, 20, 40, inf). Two bad and two good scenes.
    assert list(front_warning.SHARES) == [0.3, 0.4, 0.5, 0.6, 0.7]
    assert list(front_warning.NEARS) == [5.0, 10.0, 20.0, 40.0, np.inf]
    hit = [
        [0.0, 0.5, 0.5, 1.0, 1.0],
        [0.0, 0.5, 0.5, 1.0, 1.0],
        [0.0, 0.5, 0.5, 1.0, 1.0],
        [0.0, 0.0, 0.0, 0.5, 0.5],
        [0.0, 0.0, 0.0, 0.5, 0.5],
    ]
    false_alarm = [[0.5] * 5, [0.5] * 5, [0.0] * 5, [0.0] * 5, [0.0] * 5]
    assert [(r["share"], r["near"]) for r in sweep] == [
        (s, n) for s in front_warning.SHARES for n in front_warning.NEARS
    ]
    assert all((r["bad"], r["good"]) == (2, 2) for r in sweep)
    assert [r["hit_rate"] for r in sweep] == [x for line in hit for x in line]
    assert [r["false_alarm_rate"] for r in sweep] == [x for line in false_alarm for x in line]


def test_best_thresholds_picks_the_direction_with_fewer_false_alarms_for_each_candidate():
    # The tail signal is the larger of the two fronts' tails; the run share is the leading front's.
    rows = [
        row(front("left", 0.1, tail=0.2), front("right", 0.8, tail=0.05), extent=30.0, x=3.0, y=1.0, z=2.0),
        row(front("left", 0.6, tail=0.1), front("right", 0.2, tail=0.0), height=20.0, x=2.0, y=2.0, z=4.0),
        row(front("left", 0.7, tail=0.5), front("right", 0.1, tail=0.0), x=1.0, y=5.0, z=2.0),
        row(front("left", 0.3, tail=0.0), front("right", 0.2, tail=0.15), x=1.5, y=3.0, z=0.0),
    ]  # the first two are bad (extent 30 %, height 20 %), the last two good
    best = front_warning.best_thresholds(rows)
    assert set(best) == {"run share", "front tail", "x", "y", "z"}
    # Run share: >= 0.6 (the smaller bad) flags the good 0.7 only (1/2); <= 0.8 would flag both goods.
    assert best["run share"] == {"flag_when": ">= 0.6", "false_alarm_rate": 0.5}
    # Front tail: <= 0.2 (the larger bad) flags the good 0.15 (1/2); >= 0.1 would flag both goods (0.5, 0.15).
    assert best["front tail"] == {"flag_when": "<= 0.2", "false_alarm_rate": 0.5}
    # x separates the scenes upward (bads 2, 3; goods 1, 1.5), y downward (bads 1, 2; goods 3, 5).
    assert best["x"] == {"flag_when": ">= 2", "false_alarm_rate": 0.0}
    assert best["y"] == {"flag_when": "<= 2", "false_alarm_rate": 0.0}
    # A good scene at the threshold itself is flagged (>=): z >= 2 flags the good z = 2; z <= 4 would flag both.
    assert best["z"] == {"flag_when": ">= 2", "false_alarm_rate": 0.5}


def test_best_thresholds_without_bad_scenes_is_empty():
    assert front_warning.best_thresholds([row(front(share=0.9), extent=1.0, x=1.0)]) == {}


def test_a_signal_undefined_on_a_bad_scene_is_no_perfect_warning():
    """NaN on a bad scene: the threshold comes from the other bad scenes and NaN scenes count as flagged, so an
    undefined signal cannot pass for one with no false alarms."""
    signals = [float("nan"), 2.0, 1.0, float("nan")]
    errors = [40.0, 30.0, 1.0, 2.0]  # two bad, two good
    rows = [
        {
            "error": {"extent": e, "height": 0.0},
            "fronts": [{"share": 0.1, "tail": 0.0}, {"share": 0.2, "tail": 0.0}],
            "signals": {"energy_ratio": v},
        }
        for v, e in zip(signals, errors, strict=True)
    ]
    best = front_warning.best_thresholds(rows)["energy_ratio"]
    assert best["false_alarm_rate"] == 0.5, best  # the good NaN scene is a false alarm; 1.0 is below 2.0
