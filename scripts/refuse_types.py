"""Record in a checkpoint that data holding some particle types is refused, and why.

A model can be trained on a material and still be wrong on scenes that hold it: its
evaluation says so (``benchmarks/generalization.py``). Recorded in the checkpoint's
envelope (``refused_types``), the refusal travels with the model: ``gns rollout``,
``evaluate``, ``invert`` and the demo then refuse such data, naming the material and
the reason, unless ``--outside-envelope`` is passed. The output is a new file (an
existing one is refused); everything else in the checkpoint is kept as it was.

Usage::

    python scripts/refuse_types.py models/sand2d_general.pt --type 3 \\
        --reason "22-64 % off on held-out scenes with obstacles" --out /tmp/refusing.pt
    python scripts/refuse_types.py refusing.pt --clear --out accepting.pt
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path


def refuse(checkpoint: Path, out: Path, types: list[int], reason: str | None, clear: bool = False) -> dict[str, str]:
    """Write ``checkpoint`` to ``out`` with ``types`` refused for ``reason``; returns the refusals now recorded."""
    from gns_framework.errors import CheckpointError, GnsError
    from gns_framework.io.checkpoint import load_checkpoint, save_checkpoint
    from gns_framework.model.envelope import Envelope

    if out.exists():
        raise GnsError(f"{out}: exists; choose another --out (nothing is overwritten)")
    state = load_checkpoint(checkpoint)
    if not isinstance(state.get("envelope"), dict):
        raise CheckpointError(f"{checkpoint}: envelope: missing; retrain or fine-tune it to record one")
    envelope = Envelope.from_dict(state["envelope"])
    unknown = [t for t in types if t not in envelope.particle_types]
    if unknown:
        raise GnsError(
            f"--type {unknown[0]}: the model was not trained on it (it refuses it anyway); "
            f"its types: {envelope.particle_types}"
        )
    refused = {} if clear else dict(envelope.refused_types)
    refused.update({str(t): str(reason) for t in types})
    state["envelope"] = replace(envelope, refused_types=refused).to_dict()
    save_checkpoint(out, state)
    return refused


def main(argv: list[str] | None = None) -> int:
    from gns_framework.errors import GnsError

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint", type=Path)
    parser.add_argument("--type", type=int, action="append", default=[], help="particle type id to refuse (repeat)")
    parser.add_argument("--reason", help="what the evaluation measured on data holding it (required with --type)")
    parser.add_argument("--clear", action="store_true", help="drop the refusals recorded so far")
    parser.add_argument("--out", type=Path, required=True, help="the new checkpoint (must not exist)")
    args = parser.parse_args(argv)
    if args.type and not args.reason:
        parser.error("--type needs --reason: say what was measured on data holding it")
    if not args.type and not args.clear:
        parser.error("give --type TYPE --reason TEXT, or --clear")
    try:
        refused = refuse(args.checkpoint, args.out, args.type, args.reason, args.clear)
    except GnsError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {args.out}: refuses {refused or 'nothing it was trained on'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
