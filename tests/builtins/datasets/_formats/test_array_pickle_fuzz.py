"""Fuzzing the safe reader of geoelements pickles: damaged real files are read or refused, and never crash it.

Every input is read in a worker process of its own (:mod:`npy_reader_process`), so a
segmentation fault or an abort fails the test with the signal and the saved input
instead of taking pytest down. Every answer must be a read array or a
``DatasetError``; any other exception fails too. The seeds are real files: NumPy's
``np.save`` of geoelements trajectory tuples ``(positions, particle_type[,
material_property])`` and of tuples of float32/float64/int64 arrays of 1 to 3
dimensions, pickled with protocols 2 to 5.
"""

from __future__ import annotations

import io
import itertools
import pickletools
import random

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from npy_reader_process import ReaderProcess, npy_bytes, object_array


def _seed_items() -> dict[str, np.ndarray]:
    generator = np.random.default_rng(0)
    position = generator.random((3, 2, 2)).astype(np.float32)
    return {
        "positions, particle_type": object_array(position, np.array([6, 5], np.int64)),
        "positions, particle_type, material_property": object_array(
            position, np.array([6, 6], np.int64), np.array([0.5, 0.7])
        ),
        "float64 2-D, int64 1-D, Fortran float32 3-D": object_array(
            np.eye(2), np.arange(3), np.asfortranarray(np.ones((2, 1, 2), np.float32))
        ),
    }


SEEDS = {
    f"{name}, protocol {protocol}": npy_bytes(item, protocol)
    for name, item in _seed_items().items()
    for protocol in (2, 3, 4, 5)
}
SEED_NAMES = sorted(SEEDS)


@pytest.fixture(scope="module")
def reader(tmp_path_factory):
    process = ReaderProcess(tmp_path_factory.mktemp("crashes"))
    yield process
    process.close()


def _check(reader: ReaderProcess, data: bytes, what: str) -> str:
    answer = reader.read(data)
    assert answer.startswith(("ok ", "refused ")), f"{what}: {answer}"
    return answer


def test_the_seeds_read_as_they_were_written(reader):
    for name in SEED_NAMES:
        answer = _check(reader, SEEDS[name], name)
        assert answer.startswith("ok [") and ("<f4(3, 2, 2)" in answer or "<f8(2, 2)" in answer), (name, answer)


def _header_length(data: bytes) -> int:
    return 10 + int.from_bytes(data[8:10], "little")


@pytest.mark.parametrize("name", SEED_NAMES)
def test_every_truncation_flip_and_insertion_of_a_real_file(name, reader):
    """Each byte (header and pickle) flipped two ways, each prefix, a byte inserted at each place: read or refused."""
    data = SEEDS[name]
    rng = random.Random(name)
    outcomes = {"ok": 0, "refused": 0}
    for at in range(len(data)):
        for mutated in (
            data[:at] + bytes([data[at] ^ 0xFF]) + data[at + 1 :],
            data[:at] + bytes([data[at] ^ (1 << rng.randrange(8))]) + data[at + 1 :],
            data[:at],
            data[:at] + bytes([rng.randrange(256)]) + data[at:],
        ):
            outcomes[_check(reader, mutated, f"{name}, byte {at}").split(" ", 1)[0]] += 1
    assert outcomes["refused"] >= len(data)  # every truncation at least


def _opcode_chunks(data: bytes) -> list[bytes]:
    """The pickle of a seed cut at its opcodes' boundaries (the header is the first chunk)."""
    start = _header_length(data)
    positions = [start + pos for _, _, pos in pickletools.genops(io.BytesIO(data[start:]))]
    bounds = [0, *positions, len(data)]
    return [data[a:b] for a, b in itertools.pairwise(bounds) if b > a]


CHUNKS = {name: _opcode_chunks(data) for name, data in SEEDS.items()}
"""Each seed as its header and its opcodes (arguments included), for edits that keep opcodes whole."""

