"""Layouts with one ``<split>.npz`` per split: clear errors for missing or damaged archives."""

from __future__ import annotations

import zipfile
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from gns_framework.api import (
    DatasetError,
    DatasetMetadata,
    Trajectory,
    atomic_path,
    check_array_header,
    check_zip_member,
    load_metadata,
)
from gns_framework.contracts import Dataset

from .array_pickle import RefusedGlobal, read_npy_object_array


class NpzSplitsDataset(Dataset):
    """Base of layouts storing ``metadata.json`` beside one ``<split>.npz`` per split."""

    split_suffix = ".npz"

    def metadata(self) -> DatasetMetadata:
        return load_metadata(self.path)

    @staticmethod
    def write_split_files(
        path: Path,
        splits: Mapping[str, Sequence[Trajectory]],
        members: Callable[[Path, int, Trajectory], dict[str, Any]],
        save: Callable[[Path, dict[str, Any]], None],
    ) -> None:
        """Each split as ``path/<split>.npz``, written whole or not at all (an earlier file stays until then):
        ``members(file, index, trajectory)`` names a trajectory's arrays, ``save(file, arrays)`` writes them."""
        for split, trajectories in splits.items():
            file = path / f"{split}.npz"
            arrays: dict[str, Any] = {}  # Any: numpy's stub would match **arrays to savez_compressed's allow_pickle too
            for index, trajectory in enumerate(trajectories):
                arrays.update(members(file, index, trajectory))
            with atomic_path(file, suffix=".npz") as tmp:
                save(tmp, arrays)


def open_npz(path: Path, allow_pickle: bool = False) -> np.lib.npyio.NpzFile:
    """``path`` opened lazily; numpy unpickles its members only with ``allow_pickle`` (the user's grant)."""
    if not path.is_file():
        raise DatasetError(f"{path}: split file not found")
    try:
        return np.load(path, allow_pickle=allow_pickle)
    except (zipfile.BadZipFile, EOFError, OSError, ValueError, NotImplementedError) as exc:
        raise DatasetError(f"{path}: not a readable .npz archive (truncated or corrupt?): {exc}") from None


def read_member(archive: np.lib.npyio.NpzFile, path: Path, key: str) -> np.ndarray:
    """Member ``key`` of a layout of plain arrays: a pickled (object) member is refused, never unpickled."""
    array = _read_plain(archive, path, key)
    if array is None:
        raise DatasetError(
            f"{path}: {key}: holds a pickled object array, but this layout stores plain numeric arrays only "
            "and never unpickles"
        )
    return array


def read_array_pickle(archive: np.lib.npyio.NpzFile, path: Path, key: str) -> np.ndarray:
    """Member ``key``, an object array of numpy arrays, rebuilt without running code from the file.

    :func:`~.array_pickle.read_npy_object_array` reads the pickle
    without unpickling it and refuses anything but plain numeric arrays. Plain
    arrays, and any pickle when ``archive`` was opened with the user's
    ``--allow-pickle`` grant, are read by numpy itself; the caller checks the form.
    """
    array = _read_plain(archive, path, key)
    if array is not None:
        return array
    assert archive.zip is not None  # open (numpy drops it on close)
    try:
        return read_npy_object_array(archive.zip, f"{key}.npy")
    except RefusedGlobal as exc:
        raise DatasetError(
            f"{path}: {key}: refused to unpickle {exc.global_name}: expected a pickle of numpy arrays, which names "
            "only numpy.ndarray, numpy.dtype and numpy's multiarray._reconstruct and scalar; unpickling anything "
            "else runs code stored in the file. Only if you trust the file, opt in for its folder with "
            f"--allow-pickle {path.parent} (gns convert, train, rollout and evaluate take it)"
        ) from None
    except DatasetError:
        raise  # already names the file, the member, the byte and what was found against what was expected
    except (zipfile.BadZipFile, OSError, NotImplementedError) as exc:
        raise DatasetError(f"{path}: {key}: truncated or corrupt member: {exc}") from None
    except Exception as exc:
        # A damaged pickle can fail anywhere in the unpickler (EOFError, KeyError, TypeError, ...).
        reason = f"not a numpy object array of arrays (truncated or corrupt?): {type(exc).__name__}: {exc}"
        raise DatasetError(f"{path}: {key}: {reason}") from None


def check_member_size(archive: np.lib.npyio.NpzFile, path: Path, key: str) -> None:
    """Refuse member ``key`` before numpy inflates or allocates it: a zip bomb, or a header promising more than it
    holds.

    numpy's ``archive[key]`` allocates the array its header describes before reading
    it; the stated shape is checked here against the bytes the member holds and the
    limits (:func:`~gns_framework.limits.check_zip_member`, :func:`~gns_framework.limits.check_array_header`).
    """
    assert archive.zip is not None  # open (numpy drops it on close)
    where = f"{path}: {key}"
    try:
        info = archive.zip.getinfo(f"{key}.npy")
    except KeyError:
        return  # numpy names the missing key
    check_zip_member(where, info)
    headers = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}
    try:
        with archive.zip.open(info) as stream:
            version = np.lib.format.read_magic(stream)
            if version not in headers:
                return  # numpy refuses a format it does not know, naming it
            shape, _, dtype = headers[version](stream)
            header_bytes = stream.tell()
    except (zipfile.BadZipFile, EOFError, OSError, NotImplementedError) as exc:
        raise DatasetError(f"{where}: truncated or corrupt member: {exc}") from None
    except Exception as exc:  # numpy parses the header as a Python literal: ValueError, SyntaxError, TokenError
        raise DatasetError(f"{where}: unreadable .npy header: {type(exc).__name__}: {exc}") from None
    check_array_header(where, shape, dtype, info.file_size - header_bytes)


def _read_plain(archive: np.lib.npyio.NpzFile, path: Path, key: str) -> np.ndarray | None:
    """Member ``key`` as numpy reads it, or None for a pickled member numpy would not unpickle."""
    check_member_size(archive, path, key)
    try:
        return archive[key]
    except ValueError as exc:
        if "allow_pickle" in str(exc):
            return None
        raise DatasetError(f"{path}: {key}: unreadable array: {exc}") from None
    except (zipfile.BadZipFile, EOFError, OSError, KeyError, NotImplementedError) as exc:
        raise DatasetError(f"{path}: {key}: truncated or corrupt member: {exc}") from None
