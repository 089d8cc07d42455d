"""The dataset-layout contract: metadata and train/valid/test splits on disk."""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, ClassVar

from ..errors import DatasetError
from .params import ComponentParams, Params

if TYPE_CHECKING:
    from ..data.metadata import DatasetMetadata
    from ..data.trajectory import Trajectory


class Dataset(ABC):
    """A dataset layout on disk: metadata plus train/valid/test splits of trajectories."""

    name: ClassVar[str]
    Params: ClassVar[type[Params]] = Params
    writable: ClassVar[bool] = False
    split_suffix: ClassVar[str | None] = None
    """In a layout of one file per split beside the metadata, that file's ending (``.npz``: ``train.npz``)."""

    def __init__(self, params: ComponentParams, path: Path, allow_pickle: bool = False):
        """``allow_pickle``: the user's grant to unpickle anything from the files under ``path``.

        It comes from one command's ``--allow-pickle FOLDER`` for this folder,
        never from a recipe or a checkpoint, which can travel to other data.
        Layouts that store pickles read them without it only where they can do so
        without running code from the file.
        """
        self.params = params
        self.path = Path(path)
        self.allow_pickle = allow_pickle
        self.keep_trajectories: int | None = None
        """How many trajectories of a split stay in memory (``dataset.memory: windows``); None: all that were read."""

    @abstractmethod
    def metadata(self) -> DatasetMetadata:
        """The validated metadata of this dataset."""

    @abstractmethod
    def split(self, name: str) -> Sequence[Trajectory]:
        """Trajectories of a split (``train``, ``valid``, ``test``), loaded lazily and validated."""

    def splits(self) -> list[str]:
        """Names of the splits present on disk."""
        return [s for s in ("train", "valid", "test") if self.has_split(s)]

    def has_split(self, name: str) -> bool:
        """Whether split ``name`` is on disk: its file, in a layout of one file per split."""
        return self.split_suffix is not None and (self.path / f"{name}{self.split_suffix}").is_file()

    def split_file(self, name: str) -> Path:
        """The file of split ``name`` in a layout of one file per split; a missing one is refused, naming it."""
        if self.split_suffix is None:
            raise TypeError(f"dataset layout {self.name!r} does not keep one file per split (no split_suffix)")
        file = self.path / f"{name}{self.split_suffix}"
        if not file.is_file():
            raise DatasetError(f"{file}: split file not found")
        return file

    @classmethod
    def write(cls, path: Path, metadata: DatasetMetadata, splits: Mapping[str, Sequence[Trajectory]]) -> None:
        """Write ``metadata`` and ``splits`` in this layout (only when ``writable``)."""
        raise NotImplementedError(f"dataset layout {cls.name!r} is read-only")
