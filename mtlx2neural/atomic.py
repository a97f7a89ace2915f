"""Atomic single-file writes: write a temporary sibling, then rename it over the target.

A reader never sees a half-written file, and a failed write leaves the old file
(or no file) in place. Whole folders go through :class:`mtlx2neural.staging.Staging`.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from mtlx2neural.faults import fault_point


@contextmanager
def atomic_path(path) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (same suffix, so writers that pick a format from
    the extension still do); when the block ends normally it replaces ``path``, when it raises
    the temporary file is removed and ``path`` is untouched."""
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp{path.suffix}")
    try:
        yield tmp
        fault_point("write", path.name)  # tests: a full disk (mtlx2neural.faults)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
