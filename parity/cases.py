"""Reference cases: the ``.npz`` + ``.json`` fixtures of ``shared/parity`` (format in its README).

Cases are found, never listed: every ``*.npz`` of the folder with a ``meta/json``
member is one, so new cases in the same format are picked up as they are added.
"""

from __future__ import annotations

import functools
import itertools
import json
import os
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from gns_framework.data.batch import ParticleBatch
from gns_framework.data.trajectory import Trajectory
from gns_framework.importers.geoelements import ImportedCheckpoint, import_geoelements_checkpoint

ENV_VAR = "GNS_PARITY_DIR"
DEFAULT_DIR = Path(__file__).resolve().parents[1].parent / "shared" / "parity"
"""``<repo>/../shared/parity``: the fixtures live beside the project, never inside it."""


def parity_dir(option: str | None) -> Path:
    """The fixture folder: ``--parity-dir``, else ``$GNS_PARITY_DIR``, else ``<repo>/../shared/parity``."""
    return Path(option or os.environ.get(ENV_VAR) or DEFAULT_DIR)


def find_case_files(folder: Path) -> list[Path]:
    """Every ``*.npz`` in ``folder`` holding a ``meta/json`` member, sorted by name."""
    if not folder.is_dir():
        return []
    found = []
    for path in sorted(folder.glob("*.npz")):
        with zipfile.ZipFile(path) as archive:
            if "meta/json.npy" in archive.namelist():
                found.append(path)
    return found


@dataclass(frozen=True)
class ReferenceCase:
    """One fixture: the reference's parameters, inputs and every stored output.

    Shapes follow the fixture README: N particles, B examples, d dims, E edges.
    """

    name: str
    path: Path
    meta: dict
    arrays: dict[str, np.ndarray]

    def __contains__(self, key: str) -> bool:
        return key in self.arrays

    def tensor(self, key: str) -> Tensor:
        return torch.from_numpy(self.arrays[key])

    @property
    def parameters(self) -> dict[str, Tensor]:
        """The reference ``state_dict`` (geoelements keys)."""
        return {k[len("param/") :]: self.tensor(k) for k in self.arrays if k.startswith("param/")}

    @property
    def particle_types(self) -> list[int]:
        return sorted(set(self.arrays["input/particle_type"].tolist()))

    @property
    def examples(self) -> list[slice]:
        """Particle range of each example (particles are stored example after example)."""
        ends = np.cumsum(self.arrays["input/nparticles_per_example"]).tolist()
        return [slice(start, end) for start, end in itertools.pairwise([0, *ends])]

    def material_property(self) -> Tensor | None:
        """(N, 1) or None."""
        return self.tensor("input/material_property")[:, None] if "input/material_property" in self else None

    def batch(self) -> ParticleBatch:
        """The input window of every example, with its label."""
        counts = self.tensor("input/nparticles_per_example")
        return ParticleBatch(
            position_sequence=self.tensor("input/position_sequence"),
            particle_type=self.tensor("input/particle_type"),
            batch=torch.repeat_interleave(torch.arange(len(counts)), counts),
            num_examples=len(counts),
            next_position=self.tensor("input/next_position"),
            material_property=self.material_property(),
        )

    def trajectory(self, example: slice) -> Trajectory:
        """One example's stored trajectory, time-major as datasets hold it."""
        prop = self.material_property()
        return Trajectory(
            position=np.ascontiguousarray(self.arrays["input/trajectory"][example].transpose(1, 0, 2)),
            particle_type=self.arrays["input/particle_type"][example],
            material_property=None if prop is None else prop[example].numpy(),
            key=f"{self.name}[{example.start}:{example.stop}]",
        )

    def import_model(self) -> ImportedCheckpoint:
        """The reference parameters in the built-in components, through the user-facing importer."""
        types: list[int] | None = self.particle_types
        if self.meta["model"]["nparticle_types"] > 1 and len(types) == 1:
            # One type would be folded into the encoder bias, leaving the embedding's gradient
            # without a counterpart; keeping every row keeps every gradient comparable.
            types = None
        return import_geoelements_checkpoint(
            self.parameters,
            self.meta["metadata"],
            particle_types=types,
            noise_std=self.meta["noise_std"],
        )


@functools.cache
def load_case(path: Path) -> ReferenceCase:
    """Read (and cache: the members are LZMA-compressed) one fixture."""
    with np.load(path) as archive:
        arrays = {key: archive[key] for key in archive.files}
    return ReferenceCase(path.stem, path, json.loads(str(arrays["meta/json"])), arrays)
