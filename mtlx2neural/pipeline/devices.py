"""Where training runs: resolving and checking ``--device``, and naming the device for the record."""

from __future__ import annotations

import platform

import torch

from mtlx2neural.errors import InputError


def device_name(device: str) -> str:
    """``cpu (x86_64)`` or ``cuda:0 (<GPU name>)``: where the training ran, for the metrics."""
    if device.startswith("cuda") and torch.cuda.is_available():
        d = torch.device(device)
        return f"cuda:{d.index or 0} ({torch.cuda.get_device_name(d)})"
    return f"{device} ({platform.machine() or 'unknown'})"


def resolve_device(device: str) -> str:
    """``auto`` -> ``cuda`` when CUDA is available, else ``cpu``; anything else unchanged."""
    if device == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    return device


def check_device(device: str) -> str:
    """``device`` resolved (:func:`resolve_device`), or :class:`~mtlx2neural.errors.InputError`
    when it is not ``auto``, ``cpu``, ``cuda`` or ``cuda:N`` of a GPU this machine has."""
    try:
        d = torch.device(resolve_device(device))
    except (RuntimeError, TypeError):
        d = None
    if d is None or d.type not in ("cpu", "cuda"):
        raise InputError(f"--device {device!r}: not a device mtlx2neural trains on; give cpu, cuda, cuda:N or auto")
    if d.type == "cuda":
        if not torch.cuda.is_available():
            build = f"CUDA {torch.version.cuda}" if torch.version.cuda else "no CUDA (a CPU build)"
            raise InputError(f"--device {device}: CUDA is not available on this machine (torch {torch.__version__} "
                             f"has {build}); use --device cpu, or auto to take a GPU when there is one")
        if d.index is not None and d.index >= torch.cuda.device_count():
            raise InputError(f"--device {device}: this machine has {torch.cuda.device_count()} CUDA device(s), "
                             f"numbered from 0")
    return str(d)
