"""``gns import-geoelements``: turn a geoelements/gns checkpoint into a gns-framework checkpoint."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..importers.geoelements import NOISE_STD, import_geoelements_checkpoint
from ..io.checkpoint import save_checkpoint
from ..io.run_folder import RunFolder
from ..plugins import load_registry
from ..safe_names import safe_component


def _type_ids(text: str) -> list[int]:
    try:
        return [int(t) for t in text.split(",") if t.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integer type ids, got {text!r}") from None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", type=Path, help="geoelements model file (model-<step>.pt)")
    parser.add_argument(
        "--dataset",
        type=Path,
        required=True,
        help="the geoelements dataset folder the model was trained on (metadata.json, train.npz, ...)",
    )
    parser.add_argument("--metadata", type=Path, help="metadata.json to use (default: the dataset's)")
    parser.add_argument(
        "--train-state", type=Path, help="geoelements train state (train_state-<step>.pt): resume training"
    )
    parser.add_argument(
        "--particle-types",
        type=_type_ids,
        help="type ids of the scene, e.g. 5 or 3,6 (default: every row of the model's type embedding)",
    )
    parser.add_argument(
        "--noise-std",
        type=float,
        default=NOISE_STD,
        help=f"the --noise_std the model was trained with (default {NOISE_STD}); it enters the normalisation",
    )
    parser.add_argument("--name", help="recipe name of the imported run (default: imported-<model file stem>)")
    parser.add_argument(
        "--out", type=Path, help="checkpoint to write (default: runs/<name>/checkpoints/checkpoint-<step>.pt)"
    )


def run(args: argparse.Namespace) -> int:
    registry = load_registry()
    imported = import_geoelements_checkpoint(
        args.model,
        args.metadata or args.dataset,
        train_state=args.train_state,
        particle_types=args.particle_types,
        noise_std=args.noise_std,
        registry=registry,
    )
    name = args.name or f"imported-{args.model.stem}"
    dataset = {"name": "npz", "path": str(args.dataset)}
    state = imported.checkpoint_state(name, dataset, registry)
    out = args.out or RunFolder(Path("runs") / safe_component(name)).checkpoint(imported.step)
    out.parent.mkdir(parents=True, exist_ok=True)
    save_checkpoint(out, state)
    spec, setup = imported.model, imported.setup
    print(
        f"{out}: imported {imported.source} (step {imported.step}): latent {spec.latent_size}, "
        f"{spec.processor.params['message_passing_steps']} message-passing steps, {spec.mlp_hidden_layers} hidden "
        f"layers of {spec.mlp_hidden_size}, particle types {list(setup.particle_types)}"
        + (", with optimizer state" if imported.optimizer_state is not None else "")
    )
    return 0
