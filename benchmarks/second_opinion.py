"""Does a second model's disagreement say when a learned rollout is wrong? Hit and false-alarm rates, measured.

A learned simulator gives no sign of being wrong: its rollout looks like sand whether
its deposit is 2 % or 40 % off. Two models trained apart (another architecture, another
seed) tend to go wrong in different ways, so where their deposits disagree at least one of
them is wrong. For a primary model and a second opinion, on held-out scenes drawn from the
general envelope (``--seed``) and the four canonical scenes, this prints per scene the
primary's extent and height errors against the MPM, the disagreement (the primary's extent
and height against the second model's, %) and whether it is flagged (disagreement above
``--threshold``); with ``--perturb METRES`` instead of ``--second`` the second opinion is the
primary model itself on the same scene with every moving particle shifted by a random offset
of that standard deviation (the same offset in every input frame, so velocities are kept):
a deposit that moves more than the perturbation explains is one the scene does not settle
(sensitive to its initial state, as the MPM's deposits that move with resolution are); with ``--shift METRES``
it is the primary on the scene translated (walls and obstacles too), which a grid processor sees through
another alignment of its lattice: a deposit that moves with the lattice is one the model's own
discretization decides; with ``--mirror`` it is the primary on the scene's mirror image (x -> lo + hi - x, the side
walls swapped: the same physics), which a network that has not learned the symmetry runs otherwise.
Then, for a sweep of thresholds, the share of bad scenes (extent or
height error above 15 %) that are flagged (the hit rate; goal >= 80 %) and of good scenes
that are flagged (false alarms; goal <= 20 %). The datasets are generalization.py's
(``--out``), made on the first run.

Usage::

    python benchmarks/second_opinion.py --model models/sand2d_general.pt \\
        --second runs/sand2d_general_lean/checkpoints/best.pt --held-out 20 --seed 11 --threads 1 [--json]
    python benchmarks/second_opinion.py --model models/sand2d_general.pt --perturb 0.001 --held-out 20 --seed 11
    python benchmarks/second_opinion.py --model models/sand2d_general_fast.pt --shift 0.01 --held-out 20 --seed 11
    python benchmarks/second_opinion.py --model models/sand2d_general_fast.pt --mpm-grid 0.5 --held-out 20 --seed 11
    python benchmarks/second_opinion.py --model models/sand2d_general_fast.pt --mirror --held-out 20 --seed 12
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from generalization import ROOT, dataset

BAD = 15.0
THRESHOLDS = (5.0, 7.5, 10.0, 15.0, 20.0, 30.0, 40.0, 50.0)


DEPOSIT = ("extent_error_pct", "height_error_pct")
"""The deposit measures scored (the others, Sinkhorn among them, would take most of a warning benchmark's time)."""


@functools.cache
def deposit_scoring() -> tuple[tuple[int, ...], tuple]:
    """The installed plugins' kinematic particle types and their ``DEPOSIT`` metrics (the registry loaded once)."""
    from gns_framework.plugins import load_registry

    registry = load_registry()
    return tuple(registry.kinematic_types()), tuple(m for m in registry.metrics() if m.name in DEPOSIT)


def deposit(prediction, case, history, metadata, granular) -> dict[str, float]:
    """Extent and height errors (%) of ``prediction`` against ``case`` beyond its first ``history`` frames."""
    from gns_framework.evaluation.metrics import summarise
    from gns_framework.evaluation.report import score_prediction

    kinematic, metrics = deposit_scoring()
    scores = summarise(
        score_prediction(
            prediction, case, history, metadata, granular_types=granular, kinematic_types=kinematic, metrics=metrics
        )
    )
    return {"extent": float(scores["extent_error_pct"]), "height": float(scores["height_error_pct"])}


def perturbed(case, simulator, history: int, sigma: float, seed: int):
    """``case`` with each moving particle's first ``history`` frames shifted by one N(0, sigma^2) offset per axis."""
    generator = np.random.default_rng(seed)
    moving = simulator.predicted_mask(torch.as_tensor(case.particle_type)).numpy()
    offset = generator.normal(0.0, sigma, size=case.position.shape[1:]) * moving[:, None]
    position = case.position.copy()
    position[:history] += offset.astype(position.dtype)
    return dataclasses.replace(case, position=position)


def shifted(case, shift: float):
    """``case`` translated by ``shift`` metres along every axis, walls and obstacles with it: the same physics,
    another alignment of a grid processor's lattice (fixed in space) with the particles."""
    bounds = None if case.bounds is None else case.bounds + np.float32(shift)
    return dataclasses.replace(case, position=case.position + np.float32(shift), bounds=bounds)


def unchanged(position: np.ndarray) -> np.ndarray:
    return position


def rollouts(case, primary, second, history: int, opinion: dict, seed: int) -> list[tuple]:
    """The two (model, start, back) rollouts of a case, each prediction's positions mapped by ``back`` comparable
    with the case: the primary on it, and the second opinion: ``second`` on it, or (``opinion`` ``perturb``) the
    primary on the case perturbed, or (``shift``) on the case translated, or (``mirror``) on its mirror image."""
    from gns_framework.data.mirror import mirrored, reflected

    if opinion.get("perturb") is not None:
        return [
            (primary, case, unchanged),
            (primary, perturbed(case, primary.simulator, history, opinion["perturb"], seed), unchanged),
        ]
    if opinion.get("shift") is not None:
        return [(primary, case, unchanged), (primary, shifted(case, opinion["shift"]), lambda p: p - opinion["shift"])]
    if opinion.get("mirror"):
        back = functools.partial(reflected, axis=0, bounds=case.bounds)
        return [(primary, case, unchanged), (primary, mirrored(case, 0, case.bounds), back)]
    return [(primary, case, unchanged), (second, case, unchanged)]


def scene_figures(primary, second, data: Path, registry, opinion: dict | None = None) -> dict[str, dict]:
    """Per case of ``data``'s test split: the primary's errors against the MPM and its disagreement with ``second``
    (with ``opinion`` ``perturb`` or ``shift``: with the primary's rollout of the case perturbed or translated;
    ``mpm_grid``: with the MPM's rollout of the same drawn scene at that fraction of the data's grid)."""
    from gns_framework.assembly.data import open_dataset
    from gns_framework.evaluation.candidates import (
        cases_from_split,
        granular_particle_types,
        learned_prediction,
        simulator_candidates,
    )

    opinion = opinion or {}
    data_set = open_dataset(primary.recipe.dataset, registry, data)
    metadata = data_set.metadata()
    history = primary.simulator.setup.history
    granular = granular_particle_types(primary.simulator.setup, registry)
    cases = cases_from_split(data_set.split("test"))
    reduced_mpm = None
    if opinion.get("mpm_grid") is not None:
        reduced_mpm = simulator_candidates(metadata, registry, cases, history, (opinion["mpm_grid"],), (1.0,))[0]
    out = {}
    for case in cases:
        mine = learned_prediction(primary.simulator, case, "cpu", guard=primary.rollout_guard())
        if reduced_mpm is not None:
            theirs = reduced_mpm.simulate(case)
            disagreement = deposit(
                _own_particles(mine, case, history), _as_case(theirs, case, history), history, metadata, granular
            )
        else:
            _, (model, start, back) = rollouts(case, primary, second, history, opinion, seed=len(out))
            theirs = learned_prediction(model.simulator, start, "cpu", guard=model.rollout_guard())
            theirs = dataclasses.replace(theirs, position=back(np.asarray(theirs.position)).astype(np.float32))
            disagreement = deposit(mine, _as_case(theirs, case, history), history, metadata, granular)
        out[case.key] = {
            "error": deposit(mine, case, history, metadata, granular),
            "second_error": deposit(theirs, case, history, metadata, granular),
            "disagreement": disagreement,
        }
    return out


def _as_case(prediction, case, history: int):
    """The second opinion's rollout in place of the truth: its particles, their last input frame repeated as the
    ``history`` input frames (only the frames after them are scored), then its prediction."""
    if prediction.particle_type is None:  # the case's own particles: its input frames
        first = case.position[:history]
        types = case.particle_type
    else:
        first = np.repeat(np.asarray(prediction.start, case.position.dtype)[None], history, axis=0)
        types = np.asarray(prediction.particle_type)
    position = np.concatenate([first, np.asarray(prediction.position, case.position.dtype)])
    return dataclasses.replace(case, position=position, particle_type=types, material_property=None)


def _own_particles(prediction, case, history: int):
    """``prediction`` of ``case``'s particles saying so, to be scored against a cloud of other particles."""
    return dataclasses.replace(prediction, particle_type=case.particle_type, start=case.position[history - 1])


def flag_rates(rows: list[dict], flagged) -> dict[str, float | int]:
    """Hit rate on bad scenes (extent or height error above ``BAD``) and false-alarm rate on good ones of the
    predicate ``flagged(row)``."""
    bad = [r for r in rows if max(r["error"].values()) > BAD]
    good = [r for r in rows if max(r["error"].values()) <= BAD]
    return {
        "bad": len(bad),
        "good": len(good),
        "hit_rate": sum(map(flagged, bad)) / len(bad) if bad else float("nan"),
        "false_alarm_rate": sum(map(flagged, good)) / len(good) if good else float("nan"),
    }


def rates(rows: list[dict], threshold: float) -> dict[str, float | int]:
    """Hit rate on bad scenes and false-alarm rate on good ones when a disagreement above ``threshold`` flags."""
    return {"threshold_pct": threshold, **flag_rates(rows, lambda row: max(row["disagreement"].values()) > threshold)}


def opinion_of(args) -> dict:
    return {"perturb": args.perturb, "shift": args.shift, "mpm_grid": args.mpm_grid, "mirror": args.mirror}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", type=Path, default=ROOT / "models" / "sand2d_general.pt")
    opinion = parser.add_mutually_exclusive_group(required=True)
    opinion.add_argument("--second", type=Path, help="the second opinion: a model trained apart")
    opinion.add_argument(
        "--perturb", type=float, help="the second opinion: the model itself from input frames shifted by this std, m"
    )
    opinion.add_argument(
        "--mpm-grid",
        type=float,
        metavar="SCALE",
        help="the second opinion: the MPM on the same drawn scene at SCALE times the data's grid (e.g. 0.5: about the "
        "learned model's own time)",
    )
    opinion.add_argument(
        "--shift",
        type=float,
        help="the second opinion: the model itself on the scene translated by this many metres along every axis "
        "(walls too): another alignment of a grid processor's lattice",
    )
    opinion.add_argument(
        "--mirror",
        action="store_true",
        help="the second opinion: the model itself on the scene's mirror image (x -> lo + hi - x, side walls swapped)",
    )
    parser.add_argument("--held-out", type=int, default=20)
    parser.add_argument("--seed", type=int, default=7, help="scene seed of the held-out scenes (training used 0)")
    parser.add_argument("--out", type=Path, default=ROOT / "runs" / "generalization", help="datasets are kept here")
    parser.add_argument("--threshold", type=float, default=10.0, help="disagreement that flags a rollout, %%")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)

    from gns_framework.assembly.trained import load_trained
    from gns_framework.plugins import load_registry

    registry = load_registry()
    primary = load_trained(args.model, registry, torch.device("cpu"))
    second = primary if args.second is None else load_trained(args.second, registry, torch.device("cpu"))
    groups: dict[str, dict] = {}
    if args.held_out:
        data = dataset(
            ROOT / "scenes" / "sand_general_2d.yaml", args.out / "held_out", args.held_out, args.seed, registry
        )
        groups["held-out"] = scene_figures(primary, second, data, registry, opinion_of(args))
    canonical = {}
    for scene_path in sorted((ROOT / "scenes" / "canonical").glob("*.yaml")):
        data = dataset(scene_path, args.out / "canonical" / scene_path.stem, 1, None, registry)
        figures = scene_figures(primary, second, data, registry, opinion_of(args))
        # One trajectory drawn per canonical scene: its case goes by the scene's name.
        for figure in figures.values():
            canonical[scene_path.stem] = figure
    groups["canonical"] = canonical

    what = args.second
    if args.perturb is not None:
        what = f"itself from inputs shifted by {args.perturb} m"
    elif args.shift is not None:
        what = f"itself on the scene translated by {args.shift} m"
    elif args.mpm_grid is not None:
        what = f"the MPM at {args.mpm_grid:g} of the data's grid"
    elif args.mirror:
        what = "itself on the scene's mirror image"
    print(f"primary {args.model}, second opinion {what}; % against the MPM, disagreement against the second")
    print(
        f"{'group':<10} {'scene':<26} {'extent':>7} {'height':>7} {'2nd ext':>7} {'2nd hgt':>7} {'dis ext':>7} "
        f"{'dis hgt':>7} flag"
    )
    rows = []
    for group, cases in groups.items():
        for key, row in cases.items():
            e, s, d = row["error"], row["second_error"], row["disagreement"]
            flag = max(d.values()) > args.threshold
            bad = max(e.values()) > BAD
            mark = ("FLAG" if flag else "    ") + (" (bad)" if bad else "")
            print(
                f"{group:<10} {key:<26} {e['extent']:7.1f} {e['height']:7.1f} {s['extent']:7.1f} {s['height']:7.1f} "
                f"{d['extent']:7.1f} {d['height']:7.1f} {mark}"
            )
            rows.append({"group": group, "scene": key, **row})
    sweep = [rates(rows, threshold) for threshold in sorted({args.threshold, *THRESHOLDS})]
    for r in sweep:
        print(
            f"threshold {r['threshold_pct']:5.1f} %: flags {r['hit_rate']:.0%} of {r['bad']} bad scenes "
            f"(goal >= 80 %), {r['false_alarm_rate']:.0%} of {r['good']} good ones (goal <= 20 %)"
        )
    if args.json:
        print(json.dumps({"model": str(args.model), "second": str(what), "rows": rows, "sweep": sweep}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
