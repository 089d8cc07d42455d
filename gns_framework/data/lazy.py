"""A split of trajectories read on first access, validated, then kept in memory."""

from __future__ import annotations

from collections.abc import Callable, Sequence

from .trajectory import Trajectory


class TrajectorySequence(Sequence[Trajectory]):
    """Trajectories of one split file.

    Args:
        keys: trajectory keys in file order.
        load: reads the raw trajectory of a key (may raise DatasetError).
        source: the file, for error messages.
        dim: spatial dimensions the metadata promises.
    """

    def __init__(self, keys: Sequence[str], load: Callable[[str], Trajectory], source: str, dim: int):
        self.keys = list(keys)
        self._load = load
        self._source = source
        self._dim = dim
        self._cache: dict[int, Trajectory] = {}

    def __len__(self) -> int:
        return len(self.keys)

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        if index < 0:
            index += len(self)
        if not 0 <= index < len(self):
            raise IndexError(index)
        if index not in self._cache:
            self._cache[index] = self._load(self.keys[index]).validated(self._source, dim=self._dim)
        return self._cache[index]
