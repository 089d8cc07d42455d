"""Keeping freed memory in the process: glibc's malloc tuned once (mmap off for large blocks, a high trim
threshold), nothing done elsewhere or with GNS_KEEP_FREED_MEMORY=0."""

from __future__ import annotations

import pytest

from gns_framework.runtime import allocator


class FakeLibc:
    """Records mallopt calls and answers with ``results`` in turn (glibc returns 1 on success, 0 on error)."""

    def __init__(self, results=(1, 1)):
        self.calls: list[tuple[int, int]] = []
        self._results = list(results)

    def mallopt(self, option, value):
        self.calls.append((option, value))
        return self._results[len(self.calls) - 1]


@pytest.fixture
def fake_glibc(monkeypatch):
    """This process seen as glibc's, with a fake C library: the real one is never tuned by these tests."""
    libc = FakeLibc()
    monkeypatch.setattr(allocator.platform, "libc_ver", lambda: ("glibc", "2.39"))
    monkeypatch.setattr(allocator.ctypes, "CDLL", lambda name: libc)
    monkeypatch.delenv("GNS_KEEP_FREED_MEMORY", raising=False)
    monkeypatch.setattr(allocator, "_applied", None)
    return libc


def test_on_glibc_large_blocks_stay_off_mmap_and_the_heap_top_is_kept(fake_glibc):
    assert allocator.keep_freed_memory() is True
    # M_MMAP_MAX = -4 to 0: no block is served by mmap; M_TRIM_THRESHOLD = -1 to the largest int mallopt takes.
    assert fake_glibc.calls == [(-4, 0), (-1, 2**31 - 1)]


def test_it_is_applied_once_per_process(fake_glibc):
    assert allocator.keep_freed_memory() and allocator.keep_freed_memory()
    assert len(fake_glibc.calls) == 2


def test_a_refused_setting_means_the_tuning_is_not_in_effect(fake_glibc, monkeypatch):
    monkeypatch.setattr(allocator.ctypes, "CDLL", lambda name: FakeLibc(results=(1, 0)))
    assert allocator.keep_freed_memory() is False


def test_the_environment_opts_out(fake_glibc, monkeypatch):
    monkeypatch.setenv("GNS_KEEP_FREED_MEMORY", "0")
    assert allocator.keep_freed_memory() is False and fake_glibc.calls == []


def test_another_c_library_is_left_alone(fake_glibc, monkeypatch):
    monkeypatch.setattr(allocator.platform, "libc_ver", lambda: ("", ""))  # musl, macOS, Windows
    assert allocator.keep_freed_memory() is False and fake_glibc.calls == []
