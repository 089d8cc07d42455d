"""scripts/mirror_tests.py: which tests mirror a module, and which modules count as having logic."""

from __future__ import annotations

from pathlib import Path

from load_script import load_script

ROOT = Path(__file__).resolve().parents[2]
mirror_tests = load_script("scripts/mirror_tests.py")


def test_a_module_finds_its_mirror_and_its_topic_splits():
    found = mirror_tests.mirrors(Path("gns_framework/training/step.py"))
    assert ROOT / "tests/training/test_step.py" in found
    builtin = mirror_tests.mirrors(Path("plugins/gns_builtins/processors/grid_cnn.py"))
    assert builtin == [ROOT / "tests/builtins/processors/test_grid_cnn.py"]


def test_a_common_name_mirrors_with_its_folder():
    assert mirror_tests.mirrors(Path("plugins/gns_builtins/simulators/_mpm/solver.py")) == [
        ROOT / "tests/builtins/simulators/_mpm/test_mpm_solver.py"
    ]


def test_files_outside_the_packages_have_no_mirror():
    assert mirror_tests.mirrors(Path("benchmarks/reading_cost.py")) == []


def test_logic_is_a_function_not_constants_or_hook_lists(tmp_path):
    constants = tmp_path / "constants.py"
    constants.write_text('"""Constants."""\nLIMIT = 3\n\n@hookimpl\ndef gns_processors():\n    return [A]\n')
    assert not mirror_tests.has_logic(constants)
    logic = tmp_path / "logic.py"
    logic.write_text("def double(x):\n    return 2 * x\n")
    assert mirror_tests.has_logic(logic)
