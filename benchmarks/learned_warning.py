"""A warning learned from the model's own training scenes: does it flag the held-out scenes the model misses?

The learned sand model misses its training scenes about as often as held-out ones (benchmarks/training_fit.py: 20
of 250 over 15 %, the same kinds of scene), so its training split is a labelled set of its own failures. This fits
a logistic regression on signals from the scene and the one learned rollout (front_warning.py's: nothing needs a
simulator) to "extent or height more than 15 % off" on the training trajectories, chooses its strength and
threshold by cross-validation on them alone, and only then scores held-out seeds and the canonical scenes, which
it never saw: the hit rate (bad scenes flagged, goal >= 80 %) and false-alarm rate (good scenes flagged, goal
<= 20 %) of issue 46, item 5.

Signals (each one a number per rollout; physics in front_warning.py):

- the leading front's run share (its run over the final extent: a front the flow placed), whether a wall holds it,
  and the log of its gap to the next obstacle or wall ahead, in particle spacings (a front stopping just short of
  one is undecided);
- the tallest column's tan(phi) and aspect over tan(phi) (how far sand of that friction should run);
- the log of the sand's particle count (small scenes are few particles per front);
- the log of the energy ratio (released potential energy over the work of Coulomb friction along the horizontal
  path: a front that stopped short of where its energy would carry it raises it), of the runout ratio, of the
  kinetic energy left at the end and of the fronts' motion then.

Fit. The signals are standardised with the training rows' mean and spread; the penalised log-likelihood (L2 on the
weights, not the intercept) is minimised by scipy's L-BFGS. For each strength in ``--l2`` the training rows are
split into ``--folds`` folds and each fold scored by the fit on the others; the threshold is the out-of-fold score
that flags ``--hit`` of the bad training scenes, and the strength kept is the one whose out-of-fold false-alarm
rate is lowest (ties: the stronger). The final weights are fitted on every training row.

The fitted warning is :class:`gns_framework.model.deposit_warning.DepositWarning`, scored exactly as ``gns
rollout`` and ``gns evaluate`` score it; ``--record NEW.pt`` writes the model's checkpoint with it to a new file.

Usage (the held-out datasets are generalization.py's; rollouts are cached as front_warning.py's are)::

    python benchmarks/learned_warning.py --model models/sand2d_general_fast.pt --seed 11 12 13 \\
        --out runs/generalization runs/gen_r3_s12 runs/gen_r3_s13 --threads 1 --cache /tmp/front_warning/rollouts \\
        [--record warned.pt]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from front_warning import add_scene_arguments, gathered_rows, is_bad, parsed_with_model, scene_rows
from second_opinion import BAD, flag_rates

from gns_framework.model.deposit_signals import DepositSignals, Front
from gns_framework.model.deposit_warning import INPUTS, DepositWarning, warning_inputs


def row_signals(row: dict) -> DepositSignals:
    """The signals of one front_warning row, as the warning reads them."""
    return DepositSignals([Front(**f) for f in row["fronts"]], row["signals"])


def design(rows: list[dict]) -> tuple[np.ndarray, np.ndarray]:
    """The inputs (R, S) and the labels (R,), 1.0 where the model is more than ``BAD`` % off, of ``rows``."""
    x = np.array([warning_inputs(row_signals(row)) for row in rows], dtype=float).reshape(len(rows), len(INPUTS))
    return x, np.array([float(is_bad(row)) for row in rows])


def fit(x: np.ndarray, y: np.ndarray, l2: float) -> np.ndarray:
    """Logistic-regression weights (S + 1,), the intercept last, of standardised signals ``x`` (R, S) and labels
    ``y`` (R,): the minimum of the mean negative log-likelihood plus ``l2`` / 2 |w|^2 / R."""
    from scipy.optimize import minimize

    design_1 = np.hstack([x, np.ones((len(x), 1))])
    penalty = np.r_[np.ones(x.shape[1]), 0.0] * l2

    def objective(w: np.ndarray) -> tuple[float, np.ndarray]:
        z = design_1 @ w
        # log(1 + e^z) - y z, written so that neither large positive nor large negative z overflows.
        loss = np.logaddexp(0.0, z) - y * z
        gradient = design_1.T @ (1.0 / (1.0 + np.exp(-z)) - y) + penalty * w
        return float(loss.sum() + 0.5 * (penalty * w * w).sum()) / len(y), gradient / len(y)

    result = minimize(objective, np.zeros(x.shape[1] + 1), jac=True, method="L-BFGS-B")
    return result.x


def scores(x: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Log-odds (R,) of standardised signals ``x`` (R, S) under ``weights`` (S + 1,)."""
    return x @ weights[:-1] + weights[-1]


