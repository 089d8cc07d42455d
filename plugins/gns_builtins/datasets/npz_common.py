"""Layouts with one ``<split>.npz`` per split: clear errors for missing or damaged archives."""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np

from gns_framework.contracts import Dataset
from gns_framework.data.metadata import DatasetMetadata, load_metadata
from gns_framework.errors import DatasetError


class NpzSplitsDataset(Dataset):
    """Base of layouts storing ``metadata.json`` beside one ``<split>.npz`` per split."""

    def metadata(self) -> DatasetMetadata:
        return load_metadata(self.path)

    def has_split(self, name: str) -> bool:
        return (self.path / f"{name}.npz").is_file()


def open_npz(path: Path, allow_pickle: bool = False) -> np.lib.npyio.NpzFile:
    if not path.is_file():
        raise DatasetError(f"{path}: split file not found")
    try:
        return np.load(path, allow_pickle=allow_pickle)
    except (zipfile.BadZipFile, EOFError, OSError, ValueError) as exc:
        raise DatasetError(f"{path}: not a readable .npz archive (truncated or corrupt?): {exc}") from None


def read_member(archive: np.lib.npyio.NpzFile, path: Path, key: str) -> np.ndarray:
    try:
        return archive[key]
    except ValueError as exc:
        if "allow_pickle" in str(exc):
            raise DatasetError(
                f"{path}: {key}: holds pickled Python objects, and unpickling runs code stored in the "
                "file. Only for files you trust, opt in with `allow_pickle: true` in the recipe's "
                "dataset section (or --allow-pickle on the command line)."
            ) from None
        raise DatasetError(f"{path}: {key}: unreadable array: {exc}") from None
    except (zipfile.BadZipFile, EOFError, OSError, KeyError) as exc:
        raise DatasetError(f"{path}: {key}: truncated or corrupt member: {exc}") from None
