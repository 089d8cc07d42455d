"""Data never runs code: geoelements pickles of arrays read safely, anything more only by a per-command grant."""

from __future__ import annotations

import io
import json
import os
import pickle
import pickletools
import re
import shutil
import struct
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
import yaml
from hostile import MEMBER, write_hostile_dataset
from synthetic import soft_sphere_trajectory, synthetic_metadata
from tiny import tiny_recipe, tiny_recipe_mapping, tiny_trainer

from gns_builtins.datasets._formats.array_pickle import RefusedGlobal, read_npy_object_array
from gns_framework.cli import build_parser, main
from gns_framework.errors import DatasetError
from gns_framework.io.checkpoint import save_checkpoint

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def numpy1_npy(item: np.ndarray) -> bytes:
    """``item`` as NumPy 1.x's ``np.save`` writes it: format 1.0, a protocol-3 pickle naming ``numpy.core``."""
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, np.lib.format.header_data_from_array_1_0(item))
    payload = pickle.dumps(item, protocol=3).replace(b"numpy._core.multiarray", b"numpy.core.multiarray")
    assert b"cnumpy.core.multiarray\n_reconstruct" in payload and b"_core" not in payload
    return header.getvalue() + payload


def write_npz_as_numpy1(path: Path, members: dict[str, np.ndarray]) -> None:
    with zipfile.ZipFile(path, "w") as archive:
        for key, item in members.items():
            archive.writestr(f"{key}.npy", numpy1_npy(item))


def object_array(*fields) -> np.ndarray:
    item = np.empty(len(fields), dtype=object)
    for i, field in enumerate(fields):
        item[i] = field
    return item


def metadata_of(dataset: Path) -> dict:
    return json.loads((dataset / "metadata.json").read_text())


def safe_copy_of(source: Path, registry) -> dict[str, list]:
    cls = registry.get("dataset", "safe")
    dataset = cls(cls.Params(), source)
    return {split: list(dataset.split(split)) for split in dataset.splits()}


@pytest.fixture(scope="module")
def trajectories():
    return [
        soft_sphere_trajectory(
            seed,
            frames=8,
            block=3,
            particle_types=(6,),
            kinematic_floor=True,
            with_property=True,
            key=f"simulation_trajectory_{seed}",
        )
        for seed in range(2)
    ]


@pytest.mark.parametrize("numpy_version", ["2.x", "1.x"])
def test_geoelements_files_as_numpy_writes_them_read_without_opt_in(numpy_version, trajectories, tmp_path, registry):
    """The pickles of NumPy 2.x (protocol 4, ``numpy._core``) and 1.x (protocol 3, ``numpy.core``) hold only arrays."""
    source = tmp_path / "geoelements"
    registry.get("dataset", "npz").write(source, synthetic_metadata(trajectories, 2), {"train": trajectories})
    if numpy_version == "1.x":
        members = {t.key: object_array(t.position, t.particle_type, t.material_property[:, 0]) for t in trajectories}
        write_npz_as_numpy1(source / "train.npz", members)

    assert main(["convert", str(source), "--from", "npz", "--to", "safe", "--out", str(tmp_path / "safe")]) == 0

    back = safe_copy_of(tmp_path / "safe", registry)["train"]
    for original, read in zip(trajectories, back, strict=True):
        np.testing.assert_array_equal(original.position, read.position)
        np.testing.assert_array_equal(original.particle_type, read.particle_type)
        np.testing.assert_array_equal(original.material_property, read.material_property)


@pytest.mark.parametrize("protocol", [3, 4])
def test_array_unpickler_rebuilds_arrays_dtypes_and_scalars(protocol, tmp_path):
    record = np.array([(1.5, 2)], dtype=[("x", "<f4"), ("n", ">i8")])
    matrix = np.arange(6, dtype=np.float32).reshape(2, 3)
    item = object_array(matrix, np.arange(3), np.float32(0.5), record, [1, (2, 3)])
    with zipfile.ZipFile(tmp_path / "a.npz", "w") as archive:
        archive.writestr("m.npy", numpy1_npy(item) if protocol == 3 else _npy(item))
    with zipfile.ZipFile(tmp_path / "a.npz") as archive:
        read = read_npy_object_array(archive, "m.npy")
    assert read.shape == (5,) and read.dtype == object
    np.testing.assert_array_equal(read[0], item[0])
    assert read[0].dtype == np.float32 and read[1].dtype == item[1].dtype
    assert read[2] == np.float32(0.5) and type(read[2]) is np.float32
    assert read[3].dtype == record.dtype and read[3].tolist() == record.tolist()
    assert read[4] == [1, (2, 3)]


