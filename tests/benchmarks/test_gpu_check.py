"""benchmarks/gpu_check.sh runs every part it can on the CPU (--device cpu --dry-run), streams its documented
lines, keeps each part within its limit, and counts skips apart from failures."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
import time
from pathlib import Path

from load_script import load_script

REPO = Path(__file__).resolve().parents[2]
SCRIPT = REPO / "benchmarks" / "gpu_check.sh"


def _lines(output: str) -> list[dict[str, str]]:
    """``gpu_check: <part> key=value ... [skipped: why]`` lines as dicts with the part under ``part``."""
    parsed = []
    for line in output.splitlines():
        if line.startswith("gpu_check: "):
            body, _, why = line[len("gpu_check: ") :].partition(" skipped: ")
            part, *pairs = body.split()
            parsed.append(
                {"part": part, **dict(pair.split("=", 1) for pair in pairs), **({"skipped": why} if why else {})}
            )
    return parsed


def _environment(tmp_path) -> dict[str, str]:
    return dict(os.environ, PYTHON=sys.executable, TMPDIR=str(tmp_path), OMP_NUM_THREADS="1")


def test_the_dry_run_passes_every_cpu_part_and_reports_in_the_documented_format(tmp_path):
    result = subprocess.run(
        ["bash", str(SCRIPT), "--device", "cpu", "--dry-run"],
        capture_output=True,
        text=True,
        env=_environment(tmp_path),
        timeout=600,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    lines = _lines(result.stdout)
    parts = {line["name"]: line["status"] for line in lines if line["part"] == "part"}
    expected = {
        name: "pass"
        for name in (
            "install",
            "imports",
            "info",
            "data",
            "train",
            "resume",
            "rollout",
            "ddp",
            "sums",
            "chunks",
            "kernels",
            "capture",
            "train_capture",
            "batched",
            "scale",
            "mpm",
        )
    }
    expected["cuda_tests"] = "skip"
    if importlib.util.find_spec("warp") is None:
        expected["mpm"] = "skip"
    if importlib.util.find_spec("triton") is None:
        expected["kernels"] = "skip"
    assert parts == expected
    assert all(int(line["seconds"]) <= int(line["limit"]) + 10 for line in lines if line["part"] == "part")
    skips = [line for line in lines if line["part"] == "part" and line["status"] == "skip"]
    assert all(line["skipped"] for line in skips), "every skip says why on its line"
    # This interpreter has the project installed: nothing to install.
    assert [line["installed"] for line in lines if line["part"] == "install" and "installed" in line] == ["none"]
    imports = next(line for line in lines if line["part"] == "imports" and "builtins" in line)
    assert int(imports["builtins"]) >= 20
    ddp = next(line for line in lines if line["part"] == "ddp")
    assert ddp["ranks"] == "1" and ddp["backend"] == "gloo" and ddp["collectives"] == "ok"
    assert {line["path"] for line in lines if line["part"] == "sums"} >= {"index_add", "ordered"}
    assert next(line for line in lines if line["part"] == "chunks")["status"] == "ok"
    if (
        expected["kernels"] == "pass"
    ):  # the Triton edge block in Triton's interpreter: equal to the chunked path, the same bits twice
        kernels = [line for line in lines if line["part"] == "kernels"]
        assert {k["phase"] for k in kernels} == {"rollout", "train"}
        assert all(float(k["max_rel_diff"]) < 1e-4 and k["finite"] == "True" for k in kernels)
        assert [line["equal"] for line in lines if line["part"] == "kernels_bitwise"] == ["True"]
        assert {line["path"] for line in lines if line["part"] == "kernels_profile"} == {"chunked", "triton"}
    capture = next(line for line in lines if line["part"] == "capture")
    assert capture["status"] == "ok" and float(capture["max_abs_diff"]) <= 1e-4 and capture["captures"] == "1"
    trained = next(line for line in lines if line["part"] == "train_capture" and "captured_ms" in line)
    assert trained["status"] == "ok" and float(trained["loss_rel_diff"]) <= 1e-4 and int(trained["captures"]) >= 1
    batched = next(line for line in lines if line["part"] == "batched" and "status" in line and "scenes" in line)
    assert batched["status"] == "ok" and int(batched["classes"]) == int(batched["captures"]) >= 1
    steps = [line for line in lines if line["part"] == "step"]
    assert {(s["precision"], s["phase"]) for s in steps} == {
        (p, phase) for p in ("float32", "bfloat16") for phase in ("rollout", "train")
    }
    assert all(s["status"] == "ok" and float(s["step_s"]) > 0 and int(s["edges"]) > 0 for s in steps)
    phases = [line for line in lines if line["part"] == "phases" and line["phase"] == "train"]
    assert phases and all(
        float(p[k]) > 0 for p in phases for k in ("graph_s", "forward_s", "backward_s", "optimizer_s")
    )
    if expected["mpm"] == "pass":
        assert [line["finite"] for line in lines if line["part"] == "mpm"] == ["True"]
    summary = lines[-1]
    assert summary["part"] == "summary" and summary["failures"] == "0" and summary["parts"] == str(len(parts))
    assert summary["skips"] == str(sum(status == "skip" for status in parts.values()))


def _script_with(parts: str) -> str:
    """gpu_check.sh up to its install, then ``parts`` and the summary instead of its own parts."""
    script = SCRIPT.read_text().replace('cd "$(dirname "$0")/.."', f'cd "{REPO}"')
    head = script[: script.index("# What the interpreter lacks")]
    return head + parts + '\nsummary\n[ "$FAILURES" = 0 ]\n'


def test_a_part_streams_its_lines_and_a_killed_part_keeps_what_it_printed(tmp_path):
    """A part killed at its limit: its first line came out before the kill, the part fails, the run goes on."""
    script = tmp_path / "gpu_check.sh"
    script.write_text(
        _script_with(
            """part slow 4 "$PYTHON" -c "import time; print('gpu_check: slow first=1', flush=True); time.sleep(60)"
