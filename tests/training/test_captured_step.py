"""The training step captured at a fixed size (training.capture_step): the same steps as eager training."""

from __future__ import annotations

import pytest
import torch
from training_support import tiny_recipe

from gns_framework.config.recipe import validate_recipe
from gns_framework.model.capacity_classes import particle_capacity
from gns_framework.plugins import load_registry
from gns_framework.runtime.capture import CaptureError
from gns_framework.training.captured_step import make_capturable, padded_windows, padding_left_out
from gns_framework.training.trainer import Trainer

STEPS = 10


def recipe(dataset, builder: str = "radius_fixed_capacity", **training) -> dict:
    settings = {"steps": STEPS, "ema_decay": 0.9, "validate_every": 1000, "checkpoint_every": 1000}
    settings.update(training)
    made = tiny_recipe(dataset, **settings)
    made["model"]["graph_builder"] = {"name": builder}
    return made


def trained(made: dict, run_dir, steps: int = STEPS) -> Trainer:
    registry = load_registry()
    trainer = Trainer(validate_recipe(made, registry), registry, run_dir=run_dir, progress=False)
    trainer.checkpoints.start_afresh()
    if trainer.captured is None:
        make_capturable(trainer.optimizer)  # the same fused Adam as the captured run, so only the capture differs
    losses = [float(trainer.train_step()[0]) for _ in range(steps)]
    trainer.losses = losses  # type: ignore[attr-defined]
    return trainer


def largest_difference(a: Trainer, b: Trainer) -> tuple[float, float]:
    """The largest difference of the weights and of their averages, over the largest weight."""
    pairs = list(zip(a.simulator.parameters(), b.simulator.parameters(), strict=True))
    averaged = list(zip(a.ema.module.parameters(), b.ema.module.parameters(), strict=True))
    scale = max(p.abs().max().item() for p, _ in pairs)
    weights = max((p - q).abs().max().item() for p, q in pairs) / scale
    return weights, max((p - q).abs().max().item() for p, q in averaged) / scale


@pytest.fixture(scope="module")
def eager(uneven_dataset, tmp_path_factory):
    return trained(recipe(uneven_dataset), tmp_path_factory.mktemp("eager"))


def test_captured_training_takes_the_eager_steps(uneven_dataset, eager, tmp_path):
    captured = trained(recipe(uneven_dataset, capture_step=True), tmp_path)
    steps = captured.captured
    assert steps is not None and steps.eager_steps == 1
    # Batches of 2 of 4 scenes of 25-54 particles fall in a few classes, each captured once and replayed (again
    # where a later batch of the class needed more edges than its buffers held).
    assert 1 <= len(steps.classes) < STEPS - 1 and len(steps.classes) <= steps.captures < STEPS - 1
    assert sum(kept.steps for kept in steps.classes.values()) == STEPS - 1
    # float32 sums over padded rows in another order: a few ulps (1.2e-7) of the losses and weights, compounded
    # over 10 steps by Adam's division by the gradients' root mean square (measured: 2e-7 and 4e-8).
    assert torch.allclose(torch.tensor(captured.losses), torch.tensor(eager.losses), rtol=1e-5, atol=0)
    weights, averages = largest_difference(captured, eager)
    assert weights < 1e-6 and averages < 1e-6


def test_a_step_left_out_shows(uneven_dataset, eager, tmp_path):
    """The tolerance catches a real error: the captured run one step short of the eager one (measured 7e-4)."""
    short = trained(recipe(uneven_dataset, capture_step=True), tmp_path, steps=STEPS - 1)
    weights, _ = largest_difference(short, eager)
    assert weights > 1e-4


def test_padding_rows_copy_the_last_row_and_form_an_example_of_their_own(uneven_dataset, eager):
    drawn = eager.order.draw(0)
    batch = eager.windows.batch(drawn.mine)
    capacity = particle_capacity(batch.num_particles + 1)
    padded, padding = padded_windows(batch, capacity)
    n = batch.num_particles
    assert padded.num_particles == capacity and padded.num_examples == batch.num_examples + 1
    assert padding.tolist() == [False] * n + [True] * (capacity - n)
    assert torch.equal(padded.position_sequence[n:], batch.position_sequence[-1:].expand(capacity - n, -1, -1))
    assert torch.equal(padded.batch[n:], torch.full((capacity - n,), batch.num_examples))
    assert torch.isfinite(padded.position_sequence).all()
    with pytest.raises(ValueError, match="exceeds a class"):
        padded_windows(batch, n - 1)