def _npy(item: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.save(buffer, item)
    return buffer.getvalue()


def test_array_unpickler_refuses_numpy_globals_beyond_arrays(tmp_path):
    """A masked array needs ``numpy.ma``: more than arrays, so refused before anything is called."""
    with zipfile.ZipFile(tmp_path / "a.npz", "w") as archive:
        archive.writestr("m.npy", _npy(object_array(np.ma.masked_array([1.0, 2.0]), np.arange(2))))
    with zipfile.ZipFile(tmp_path / "a.npz") as archive, pytest.raises(RefusedGlobal) as info:
        read_npy_object_array(archive, "m.npy")
    assert info.value.global_name == "numpy.ma.core._mareconstruct"


def test_damaged_pickle_is_named_by_file_and_member(trajectories, tmp_path, registry):
    cls = registry.get("dataset", "npz")
    cls.write(tmp_path, synthetic_metadata(trajectories, 2), {"train": trajectories})
    whole = numpy1_npy(object_array(trajectories[0].position, trajectories[0].particle_type))
    with zipfile.ZipFile(tmp_path / "train.npz", "w") as archive:
        archive.writestr("simulation_trajectory_0.npy", whole[: len(whole) // 2])
    with pytest.raises(
        DatasetError,
        match=r"train\.npz: simulation_trajectory_0: not a numpy object array of arrays "
        r"\(truncated or corrupt\?\): ",
    ):
        cls(cls.Params(), tmp_path).split("train")[0]


# --- every command that reads data refuses a hostile file ----------------------------------------------------


@pytest.fixture(scope="module")
def trained_state(dataset_2d, tmp_path_factory):
    """The state of a tiny model trained one step on ``dataset_2d``, to store under recipes of our choosing."""
    trainer = tiny_trainer(tiny_recipe(dataset_2d), tmp_path_factory.mktemp("granting") / "run")
    trainer.train(1)
    trainer.close()
    return trainer.checkpoints.state()


def granting_checkpoint(state: dict, path: Path, dataset: Path) -> Path:
    """A checkpoint as earlier versions wrote it for a recipe with ``dataset: {name: npz, allow_pickle: true}``."""
    recipe = {**state["recipe"], "dataset": {"name": "npz", "path": str(dataset), "allow_pickle": True}}
    return save_checkpoint(path, {**state, "recipe": recipe})


def _convert(hostile, trusted, tmp_path, state):
    return ["convert", str(hostile), "--from", "npz", "--to", "safe", "--out", str(tmp_path / "out")]


def _train(hostile, trusted, tmp_path, state):
    recipe = tiny_recipe_mapping(hostile, tmp_path / "run")
    recipe["dataset"]["name"] = "npz"
    (tmp_path / "recipe.yaml").write_text(yaml.safe_dump(recipe))
    return ["train", str(tmp_path / "recipe.yaml"), "--no-progress", "--no-tracking"]


def _rollout_of_its_own_data(hostile, trusted, tmp_path, state):
    checkpoint = granting_checkpoint(state, tmp_path / "run" / "checkpoints" / "model.pt", hostile)
    return ["rollout", str(checkpoint), "--no-progress"]


def _rollout_of_other_data(hostile, trusted, tmp_path, state):
    checkpoint = granting_checkpoint(state, tmp_path / "run" / "checkpoints" / "model.pt", trusted)
    return ["rollout", str(checkpoint), "--dataset", str(hostile), "--no-progress"]


def _evaluate_of_its_own_data(hostile, trusted, tmp_path, state):
    checkpoint = granting_checkpoint(state, tmp_path / "run" / "checkpoints" / "model.pt", hostile)
    return ["evaluate", str(checkpoint), "--no-simulator", "--out", str(tmp_path / "report")]


def _evaluate_of_other_data(hostile, trusted, tmp_path, state):
    checkpoint = granting_checkpoint(state, tmp_path / "run" / "checkpoints" / "model.pt", trusted)
    return ["evaluate", str(checkpoint), "--dataset", str(hostile), "--no-simulator", "--out", str(tmp_path / "report")]


COMMANDS = [
    _convert,
    _train,
    _rollout_of_its_own_data,
    _rollout_of_other_data,
    _evaluate_of_its_own_data,
    _evaluate_of_other_data,
]


@pytest.mark.parametrize("command", COMMANDS, ids=[c.__name__.lstrip("_") for c in COMMANDS])
def test_hostile_file_is_refused_by_every_command_that_reads_data(command, dataset_2d, trained_state, tmp_path, capsys):
    """Refused by name (file, member, global) with an opt-in the command takes; checkpoints' stored grants are void."""
    marker = tmp_path / "marker"
    hostile = write_hostile_dataset(tmp_path / "hostile", metadata_of(dataset_2d), marker)
    trusted = Path(shutil.copytree(dataset_2d, tmp_path / "trusted"))
    argv = command(hostile, trusted, tmp_path, trained_state)

    code = main(argv)

    err = capsys.readouterr().err
    assert not marker.exists(), "the payload ran"
    assert code == 2, err
    assert re.search(rf"{re.escape(str(hostile))}/\w+\.npz: {MEMBER}: refused to unpickle builtins\.exec", err), err
    assert f"--allow-pickle {hostile} " in err
    # The opt-in the message suggests exists for this command.
    build_parser([argv[0]]).parse_args([*argv, "--allow-pickle", str(hostile)])


def test_a_recipe_cannot_grant_unpickling(dataset_2d, tmp_path, capsys):
    marker = tmp_path / "marker"
    hostile = write_hostile_dataset(tmp_path / "hostile", metadata_of(dataset_2d), marker)
    recipe = tiny_recipe_mapping(hostile, tmp_path / "run")
    recipe["dataset"].update(name="npz", allow_pickle=True)
    (tmp_path / "recipe.yaml").write_text(yaml.safe_dump(recipe))

    code = main(["train", str(tmp_path / "recipe.yaml"), "--no-progress", "--no-tracking"])

    err = capsys.readouterr().err
    assert not marker.exists(), "the payload ran"
    assert code == 2 and "dataset.allow_pickle: a recipe cannot grant unpickling" in err, err
    assert "--allow-pickle FOLDER" in err


# --- files that need more than arrays: a grant per command, for one folder -----------------------------------


def write_masked(folder: Path, source: Path, registry) -> Path:
    """``source`` in the geoelements layout with masked positions: benign, but its pickle needs ``numpy.ma``."""
    folder.mkdir()
    shutil.copy(source / "metadata.json", folder)
    for split, trajectories in safe_copy_of(source, registry).items():
        members = {t.key: object_array(np.ma.masked_array(t.position), t.particle_type) for t in trajectories}
        np.savez(folder / f"{split}.npz", **members)
    return folder


def test_allow_pickle_grants_one_folder_for_one_command(dataset_2d, tmp_path, registry, capsys):
    data = write_masked(tmp_path / "masked", dataset_2d, registry)
    convert = ["convert", str(data), "--from", "npz", "--to", "safe", "--out", str(tmp_path / "safe")]

    assert main(convert) == 2
    err = capsys.readouterr().err
    assert "train.npz: train_000: refused to unpickle numpy.ma.core._mareconstruct" in err, err
    assert main([*convert, "--allow-pickle", str(dataset_2d)]) == 2
    err = capsys.readouterr().err
    assert f"--allow-pickle {dataset_2d}: this command reads the dataset in {data}" in err, err
    assert main([*convert, "--allow-pickle", str(data)]) == 0
    converted, original = safe_copy_of(tmp_path / "safe", registry), safe_copy_of(dataset_2d, registry)
    np.testing.assert_array_equal(converted["train"][0].position, original["train"][0].position)

    recipe = tiny_recipe_mapping(data, tmp_path / "run")
    recipe["dataset"]["name"] = "npz"
    (tmp_path / "recipe.yaml").write_text(yaml.safe_dump(recipe))
    train = ["train", str(tmp_path / "recipe.yaml"), "--steps", "1", "--no-progress", "--no-tracking"]
    assert main([*train, "--allow-pickle", str(data)]) == 0, capsys.readouterr().err
    checkpoint = next((tmp_path / "run" / "checkpoints").glob("checkpoint-*.pt"))
    rollout = ["rollout", str(checkpoint), "--steps", "2", "--trajectories", "1", "--no-progress"]
    # The checkpoint of a granted run holds no grant: the next command needs its own.
    assert main(rollout) == 2 and "refused to unpickle numpy.ma.core._mareconstruct" in capsys.readouterr().err
    assert main([*rollout, "--allow-pickle", str(data)]) == 0, capsys.readouterr().err


# --- no pickle machinery runs on the file's bytes: NumPy's own pickles read exactly, forgeries refused ---------

from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402
from npy_reader_process import ReaderProcess, npy_bytes, npy_header, npz_bytes  # noqa: E402

from gns_builtins.datasets._formats.array_pickle import PLAIN_DTYPES, ArrayPickleError  # noqa: E402

READABLE = {
    "positions, particle_type": lambda: object_array(
        np.arange(24, dtype=np.float32).reshape(3, 4, 2), np.array([6, 6, 3, 6], np.int64)
    ),
    "positions, particle_type, material_property": lambda: object_array(
        np.linspace(0, 1, 12, dtype=np.float32).reshape(2, 3, 2), np.full(3, 6, np.int64), np.full(3, 0.7)
    ),
    "float64 2-D, int64 1-D, float32 3-D": lambda: object_array(
        np.eye(3), np.arange(-2, 3, dtype=np.int64), np.ones((2, 1, 3), np.float32)
    ),
    "Fortran order, a strided view": lambda: object_array(
        np.asfortranarray(np.arange(6.0).reshape(2, 3)), np.arange(9)[::3]
    ),
    "big-endian, empty, 0-d": lambda: object_array(
        np.arange(3, dtype=">f8"), np.zeros((0, 2), np.float32), np.array(2.5)
    ),
    "bool, uint8, complex64, float16": lambda: object_array(
        np.array([True, False]), np.array([255], np.uint8), np.array([1j], np.complex64), np.array([0.5], np.float16)
    ),
    "a list, not an object array": lambda: [np.arange(3), np.arange(2)],
}


def _read_bytes(npy: bytes, name: str = "train.npz") -> np.ndarray:
    buffer = io.BytesIO(npz_bytes({"simulation_trajectory_0": npy}))
    with zipfile.ZipFile(buffer) as archive:
        archive.filename = name
        return read_npy_object_array(archive, "simulation_trajectory_0.npy")


def _assert_same_items(read: np.ndarray, item: np.ndarray) -> None:
    assert read.dtype == object and read.shape == item.shape
    for got, want in zip(read, item, strict=True):
        assert type(got) is np.ndarray and got.dtype.str == want.dtype.str and got.shape == want.shape
        np.testing.assert_array_equal(got, want)
        assert got.flags.owndata and got.flags.writeable, "built by np.frombuffer(...).copy(), not a view"
        if want.ndim > 1 and want.flags.f_contiguous and not want.flags.c_contiguous:
            assert got.flags.f_contiguous


@pytest.mark.parametrize("protocol", [2, 3, 4, 5])
@pytest.mark.parametrize("case", [k for k in READABLE if k != "a list, not an object array"])
def test_numpy_pickles_of_protocols_2_to_5_are_read_exactly(case, protocol):
    item = READABLE[case]()
    _assert_same_items(_read_bytes(npy_bytes(item, protocol)), item)


@settings(max_examples=60, deadline=None, database=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(
    protocol=st.integers(2, 5),
    fields=st.lists(
        st.tuples(
            st.sampled_from(sorted(PLAIN_DTYPES)), st.lists(st.integers(0, 4), min_size=1, max_size=3), st.booleans()
        ),
        min_size=1,
        max_size=3,
    ),
    seed=st.integers(0, 2**32 - 1),
)
def test_any_object_array_of_plain_arrays_round_trips(protocol, fields, seed):
    """Whatever whitelisted dtype, shape (1 to 3 dims) and order, the reader gives what NumPy pickled."""
    generator = np.random.default_rng(seed)
    arrays = []
    for dtype, shape, fortran in fields:
        raw = generator.integers(0, 256, size=int(np.prod(shape)) * np.dtype(dtype).itemsize, dtype=np.uint8)
        array = np.frombuffer(raw.tobytes(), dtype=dtype).reshape(shape)
        arrays.append(np.asfortranarray(array) if fortran else array.copy())
    item = object_array(*arrays)
    read = _read_bytes(npy_bytes(item, protocol))
    assert read.shape == item.shape
    for got, want in zip(read, item, strict=True):
        assert got.dtype.str == want.dtype.str and got.shape == want.shape
        assert got.tobytes() == want.tobytes()  # bit for bit: NaN payloads too


# Pickles written opcode by opcode: what a forger writes.

P = pickle


def _u(text: str) -> bytes:
    data = text.encode()
    return P.SHORT_BINUNICODE + bytes([len(data)]) + data


def _global(module: str, name: str) -> bytes:
    return _u(module) + _u(name) + P.STACK_GLOBAL


def _int(value: int) -> bytes:
    return P.BININT1 + bytes([value]) if 0 <= value < 256 else P.BININT + struct.pack("<i", value)


def _bytes(data: bytes) -> bytes:
    return (
        P.SHORT_BINBYTES + bytes([len(data)]) + data
        if len(data) < 256
        else P.BINBYTES + struct.pack("<I", len(data)) + data
    )


def _tuple(*items: bytes) -> bytes:
    return P.MARK + b"".join(items) + P.TUPLE


def _dtype(code: str, order: str, flags: int, elsize: int = -1, alignment: int = -1) -> bytes:
    """``numpy.dtype(code)`` and its state, as NumPy pickles a dtype: the flags are the file's to choose."""
    state = _tuple(_int(3), _u(order), P.NONE, P.NONE, P.NONE, _int(elsize), _int(alignment), _int(flags))
    return _global("numpy", "dtype") + _u(code) + P.NEWFALSE + P.NEWTRUE + P.TUPLE3 + P.REDUCE + state + P.BUILD


def _array(shape: tuple[int, ...], dtype: bytes, data: bytes, fortran: bytes = P.NEWFALSE) -> bytes:
    """``_reconstruct(ndarray, (0,), b'b')`` then ``BUILD`` with ``(1, shape, dtype, fortran, data)``."""
    head = _global("numpy._core.multiarray", "_reconstruct") + _global("numpy", "ndarray")
    head += _int(0) + P.TUPLE1 + _bytes(b"b") + P.TUPLE3 + P.REDUCE
    return head + _tuple(_int(1), _tuple(*map(_int, shape)), dtype, fortran, data) + P.BUILD


def _pickle(body: bytes) -> bytes:
    return P.PROTO + b"\x04" + body + P.STOP


OBJECT_DTYPE = _dtype("O8", "|", 63)


def _tuple_of(*arrays: bytes) -> bytes:
    """The object array holding ``arrays``, as ``np.save`` pickles a geoelements trajectory tuple."""
    return _array((len(arrays),), OBJECT_DTYPE, P.EMPTY_LIST + P.MARK + b"".join(arrays) + P.APPENDS)


FLOATS = _array((2,), _dtype("f8", "<", 0), _bytes(struct.pack("<2d", 1.0, 2.0)))
TYPES = _array((2,), _dtype("i8", "<", 0), _bytes(struct.pack("<2q", 6, 6)))

FORGED_OBJECT_DTYPE = _pickle(_array((2,), _dtype("O8", "|", 0), _bytes(struct.pack("<2Q", 0x4141414141414141, 0x10))))
"""The reported attack: the object dtype with its pickled flags 0, so NumPy takes the file's bytes for pointers."""


def test_the_forged_pickle_is_built_from_opcodes_and_is_accepted_by_pickletools():
    ops = [op.name for op, _, _ in pickletools.genops(FORGED_OBJECT_DTYPE)]
    assert ops.count("REDUCE") == 2 and ops.count("BUILD") == 2 and ops[-1] == "STOP"
    assert _read_bytes(npy_header() + _pickle(_tuple_of(FLOATS, TYPES)))[0].tolist() == [1.0, 2.0]


def test_the_forged_pickle_crashes_numpys_own_unpickler(tmp_path):
    """What the test guards against is real: numpy's ``__setstate__`` on these bytes dies (or this numpy refuses)."""
    script = "import pickle, sys; a = pickle.loads(sys.stdin.buffer.read()); print(repr(a))"
    done = subprocess.run([sys.executable, "-c", script], input=FORGED_OBJECT_DTYPE, capture_output=True, timeout=120)
    if done.returncode >= 0:
        pytest.skip(f"this numpy does not crash on the forged dtype (exit status {done.returncode})")
    assert done.returncode < 0


@pytest.fixture(scope="module")
def reader(tmp_path_factory):
    process = ReaderProcess(tmp_path_factory.mktemp("crashes"))
    yield process
    process.close()


FORGED = {
    "the object dtype with flags 0 (the attack)": (
        FORGED_OBJECT_DTYPE,
        " of the pickle: numpy.dtype('O8') with state (3, '|', None, None, None, -1, -1, 0); "
        "expected numpy.dtype('O8', False, True) with state (3, '|', None, None, None, -1, -1, 63)",
    ),
    "the attack inside a trajectory tuple": (
        _pickle(_tuple_of(FORGED_OBJECT_DTYPE[2:-1], TYPES)),
        "numpy.dtype('O8') with state (3, '|', None, None, None, -1, -1, 0)",
    ),
    "float64 with the object flags": (
        _pickle(_array((2,), _dtype("f8", "<", 63), _bytes(bytes(16)))),
        "numpy.dtype('f8') with state (3, '<', None, None, None, -1, -1, 63); expected numpy.dtype('f8', False, True) "
        "with state (3, '<', None, None, None, -1, -1, 0)",
    ),
    "a unicode dtype": (_pickle(_array((1,), _dtype("U2", "<", 8, 8, 4), _bytes(bytes(8)))), "dtype '<U2'"),
    "long double": (_pickle(_array((1,), _dtype("f16", "<", 0), _bytes(bytes(16)))), "dtype '<f16'"),
    "a multi-byte dtype without byte order": (
        _pickle(_array((1,), _dtype("f8", "|", 0), _bytes(bytes(8)))),
        "dtype '|f8'",
    ),
    "too few bytes": (
        _pickle(_array((3,), _dtype("f8", "<", 0), _bytes(bytes(16)))),
        "16 bytes of data for a float64 array of shape (3,); expected 3 x 8 = 24 bytes",
    ),
    "too many bytes": (_pickle(_array((1,), _dtype("f8", "<", 0), _bytes(bytes(16)))), "16 bytes of data"),
    "a negative dimension": (
        _pickle(_array((2,), _dtype("f8", "<", 0), _bytes(bytes(16)))).replace(_tuple(_int(2)), _tuple(_int(-2)), 1),
        "shape (-2,); expected a tuple of at most 32 non-negative ints",
    ),
    "a shape of 2^62 elements over an empty axis": (
        _pickle(_array((0,), _dtype("f8", "<", 0), _bytes(b""))).replace(
            _tuple(_int(0)), _tuple(_int(0), P.LONG1 + b"\x08" + (2**62).to_bytes(8, "little")), 1
        ),
        "with at most 1099511627776 elements",
    ),
    "a 33-dimensional shape": (
        _pickle(_array((1,) * 33, _dtype("f8", "<", 0), _bytes(bytes(8)))),
        "a tuple of at most 32 non-negative ints",
    ),
    "an order flag that is not a bool": (
        _pickle(_array((1,), _dtype("f8", "<", 0), _bytes(bytes(8)), fortran=_int(7))),
        "order flag 7",
    ),
    "an object array with bytes for data": (
        _pickle(_array((2,), OBJECT_DTYPE, _bytes(bytes(16)))),
        "an object array of shape (2,) with a bytes for data",
    ),
    "an object array of the wrong length": (
        _pickle(_array((3,), OBJECT_DTYPE, P.EMPTY_LIST + P.MARK + FLOATS + P.APPENDS)),
        "a list of 3 items",
    ),
    "os.system by GLOBAL": (_pickle(b"cos\nsystem\n" + _u("true") + P.TUPLE1 + P.REDUCE), "refused global os.system"),
    "numpy.frombuffer": (_pickle(_global("numpy", "frombuffer")), "refused global numpy.frombuffer"),
    "a numpy.dtype REDUCE with other arguments": (
        _pickle(_global("numpy", "dtype") + _u("f8") + P.TUPLE1 + P.REDUCE),
        "numpy.dtype('f8',); expected (code, False, True)",
    ),
    "_reconstruct of another class": (
        _pickle(
            _global("numpy._core.multiarray", "_reconstruct")
            + _global("numpy", "dtype")
            + _int(0)
            + P.TUPLE1
            + _bytes(b"b")
            + P.TUPLE3
            + P.REDUCE
        ),
        "expected (numpy.ndarray, (0,), b'b')",
    ),
    "REDUCE of numpy.ndarray itself": (
        _pickle(_global("numpy", "ndarray") + _tuple(_int(1)) + P.REDUCE),
        "REDUCE calling numpy.ndarray",
    ),
    "NEWOBJ": (_pickle(_global("numpy", "ndarray") + P.EMPTY_TUPLE + P.NEWOBJ), "opcode NEWOBJ"),
    "an out-of-band buffer": (_pickle(P.NEXT_BUFFER), "opcode NEXT_BUFFER"),
    "a Python 2 string": (_pickle(P.SHORT_BINSTRING + b"\x01b"), "opcode SHORT_BINSTRING"),
    "protocol 1": (P.PROTO + b"\x01" + P.NONE + P.STOP, "pickle protocol 1; expected 2 to 5"),
    "a second BUILD of an array": (_pickle(FLOATS + _tuple(_int(1)) + P.BUILD), "a second BUILD of the array"),
    "a dtype used before its state": (
        _pickle(
            _array(
                (1,),
                _global("numpy", "dtype") + _u("f8") + P.NEWFALSE + P.NEWTRUE + P.TUPLE3 + P.REDUCE,
                _bytes(bytes(8)),
            )
        ),
        "is used before its state is set",
    ),
    "a list holding itself": (
        _pickle(
            _array(
                (1,),
                OBJECT_DTYPE,
                P.EMPTY_LIST + P.BINPUT + b"\x07" + P.EMPTY_LIST + P.BINGET + b"\x07" + P.APPEND + P.TUPLE1,
            )
        ).replace(P.TUPLE1 + P.BUILD, P.BUILD),
        "",
    ),
    "lists nested 100 deep": (
        _pickle(_array((1,), OBJECT_DTYPE, P.EMPTY_LIST + (P.EMPTY_LIST * 100) + P.APPEND * 100)),
        "containers nested deeper than 64",
    ),
    "a dict key that is an array": (
        _pickle(P.EMPTY_DICT + FLOATS + _int(1) + P.SETITEM),
        "a dict key of the array made at byte",
    ),
    "BINGET of an index never stored": (_pickle(P.BINGET + b"\x09"), "BINGET 9, which was never stored"),
    "a structured dtype with an object field": (
        _pickle(
            _array(
                (1,),
                _global("numpy", "dtype")
                + _u("V8")
                + P.NEWFALSE
                + P.NEWTRUE
                + P.TUPLE3
                + P.REDUCE
                + _tuple(
                    _int(3),
                    _u("|"),
                    P.NONE,
                    _u("p") + P.TUPLE1,
                    P.EMPTY_DICT + _u("p") + OBJECT_DTYPE + _int(0) + P.TUPLE2 + P.SETITEM,
                    _int(8),
                    _int(1),
                    _int(63),
                )
                + P.BUILD,
                _bytes(bytes(8)),
            )
        ),
        "field 'p' of dtype object; expected a numeric field",
    ),
    "a structured dtype with a field past its end": (
        _pickle(
            _array(
                (1,),
                _global("numpy", "dtype")
                + _u("V8")
                + P.NEWFALSE
                + P.NEWTRUE
                + P.TUPLE3
                + P.REDUCE
                + _tuple(
                    _int(3),
                    _u("|"),
                    P.NONE,
                    _u("p") + P.TUPLE1,
                    P.EMPTY_DICT + _u("p") + _dtype("f8", "<", 0) + _int(4) + P.TUPLE2 + P.SETITEM,
                    _int(8),
                    _int(1),
                    _int(16),
                )
                + P.BUILD,
                _bytes(bytes(8)),
            )
        ),
        "field 'p' at bytes 4..12; expected within the item's 8 bytes",
    ),
    "a float array where the header promises an object array": (_pickle(FLOATS), "the pickle holds dtype float64"),
    "a truncated pickle": (
        _pickle(_tuple_of(FLOATS, TYPES))[:-40],
        "not a numpy object array of arrays (truncated or corrupt?)",
    ),
    "values left on the stack": (_pickle(_tuple_of(FLOATS, TYPES) + P.NONE), "STOP with 2 values and 0 marks left"),
}


@pytest.mark.parametrize("case", list(FORGED))
def test_forged_pickles_are_refused_with_a_located_error_and_no_crash(case, reader):
    """Read in a process of its own: a refusal names file, member, byte and found vs expected; nothing dies."""
    body, expected = FORGED[case]
    answer = reader.read(npy_header() + body)
    assert re.match(
        r"refused fuzz\.npz: m: (refused|not a numpy object array of arrays \(truncated or corrupt\?\)): ", answer
    ), answer
    assert expected in answer, answer


def test_a_refusal_is_a_dataset_error_with_its_parts():
    with pytest.raises(ArrayPickleError) as info:
        _read_bytes(npy_header() + _pickle(_array((3,), _dtype("f8", "<", 0), _bytes(bytes(16)))))
    error = info.value
    assert isinstance(error, DatasetError)
    assert (error.file, error.member) == ("train.npz", "simulation_trajectory_0")
    assert error.found == "16 bytes of data for a float64 array of shape (3,)"
    assert error.expected == "3 x 8 = 24 bytes" and isinstance(error.position, int)


def _forged_dataset(folder: Path, metadata: dict) -> Path:
    folder.mkdir(parents=True)
    (folder / "metadata.json").write_text(json.dumps(metadata))
    npy = npy_header() + _pickle(_tuple_of(FORGED_OBJECT_DTYPE[2:-1], TYPES))
    for split in ("train", "valid", "test"):
        (folder / f"{split}.npz").write_bytes(npz_bytes({MEMBER: npy}))
    return folder


@pytest.mark.parametrize("command", ["convert", "train"])
def test_the_forged_npz_is_refused_by_convert_and_train_in_one_line(command, dataset_2d, tmp_path):
    """The reported crash, end to end: ``gns convert --from npz`` and ``gns train`` exit 2 naming file and member."""
    hostile = _forged_dataset(tmp_path / "hostile", metadata_of(dataset_2d))
    if command == "convert":
        argv = ["convert", str(hostile), "--from", "npz", "--to", "safe", "--out", str(tmp_path / "out")]
    else:
        recipe = tiny_recipe_mapping(hostile, tmp_path / "run")
        recipe["dataset"]["name"] = "npz"
        (tmp_path / "recipe.yaml").write_text(yaml.safe_dump(recipe))
        argv = ["train", str(tmp_path / "recipe.yaml"), "--no-progress", "--no-tracking"]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    done = subprocess.run(
        [sys.executable, "-m", "gns_framework.cli", *argv],
        capture_output=True,
        text=True,
        timeout=300,
        env=env,
        cwd=tmp_path,
    )
    assert done.returncode == 2, (done.returncode, done.stderr)
    line = f"gns {command}: error: {hostile}/train.npz: {MEMBER}: refused: byte "
    assert line in done.stderr and "numpy.dtype('O8') with state (3, '|', None, None, None, -1, -1, 0)" in done.stderr
    assert "Traceback" not in done.stderr
