"""MLflow tracking: rank 0's params, metrics and artifacts in a SQLite store and on an mlflow server; gns compare."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request

import pytest
from spawned import free_loopback_port
from training_support import (
    last_logged_step,
    subprocess_env,
    tiny_recipe,
    wait_until,
    write_recipe,
)

from gns_framework.cli import main
from gns_framework.io.run_folder import RunFolder, checkpoint_name
from gns_framework.training.tracking import read_metrics

mlflow = pytest.importorskip("mlflow")

EXPECTED_METRICS = {
    "train_loss",
    "valid_one_step_loss",
    "valid_one_step_position_mse",
    "steps_per_s",
    "particles_per_s",
    "lr",
}


def train(recipe_file, run_dir, *extra: str) -> None:
    assert (
        main(["train", str(recipe_file), "--out", str(run_dir), "--experiment", "tiny-exp", "--no-progress", *extra])
        == 0
    )


def check_tracked_run(client, run_id: str, steps: int) -> None:
    run = client.get_run(run_id)
    params = run.data.params
    assert params["recipe.model.latent_size"] == "16"
    assert params["recipe.model.processor.name"] == "interaction_network"
    assert params["plugins.processor/interaction_network.distribution"] == "gns-framework"
    assert params["world_size"] == "1"
    assert params["git_commit"]
    assert set(run.data.metrics) >= EXPECTED_METRICS
    assert [m.step for m in client.get_metric_history(run_id, "train_loss")][-1] == steps
    artifacts = {a.path for a in client.list_artifacts(run_id)}
    assert {"recipe.yaml", checkpoint_name(steps)} <= artifacts
    assert run.info.status == "FINISHED"


def test_training_tracks_to_a_sqlite_store_created_on_first_use_and_compare_reads_it(
    uneven_dataset, tmp_path, monkeypatch, capsys
):
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    recipe_file = write_recipe(tmp_path / "recipe.yaml", tiny_recipe(uneven_dataset, steps=4))
    train(recipe_file, tmp_path / "run-a")
    assert (tmp_path / "mlflow.db").is_file()
    train(recipe_file, tmp_path / "run-a", "--resume", "--steps", "6")
    train(recipe_file, tmp_path / "run-b", "--steps", "2")

    client = mlflow.tracking.MlflowClient(f"sqlite:///{tmp_path / 'mlflow.db'}")
    run_a = json.loads((tmp_path / "run-a" / RunFolder.MLFLOW_RUN).read_text())["run_id"]
    run_b = json.loads((tmp_path / "run-b" / RunFolder.MLFLOW_RUN).read_text())["run_id"]
    assert run_a != run_b
    check_tracked_run(client, run_a, steps=6)  # the resumed training went on in the same MLflow run
    assert client.get_run(run_a).data.tags["changed.recipe.training.steps"] == "4 -> 6"
    check_tracked_run(client, run_b, steps=2)
    # MLflow 3's UI opens a training experiment on its runs, not on its GenAI view.
    assert client.get_experiment_by_name("tiny-exp").tags["mlflow.experimentKind"] == "custom_model_development"

    checkpoint = tmp_path / "run-a" / "checkpoints" / checkpoint_name(6)
    assert (
        main(["rollout", "--outside-envelope", str(checkpoint), "--trajectories", "1", "--steps", "3", "--no-progress"])
        == 0
    )
    assert [(m.step, m.value > 0) for m in client.get_metric_history(run_a, "rollout_position_mse_test")] == [(6, True)]
    assert client.get_run(run_a).info.status == "FINISHED"

    capsys.readouterr()
    plot = tmp_path / "compare.png"
    assert (
        main(
            [
                "compare",
                "tiny-exp",
                "--metrics",
                "train_loss",
                "steps_per_s",
                "--params",
                "training.steps",
                "world_size",
                "--plot",
                str(plot),
            ]
        )
        == 0
    )
    table = capsys.readouterr().out.splitlines()
    assert table[0].split() == [
        "run",
        "experiment",
        "id",
        "status",
        "training.steps",
        "world_size",
        "train_loss",
        "steps_per_s",
    ]
    rows = {line.split()[2]: line.split() for line in table[1:3]}
    assert rows[run_a[:8]][4] == "4" and rows[run_b[:8]][4] == "2"
    assert plot.read_bytes().startswith(b"\x89PNG")
    # By default the plot is named after what it compares, by experiment name even when runs are given by id.
    assert main(["compare", run_a[:8], "--metrics", "train_loss", "--plot"]) == 0
    assert (tmp_path / "compare-tiny-exp-train_loss.png").is_file()


def test_damaged_checkpoints_never_give_the_mlflow_run_a_second_history_and_a_restart_gets_a_new_run(
    uneven_dataset, tmp_path, capsys
):
    store = f"sqlite:///{tmp_path / 'store.db'}"
    recipe_file = write_recipe(tmp_path / "recipe.yaml", tiny_recipe(uneven_dataset, steps=2, checkpoint_every=2))
    run_dir = tmp_path / "run"
    train(recipe_file, run_dir, "--tracking-uri", store)
    first = json.loads((run_dir / RunFolder.MLFLOW_RUN).read_text())["run_id"]
    client = mlflow.tracking.MlflowClient(store)
    history = [(m.step, m.value) for m in client.get_metric_history(first, "train_loss")]
    checkpoint = run_dir / "checkpoints" / checkpoint_name(2)
    checkpoint.write_bytes(checkpoint.read_bytes()[:-100])

    resumed = ["train", str(recipe_file), "--out", str(run_dir), "--experiment", "tiny-exp", "--tracking-uri", store]
    assert main([*resumed, "--resume", "--no-progress"]) == 2
    assert "every checkpoint is damaged" in capsys.readouterr().err
    train(recipe_file, run_dir, "--tracking-uri", store, "--restart")
    second = json.loads((run_dir / RunFolder.MLFLOW_RUN).read_text())["run_id"]
    assert second != first
    assert json.loads((run_dir / "earlier-1" / RunFolder.MLFLOW_RUN).read_text())["run_id"] == first
    assert [(m.step, m.value) for m in client.get_metric_history(first, "train_loss")] == history
    check_tracked_run(client, second, steps=2)


def test_compare_names_the_choices_for_an_unknown_experiment(tmp_path, uneven_dataset, capsys):
    database = tmp_path / "store.db"
    recipe_file = write_recipe(tmp_path / "recipe.yaml", tiny_recipe(uneven_dataset, steps=1))
    train(recipe_file, tmp_path / "run", "--tracking-uri", f"sqlite:///{database}")
    assert main(["compare", "tiny-xp", "--tracking-uri", f"sqlite:///{database}"]) == 2
    assert "no experiment or run 'tiny-xp'; experiments: Default, tiny-exp" in capsys.readouterr().err


def test_import_and_help_never_import_mlflow():
    code = (
        "import sys, contextlib, io\n"
        "import gns_framework, gns_framework.training.trainer, gns_framework.cli as cli\n"
        "for argv in (['--help'], ['train', '--help'], ['compare', '--help']):\n"
        "    with contextlib.suppress(SystemExit), contextlib.redirect_stdout(io.StringIO()):\n"
        "        cli.main(argv)\n"
        "print(sorted(m for m in sys.modules if m.split('.')[0] == 'mlflow'))\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], env=subprocess_env(), capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "[]"


def wait_for_health(url: str, server: subprocess.Popen, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if server.poll() is not None:
            raise AssertionError(f"mlflow server exited with {server.returncode}: {server.stdout.read()}")
        try:
            with urllib.request.urlopen(f"{url}/health", timeout=2) as response:
                if response.status == 200:
                    return
        except (urllib.error.URLError, ConnectionError, TimeoutError):
            time.sleep(0.25)
    raise AssertionError(f"mlflow server at {url} not healthy within {timeout} s")


def test_training_goes_on_without_mlflow_when_the_server_is_unreachable_at_the_start(
    uneven_dataset, tmp_path, monkeypatch
):
    monkeypatch.setenv("MLFLOW_HTTP_REQUEST_MAX_RETRIES", "0")
    nobody = f"http://127.0.0.1:{free_loopback_port()}"
    recipe_file = write_recipe(tmp_path / "recipe.yaml", tiny_recipe(uneven_dataset, steps=2))
    with pytest.warns(UserWarning, match=f"MLflow at {nobody} unreachable .*training goes on without it"):
        train(recipe_file, tmp_path / "run", "--tracking-uri", nobody)
    assert [line["step"] for line in read_metrics(tmp_path / "run")] == [2]
    assert not (tmp_path / "run" / RunFolder.MLFLOW_RUN).exists()


def test_rollout_and_evaluation_metrics_for_an_unreachable_server_are_a_warning(tmp_path, monkeypatch):
    from gns_framework.training.mlflow_tracker import log_to_recorded_run

    monkeypatch.setenv("MLFLOW_HTTP_REQUEST_MAX_RETRIES", "0")
    nobody = f"http://127.0.0.1:{free_loopback_port()}"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", nobody)  # the user's store: a record naming another is never written to
    (tmp_path / RunFolder.MLFLOW_RUN).write_text(
        json.dumps({"tracking_uri": nobody, "experiment": "x", "run_id": "abc"})
    )
    with pytest.warns(
        UserWarning, match=f"MLflow at {nobody} unreachable .*rollout_position_mse_test 0.5 not logged to its run abc"
    ):
        assert log_to_recorded_run(tmp_path, {"rollout_position_mse_test": 0.5}, step=3) is None


def start_server(folder, port: int) -> subprocess.Popen:
    """An ``mlflow server`` on 127.0.0.1:``port`` whose store and artifacts live in ``folder`` (kept across
    restarts)."""
    command = [
        sys.executable,
        "-m",
        "mlflow",
        "server",
        "--host",
        "127.0.0.1",
        "--port",
        str(port),
        "--workers",
        "1",
        "--backend-store-uri",
        f"sqlite:///{folder / 'server.db'}",
        "--artifacts-destination",
        str(folder / "artifacts"),
    ]
    server = subprocess.Popen(
        command,
        env=subprocess_env(),
        cwd=folder,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
    )
    wait_for_health(f"http://127.0.0.1:{port}", server, timeout=120)
    return server


def stop_server(server: subprocess.Popen) -> None:
    if server.poll() is not None:
        return
    os.killpg(server.pid, signal.SIGTERM)
    try:
        server.wait(timeout=20)
    except subprocess.TimeoutExpired:
        os.killpg(server.pid, signal.SIGKILL)
        server.wait()


def test_training_tracks_to_an_mlflow_server_on_loopback(uneven_dataset, tmp_path):
    port = free_loopback_port()
    url = f"http://127.0.0.1:{port}"
    server = start_server(tmp_path, port)
    try:
        recipe_file = write_recipe(tmp_path / "recipe.yaml", tiny_recipe(uneven_dataset, steps=2))
        train(recipe_file, tmp_path / "run", "--tracking-uri", url)
        run_id = json.loads((tmp_path / "run" / RunFolder.MLFLOW_RUN).read_text())["run_id"]
        check_tracked_run(mlflow.tracking.MlflowClient(url), run_id, steps=2)
        assert list((tmp_path / "artifacts").rglob("recipe.yaml")), "artifacts did not reach the server's store"
    finally:
        stop_server(server)


def logged_steps(client, run_id: str, metric: str = "train_loss") -> list[int]:
    return sorted(m.step for m in client.get_metric_history(run_id, metric))


def test_an_mlflow_server_that_stops_during_training_never_holds_it_up_and_gets_what_it_missed_when_back(
    uneven_dataset, tmp_path, monkeypatch, recwarn, capsys
):
    """The server is stopped after step 3 and started again after step 8 (the hook waits meanwhile, so the
    server gets the steps it missed before training goes on); a resumed run then loses it for good at step 13."""
    # Each request to the stopped server fails after about 4 s of MLflow's own retries (0 s, then 4 s apart), so a
    # trainer that waited on one would pause that long; the outbox tries again every half second.
    monkeypatch.setenv("MLFLOW_HTTP_REQUEST_MAX_RETRIES", "2")
    monkeypatch.setenv("MLFLOW_HTTP_REQUEST_BACKOFF_FACTOR", "2")
    monkeypatch.setenv("MLFLOW_HTTP_REQUEST_TIMEOUT", "5")
    monkeypatch.setenv("GNS_TRACKING_RETRY_SECONDS", "0.5")
    port = free_loopback_port()
    url = f"http://127.0.0.1:{port}"
    client = mlflow.tracking.MlflowClient(url)
    servers = [start_server(tmp_path, port)]
    run_dir = tmp_path / "run"
    stop_after, start_after, lost_after = 3, 8, 13
    server_down, training_thread_requests = threading.Event(), []

    from gns_framework.training.trainer import Trainer

    def recorded(name, method):
        def request(self, *args, **kwargs):
            if server_down.is_set() and threading.current_thread() is threading.main_thread():
                training_thread_requests.append(name)
            return method(self, *args, **kwargs)

        return request

    # Every request the tracker makes goes through the client: none may come from the training thread in an outage.
    for name in ("log_batch", "log_artifact", "get_run", "set_terminated", "update_run", "create_run"):
        monkeypatch.setattr(
            mlflow.tracking.MlflowClient, name, recorded(name, getattr(mlflow.tracking.MlflowClient, name))
        )
    train_step = Trainer.train_step

    def train_step_with_outages(trainer):
        result = train_step(trainer)
        if trainer.step in (stop_after, lost_after):
            stop_server(servers[-1])
        if trainer.step == stop_after:
            server_down.set()
        if trainer.step == start_after:
            server_down.clear()
            servers.append(start_server(tmp_path, port))
            run_id = json.loads((run_dir / RunFolder.MLFLOW_RUN).read_text())["run_id"]
            deadline = time.monotonic() + 60
            while logged_steps(client, run_id) != list(range(1, start_after)) and time.monotonic() < deadline:
                time.sleep(0.2)
            assert logged_steps(client, run_id) == list(range(1, start_after)), "the steps of the outage were not sent"
        return result

    monkeypatch.setattr(Trainer, "train_step", train_step_with_outages)
    recipe = tiny_recipe(uneven_dataset, steps=12, log_every=1, validate_every=4, checkpoint_every=4)
    recipe_file = write_recipe(tmp_path / "recipe.yaml", recipe)
    try:
        train(recipe_file, run_dir, "--tracking-uri", url)
        run_id = json.loads((run_dir / RunFolder.MLFLOW_RUN).read_text())["run_id"]
        assert [str(w.message) for w in recwarn if "unreachable" in str(w.message)], "no warning of the outage"
        assert "is back" in capsys.readouterr().err
        check_tracked_run(client, run_id, steps=12)
        assert logged_steps(client, run_id) == list(range(1, 13))
        assert logged_steps(client, run_id, "valid_one_step_loss") == [4, 8, 12]
        # Steps 4 to 8 ran with the server down (validation and a checkpoint included): the trainer sent nothing itself.
        assert training_thread_requests == []

        recwarn.clear()
        train(recipe_file, run_dir, "--tracking-uri", url, "--resume", "--steps", "16")
        unsent = [str(w.message) for w in recwarn if "did not receive" in str(w.message)]
        assert len(unsent) == 1 and "steps 13 to 16" in unsent[0] and str(run_dir / "metrics.jsonl") in unsent[0], (
            unsent
        )
        assert [line["step"] for line in read_metrics(run_dir)][-4:] == [13, 14, 15, 16]
    finally:
        stop_server(servers[-1])


def test_under_torchrun_a_killed_mlflow_server_stops_neither_rank(uneven_dataset, tmp_path):
    """Rank 0 alone talks to the server and every rank meets it at each step, so a rank 0 stuck on the server
    (or ended by it) would hold up or end the whole job."""
    port = free_loopback_port()
    url = f"http://127.0.0.1:{port}"
    server = start_server(tmp_path, port)
    run_dir = tmp_path / "run"
    recipe = tiny_recipe(uneven_dataset, steps=200, log_every=1, validate_every=1000, checkpoint_every=1000)
    recipe_file = write_recipe(tmp_path / "recipe.yaml", recipe)
    env = subprocess_env() | {
        "MLFLOW_HTTP_REQUEST_MAX_RETRIES": "2",
        "MLFLOW_HTTP_REQUEST_BACKOFF_FACTOR": "2",
        "GNS_TRACKING_CLOSE_SECONDS": "20",
    }
    command = [
        sys.executable,
        "-m",
        "torch.distributed.run",
        "--nnodes",
        "1",
        "--nproc-per-node",
        "2",
        "--master-addr",
        "127.0.0.1",
        "--master-port",
        str(free_loopback_port()),
        "--local-addr",
        "127.0.0.1",
        "-m",
        "gns_framework.cli",
        "train",
        str(recipe_file),
        "--out",
        str(run_dir),
        "--tracking-uri",
        url,
        "--experiment",
        "tiny-exp",
        "--no-progress",
    ]
    log = tmp_path / "torchrun.log"
    with open(log, "w") as output:
        job = subprocess.Popen(
            command, env=env, cwd=tmp_path, stdout=output, stderr=subprocess.STDOUT, start_new_session=True
        )
    try:
        wait_until(lambda: last_logged_step(run_dir) >= 10, 120, "step 10", job)
        os.killpg(server.pid, signal.SIGKILL)
        server.wait()
        killed_at = last_logged_step(run_dir)
        job.wait(timeout=240)
    finally:
        if job.poll() is None:
            os.killpg(job.pid, signal.SIGKILL)
            job.wait()
        stop_server(server)
    text = log.read_text()
    assert job.returncode == 0, text
    assert killed_at < 200, "training ended before the server was killed"
    assert "unreachable" in text and "did not receive metrics of" in text, text
    assert "trained tiny to step 200" in text
    assert [line["step"] for line in read_metrics(run_dir)] == list(range(1, 201))
