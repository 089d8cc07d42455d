"""benchmarks/learned_warning.py: the logistic fit against a known model, the threshold that flags a share of the
bad scenes, the cross-validated choice on rows where one signal tells bad from good, its refusal of too few bad
scenes, and the report's rates per group through main() on hand-made rows."""

from __future__ import annotations

import json

import numpy as np
import pytest
from load_script import load_script

learned_warning = load_script("benchmarks/learned_warning.py")


def row(share: float, bad: bool, rng: np.random.Generator, group: str = "held-out s1", scene: str = "s") -> dict:
    """A front_warning row whose leading front ran ``share`` of the extent, the other signals drawn at random, and
    an extent error above (``bad``) or below the 15 % line."""
    signals = {
        "tan_phi": rng.uniform(0.5, 0.9),
        "aspect_over_tan_phi": rng.uniform(0.8, 3.0),
        "sand_particles": int(rng.integers(300, 3000)),
        "energy_ratio": rng.uniform(0.1, 1.0),
        "runout_ratio": rng.uniform(1.0, 3.0),
        "end_energy": 10 ** rng.uniform(-6, -3),
    }
    front = {"side": "right", "run": 1.0, "share": share, "gap": rng.uniform(0, 50), "at_wall": False, "tail": 0.1}
    behind = {**front, "side": "left", "share": 0.0}
    return {
        "group": group,
        "scene": scene,
        "error": {"extent": 30.0 if bad else 2.0, "height": 1.0},
        "fronts": [front, behind],
        "signals": signals,
    }


def separable_rows(count: int, seed: int) -> list[dict]:
    """Rows whose run share alone decides: bad ones ran 0.6-0.9 of their extent, good ones 0-0.4; one in eight bad."""
    rng = np.random.default_rng(seed)
    return [
        row(rng.uniform(0.6, 0.9), True, rng) if k % 8 == 0 else row(rng.uniform(0.0, 0.4), False, rng)
        for k in range(count)
    ]


def test_the_fit_recovers_a_known_logistic_model():
    # 20,000 draws from log-odds 1.5 x0 - 2 x1 + 0.5: each weight's standard error is about 0.03, so 0.15 is 5 of
    # them; a fit that dropped the intercept or flipped a sign would be off by 0.5 or more.
    rng = np.random.default_rng(0)
    x = rng.standard_normal((20_000, 2))
    truth = np.array([1.5, -2.0, 0.5])
    y = (rng.uniform(size=len(x)) < 1 / (1 + np.exp(-(x @ truth[:2] + truth[2])))).astype(float)
    weights = learned_warning.fit(x, y, l2=1e-6)
    assert np.abs(weights - truth).max() < 0.15


def test_the_penalty_shrinks_the_weights_and_not_the_intercept():
    rng = np.random.default_rng(1)
    x = rng.standard_normal((400, 2))
    y = (x[:, 0] + rng.standard_normal(400) > 1.0).astype(float)
    free, shrunk = learned_warning.fit(x, y, 1e-6), learned_warning.fit(x, y, 1e4)
    assert abs(shrunk[0]) < 0.05 * abs(free[0])
    # With the weights near 0, the intercept is the log-odds of the base rate.
    base = y.mean()
    assert shrunk[2] == pytest.approx(np.log(base / (1 - base)), abs=0.05)


def test_the_threshold_flags_the_asked_share_of_the_bad_scores():
    score = np.array([3.0, 2.0, 1.0, 0.0, -1.0, 5.0, -3.0])
    bad = np.array([True, True, True, True, True, False, False])
    assert learned_warning.threshold_for(score, bad, 0.8) == 0.0  # 4 of the 5 bad at or above it
    assert learned_warning.threshold_for(score, bad, 1.0) == -1.0
    assert learned_warning.threshold_for(score, bad, 0.2) == 3.0


def test_cross_validation_on_rows_where_the_run_share_decides():
    warning = learned_warning.trained_warning(separable_rows(160, 0), [1.0, 10.0], folds=5, hit=0.8)
    for tried in warning.cross_validated:
        assert tried["hit_rate"] >= 0.8 and tried["false_alarm_rate"] == 0.0
    weights = dict(zip(warning.record.inputs, warning.record.weights, strict=True))
    assert max(weights, key=lambda name: abs(weights[name])) == "run share" and weights["run share"] > 0
    assert warning.l2 == 10.0  # equal false alarms: the stronger penalty
    fresh = separable_rows(80, 1)
    flags = warning.flags(fresh)
    bad = np.array([learned_warning.is_bad(r) for r in fresh])
    assert flags[bad].all() and not flags[~bad].any()


def test_too_few_bad_training_scenes_are_refused_with_the_counts():
    rows = separable_rows(24, 2)  # 3 bad
    with pytest.raises(ValueError, match="3 bad and 21 good training scenes: fewer than 5 folds"):
        learned_warning.trained_warning(rows, [1.0], folds=5, hit=0.8)


def test_main_reports_each_group_and_all(monkeypatch, capsys):
    training = separable_rows(160, 3)
    rng = np.random.default_rng(4)
    held = [
        row(0.8, True, rng, "held-out s7", "a"),
        row(0.7, True, rng, "held-out s7", "b"),
        row(0.1, False, rng, "held-out s7", "c"),
        row(0.75, False, rng, "canonical", "d"),  # a good scene that looks bad: a false alarm
    ]
    monkeypatch.setattr(
        learned_warning, "scene_rows", lambda *a, **k: {r["scene"] + str(i): r for i, r in enumerate(training)}
    )
    monkeypatch.setattr(learned_warning, "gathered_rows", lambda *a: held)
    args = ["--model", "models/sand2d_general_fast.pt", "--seed", "7", "--out", "unused", "--folds", "5", "--json"]
    assert learned_warning.main(args) == 0
    out = capsys.readouterr().out
    result = json.loads(out.strip().splitlines()[-1])
    assert result["rates"]["held-out s7"] == {"bad": 2, "good": 1, "hit_rate": 1.0, "false_alarm_rate": 0.0}
    assert result["rates"]["canonical"]["false_alarm_rate"] == 1.0
    assert result["rates"]["all"] == {"bad": 2, "good": 2, "hit_rate": 1.0, "false_alarm_rate": 0.5}
    assert "held-out s7   2 of 2 bad, 0 of 1 good flagged" in out


def test_main_names_the_data_when_it_has_too_few_bad_scenes(monkeypatch, capsys):
    training = separable_rows(24, 5)  # 3 bad
    monkeypatch.setattr(learned_warning, "scene_rows", lambda *a, **k: {str(i): r for i, r in enumerate(training)})
    args = ["--model", "models/sand2d_general_fast.pt", "--data", "my_data", "--seed", "7", "--out", "unused"]
    with pytest.raises(SystemExit) as exit_:
        learned_warning.main([*args, "--folds", "5"])
    assert exit_.value.code == 2
    assert "my_data: 3 bad and 21 good training scenes: fewer than 5 folds" in capsys.readouterr().err