def test_padding_rows_join_no_edge_and_leave_every_displacement_finite(uneven_dataset, eager):
    batch = eager.windows.batch(eager.order.draw(0).mine)
    n = batch.num_particles
    padded, padding = padded_windows(batch, n + 12)
    simulator = eager.simulator
    # Left in, the 12 copies of one position in an example of their own would join each other: 144 edges.
    graph = simulator.build_graph(padded.position_sequence, padded)
    among_padding = (graph.senders >= n) & (graph.senders < n + 12)
    assert int(among_padding.sum()) == 144
    with padding_left_out(simulator, padding):
        graph = simulator.build_graph(padded.position_sequence, padded)
    assert simulator.graph_builder.name == "radius_fixed_capacity"  # put back
    sink = n + 12  # the fixed-capacity graph's padding edges join its sink node
    for rows in (graph.senders, graph.receivers):
        assert bool(((rows < n) | (rows == sink)).all())
    assert bool(torch.isfinite(graph.displacement).all())


def test_an_overflowing_class_is_captured_again_and_its_step_redone(uneven_dataset, eager, tmp_path):
    made = recipe(uneven_dataset, capture_step=True)
    registry = load_registry()
    trainer = Trainer(validate_recipe(made, registry), registry, run_dir=tmp_path, progress=False)
    trainer.checkpoints.start_afresh()
    for _ in range(3):
        trainer.train_step()
    steps = trainer.captured
    assert steps is not None
    builder = trainer.simulator.graph_builder
    # Every class's edge buffer a tenth of what it needs: the next step of any class overflows.
    for search in builder._kept.values():
        search.edge_capacity //= 10
    before = steps.captures
    losses = [float(trainer.train_step()[0]) for _ in range(STEPS - 3)]
    assert steps.captures > before
    # The same steps as eager training: no update was taken from an incomplete graph.
    assert torch.allclose(torch.tensor(losses), torch.tensor(eager.losses[3:]), rtol=1e-5, atol=0)
    assert largest_difference(trainer, eager)[0] < 1e-6


def test_a_builder_that_waits_for_the_device_is_named(uneven_dataset, tmp_path):
    made = recipe(uneven_dataset, builder="radius", capture_step=True)
    registry = load_registry()
    trainer = Trainer(validate_recipe(made, registry), registry, run_dir=tmp_path, progress=False)
    trainer.checkpoints.start_afresh()
    trainer.train_step()
    with pytest.raises(CaptureError, match="graph builder 'radius' waits for the device"):
        trainer.train_step()


READS = ("item", "tolist", "cpu", "numpy", "__bool__", "__int__", "__float__", "__index__")


def test_a_replayed_step_reads_back_once_the_capacity_check(uneven_dataset, tmp_path, monkeypatch):
    """After its classes are captured a step waits for the device once: the graph builder's check before the update."""
    from gns_builtins._kernels import fixed_capacity

    registry = load_registry()
    made = recipe(uneven_dataset, capture_step=True, steps=40)
    trainer = Trainer(validate_recipe(made, registry), registry, run_dir=tmp_path, progress=False)
    trainer.checkpoints.start_afresh()
    for _ in range(30):  # every pair of the 4 scenes met, every class captured and grown to what it needs
        trainer.train_step()
    steps = trainer.captured
    assert steps is not None
    captures = steps.captures
    documented: list = []
    originals = {name: getattr(torch.Tensor, name) for name in READS}

    def counted(tensor):
        documented.append(tuple(tensor.shape))
        return originals["tolist"](tensor)

    def forbidden(name):
        def read(self, *args, **kwargs):
            raise AssertionError(f"Tensor.{name} in a captured training step")

        return read

    with monkeypatch.context() as patch:
        for name in READS:
            patch.setattr(torch.Tensor, name, forbidden(name))
        patch.setattr(fixed_capacity, "read_back", counted)
        losses = [trainer.train_step()[0] for _ in range(3)]
    assert steps.captures == captures, "no class was new or grew: the steps replayed captures"
    # The running maximum of what a search needed: pairs, candidates and grid cells per axis.
    assert documented == [(4,)] * 3
    assert all(bool(torch.isfinite(loss)) for loss in losses)


def test_a_captured_run_resumes_where_it_stopped(uneven_dataset, eager, tmp_path):
    """Stopped after 4 steps and resumed in a new process's trainer: the resumed run's first step is eager (it
    makes Adam capturable again from the checkpoint's state), the rest replayed; the weights end as eager ones."""
    registry = load_registry()
    made = recipe(uneven_dataset, capture_step=True, checkpoint_every=4)
    first = Trainer(validate_recipe(made, registry), registry, run_dir=tmp_path, progress=False)
    first.checkpoints.start_afresh()
    first.train(4)
    first.close()
    resumed = Trainer(validate_recipe(made, registry), registry, run_dir=tmp_path, progress=False)
    assert resumed.checkpoints.resume() is not None and resumed.step == 4
    losses = [float(resumed.train_step()[0]) for _ in range(STEPS - 4)]
    assert resumed.captured is not None and resumed.captured.eager_steps == 1
    assert torch.allclose(torch.tensor(losses), torch.tensor(eager.losses[4:]), rtol=1e-5, atol=0)
    weights, averages = largest_difference(resumed, eager)
    assert weights < 1e-6 and averages < 1e-6
