"""Ordered sums at indices (the GPUs' replacement of index_add_): index_add_'s values, the same bits every run;
with GNS_FLOAT64_SUMS=1, the same bits whatever the order of the rows."""

from __future__ import annotations

import pytest
import torch

from gns_builtins._kernels.segment_sum import segment_sum_, sorted_segment_sum_


def _case(seed: int, rows: int = 500, nodes: int = 37, features: int = 8):
    generator = torch.Generator().manual_seed(seed)
    keys = torch.randint(0, nodes, (rows,), generator=generator)
    values = torch.randn(rows, features, generator=generator) * torch.logspace(-3, 3, features)
    start = torch.randn(nodes, features, generator=generator)
    return keys, values, start


def test_sums_equal_index_add():
    keys, values, start = _case(0)
    expected = start.clone().index_add_(0, keys, values)
    got = segment_sum_(start.clone(), keys, values)
    # float32 sums of ~14 rows per node: a few ulp of the largest partial sum.
    scale = values.abs().sum(0) + start.abs()
    assert ((got - expected).abs() <= 8 * torch.finfo(torch.float32).eps * scale).all()
    order = torch.argsort(keys, stable=True)
    assert torch.equal(sorted_segment_sum_(start.clone(), keys[order], values[order]), got)


def test_float32_sums_give_the_same_bits_every_run():
    keys, values, start = _case(1, rows=4000, nodes=50)
    first = segment_sum_(start.clone(), keys, values)
    assert torch.equal(segment_sum_(start.clone(), keys, values), first)
    shuffle = torch.randperm(keys.numel(), generator=torch.Generator().manual_seed(0))
    assert not torch.equal(segment_sum_(start.clone(), keys[shuffle], values[shuffle]), first), (
        "float32 sums in another order agree: the float64 option below would test nothing"
    )


@pytest.fixture
def float64_sums(monkeypatch):
    monkeypatch.setenv("GNS_FLOAT64_SUMS", "1")


def test_with_float64_sums_the_order_of_the_rows_changes_no_bit(float64_sums):
    """What atomics do to index_add_ on a GPU, done by hand: the rows arrive in another order."""
    keys, values, start = _case(1)
    reference = segment_sum_(start.clone(), keys, values)
    for seed in range(5):
        shuffle = torch.randperm(keys.numel(), generator=torch.Generator().manual_seed(seed))
        assert torch.equal(segment_sum_(start.clone(), keys[shuffle], values[shuffle]), reference)
    in_float32 = start.clone()
    for k in torch.randperm(keys.numel(), generator=torch.Generator().manual_seed(9)).tolist():
        in_float32[keys[k]] += values[k]
    assert not torch.equal(in_float32, reference), "the case is too easy: float32 sums in another order agree"


def test_empty_and_single_runs():
    out = torch.ones(3, 2)
    assert torch.equal(sorted_segment_sum_(out.clone(), torch.empty(0, dtype=torch.long), torch.empty(0, 2)), out)
    got = sorted_segment_sum_(torch.zeros(3, 2), torch.tensor([0, 2]), torch.tensor([[1.0, 2.0], [3.0, 4.0]]))
    assert torch.equal(got, torch.tensor([[1.0, 2.0], [0.0, 0.0], [3.0, 4.0]]))


@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_sums_are_within_float32_rounding_of_a_float64_reference(dtype, monkeypatch):
    """float64 runs are rounded once: within 2 ulp of the absolute sum; float32 runs of ~80 rows within 80."""
    monkeypatch.setenv("GNS_FLOAT64_SUMS", "1" if dtype == "float64" else "0")
    keys, values, start = _case(3, rows=4000, nodes=50)
    reference = start.double().index_add_(0, keys, values.double())
    got = segment_sum_(start.clone(), keys, values)
    ulps = 2 if dtype == "float64" else int(torch.bincount(keys).max()) + 1
    bound = ulps * torch.finfo(torch.float32).eps * (start.double().abs().index_add_(0, keys, values.double().abs()))
    assert ((got.double() - reference).abs() <= bound).all()
    wrong = got.clone()
    wrong[7, 3] += 1e-3 * bound[7, 3].item() / torch.finfo(torch.float32).eps  # a real error, far above rounding
    assert not ((wrong.double() - reference).abs() <= bound).all()


def test_deterministic_sums_switch_picks_the_path_on_accelerators_only():
    from gns_builtins._kernels.segment_sum import needs_ordered_sums
    from gns_framework.runtime.deterministic import deterministic_sums, set_deterministic_sums

    assert deterministic_sums() is True
    assert needs_ordered_sums(torch.device("cuda")) and not needs_ordered_sums(torch.device("cpu"))
    try:
        set_deterministic_sums(False)
        assert not needs_ordered_sums(torch.device("cuda"))
    finally:
        set_deterministic_sums(True)
