"""Parsers of the flag values argparse cannot check by itself: each returns the value or raises
:class:`argparse.ArgumentTypeError` with the message argparse prints (exit 2, before any work)."""

from __future__ import annotations

import argparse
import math


def _positive(text: str) -> float | None:
    try:
        value = float(text)
    except ValueError:
        return None
    return value if 0 < value < math.inf else None


def texel_density(text: str) -> float:
    """``--texel-density D``: a positive number of latent texels per metre of surface."""
    value = _positive(text)
    if value is None:
        raise argparse.ArgumentTypeError(f"{text!r} is not a texel density (a positive number of latent texels "
                                         f"per metre, e.g. 512)")
    return value


def texel_cap(text: str) -> int | None:
    """``--max-texels N``: a whole number of texels per side; 0 is no cap (None)."""
    n = int(text) if text.strip().isdigit() else -1
    if n < 0:
        raise argparse.ArgumentTypeError(f"{text!r} is not a texel count (a whole number; 0: no cap)")
    return n or None


def flip_budget(text: str) -> float:
    """``--max-error F``: a positive HDR FLIP budget."""
    value = _positive(text)
    if value is None:
        raise argparse.ArgumentTypeError(f"{text!r} is not an HDR FLIP budget (a positive number, e.g. 0.1)")
    return value


def workers(text: str):
    """``--workers N|ray|ray://HOST:PORT`` (:func:`mtlx2neural.pipeline.workers.parse_workers`)."""
    # Local: --help and option errors answer without importing torch (jobs imports it).
    from mtlx2neural.pipeline.workers import parse_workers

    try:
        return parse_workers(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def uv(text: str) -> tuple[float, float]:
    """``--texel U,V``: a texture coordinate, two finite numbers."""
    try:
        u, v = (float(x) for x in text.split(","))
    except ValueError:
        u = v = math.nan
    if not (math.isfinite(u) and math.isfinite(v)):
        raise argparse.ArgumentTypeError(f"{text!r} is not a texture coordinate: give U,V, e.g. 0.25,0.75")
    return u, v
