"""The figures of a `benchmarks/gpu_check.sh` run, from its output, as one record of docs/gpu_results.json.

Usage:
    benchmarks/gpu_check.sh | tee gpu_check.log
    python benchmarks/gpu_results.py gpu_check.log [--commit HASH] [--date YYYY-MM-DD] [--out docs/gpu_results.json]

Reads the ``gpu_check: ...`` lines and appends to ``--out`` (a JSON list, made when absent;
without ``--out`` the record is printed) one record: ``date``, ``commit``, ``device``,
``precision`` (the precision of the step times), ``rollout_ms`` and ``training_ms`` keyed by
particle count (the ``scale`` part's median steps at that precision; stored activations where
both were timed, else recompute), the edge kernels' times and speed-ups (``kernels``), whether
the ordered sums and the Triton training step gave the same bits twice (``same_bits``), float32
rollout steps eager and captured on the fixed-capacity graph keyed by particle count
(``captured_rollout_ms``: ``eager_ms``, ``captured_ms``, ``max_abs_diff``), training steps the same way
(``captured_training_ms``: ``eager_ms``, ``captured_ms``, ``loss_rel_diff``), and
``small_scene_rollout_s`` and ``batched_s_per_scene`` when the run measured them (else None).
Every figure docs/performance.md quotes from a device run lives here, run by run.
"""

from __future__ import annotations

import argparse
import datetime
import json
import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def parse_lines(text: str) -> list[tuple[str, dict[str, str]]]:
    """``(part, {key: value})`` of every ``gpu_check: <part> key=value ...`` line, in order."""
    out = []
    for line in text.splitlines():
        if not line.startswith("gpu_check: "):
            continue
        part, *pairs = line[len("gpu_check: ") :].split(" ")
        fields = dict(pair.split("=", 1) for pair in pairs if "=" in pair)
        out.append((part, fields))
    return out


def record(text: str, commit: str, date: str, precision: str = "bfloat16") -> dict:
    """One docs/gpu_results.json record from a gpu_check run's output."""
    lines = parse_lines(text)
    device = next((f for p, f in lines if p == "device"), {})
    steps = [f for p, f in lines if p == "step" and f.get("status") == "ok" and f.get("precision") == precision]
    times: dict[str, dict[str, float]] = {"rollout": {}, "train": {}}
    for memory in ("recompute", "stored"):  # stored last: it wins where both were timed
        for f in steps:
            if f.get("memory") == memory:
                times[f["phase"]][f["particles"]] = round(1e3 * float(f["step_s"]), 3)
    kernels = [
        {key: f[key] for key in ("particles", "precision", "phase", "chunked_ms", "triton_ms", "speedup") if key in f}
        for p, f in lines
        if p == "kernels" and "speedup" in f
    ]
    same_bits = {f"sums_{f['path']}": f["same_bits_twice"] == "True" for p, f in lines if p == "sums" and "path" in f}
    same_bits.update(
        {f"triton_train_{f['precision']}": f["equal"] == "True" for p, f in lines if p == "kernels_bitwise"}
    )
    captured = {
        f["particles"]: {key: float(f[key]) for key in ("eager_ms", "captured_ms", "max_abs_diff")}
        for p, f in lines
        if p == "capture" and f.get("status") in ("ok", "differ") and "captured_ms" in f
    }
    captured_training = {
        f["particles"]: {key: float(f[key]) for key in ("eager_ms", "captured_ms", "loss_rel_diff")}
        for p, f in lines
        if p == "train_capture" and "captured_ms" in f
    }
    small = next((float(f["seconds"]) for p, f in lines if p == "small_scene" and "seconds" in f), None)
    batched = next((float(f["s_per_scene"]) for p, f in lines if p == "batched" and "s_per_scene" in f), None)
    return {
        "date": date,
        "commit": commit,
        "device": device.get("name", "unknown").replace("_", " "),
        "precision": precision,
        "rollout_ms": times["rollout"],
        "training_ms": times["train"],
        "kernels": kernels,
        "same_bits": same_bits,
        "captured_rollout_ms": captured,
        "captured_training_ms": captured_training,
        "small_scene_rollout_s": small,
        "batched_s_per_scene": batched,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("log", type=Path, help="the output of benchmarks/gpu_check.sh")
    parser.add_argument("--commit", help="default: the repository's HEAD")
    parser.add_argument("--date", default=datetime.date.today().isoformat())
    parser.add_argument("--precision", default="bfloat16", help="the precision of rollout_ms and training_ms")
    parser.add_argument("--out", type=Path, help="append to this JSON list (docs/gpu_results.json)")
    args = parser.parse_args(argv)
    commit = (
        args.commit
        or subprocess.run(
            ["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=True
        ).stdout.strip()
    )
    entry = record(args.log.read_text(), commit, args.date, args.precision)
    if args.out is None:
        print(json.dumps(entry, indent=2))
        return 0
    runs = json.loads(args.out.read_text()) if args.out.exists() else []
    if not isinstance(runs, list):
        raise SystemExit(f"gpu_results.py: {args.out} holds no JSON list of runs")
    runs.append(entry)
    args.out.write_text(json.dumps(runs, indent=2) + "\n")
    print(f"gpu_results.py: {len(runs)} run(s) in {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
