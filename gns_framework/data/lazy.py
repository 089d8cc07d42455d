"""A split of trajectories read on first access, validated, then kept in memory (all, or the most recently used)."""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Callable, Sequence
from functools import lru_cache

from .file_identity import unchanged_reads
from .trajectory import DomainCheck, Trajectory


class Split(Sequence[Trajectory]):
    """A split's trajectories by index (negative from the end) or slice (a list); ``_at`` reads index i."""

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        if not -len(self) <= index < len(self):
            raise IndexError(f"trajectory {index} of a split of {len(self)}")
        return self._at(index % len(self))

    @abstractmethod
    def _at(self, index: int) -> Trajectory: ...


class TrajectorySequence(Split):
    """Trajectories of one split file: ``keys`` in file order, each read by ``load(key)`` (which may raise
    DatasetError) and validated against ``dim``, the spatial dimensions or the domain every particle must lie in
    (``DatasetMetadata.domain_check()``); ``source``, the file, names them in errors; ``keep`` of the most recently
    used stay in memory (None: every one read stays)."""

    def __init__(
        self, keys: Sequence[str], load: Callable[[str], Trajectory], source: str, dim: int | DomainCheck, keep=None
    ):
        self.keys, self._load, self._source = list(keys), load, source
        self._domain: DomainCheck | None = None if isinstance(dim, int) else dim
        self._dim = dim if isinstance(dim, int) else len(dim.bounds)
        self._get = lru_cache(maxsize=keep)(unchanged_reads(self._validated, source))

    def __len__(self) -> int:
        return len(self.keys)

    def _at(self, index: int) -> Trajectory:
        return self._get(index)

    def in_parts(self, index: int) -> Trajectory:
        """Trajectory ``index`` for processes that each read a run of its particles (``Trajectory.particles``)."""
        return self._validated(index, in_parts=True)

    def _validated(self, index: int, in_parts: bool = False) -> Trajectory:
        return self._load(self.keys[index]).validated(self._source, self._dim, self._domain, in_parts)
