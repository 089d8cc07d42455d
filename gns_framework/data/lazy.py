"""A split of trajectories read on first access, validated, then kept in memory (all, or the most recently used)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from functools import lru_cache

from .trajectory import Trajectory


class TrajectorySequence(Sequence[Trajectory]):
    """Trajectories of one split file.

    Args:
        keys: trajectory keys in file order.
        load: reads the raw trajectory of a key (may raise DatasetError).
        source: the file, for error messages.
        dim: spatial dimensions the metadata promises.
        keep: how many recently used trajectories stay in memory (None: every one read stays).
    """

    def __init__(
        self, keys: Sequence[str], load: Callable[[str], Trajectory], source: str, dim: int, keep: int | None = None
    ):
        self.keys = list(keys)
        self._load = load
        self._source = source
        self._dim = dim
        self._get = lru_cache(maxsize=keep)(self._validated)

    def __len__(self) -> int:
        return len(self.keys)

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        if index < 0:
            index += len(self)
        if not 0 <= index < len(self):
            raise IndexError(index)
        return self._get(index)

    def _validated(self, index: int) -> Trajectory:
        return self._load(self.keys[index]).validated(self._source, dim=self._dim)
