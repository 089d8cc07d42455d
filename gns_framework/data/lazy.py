"""A split of trajectories read on first access, validated, then kept in memory (all, or the most recently used)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from functools import lru_cache

from .npz_mapping import DatasetChanged, FileIdentity, check_unchanged
from .trajectory import DomainCheck, Trajectory


class TrajectorySequence(Sequence[Trajectory]):
    """Trajectories of one split file.

    Args:
        keys: trajectory keys in file order.
        load: reads the raw trajectory of a key (may raise DatasetError).
        source: the file, for error messages.
        dim: spatial dimensions the metadata promises.
        keep: how many recently used trajectories stay in memory (None: every one read stays).
        domain: where particles may be (``DatasetMetadata.domain_check()``); None: not checked.
    """

    def __init__(
        self,
        keys: Sequence[str],
        load: Callable[[str], Trajectory],
        source: str,
        dim: int,
        keep: int | None = None,
        domain: DomainCheck | None = None,
    ):
        self.keys = list(keys)
        self._load = load
        self._source = source
        self._dim = dim
        self._domain = domain
        self._get = lru_cache(maxsize=keep)(self._validated)
        # The file as it was when the split was opened: every later read checks it is still that file, unchanged,
        # so a split rewritten between two reads never mixes old and new trajectories.
        self._identity = FileIdentity.of_path(source)

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
        self._check_unchanged()
        raw = self._load(self.keys[index])
        check_unchanged(raw.position)  # a mapped member: checked before validation reads its every page
        trajectory = raw.validated(self._source, dim=self._dim, domain=self._domain)
        self._check_unchanged()
        return trajectory

    def _check_unchanged(self) -> None:
        if self._identity is None:
            return
        change = self._identity.change(FileIdentity.of_path(self._source))
        if change is not None:
            raise DatasetChanged(
                f"{self._source}: changed while it was being read ({change}); stopped rather than read it: put the "
                "data back as it was (or train on a copy), then resume"
            )
