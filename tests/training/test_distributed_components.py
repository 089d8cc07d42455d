"""Every built-in processor, integrator and graph builder trains under 2-process torchrun, the ranks in step.

DistributedDataParallel (without ``find_unused_parameters``) stops a run at the step
after a parameter got no gradient, so a component with a parameter its output never
reaches fails here; one whose ranks drift apart fails the equality checks.
"""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from spawned import free_loopback_port
from tiny import TINY_GRAPH_BUILDERS as GRAPH_BUILDERS
from tiny import TINY_PROCESSORS as PROCESSORS
from training_support import subprocess_env, tiny_recipe, trainable_integrators

from gns_framework.plugins import load_registry

REGISTRY = load_registry()
WORKER = Path(__file__).with_name("ddp_worker.py")
STEPS = 3
"""Two would do (DDP refuses a parameter without a gradient at the next step); the third shows the ranks stay in
step."""


# Integrators that share another's position map are refused for training (tests/assembly/test_learned.py).
TRAINABLE_INTEGRATORS = trainable_integrators(REGISTRY)


def cases():
    """Each processor with an integrator and a graph builder, so that every built-in is in some case.

    radius_torch_cluster has a case of its own (with the reference components), skipped
    when torch-cluster is missing, so that no other component loses its case with it.
    """
    integrators = TRAINABLE_INTEGRATORS
    builders = [name for name in GRAPH_BUILDERS if name != "radius_torch_cluster"]
    count = max(len(PROCESSORS), len(integrators), len(builders))
    processors = sorted(PROCESSORS)
    for i in range(count):
        yield pytest.param(
            processors[i % len(processors)],
            integrators[i % len(integrators)],
            builders[i % len(builders)],
            id=f"{processors[i % len(processors)]}-{integrators[i % len(integrators)]}-{builders[i % len(builders)]}",
        )
    torch_cluster = pytest.mark.skipif(
        not importlib.util.find_spec("torch_cluster"), reason="torch-cluster is not installed"
    )
    yield pytest.param(
        "interaction_network",
        "semi_implicit_euler",
        "radius_torch_cluster",
        marks=torch_cluster,
        id="interaction_network-semi_implicit_euler-radius_torch_cluster",
    )


def test_the_cases_cover_every_built_in_component():
    covered = [param.values for param in cases()]

    def built_in(kind: str) -> set[str]:  # installed plugins, such as the example processor, add others
        return {e.name for e in REGISTRY.entries(kind) if e.distribution == "gns-framework"}

    assert {c[0] for c in covered} == built_in("processor") == set(PROCESSORS)
    assert {c[1] for c in covered} == set(TRAINABLE_INTEGRATORS)
    assert {c[2] for c in covered} == built_in("graph_builder") == set(GRAPH_BUILDERS)


@pytest.mark.parametrize("processor, integrator, builder", list(cases()))
def test_trains_under_torchrun_with_every_gradient_present_and_equal_on_both_ranks(
    processor, integrator, builder, uneven_dataset, tmp_path
):
    recipe = tiny_recipe(
        uneven_dataset, name="ddp-components", steps=STEPS, checkpoint_every=STEPS, validate_every=1000
    )
    recipe["model"].update(
        processor={"name": processor, **PROCESSORS[processor]},
        integrator={"name": integrator},
        graph_builder={"name": builder, **GRAPH_BUILDERS[builder]},
    )
    if builder == "periodic_radius":
        recipe["model"]["periodic"] = [True, False]  # wrap x, so that ghosts and minimum images take part
    recipe_file = tmp_path / "recipe.json"
    recipe_file.write_text(json.dumps(recipe))
    command = [
        sys.executable,
        "-m",
        "torch.distributed.run",
        "--nnodes",
        "1",
        "--nproc-per-node",
        "2",
        "--master-addr",
        "127.0.0.1",
        "--master-port",
        str(free_loopback_port()),
        "--local-addr",
        "127.0.0.1",
        str(WORKER),
        str(recipe_file),
        str(tmp_path),
        str(STEPS),
    ]
    result = subprocess.run(command, env=subprocess_env(), cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr

    rank0, rank1 = (torch.load(tmp_path / f"rank{rank}.pt", weights_only=True) for rank in (0, 1))
    assert len(rank0["losses"]) == STEPS and rank0["losses"] == rank1["losses"]
    without = sorted(name for name, grad in rank0["grads"].items() if grad is None)
    assert not without, f"parameters without a gradient: {without}"
    for name, grad in rank0["grads"].items():
        assert torch.equal(grad, rank1["grads"][name]), f"gradient of {name} differs between ranks"
        assert torch.equal(rank0["params"][name], rank1["params"][name]), f"{name} differs between ranks"
