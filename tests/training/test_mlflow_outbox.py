"""The outbox of an MLflow run: in order, never blocking, refused requests given up, outages named."""

from __future__ import annotations

import threading

import pytest


def test_outbox_never_blocks_keeps_order_gives_up_refused_requests_and_names_what_an_outage_kept_back():
    pytest.importorskip("mlflow")
    from mlflow.exceptions import MlflowException
    from mlflow.protos.databricks_pb2 import INVALID_PARAMETER_VALUE

    from gns_framework.training.mlflow_outbox import Outbox, Request

    sent, server_up, release, sending, failed_try = (
        [],
        threading.Event(),
        threading.Event(),
        threading.Event(),
        threading.Event(),
    )

    senders = set()

    def send_metrics(entries):
        senders.add(threading.current_thread().name)
        sending.set()
        release.wait(timeout=30)  # a hang guard: an outbox that sent from put() would wait here
        if not server_up.is_set():
            failed_try.set()
            raise ConnectionError("connection refused")
        sent.extend(entries)

    def refused():
        raise MlflowException("bad value", error_code=INVALID_PARAMETER_VALUE)

    outbox = Outbox("the server", "metrics.jsonl", send_metrics, retry_seconds=0.05, close_seconds=10, capacity=4)
    with pytest.warns(UserWarning) as caught:
        for step in range(1, 7):
            outbox.put(Request(f"step {step}", metrics=[f"m{step}"], step=step))
        # Every put returned while the server held the first request, sent from the outbox's own thread.
        assert sending.wait(timeout=30) and not release.is_set() and senders == {"gns-tracking"}
        release.set()
        assert failed_try.wait(timeout=30)
        outbox.put(Request("a refused request", send=refused))
        outbox.put(Request("step 7", metrics=["m7"], step=7))
        server_up.set()
        outbox.close()
    messages = [str(w.message) for w in caught]
    assert any("unreachable (connection refused)" in m for m in messages), messages
    assert any("the oldest metrics are given up" in m for m in messages), messages
    assert any("refused a refused request: bad value" in m for m in messages), messages
    # Capacity 4: the 8 requests of the outage gave up the 4 oldest metrics, never the other requests.
    assert sent == ["m5", "m6", "m7"]
    assert any("did not receive metrics of 4 logs (steps 1 to 4)" in m for m in messages), messages
