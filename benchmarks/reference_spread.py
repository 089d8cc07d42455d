"""How far the simulator's own deposit moves between equally valid runs of one scene: the floor under a learned error.

The held-out data is one run of the MLS-MPM per drawn scene, its particles laid on a lattice with a random jitter
(0.2 spacings). Another jitter is as valid a sample of the same scene; so is a smaller time step. Per held-out
scene (and canonical scene) this runs the MPM again on the drawn scene with a fresh jitter, at the data's grid and
time step (and at the other ``--substeps-scale`` given, on the same fresh jitter), and prints each run's extent and
height difference from the data beside the learned model's error (its rollouts shared with the warning benchmarks
through ``--cache``). Where the simulator's own runs of a scene are further apart than the learned model is from
one of them, no model can be held to a worst case below that spread there.

Usage::

    python benchmarks/reference_spread.py --seed 12 13 --out runs/gen_r3_s12 runs/gen_r3_s13 --threads 2 \\
        --cache /tmp/front_warning/rollouts [--substeps-scale 1 2] [--json]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from front_warning import add_scene_arguments, gathered_rows, learned_rollout, parsed_with_model
from second_opinion import BAD, deposit


def scene_rows(model, data: Path, registry, substep_scales: tuple[float, ...], cache: Path | None) -> dict[str, dict]:
    """Per case of ``data``'s test split: the learned extent and height errors against the data (%) and, per
    substep scale, those of the MPM's run of the same drawn scene with a fresh lattice jitter."""
    from gns_framework.assembly.data import open_dataset
    from gns_framework.evaluation.candidates import cases_from_split, granular_particle_types, simulator_candidates

    data_set = open_dataset(model.recipe.dataset, registry, data)
    metadata = data_set.metadata()
    history = model.simulator.setup.history
    granular = granular_particle_types(model.simulator.setup, registry)
    cases = cases_from_split(data_set.split("test"))
    runs = simulator_candidates(metadata, registry, cases, history, (1.0,), substep_scales, fresh_jitter=True)
    out = {}
    for case in cases:
        out[case.key] = {
            "learned": deposit(learned_rollout(model, case, cache), case, history, metadata, granular),
            "mpm": {
                f"{scale:g}": deposit(run.simulate(case), case, history, metadata, granular)
                for scale, run in zip(substep_scales, runs, strict=True)
            },
        }
    return out


def spread(row: dict) -> float:
    """The largest extent or height difference from the data among the simulator's other runs of the scene (%)."""
    return max(max(run["extent"], run["height"]) for run in row["mpm"].values())


def worst(errors: dict[str, float]) -> float:
    return max(errors["extent"], errors["height"])


def report(rows: list[dict]) -> dict:
    """Print the per-scene table and the summary; return the summary."""
    scales = list(rows[0]["mpm"])
    head = " | ".join(f"MPM fresh jitter x{s} substeps extent / height" for s in scales)
    print(f"| group | scene | learned extent / height | {head} |")
    print("|---|---|---:|" + "---:|" * len(scales))
    for row in sorted(rows, key=lambda r: -worst(r["learned"])):
        runs = " | ".join(f"{run['extent']:.1f} / {run['height']:.1f} %" for run in row["mpm"].values())
        learned = row["learned"]
        print(f"| {row['group']} | {row['scene']} | {learned['extent']:.1f} / {learned['height']:.1f} % | {runs} |")
    bad = [r for r in rows if worst(r["learned"]) > BAD]
    spreads = [spread(r) for r in rows]
    summary = {
        "scenes": len(rows),
        "spread_median_pct": statistics.median(spreads),
        "spread_worst_pct": max(spreads),
        "spread_over_bad": sum(s > BAD for s in spreads),
        "spread_over_10": sum(s > 10.0 for s in spreads),
        "learned_over_bad": len(bad),
        "bad_with_spread_over_10": sum(spread(r) > 10.0 for r in bad),
        "learned_beyond_spread_plus_bad": sum(worst(r["learned"]) > spread(r) + BAD for r in rows),
    }
    print(
        f"\nthe simulator's own spread (largest extent or height difference of its other runs from the data): median "
        f"{summary['spread_median_pct']:.1f} %, worst {summary['spread_worst_pct']:.1f} %, over {BAD:g} % on "
        f"{summary['spread_over_bad']} and over 10 % on {summary['spread_over_10']} of {len(rows)} scenes"
    )
    print(
        f"learned worse than {BAD:g} % on {len(bad)} scenes, {summary['bad_with_spread_over_10']} of them with a "
        f"spread over 10 %; learned further than the spread plus {BAD:g} % on "
        f"{summary['learned_beyond_spread_plus_bad']}"
    )
    return summary


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_scene_arguments(parser)
    parser.add_argument(
        "--substeps-scale",
        type=float,
        nargs="+",
        default=[1.0],
        help="time steps of the fresh-jitter runs, as multiples of the data's substeps per frame",
    )
    parser.add_argument("--json", action="store_true", help="also print the rows and summary as one JSON line")
    args, registry, model = parsed_with_model(parser, argv)
    scales = tuple(args.substeps_scale)
    rows = gathered_rows(args, registry, lambda data, rollouts: scene_rows(model, data, registry, scales, rollouts))
    print(f"{args.model}: % against the MPM run that made the data (learned), and between the MPM's own runs")
    summary = report(rows)
    if args.json:
        print(json.dumps({"model": str(args.model), "rows": rows, **summary}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