def threshold_for(score: np.ndarray, bad: np.ndarray, hit: float) -> float:
    """The highest score at or above which at least ``hit`` of the bad rows' scores lie."""
    ranked = np.sort(score[bad])[::-1]
    return float(ranked[int(np.ceil(hit * len(ranked))) - 1])


@dataclasses.dataclass(frozen=True)
class LearnedWarning:
    """A fitted warning (the record a checkpoint stores) and how it was chosen.

    Attributes:
        record: standardisation, weights and threshold, scored as ``gns rollout`` and ``gns evaluate`` score it.
        l2: the strength kept.
        cross_validated: per strength tried, its out-of-fold hit and false-alarm rates.
    """

    record: DepositWarning
    l2: float
    cross_validated: list[dict]

    def score(self, rows: list[dict]) -> np.ndarray:
        return np.array([self.record.score_signals(row_signals(row)).score for row in rows])

    def flags(self, rows: list[dict]) -> np.ndarray:
        return self.score(rows) >= self.record.threshold


def folds_of(count: int, folds: int, seed: int) -> list[np.ndarray]:
    """``folds`` disjoint index sets covering ``range(count)``, shuffled by ``seed``."""
    order = np.random.default_rng(seed).permutation(count)
    return [order[k::folds] for k in range(folds)]