part absent 10 "$PYTHON" -c "print('skipped: nothing to measure here'); raise SystemExit(77)"
part quick 10 "$PYTHON" -c "print('gpu_check: quick value=2')"
"""
        )
    )
    process = subprocess.Popen(
        ["bash", str(script), "--device", "cpu", "--dry-run"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=_environment(tmp_path),
    )
    started = time.monotonic()
    first = process.stdout.readline()
    while not first.startswith("gpu_check: slow"):
        first = process.stdout.readline()
    seen_after = time.monotonic() - started
    rest, _ = process.communicate(timeout=120)
    assert first.strip() == "gpu_check: slow first=1"
    assert seen_after < 4, "the line came out while the part ran, not after it"
    parts = {line["name"]: line for line in _lines(rest) if line["part"] == "part"}
    assert parts["slow"]["status"] == "fail" and parts["slow"]["timed_out"] == "4s"
    assert parts["absent"]["status"] == "skip" and parts["absent"]["skipped"] == "nothing to measure here"
    assert parts["quick"]["status"] == "pass"
    assert "gpu_check: quick value=2" in rest
    assert process.returncode != 0
    summary = _lines(rest)[-1]
    assert (summary["failures"], summary["skips"]) == ("1", "1")


def test_the_run_budget_limits_the_parts_and_skips_what_no_longer_fits(tmp_path):
    script = tmp_path / "gpu_check.sh"
    script.write_text(
        _script_with(
            """part first 100 "$PYTHON" -c "import os; print('gpu_check: first limit=' + os.environ['GPU_CHECK_PART_LIMIT_S'])"
part sleeper 100 "$PYTHON" -c "import time; time.sleep(60)"
part late 100 "$PYTHON" -c "print('gpu_check: late ran=1')"
"""  # noqa: E501 - a script's lines, one command each
        )
    )
    result = subprocess.run(
        ["bash", str(script), "--device", "cpu", "--dry-run", "--budget-s", "20"],
        capture_output=True,
        text=True,
        env=_environment(tmp_path),
        timeout=120,
    )
    lines = _lines(result.stdout)
    parts = {line["name"]: line for line in lines if line["part"] == "part"}
    # The budget less what ran (install) less 5 s of margin: below the part's own 100 s.
    assert int(parts["first"]["limit"]) <= 15
    assert parts["sleeper"]["status"] == "fail" and int(parts["sleeper"]["seconds"]) <= 20
    assert parts["late"]["status"] == "skip" and parts["late"]["skipped"].startswith("over_budget")
    assert "gpu_check: late ran=1" not in result.stdout


def test_the_scale_part_watches_its_deadline_inside_a_size(tmp_path):
    """Given 12 s, many repeats of a size stop early and the part ends within its limit, saying what it left out."""
    environment = dict(_environment(tmp_path), GPU_CHECK_PART_LIMIT_S="12")
    started = time.monotonic()
    result = subprocess.run(
        [
            sys.executable,
            str(REPO / "benchmarks" / "gpu_check.py"),
            "scale",
            "--device",
            "cpu",
            "--sizes",
            "300",
            "--precisions",
            "float32",
            "bfloat16",
            "--repeat",
            "1000",
        ],
        capture_output=True,
        text=True,
        env=environment,
        timeout=120,
    )
    elapsed = time.monotonic() - started
    assert result.returncode == 0, result.stderr
    steps = [line for line in _lines(result.stdout) if line["part"] == "step"]
    assert steps and elapsed < 12 + 5
    assert all(line["status"] == "over_budget" or int(line["repeats"]) < 1000 for line in steps)


def _gpu_check_module():
    return load_script("benchmarks/gpu_check.py")


def test_at_a_million_particles_the_configuration_expected_to_fit_runs_first():
    cases = _gpu_check_module()._cases(1_000_000, ["float32", "tf32", "bfloat16"], large=True)
    assert cases[0] == ("bfloat16", "train", "recompute")
    assert cases[1:4] == [
        ("bfloat16", "rollout", "stored"),
        ("float32", "rollout", "stored"),
        ("tf32", "rollout", "stored"),
    ]
    assert len(set(cases)) == len(cases) == 3 + 3 * 2
    small = _gpu_check_module()._cases(10_000, ["float32", "bfloat16"], large=False)
    assert small[:2] == [("float32", "rollout", "stored"), ("float32", "train", "stored")]


def test_a_failing_part_fails_the_check(tmp_path):
    """A rollout of a checkpoint that is not there: the part fails, and so does the script."""
    script = SCRIPT.read_text().replace('--steps "$MORE" --resume', "--steps 5 --resume")
    script = script.replace('cd "$(dirname "$0")/.."', f'cd "{REPO}"')
    # Only the parts up to the rollout: the failure is the point, not the figures.
    script = script[: script.index("GPUS=0")] + '\nsummary\n[ "$FAILURES" = 0 ]\n'
    broken = tmp_path / "gpu_check.sh"
    broken.write_text(script)
    result = subprocess.run(
        ["bash", str(broken), "--device", "cpu", "--dry-run"],
        capture_output=True,
        text=True,
        env=_environment(tmp_path),
        timeout=300,
    )
    assert result.returncode != 0
    parts = {line["name"]: line["status"] for line in _lines(result.stdout) if line["part"] == "part"}
    assert parts["rollout"] == "fail" and parts["train"] == "pass"