mutation = st.one_of(
    st.tuples(st.just("flip"), st.floats(0, 1, exclude_max=True), st.integers(1, 255)),
    st.tuples(st.just("set"), st.floats(0, 1, exclude_max=True), st.integers(0, 255)),
    st.tuples(st.just("insert"), st.floats(0, 1), st.binary(min_size=1, max_size=8)),
    st.tuples(st.just("delete"), st.floats(0, 1, exclude_max=True), st.integers(1, 16)),
    st.tuples(st.just("truncate"), st.floats(0, 1, exclude_max=True), st.just(0)),
    st.tuples(st.just("drop opcode"), st.floats(0, 1, exclude_max=True), st.just(0)),
    st.tuples(st.just("repeat opcode"), st.floats(0, 1, exclude_max=True), st.integers(1, 3)),
    st.tuples(st.just("swap opcodes"), st.floats(0, 1, exclude_max=True), st.floats(0, 1, exclude_max=True)),
    st.tuples(
        st.just("splice opcode"),
        st.floats(0, 1, exclude_max=True),
        st.tuples(st.sampled_from(SEED_NAMES), st.floats(0, 1, exclude_max=True)),
    ),
)


def _mutate(name: str, edits: list[tuple]) -> bytes:
    chunks = list(CHUNKS[name])
    data = b"".join(chunks)
    for kind, where, value in edits:
        if kind.endswith(("opcode", "opcodes")):
            chunks = _opcodes_of(data, chunks)
            if len(chunks) < 2:
                continue
            index = 1 + int(where * (len(chunks) - 1))  # never the header: the pickle is the target
            if kind == "drop opcode":
                del chunks[index]
            elif kind == "repeat opcode":
                chunks[index:index] = [chunks[index]] * value
            elif kind == "swap opcodes":
                other = 1 + int(value * (len(chunks) - 1))
                chunks[index], chunks[other] = chunks[other], chunks[index]
            else:
                source, at = value
                donor = CHUNKS[source]
                chunks.insert(index, donor[1 + int(at * (len(donor) - 1))])
            data = b"".join(chunks)
            continue
        at = int(where * len(data))
        if not data and kind in ("flip", "set", "delete"):
            continue
        if kind == "flip":
            data = data[:at] + bytes([data[at] ^ value]) + data[at + 1 :]
        elif kind == "set":
            data = data[:at] + bytes([value]) + data[at + 1 :]
        elif kind == "insert":
            data = data[:at] + value + data[at:]
        elif kind == "delete":
            data = data[:at] + data[at + value :]
        else:
            data = data[:at]
        chunks = None
    return data


def _opcodes_of(data: bytes, chunks: list[bytes] | None) -> list[bytes]:
    """``chunks`` if still current, else ``data`` cut at whatever opcodes it still parses into (rest: one chunk)."""
    if chunks is not None:
        return chunks
    start = min(_header_length(data), len(data))
    pieces, positions = [data[:start]], []
    try:
        for _, _, pos in pickletools.genops(io.BytesIO(data[start:])):
            positions.append(start + pos)
    except ValueError:
        pass
    bounds = [*positions, len(data)]
    pieces += [data[a:b] for a, b in itertools.pairwise(bounds) if b > a]
    if positions and positions[0] > start:
        pieces.insert(1, data[start : positions[0]])
    return pieces


@settings(max_examples=400, deadline=None, database=None, derandomize=True, suppress_health_check=list(HealthCheck))
@given(name=st.sampled_from(SEED_NAMES), edits=st.lists(mutation, min_size=1, max_size=4))
def test_random_edits_of_real_files_never_crash_the_reader(reader, name, edits):
    """Byte edits (flips, sets, insertions, deletions, truncations) and opcode edits (drop, repeat, swap, splice)."""
    _check(reader, _mutate(name, edits), f"{name} with {edits}")


def test_the_harness_sees_a_death_by_signal(tmp_path):
    """The worker's death is reported, with the signal, the input saved, and the next input gets a fresh worker."""
    from npy_reader_process import ReaderDied

    process = ReaderProcess(tmp_path)
    try:
        process.read(SEEDS[SEED_NAMES[0]])
        process.process.stdin.write(b"\x00\x00\x00")  # half a length prefix: the worker waits for the rest
        process.process.stdin.flush()
        process.process.send_signal(11)
        with pytest.raises(ReaderDied, match=r"died by signal SIGSEGV reading 0 bytes, saved to .*crash-2\.npy"):
            process.read(b"")
        assert process.read(SEEDS[SEED_NAMES[0]]).startswith("ok ")
    finally:
        process.close()