def trained_warning(rows: list[dict], l2s: list[float], folds: int, hit: float, seed: int = 0) -> LearnedWarning:
    """The warning fitted to ``rows`` (the model's training scenes), its strength and threshold chosen by
    cross-validation as the module says."""
    x, y = design(rows)
    bad = y > 0
    if bad.sum() < folds or (~bad).sum() < folds:
        raise ValueError(f"{int(bad.sum())} bad and {int((~bad).sum())} good training scenes: fewer than {folds} folds")
    mean, scale = x.mean(axis=0), x.std(axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    z = (x - mean) / scale
    tried = []
    for l2 in l2s:
        out_of_fold = np.empty(len(y))
        for held in folds_of(len(y), folds, seed):
            kept = np.setdiff1d(np.arange(len(y)), held)
            out_of_fold[held] = scores(z[held], fit(z[kept], y[kept], l2))
        threshold = threshold_for(out_of_fold, bad, hit)
        flagged = out_of_fold >= threshold
        tried.append(
            {
                "l2": l2,
                "threshold": threshold,
                "hit_rate": float(flagged[bad].mean()),
                "false_alarm_rate": float(flagged[~bad].mean()),
            }
        )
    best = min(tried, key=lambda t: (t["false_alarm_rate"], -t["l2"]))
    weights = fit(z, y, best["l2"])
    record = DepositWarning(
        inputs=tuple(INPUTS),
        mean=tuple(map(float, mean)),
        scale=tuple(map(float, scale)),
        weights=tuple(map(float, weights[:-1])),
        intercept=float(weights[-1]),
        threshold=best["threshold"],
        error_pct=BAD,
        fitted_on=(
            f"{len(y)} training scenes ({int(bad.sum())} over {BAD:g} %); out of fold it flagged "
            f"{best['hit_rate']:.0%} of those and {best['false_alarm_rate']:.0%} of the others (l2 {best['l2']:g})"
        ),
    )
    return LearnedWarning(record, best["l2"], tried)


def report(warning: LearnedWarning, training: list[dict], rows: list[dict]) -> dict:
    """Print the choice, the weights, the held-out table and the rates per group and pooled; return them."""
    print(f"training scenes: {len(training)}, {int(sum(map(is_bad, training)))} over {BAD:g} %")
    for t in warning.cross_validated:
        print(
            f"  l2 {t['l2']:<5g} out-of-fold: flags {t['hit_rate']:.0%} of bad, {t['false_alarm_rate']:.0%} of good"
            f"{'  <- kept' if t['l2'] == warning.l2 else ''}"
        )
    print("weights on standardised signals (log-odds per standard deviation):")
    for name, weight in zip(warning.record.inputs, warning.record.weights, strict=True):
        print(f"  {name:<22} {weight:+.2f}")
    score = warning.score(rows)
    threshold = warning.record.threshold
    flagged = {id(row): bool(s >= threshold) for row, s in zip(rows, score, strict=True)}
    print(f"\n{'group':<13} {'scene':<24} {'extent':>6} {'height':>6} {'score':>6} flag")
    for row, s in zip(rows, score, strict=True):
        mark = ("FLAG" if flagged[id(row)] else "    ") + (" (bad)" if is_bad(row) else "")
        print(
            f"{row['group']:<13} {row['scene']:<24} {row['error']['extent']:6.1f} {row['error']['height']:6.1f} "
            f"{s:6.2f} {mark}"
        )
    groups = {}
    for group in dict.fromkeys(row["group"] for row in rows):
        groups[group] = flag_rates([r for r in rows if r["group"] == group], lambda r: flagged[id(r)])
    groups["all"] = flag_rates(rows, lambda r: flagged[id(r)])
    print(f"\nthreshold {threshold:.2f} (log-odds); goal: >= 80 % of bad flagged, <= 20 % of good")
    for group, rates in groups.items():
        hits = round(rates["hit_rate"] * rates["bad"]) if rates["bad"] else 0
        alarms = round(rates["false_alarm_rate"] * rates["good"]) if rates["good"] else 0
        print(f"  {group:<13} {hits} of {rates['bad']} bad, {alarms} of {rates['good']} good flagged")
    return {
        "l2": warning.l2,
        "threshold": threshold,
        "cross_validated": warning.cross_validated,
        "weights": dict(zip(warning.record.inputs, warning.record.weights, strict=True)),
        "intercept": warning.record.intercept,
        "scores": {f"{row['group']}/{row['scene']}": float(s) for row, s in zip(rows, score, strict=True)},
        "rates": groups,
    }


def record(model: Path, warning: LearnedWarning, unseen: dict, out: Path) -> None:
    """Write ``model``'s checkpoint with ``warning`` (and its rates on the unseen scenes, in its description) to
    ``out``."""
    from gns_framework.io.checkpoint import load_checkpoint, save_checkpoint

    state = load_checkpoint(model, map_location="cpu")
    state.pop("format", None)
    fitted_on = (
        f"{warning.record.fitted_on}; on {unseen['bad'] + unseen['good']} scenes it never saw it flagged "
        f"{unseen['hit_rate']:.0%} of {unseen['bad']} over {BAD:g} % and {unseen['false_alarm_rate']:.0%} of "
        f"{unseen['good']} others"
    )
    stored = dataclasses.replace(warning.record, fitted_on=fitted_on)
    save_checkpoint(out, {**state, "deposit_warning": stored.to_dict()})
    print(f"wrote {out} with the warning ({fitted_on})")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_scene_arguments(parser)
    parser.add_argument("--data", type=Path, help="the model's training data (default: its recipe's dataset path)")
    parser.add_argument("--limit", type=int, help="fit on the first N training trajectories only")
    parser.add_argument("--folds", type=int, default=10, help="cross-validation folds on the training scenes")
    parser.add_argument("--hit", type=float, default=0.8, help="share of bad training scenes the threshold flags")
    parser.add_argument(
        "--l2", type=float, nargs="+", default=[0.3, 1.0, 3.0, 10.0], help="penalty strengths to choose from"
    )
    parser.add_argument("--json", action="store_true", help="also print the fit and rates as one JSON line")
    parser.add_argument(
        "--record",
        type=Path,
        metavar="NEW.pt",
        help="write the model's checkpoint with the fitted warning to this new file (gns rollout and gns evaluate "
        "then score every rollout with it); the model's own file is never changed",
    )
    args, registry, model = parsed_with_model(parser, argv)
    if args.record is not None and args.record.exists():
        parser.error(f"--record {args.record}: exists; choose a new file")
    data = args.data or Path(model.recipe.dataset.path)
    cache = None if args.cache is None else args.cache / args.model.stem / "train"
    training = list(scene_rows(model, data, registry, cache, split="train", limit=args.limit).values())
    try:
        warning = trained_warning(training, args.l2, args.folds, args.hit)
    except ValueError as error:
        parser.error(f"{data}: {error}")
    rows = gathered_rows(args, registry, lambda data, rollouts: scene_rows(model, data, registry, rollouts))
    print(f"{args.model}: a warning fitted on its {len(training)} training scenes, scored on scenes it never saw")
    summary = report(warning, training, rows)
    if args.record is not None:
        record(args.model, warning, summary["rates"]["all"], args.record)
    if args.json:
        print(json.dumps({"model": str(args.model), **summary}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
