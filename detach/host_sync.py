"""When the environment step may read a tensor's value on the host.

Reading a value of an accelerator tensor (`bool(t.any())`, `len(t.nonzero())`, `.item()`)
waits for every queued kernel, so a step with a few such reads runs at the pace of its reads,
not of its kernels. On the CPU a read costs nothing, and skipping the work a mask leaves idle
saves time. `may_any(mask)` answers "must the work guarded by this mask run?": exactly for CPU
tensors, and True without reading on an accelerator, where the guarded work is written so that
an all-false mask changes nothing. `deferred_reads()` gives CPU tensors the accelerator's answer,
so a test on a CPU can check that the step makes no other host read (tests/test_host_sync.py).
Code traced by `torch.compile` (`sim.compile`) gets the accelerator's answer too: a read there
would split the compiled graph in two.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar

import torch

_DEFERRED: ContextVar[bool] = ContextVar("detach_deferred_host_reads", default=False)


def reads_are_free(t: torch.Tensor) -> bool:
    """Whether reading t's values on the host costs no synchronisation (a CPU tensor, outside
    `deferred_reads` and outside code that `torch.compile` traces)."""
    return not torch.compiler.is_compiling() and t.device.type == "cpu" and not _DEFERRED.get()


def may_any(mask: torch.Tensor) -> bool:
    """mask.any() where reading it is free, else True (see the module docstring)."""
    return bool(mask.any()) if reads_are_free(mask) else True


def rows_at(n: int, ids: torch.Tensor, values: torch.Tensor, fill: float | bool = 0) -> torch.Tensor:
    """[n, ...]: values [len(ids), ...] at rows ids, fill elsewhere. Widening a subset to all
    rows by scatter needs no host read; narrowing all rows to a subset by mask would."""
    out = torch.full((n, *values.shape[1:]), fill, dtype=values.dtype, device=values.device)
    out[ids] = values
    return out


@contextmanager
def deferred_reads() -> Iterator[None]:
    """Within this block, CPU tensors are treated as an accelerator's: `may_any` is True."""
    token = _DEFERRED.set(True)
    try:
        yield
    finally:
        _DEFERRED.reset(token)


def to_device_async(t: torch.Tensor, device: torch.device) -> torch.Tensor:
    """t (a host tensor) on device without waiting: on CUDA through pinned memory and a
    non-blocking copy, since a copy from pageable memory waits for the device's queue (torch's
    caching host allocator keeps the pinned buffer until the copy is done); as is elsewhere."""
    if device.type != "cuda" or t.device.type != "cpu":
        return t.to(device)
    return t.pin_memory().to(device, non_blocking=True)
