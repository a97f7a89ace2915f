"""Non-blocking advisory file locks held by a process for its lifetime.

``flock`` on POSIX and ``msvcrt.locking`` on Windows: the operating system releases them when
the holder exits, by a crash or a kill included, so a lock that can be taken proves that its
previous holder is gone. Used by the output lock (:mod:`mtlx2neural.pipeline.lock`) and by the
staging folders' owner files (:mod:`mtlx2neural.staging`).
"""

from __future__ import annotations

import os

try:  # POSIX
    import fcntl

    def try_lock(fd: int) -> bool:
        """Take an exclusive lock on the open file ``fd``; False when another process holds it."""
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return True
        except BlockingIOError:
            return False

    def unlock(fd: int) -> None:
        fcntl.flock(fd, fcntl.LOCK_UN)
except ImportError:  # Windows
    import msvcrt

    def try_lock(fd: int) -> bool:
        """Take an exclusive lock on the open file ``fd``; False when another process holds it."""
        try:
            os.lseek(fd, 0, os.SEEK_SET)
            msvcrt.locking(fd, msvcrt.LK_NBLCK, 1)
            return True
        except OSError:
            return False

    def unlock(fd: int) -> None:
        os.lseek(fd, 0, os.SEEK_SET)
        msvcrt.locking(fd, msvcrt.LK_UNLCK, 1)
