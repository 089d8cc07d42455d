"""Shared fixtures: an isolated registry and small synthetic datasets made in-process."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import torch

# Without a GPU, Triton runs its kernels on the CPU (the kernels' tests need it); it reads this when
# triton is first imported, so it is set before anything imports it. CPU models take the Triton path
# only where a test sets GNS_TRITON=interpret.
if not torch.cuda.is_available():
    os.environ.setdefault("TRITON_INTERPRET", "1")

from rollouts import small_metadata, small_rollout
from synthetic import write_synthetic_dataset

from gns_framework.plugins import load_registry

REPO = Path(__file__).resolve().parents[1]


def pytest_collection_modifyitems(config, items):
    """Tests marked ``cuda`` are skipped, saying why, where torch sees no GPU."""
    import torch

    if torch.cuda.is_available():
        return
    reason = pytest.mark.skip(
        reason=f"needs a CUDA GPU: torch {torch.__version__} sees none (torch.cuda.is_available() is False)"
    )
    for item in items:
        if "cuda" in item.keywords:
            item.add_marker(reason)


@pytest.fixture(scope="session", autouse=True)
def mlflow_store_of_the_session(tmp_path_factory):
    """`gns train` tracks to MLflow by default: keep the tests' runs out of the working directory."""
    uri = f"sqlite:///{tmp_path_factory.mktemp('mlflow') / 'mlflow.db'}"
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("MLFLOW_TRACKING_URI", uri)
        yield uri


@pytest.fixture(scope="module")
def one_torch_thread():
    """One intra-op thread for a module's tests, and the count before restored after them.

    On shared cores OpenMP workers spin while other jobs hold the cores; one thread keeps
    the stiff and extreme cases quick. Module-scoped so hypothesis tests can use it.
    """
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="session")
def registry():
    return load_registry()


@pytest.fixture(scope="session")
def dataset_2d(tmp_path_factory) -> Path:
    return write_synthetic_dataset(tmp_path_factory.mktemp("data") / "synthetic2d", train=4, valid=2, test=1)


@pytest.fixture(scope="session")
def dataset_multimaterial(tmp_path_factory) -> Path:
    return write_synthetic_dataset(
        tmp_path_factory.mktemp("data") / "multimaterial2d",
        train=2,
        valid=1,
        test=1,
        particle_types=(5, 6),
        kinematic_floor=True,
        with_property=True,
        frames=20,
    )


@pytest.fixture(scope="session")
def sim_registry():
    return load_registry()


@pytest.fixture(scope="session")
def materials(sim_registry):
    """Every installed material by name, as ground-truth simulators take them."""
    return {name: sim_registry.get("material", name) for name in sim_registry.names("material")}


@pytest.fixture
def make_metadata():
    """Factory of unit-box metadata: ``make_metadata(dim=2, dt=0.01)``."""
    return small_metadata


@pytest.fixture
def make_rollout():
    """Factory of small rollouts: ``make_rollout(dim=2, steps=8, particles=12, history=6, seed=0)``."""
    return small_rollout
