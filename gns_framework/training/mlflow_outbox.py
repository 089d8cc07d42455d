"""The outbox of an MLflow run: requests to a tracking server sent in order from a thread of their own.

A server that is slow or down never holds up training: what cannot be sent waits in
line and goes out when the server is back (``mlflow_tracker.py`` uses it).
"""

from __future__ import annotations

import collections
import math
import sys
import threading
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import cast

METRICS_PER_REQUEST = 1000
"""MLflow's limit of metrics in one log_batch request: the outbox joins batches up to it."""

OUTBOX_CAPACITY = 10_000
"""Calls that may wait for the server; beyond it the oldest waiting metrics are given up (metrics.jsonl keeps them)."""


def server_unreachable(error: BaseException) -> bool:
    """Whether ``error`` says the tracking server could not be reached, timed out, failed or is busy (5xx, 429):
    worth trying again later, unlike a request the server refused (4xx)."""
    from mlflow.exceptions import MlflowException

    if isinstance(error, MlflowException):
        status = error.get_http_status_code()
    else:
        status = getattr(getattr(error, "response", None), "status_code", None)
        if status is None:
            return isinstance(error, OSError)  # requests' connection errors and timeouts are OSErrors
    return status >= 500 or status == 429


@dataclass
class Request:
    """A request waiting in the outbox: ``send`` makes it; or, for a batch of metric entries, ``metrics`` of
    ``step``, which the outbox sends joined with the batches next to it, and which alone it may give up when full."""

    what: str
    send: Callable[[], None] | None = None
    metrics: list | None = None
    step: int | None = None


class Outbox:
    """Sends a tracking server's requests, in order, from a thread of its own, so that training never waits on it.

    A request the server cannot be reached for (server_unreachable) stays first in
    line and is tried again every ``retry_seconds``, with one warning per outage;
    everything queued behind it goes out when the server is back. A request the
    server refuses is given up with a warning. ``close`` waits at most
    ``close_seconds`` for the line to empty, then warns about what is left.

    Args:
        where: the server, as warnings name it.
        kept_in: where the metrics are kept whatever happens here, as warnings name it.
        send_metrics: sends a list of metric entries in one request.
    """

    def __init__(
        self,
        where: str,
        kept_in: str,
        send_metrics: Callable[[list], None],
        retry_seconds: float,
        close_seconds: float,
        capacity: int = OUTBOX_CAPACITY,
    ):
        self.where, self.kept_in = where, kept_in
        self._send_metrics = send_metrics
        self.retry_seconds, self.close_seconds, self.capacity = retry_seconds, close_seconds, capacity
        self._waiting: collections.deque[Request] = collections.deque()
        self._changed = threading.Condition()
        self._closing = False
        self._close_deadline = math.inf
        self._given_up_steps: list[int] = []
        self._thread = threading.Thread(target=self._work, name="gns-tracking", daemon=True)
        self._thread.start()

    def put(self, request: Request) -> None:
        """Queue ``request``; returns at once. A full outbox gives up its oldest metrics to make room."""
        with self._changed:
            if len(self._waiting) >= self.capacity:
                oldest = next((r for r in self._waiting if r.metrics is not None), None)
                if oldest is not None:
                    self._waiting.remove(oldest)
                    if not self._given_up_steps:
                        warnings.warn(
                            f"tracking: more than {self.capacity} requests wait for {self.where}; the oldest metrics "
                            f"are given up from now on (they stay in {self.kept_in})",
                            stacklevel=3,
                        )
                    assert oldest.step is not None  # a batch of metrics has its step
                    self._given_up_steps.append(oldest.step)
            self._waiting.append(request)
            self._changed.notify()

    def _next(self) -> list[Request]:
        """The first waiting request, or a run of consecutive metrics batches that fit one request."""
        first = self._waiting[0]
        if first.metrics is None:
            return [first]
        run, size = [], 0
        for request in self._waiting:
            if request.metrics is None or size + len(request.metrics) > METRICS_PER_REQUEST:
                break
            run.append(request)
            size += len(request.metrics)
        return run

    def _work(self) -> None:
        outage_since = None
        while True:
            with self._changed:
                self._changed.wait_for(lambda: self._waiting or self._closing)
                if not self._waiting:
                    return
                requests = self._next()
            try:
                if requests[0].metrics is None:
                    cast("Callable[[], None]", requests[0].send)()  # a request without metrics has send
                else:  # a run of metrics batches (_next)
                    self._send_metrics([entry for request in requests for entry in cast(list, request.metrics)])
            except Exception as error:  # whatever the server does, training goes on
                if not server_unreachable(error):
                    what = requests[0].what
                    if len(requests) > 1:
                        what = f"the metrics of steps {requests[0].step} to {requests[-1].step}"
                    warnings.warn(f"tracking: {self.where} refused {what}: {error}", stacklevel=1)
                    self._done(requests)
                    continue
                if outage_since is None:
                    outage_since = time.monotonic()
                    warnings.warn(
                        f"tracking: {self.where} unreachable ({first_line(error)}); training goes on, the metrics "
                        f"are kept in {self.kept_in} and sent when it is back (trying every {self.retry_seconds:g} s)",
                        stacklevel=1,
                    )
                with self._changed:
                    if self._closing:
                        # An ending run keeps trying, every few seconds, until close's deadline.
                        remaining = self._close_deadline - time.monotonic()
                        if remaining <= 0:
                            return
                        print(
                            f"tracking: {self.where} still unreachable; {len(self._waiting)} request(s) wait, "
                            f"trying again for up to {remaining:.0f} s more",
                            file=sys.stderr,
                        )
                        self._changed.wait(timeout=min(remaining, max(0.05, min(self.retry_seconds, 5.0))))
                    else:
                        self._changed.wait_for(lambda: self._closing, timeout=self.retry_seconds)
                continue
            self._done(requests)
            if outage_since is not None:
                print(
                    f"tracking: {self.where} is back after {time.monotonic() - outage_since:.0f} s; "
                    f"what it missed is being sent",
                    file=sys.stderr,
                )
                outage_since = None

    def _done(self, requests: list[Request]) -> None:
        with self._changed:
            for request in requests:
                if self._waiting and self._waiting[0] is request:
                    self._waiting.popleft()

    def close(self, later: str = "") -> list[Request]:
        """Send what waits, trying again while the server is unreachable, for at most ``close_seconds``; then warn
        about anything left unsent (``later``: how to send it afterwards). Returns what was left."""
        with self._changed:
            waiting = len(self._waiting)
            self._close_deadline = time.monotonic() + self.close_seconds
            self._closing = True
            self._changed.notify()
        if waiting > 1:
            print(
                f"tracking: sending {waiting} waiting request(s) to {self.where} (for up to {self.close_seconds:g} s)",
                file=sys.stderr,
            )
        self._thread.join(timeout=self.close_seconds + 1.0)
        with self._changed:
            left = list(self._waiting)
        steps = sorted(self._given_up_steps + [cast(int, r.step) for r in left if r.metrics is not None])
        others = [r.what for r in left if r.metrics is None]
        if steps or others:
            parts = [f"metrics of {len(steps)} logs (steps {steps[0]} to {steps[-1]})"] if steps else []
            warnings.warn(
                f"tracking: {self.where} did not receive {', '.join(parts + others)} within {self.close_seconds:g} s; "
                f"the metrics are in {self.kept_in}{later}",
                stacklevel=2,
            )
        return left


def first_line(error: BaseException) -> str:
    """The first line of ``error``'s message: MLflow's can run to a traceback, too long for a warning."""
    text = str(error).strip().splitlines()
    return text[0] if text else type(error).__name__
