"""Warp's start-up: no "no CUDA driver" warning on a CPU run unless CUDA was asked for; other lines pass."""

from __future__ import annotations

import os

import pytest

from gns_builtins.simulators._mpm import solver as mpm_solver
from gns_framework.errors import GnsError


def _noisy_init():
    """What Warp's core does on a machine without a driver: C-level writes to descriptor 2."""
    os.write(2, f"Warp CUDA warning: {mpm_solver.NO_CUDA_DRIVER}. GPU execution will not be available.\n".encode())
    os.write(2, b"Warp: some other notice\n")


@pytest.mark.parametrize("device, warned", [("auto", False), ("cpu", False), ("cuda:0", True)])
def test_the_missing_driver_warning_is_dropped_only_when_cuda_was_not_asked_for(monkeypatch, capfd, device, warned):
    monkeypatch.setattr(mpm_solver.wp, "init", _noisy_init)
    monkeypatch.setattr(mpm_solver.wp, "get_cuda_device_count", lambda: 0)
    if device.startswith("cuda"):
        with pytest.raises(GnsError, match=r"simulator\.device .* no CUDA device is available"):
            mpm_solver.resolve_device(device)
    else:
        assert mpm_solver.resolve_device(device) == "cpu"
    err = capfd.readouterr().err
    assert (mpm_solver.NO_CUDA_DRIVER in err) is warned
    assert "Warp: some other notice" in err, "only the driver line is dropped"
