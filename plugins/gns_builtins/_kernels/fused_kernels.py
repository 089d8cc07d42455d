"""Fused bias, ReLU, LayerNorm and residual passes for the chunked edge block on CPU, forward and backward.

On a cache-sized chunk the torch path spends as long on its elementwise passes as
on the matrix products (docs/performance.md): every pass is an OpenMP fork/join
and a read and write of the chunk. ``fused_kernels.c`` does in one pass each: a bias
with its ReLU; the last bias, the LayerNorm, the residual and the sum at receivers; the LayerNorm backward
with the gather of the aggregate's gradient and three column sums; and the ReLU
backward with its bias gradient.

The C file is compiled at first use with the system C compiler (``$CC``, else
``cc``) into a per-user cache keyed by the source, the compiler and the CPU, and
loaded with ctypes. Without a compiler, or with ``GNS_FUSED_KERNELS=0``, every
caller keeps the torch path, which computes the same values.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import platform
import subprocess
import tempfile
import warnings
from functools import cache
from pathlib import Path

import torch
from torch import Tensor

from gns_framework.api import avoids_read_backs

IMPLEMENTS = "processors/interaction_network.py: InteractionStep with edge_block: plain"  # see reading_cost.py

SOURCE = Path(__file__).with_name("fused_kernels.c")
FLAGS = ("-O3", "-march=native", "-fopenmp", "-fPIC", "-shared")


def cache_dir() -> Path:
    """``$GNS_KERNEL_CACHE``, else ``$XDG_CACHE_HOME/gns-framework/kernels`` (``~/.cache`` by default)."""
    if os.environ.get("GNS_KERNEL_CACHE"):
        return Path(os.environ["GNS_KERNEL_CACHE"])
    return Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "gns-framework" / "kernels"


def _cpu_signature() -> str:
    """The model and flags lines of /proc/cpuinfo: ``-march=native`` code is only valid on the same CPU."""
    try:
        lines = Path("/proc/cpuinfo").read_text().splitlines()
    except OSError:
        return platform.processor()
    return "\n".join(sorted({line for line in lines if line.startswith(("model name", "flags"))}))


def _build(compiler: str) -> Path:
    version = subprocess.run([compiler, "--version"], capture_output=True, text=True, check=True).stdout
    source = SOURCE.read_bytes()
    key = hashlib.sha256(b"\0".join([source, " ".join(FLAGS).encode(), version.encode(), _cpu_signature().encode()]))
    library = cache_dir() / f"fused_kernels-{key.hexdigest()[:16]}.so"
    if library.exists():
        return library
    library.parent.mkdir(parents=True, exist_ok=True)
    # Built beside its final name and renamed: concurrent processes never load a half-written file.
    with tempfile.TemporaryDirectory(dir=library.parent) as scratch:
        built = Path(scratch) / library.name
        command = [compiler, *FLAGS, "-o", str(built), str(SOURCE), "-lm"]
        result = subprocess.run(command, capture_output=True, text=True, check=False)
        if result.returncode != 0:
            raise RuntimeError(f"{compiler} failed on {SOURCE}:\n{result.stderr.strip()}")
        os.replace(built, library)
    return library


@cache
def library() -> ctypes.CDLL | None:
    """The loaded kernels, or None (disabled, or no working compiler: warned once)."""
    if os.environ.get("GNS_FUSED_KERNELS", "1") == "0":
        return None
    compiler = os.environ.get("CC", "cc")
    try:
        lib = ctypes.CDLL(str(_build(compiler)))
    except (OSError, RuntimeError, subprocess.SubprocessError) as error:
        warnings.warn(f"fused CPU kernels unavailable, using the torch path: {error}", RuntimeWarning, stacklevel=2)
        return None
    i64, ptr, f32 = ctypes.c_int64, ctypes.c_void_p, ctypes.c_float
    lib.bias_relu.argtypes = [i64, i64, ptr, ptr]
    lib.layer_norm_residual.argtypes = [i64, i64, ptr, ptr, ptr, ptr, f32, ptr, ptr, ptr, ptr, ptr, ptr]
    lib.layer_norm_backward.argtypes = [i64, i64, ptr, ptr, ptr, ptr, ptr, ptr, ptr, ptr, ptr, ptr, ptr, ptr]
    lib.relu_backward.argtypes = [i64, i64, ptr, ptr, ptr]
    for function in (lib.bias_relu, lib.layer_norm_residual, lib.layer_norm_backward, lib.relu_backward):
        function.restype = None
    return lib


def _kernels() -> ctypes.CDLL:
    """The loaded kernels, for the functions below: their callers check :func:`applies` first."""
    lib = library()
    assert lib is not None, "the fused kernels are unavailable: check applies() first"
    return lib


def applies(*tensors: Tensor | None) -> bool:
    """Whether the kernels can take these tensors: float32 (int64 indices), contiguous, on CPU, and built.

    Not while the CPU stands in for an accelerator (a captured step's emulation cannot see ctypes kernels).
    """
    if avoids_read_backs(torch.device("cpu")):
        return False
    for t in tensors:
        if t is not None and not (
            t.device.type == "cpu" and t.dtype in (torch.float32, torch.int64) and t.is_contiguous()
        ):
            return False
    return library() is not None


def _address(t: Tensor | None) -> int | None:
    return None if t is None else t.data_ptr()


def bias_relu_(a: Tensor, bias: Tensor) -> Tensor:
    """``a = relu(a + bias)`` in place; ``a`` (C, H), ``bias`` (H,)."""
    rows, width = a.shape
    _kernels().bias_relu(rows, width, a.data_ptr(), bias.data_ptr())
    return a


def layer_norm_residual(
    a: Tensor,
    bias: Tensor | None,
    gamma: Tensor,
    beta: Tensor,
    eps: float,
    residual: Tensor,
    out: Tensor,
    aggregate: Tensor,
    receivers: Tensor,
    stats: bool,
) -> tuple[Tensor | None, Tensor | None]:
    """``a += bias`` (unless None), ``u = LayerNorm(a)``, ``out = residual + u``, ``aggregate[receivers] += u``.

    ``a``, ``residual`` and ``out``: (C, H); ``out`` may be ``residual``. ``aggregate``
    (N, H); ``receivers`` (C,) int64, **sorted ascending** (each thread then owns whole
    rows of ``aggregate``, and every row sums in edge order, as ``index_add_``).
    Returns ``(mean, rstd)``, (C, 1) as ``torch.native_layer_norm`` returns them, when
    ``stats``, else ``(None, None)``.
    """
    rows, width = a.shape
    mean, rstd = (a.new_empty(rows, 1), a.new_empty(rows, 1)) if stats else (None, None)
    _kernels().layer_norm_residual(
        rows,
        width,
        a.data_ptr(),
        _address(bias),
        gamma.data_ptr(),
        beta.data_ptr(),
        eps,
        residual.data_ptr(),
        out.data_ptr(),
        aggregate.data_ptr(),
        receivers.data_ptr(),
        _address(mean),
        _address(rstd),
    )
    return mean, rstd


def layer_norm_backward(
    grad_aggregate: Tensor | None,
    receivers: Tensor,
    grad_out: Tensor | None,
    a: Tensor,
    mean: Tensor,
    rstd: Tensor,
    gamma: Tensor,
    grad_residual: Tensor,
    grad_gamma: Tensor,
    grad_beta: Tensor,
    grad_bias: Tensor | None,
) -> Tensor:
    """Gradient at ``a`` of :func:`layer_norm_residual`, from ``grad_aggregate[receivers] + grad_out``.

    ``grad_aggregate`` (N, H) and ``grad_out`` (C, H) may each be None, not both.
    Copies ``grad_out`` into ``grad_residual`` (C, H) while reading it (untouched when
    None). Adds into ``grad_gamma``, ``grad_beta`` and, unless None, ``grad_bias`` (the
    column sum of the returned (C, H) gradient: the bias gradient of the layer that
    produced ``a``).
    """
    rows, width = a.shape
    grad_a = torch.empty_like(a)
    _kernels().layer_norm_backward(
        rows,
        width,
        _address(grad_aggregate),
        receivers.data_ptr(),
        _address(grad_out),
        a.data_ptr(),
        mean.data_ptr(),
        rstd.data_ptr(),
        gamma.data_ptr(),
        grad_a.data_ptr(),
        grad_residual.data_ptr(),
        grad_gamma.data_ptr(),
        grad_beta.data_ptr(),
        _address(grad_bias),
    )
    return grad_a


def relu_backward_(grad: Tensor, z: Tensor, grad_bias: Tensor | None) -> Tensor:
    """``grad`` zeroed where ``z`` (a ReLU output) is 0, in place; its column sum added into ``grad_bias``."""
    rows, width = grad.shape
    _kernels().relu_backward(rows, width, grad.data_ptr(), z.data_ptr(), _address(grad_bias))
    return grad
