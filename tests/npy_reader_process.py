"""The safe ``.npy`` object-array reader run in a process of its own, so a crash (a death by signal) is seen.

:class:`ReaderProcess` starts one worker and sends it ``.npy`` files one after another
(length-prefixed on its stdin); the worker wraps each in an ``.npz`` named
``fuzz.npz`` with the member ``m.npy``, reads it with
:func:`gns_builtins.datasets._formats.array_pickle.read_npy_object_array`, touches every array it
got (sum, copy, repr), and answers one line: ``ok <summary>``, ``refused <message>``
(a :class:`~gns_framework.errors.DatasetError`) or ``other <type>: <message>`` (any
other exception). A worker that dies is reported with its signal and the input that
killed it, and a fresh worker is started for the next input.
"""

from __future__ import annotations

import io
import os
import pickle
import signal
import struct
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np

WORKER = r"""
import io, struct, sys, zipfile
import numpy as np
from gns_builtins.datasets._formats.array_pickle import read_npy_object_array
from gns_framework.errors import DatasetError

def touch(value, depth=0):
    if isinstance(value, np.ndarray):
        if value.dtype == object:
            return "[" + ",".join(touch(v, depth + 1) for v in value.reshape(-1)) + "]"
        value.copy().sum()
        repr(value)
        return f"{value.dtype.str}{value.shape}"
    if isinstance(value, (list, tuple)):
        return "(" + ",".join(touch(v, depth + 1) for v in value) + ")"
    repr(value)
    return type(value).__name__

source, sink = sys.stdin.buffer, sys.stdout.buffer
while True:
    head = source.read(4)
    if len(head) < 4:
        break
    data = source.read(struct.unpack(">I", head)[0])
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        archive.writestr("m.npy", data)
    try:
        with zipfile.ZipFile(buffer) as archive:
            archive.filename = "fuzz.npz"
            reply = "ok " + touch(read_npy_object_array(archive, "m.npy"))
    except DatasetError as exc:
        reply = "refused " + str(exc)
    except Exception as exc:
        reply = f"other {type(exc).__name__}: {exc}"
    sink.write(reply.replace("\n", " ").encode("utf-8", "backslashreplace")[:4000] + b"\n")
    sink.flush()
"""


class ReaderDied(AssertionError):
    """The worker died (by a signal, or exited) while reading an input."""


class ReaderProcess:
    """One long-lived worker reading ``.npy`` files; see the module docstring."""

    def __init__(self, crash_dir: Path):
        self.crash_dir = Path(crash_dir)
        self.process: subprocess.Popen | None = None
        self.count = 0

    def _start(self) -> subprocess.Popen:
        env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONFAULTHANDLER": ""}
        return subprocess.Popen(
            [sys.executable, "-c", WORKER],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            env=env,
        )

    def read(self, npy: bytes) -> str:
        """The worker's answer for ``npy``; raises :class:`ReaderDied` (with the input saved) if it died."""
        if self.process is None:  # the first input, or the one after a reported death
            self.process = self._start()
        self.count += 1
        try:
            self.process.stdin.write(struct.pack(">I", len(npy)) + npy)
            self.process.stdin.flush()
            line = self.process.stdout.readline()
        except BrokenPipeError:
            line = b""
        if line:
            return line.decode("utf-8").rstrip("\n")
        code = self.process.wait()
        self.process = None
        self.crash_dir.mkdir(parents=True, exist_ok=True)
        saved = self.crash_dir / f"crash-{self.count}.npy"
        saved.write_bytes(npy)
        cause = f"signal {signal.Signals(-code).name}" if code < 0 else f"exit status {code}"
        raise ReaderDied(f"the reader died by {cause} reading {len(npy)} bytes, saved to {saved}")

    def close(self) -> None:
        if self.process is not None and self.process.poll() is None:
            self.process.stdin.close()
            self.process.wait(timeout=30)
        self.process = None


def object_array(*fields) -> np.ndarray:
    """A 1-D object array holding ``fields`` (as geoelements builds its trajectory tuples)."""
    item = np.empty(len(fields), dtype=object)
    for index, value in enumerate(fields):
        item[index] = value
    return item


def npy_header(shape: tuple[int, ...] = (2,)) -> bytes:
    """The format-1.0 ``.npy`` header of an object array of ``shape``, as ``np.save`` writes it."""
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "|O", "fortran_order": False, "shape": shape})
    return header.getvalue()


def npy_bytes(item: np.ndarray, protocol: int) -> bytes:
    """``item`` as a ``.npy`` file: NumPy's header and NumPy's own pickle of it with ``protocol``."""
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, np.lib.format.header_data_from_array_1_0(item))
    return header.getvalue() + pickle.dumps(item, protocol=protocol)


def npz_bytes(members: dict[str, bytes]) -> bytes:
    """An ``.npz`` (a zip) holding ``.npy`` files given as bytes."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        for key, data in members.items():
            archive.writestr(f"{key}.npy", data)
    return buffer.getvalue()
