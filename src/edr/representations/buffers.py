"""Output memory for the fused kernels: ``out=`` checked, and big outputs recycled.

A fresh output of tens of MB (a 250-frame 320x240 clip of EDR events is 153 MB) is returned to
the OS when freed (glibc serves it by mmap), and the next call's output pays a page fault and a
zeroed page per 4 KiB on first write: more than EDR's own computation. :data:`RECYCLED` keeps
the memory of big outputs once the caller has dropped every tensor that views it, and hands it
to the next call of the same size: the plain call then runs as fast as with ``out=``, without
changing the process's allocator. It holds at most ``limit_bytes`` (1 GiB) of freed outputs;
:meth:`Recycler.clear` gives them back.

An output's death runs no Python code: its weak reference's callback is a C method that queues
the reference, and the next call takes the queue in. Ctrl-C or SIGTERM raises where Python code
runs, and in a callback of the garbage collector it would be printed and dropped ("Exception
ignored in"), leaving training to carry on.
"""

from __future__ import annotations

import threading
import weakref
from collections import OrderedDict

import numpy as np
import torch


class Recycler:
    """Outputs of ``min_bytes`` or more, backed by memory this object keeps after they die."""

    def __init__(self, limit_bytes: int = 1 << 30, min_bytes: int = 4 << 20) -> None:
        self.limit_bytes, self.min_bytes = limit_bytes, min_bytes
        self._free: OrderedDict[int, list[np.ndarray]] = OrderedDict()  # nbytes -> owners, LRU
        self._free_bytes = 0
        self._lock = threading.Lock()
        self._lent: dict[int, tuple[weakref.ref, np.ndarray]] = {}  # id(ref) -> (ref, owner)
        self._dead: list[weakref.ref] = []  # refs whose view died: list.append runs no bytecode

    def empty(self, shape: tuple[int, ...], dtype: torch.dtype = torch.float32) -> torch.Tensor:
        """An uninitialised CPU tensor, on recycled memory when it is big."""
        nbytes = int(np.prod(shape)) * torch.empty((), dtype=dtype).element_size()
        if nbytes < self.min_bytes:
            return torch.empty(shape, dtype=dtype)
        with self._lock:
            self._take_back()
            owners = self._free.get(nbytes)
            owner = owners.pop() if owners else None
            if owner is not None:
                self._free_bytes -= nbytes
                if not owners:
                    del self._free[nbytes]
        if owner is None:
            owner = np.empty(nbytes, np.uint8)
        view = owner[:]  # the tensor keeps this view alive; when it dies the owner comes back
        ref = weakref.ref(view, self._dead.append)
        with self._lock:
            self._lent[id(ref)] = (ref, owner)
        return torch.from_numpy(view).view(dtype).view(shape)

    def _take_back(self) -> None:
        """Hold for reuse the owners whose views died since the last call (under the lock)."""
        while self._dead:
            _, owner = self._lent.pop(id(self._dead.pop()))
            self._free.setdefault(owner.nbytes, []).append(owner)
            self._free.move_to_end(owner.nbytes)
            self._free_bytes += owner.nbytes
        while self._free_bytes > self.limit_bytes and self._free:
            nbytes, owners = next(iter(self._free.items()))  # least recently given back
            owners.pop(0)
            self._free_bytes -= nbytes
            if not owners:
                del self._free[nbytes]

    @property
    def free_bytes(self) -> int:
        """Bytes of freed outputs held for reuse."""
        with self._lock:
            self._take_back()
            return self._free_bytes

    def clear(self) -> None:
        """Give every held buffer back to the allocator."""
        with self._lock:
            self._take_back()
            self._free.clear()
            self._free_bytes = 0


RECYCLED = Recycler()


def output(
    out: torch.Tensor | None, shape: tuple[int, ...], dtype: torch.dtype, device: torch.device
) -> torch.Tensor:
    """``out`` checked against the result it will hold, or a new (recycled) tensor."""
    if out is None:
        if device.type == "cpu":
            return RECYCLED.empty(shape, dtype)
        return torch.empty(shape, dtype=dtype, device=device)
    if tuple(out.shape) != tuple(shape) or out.dtype != dtype or out.device != device:
        raise ValueError(
            f"out is {out.dtype} {tuple(out.shape)} on {out.device}; this call writes "
            f"{dtype} {tuple(shape)} on {device}"
        )
    return out


def writable(out: torch.Tensor) -> bool:
    """Whether a fused kernel can write straight into ``out`` (CPU float32, contiguous)."""
    return out.device.type == "cpu" and out.dtype == torch.float32 and out.is_contiguous()
