"""``gns envelope MODEL [SCENE.yaml]``: what a model was trained on, in a scene file's terms; a scene file checked
against it before any data is generated."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import GnsError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", type=Path, help="a trained checkpoint (e.g. models/sand2d_general.pt)")
    parser.add_argument(
        "scene",
        type=Path,
        nargs="?",
        help="a scene file to check against the model's training, field by field, before generating its data; "
        "exit 1 when something lies outside",
    )


def run(args: argparse.Namespace) -> int:
    from ..assembly.trained import load_trained
    from ..ground_truth.scene_spec import SceneSpec, load_scene
    from ..model.scene_envelope import scene_file_terms, scene_problems
    from ..plugins import load_registry

    scene = load_scene(args.scene) if args.scene is not None else None  # a bad scene file is refused first
    model = load_trained(args.model, load_registry())
    if model.envelope is None:
        raise GnsError(f"{args.model}: records no training envelope (written before envelopes were recorded)")
    provenance = getattr(model.metadata, "generated_from", None)
    trained = SceneSpec.model_validate(provenance["scene"]) if isinstance(provenance, dict) else None
    if scene is None:
        print(f"{args.model} was trained on (step {model.step}):")
        for line in scene_file_terms(trained, model.envelope):
            print(f"  {line}")
        if trained is None:
            print("  (its data was not made by gns generate: no training scene is recorded)")
        return 0
    problems = scene_problems(scene, model.envelope, trained)
    if not problems:
        print(f"{args.scene}: inside the envelope of {args.model}")
        return 0
    print(f"{args.scene}: {len(problems)} field(s) outside the envelope of {args.model}:")
    for field, why in problems:
        print(f"  {field}: {why}")
    return 1
