"""Every recipe says how to make its data: one ``# Data:`` command that writes the folder it trains on.

Data joined from several generated datasets (``python scripts/merge_datasets.py A B --out C``)
names its parts, each written by a ``gns generate`` line of the same comment block.

For ``gns generate`` the scene must load and hold what the recipe's model expects
(its materials and material properties); for ``gns convert`` the command must
parse. Both must write ``dataset.path``. The commands themselves are tested
elsewhere: generation in tests/ground_truth, the periodic recipe's conversion in
tests/cli/test_convert.py.
"""

from __future__ import annotations

import shlex
from pathlib import Path

import pytest
import yaml
from load_script import load_script

from gns_framework.cli import build_parser
from gns_framework.ground_truth.scene_spec import load_scene
from gns_framework.plugins import load_registry

ROOT = Path(__file__).resolve().parents[1]
RECIPES = sorted((ROOT / "recipes").rglob("*.yaml"))


MERGE = ["python", "scripts/merge_datasets.py"]


def data_command(recipe: Path) -> list[str]:
    """The ``gns ...`` words of the recipe's ``# Data:`` line (text after ``(`` is a remark, not the command)."""
    lines = [line for line in recipe.read_text().splitlines() if line.startswith("# Data:")]
    assert len(lines) == 1, f"{recipe}: expected one '# Data: gns ...' line, found {len(lines)}"
    command = lines[0].removeprefix("# Data:").split("(")[0]
    words = shlex.split(command)
    if words[:2] == MERGE:
        return words
    assert words[:1] == ["gns"], f"{recipe}: the data line is not a gns command: {command!r}"
    return words[1:]


def merged_parts(recipe: Path, words: list[str], raw: dict) -> list[list[str]]:
    """The ``gns generate`` words of each part a merge names; asserts the merge writes ``dataset.path``."""
    args = merge_parser().parse_args(words[2:])
    assert Path(args.out) == Path(raw["dataset"]["path"]), f"{recipe}: the merge writes {args.out}"
    generated = {}
    for line in recipe.read_text().splitlines():
        text = line.lstrip("#").strip()
        if line.startswith("#") and text.startswith("gns generate "):
            part = shlex.split(text)
            generated[Path(build_parser(["generate"]).parse_args(part[1:]).out)] = part[1:]
    missing = [str(s) for s in args.sources if Path(s) not in generated]
    assert not missing, f"{recipe}: no 'gns generate' line writes the merged part(s) {missing}"
    return [generated[Path(s)] for s in args.sources]


def merge_parser():
    return load_script("scripts/merge_datasets.py").parser()


@pytest.mark.parametrize("recipe", RECIPES, ids=[str(p.relative_to(ROOT)) for p in RECIPES])
def test_the_recipe_says_how_to_make_the_data_it_trains_on(recipe):
    raw = yaml.safe_load(recipe.read_text())
    words = data_command(recipe)
    if words[:2] == MERGE:
        for part in merged_parts(recipe, words, raw):
            check_generated(recipe, raw, build_parser([part[0]]).parse_args(part))
        return
    args = build_parser([words[0]]).parse_args(words)
    assert Path(args.out) == Path(raw["dataset"]["path"]), f"{recipe}: the data command writes {args.out}"
    if args.command == "convert":
        return
    assert args.command == "generate", f"{recipe}: data from gns generate or gns convert, not gns {args.command}"
    check_generated(recipe, raw, args)


def check_generated(recipe: Path, raw: dict, args) -> None:
    """The scene of a ``gns generate`` command holds what the recipe's model expects."""
    scene = load_scene(ROOT / args.scene)
    model = raw.get("model", {})
    registry = load_registry()
    in_scene = {material for _, material in scene.material_uses()}
    assert in_scene <= set(registry.names("material"))
    if model.get("materials") is not None:
        assert in_scene <= set(model["materials"]), f"{recipe}: {args.scene} holds {sorted(in_scene)}"
    if model.get("material_properties") is not None:
        assert set(model["material_properties"]) <= set(scene.property_names), f"{recipe}: {args.scene}"
