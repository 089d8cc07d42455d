"""benchmarks/front_warning.py: the rule's flag at its thresholds and its rates over the grid, and the tuned
thresholds of the other candidates, on hand-made rows whose answers are derived by hand (the signals themselves are
tests/evaluation/test_deposit_signals.py's)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

import front_warning

from gns_framework.model.deposit_signals import Front, fronts

REL = 1e-9
H = 0.125


def test_the_rule_flags_the_front_that_ran_far_toward_an_obstacle_and_not_the_other():
    # The synthetic column of tests/evaluation/test_deposit_signals.py: the right front runs 6 spacings of a
    # 1.375 m extent (share 6/11) and ends 2 spacings before a block; the left one runs 1 spacing.
    x, y = np.meshgrid(H * np.arange(5), H * np.arange(5))
    start = np.stack([x.ravel(), y.ravel()], axis=1)
    final = start.copy()
    final[:, 0] = -0.125 + start[:, 0] / 0.5 * 1.375
    path = start[None] + np.linspace(0.0, 1.0, 20)[:, None, None] * (final - start)[None]
    bx, by = np.meshgrid(1.5 + H * np.arange(3), H * np.arange(3))
    block = np.stack([bx.ravel(), by.ravel()], axis=1)
    sides = {f.side: f for f in fronts(path, start, block, np.array([[-1.0, 3.0], [0.0, 2.0]]), H)}
    assert front_warning.undecided(sides["right"]) and not front_warning.undecided(sides["left"])
    held = Front("right", run=0.75, share=0.6, gap=1.0, at_wall=True, tail=0.0)
    assert not front_warning.undecided(held), "a front a wall holds is placed by the wall"


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
