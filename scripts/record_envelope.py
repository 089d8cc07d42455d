"""Record the training envelope in a checkpoint written before checkpoints carried one.

Measures the envelope (gns_framework.model.envelope) on the training split of the data
the model was trained on, seen as its recipe sees it (frame stride), and writes the
checkpoint with it to a new file; the input is never changed. Used once for the shipped
models/sand2d_fast.pt and models/sand2d_throw.pt (regenerate their data first with the
commands of models/README.md: generation is deterministic, so it is the same data).

With ``--fields``, only those fields of the measured envelope are written and the rest of the stored one is kept:
how the shipped general sand models got ``fixed_properties`` (their obstacles' friction, never recorded: 0) without
their other figures moving with later changes to how those are measured.

Usage::

    python scripts/record_envelope.py models/sand2d_fast.pt --dataset data/demo_sand_2d --out sand2d_fast.pt
    python scripts/record_envelope.py models/sand2d_general.pt --dataset data/sand_general_2d \
        --fields fixed_properties --out sand2d_general.pt
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np


def main(argv: list[str] | None = None) -> int:
    from gns_framework.assembly.data import open_dataset
    from gns_framework.assembly.trained import load_trained
    from gns_framework.data.metadata import compute_statistics
    from gns_framework.io.checkpoint import load_checkpoint, save_checkpoint
    from gns_framework.model.envelope import measure_envelope
    from gns_framework.plugins import load_registry

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint", type=Path)
    parser.add_argument("--dataset", type=Path, required=True, help="the data the model was trained on")
    parser.add_argument("--out", type=Path, required=True, help="new checkpoint file (must not exist)")
    parser.add_argument(
        "--fields", nargs="+", metavar="FIELD", help="record only these envelope fields; keep the stored others"
    )
    args = parser.parse_args(argv)
    if args.out.exists():
        print(f"{args.out}: exists; choose a new file", file=sys.stderr)
        return 2
    registry = load_registry()
    loaded = load_trained(args.checkpoint, registry)
    dataset = open_dataset(loaded.recipe.dataset, registry, args.dataset)
    train = dataset.split("train")
    # The data must be what the model was trained on: its normalisation statistics say so.
    kinematic = registry.kinematic_types()
    measured = compute_statistics(list(train), kinematic)
    stored = loaded.metadata.to_json_dict()
    for key in ("vel_std", "acc_std"):
        if not np.allclose(measured[key], stored[key], rtol=1e-6):
            print(
                f"{args.dataset}: {key} {measured[key]} differs from the model's {stored[key]}: not its training data",
                file=sys.stderr,
            )
            return 2
    setup = loaded.simulator.setup
    envelope = measure_envelope(
        dataset.metadata(),
        train,
        setup,
        {t: registry.material_by_type(t).name for t in setup.particle_types},
        loaded.recipe.dataset.frame_stride,
    )
    state = load_checkpoint(args.checkpoint, map_location="cpu")
    state.pop("format", None)
    recorded = envelope.to_dict()
    if args.fields:
        unknown = sorted(set(args.fields) - set(recorded))
        stored = state.get("envelope")
        if unknown or not isinstance(stored, dict):
            why = f"unknown field(s) {unknown}; the fields are {sorted(recorded)}" if unknown else "it holds none"
            print(f"--fields: {why}", file=sys.stderr)
            return 2
        recorded = {**stored, **{name: recorded[name] for name in args.fields}}
        envelope = type(envelope).from_dict(recorded)
    save_checkpoint(args.out, {**state, "envelope": recorded})
    for quantity, trained in envelope.rows():
        print(f"{quantity:<22} {trained}")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
