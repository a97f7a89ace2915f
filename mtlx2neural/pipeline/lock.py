"""One conversion at a time per output folder: an advisory lock on ``OUT/.mtlx2neural.lock``.

The lock is the operating system's (``flock`` on POSIX, ``msvcrt.locking`` on
Windows), so it is released when the holding process exits, even by a crash or a
kill: a stale lock file never blocks a later run. The holder writes who it is
(pid, host, start time, command line) into the file; a second run that finds the
lock held exits with an :class:`~mtlx2neural.errors.InputError` (exit 2) that
names that process.
"""

from __future__ import annotations

import json
import os
import platform
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from mtlx2neural.errors import InputError
from mtlx2neural.file_lock import try_lock as _try_lock
from mtlx2neural.file_lock import unlock as _unlock

LOCK_FILE = ".mtlx2neural.lock"


def _holder(path: Path) -> str:
    try:
        info = json.loads(path.read_text() or "{}")
    except (OSError, ValueError):
        return "another process"
    when = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(info.get("started", 0)))
    return f"pid {info.get('pid', '?')} on {info.get('host', '?')}, started {when}: {info.get('command', '?')}"


@contextmanager
def output_lock(folder) -> Iterator[Path]:
    """Hold the lock on the output folder ``folder`` (created if missing) for the block's duration."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / LOCK_FILE
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        if not _try_lock(fd):
            raise InputError(f"{folder}: another mtlx2neural run is writing this output ({_holder(path)}). "
                             f"Wait for it to finish, or choose another output with -o")
        info = {"pid": os.getpid(), "host": platform.node(), "started": time.time(),
                "command": " ".join(sys.argv) or "python"}
        os.ftruncate(fd, 0)
        os.lseek(fd, 0, os.SEEK_SET)
        os.write(fd, json.dumps(info).encode())
        try:
            yield path
        finally:
            os.ftruncate(fd, 0)
            _unlock(fd)
    finally:
        os.close(fd)
