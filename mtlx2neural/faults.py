"""Fault injection for crash and failure tests: the environment variable ``MTLX2NEURAL_FAULT``.

Code that must survive a crash names its dangerous instants with :func:`fault_point`. A test
sets ``MTLX2NEURAL_FAULT`` to a comma-separated list of ``POINT[=ACTION]`` items; a point fires
when its name, or ``name:detail``, equals ``POINT``. Actions:

- ``kill`` (default): SIGKILL this process, as an out-of-memory killer or a power cut would;
- ``exit``: ``os._exit(255)``, as a C library's ``exit()`` does (no Python clean-up runs);
- ``enospc``: raise ``OSError(ENOSPC)`` ("No space left on device"), as a full disk does.

Unset (always, outside tests) the points cost one dictionary lookup. Points in use:

- ``commit:<k>``: before the k-th rename (from 0) of :meth:`mtlx2neural.staging.Staging.commit`,
  and ``commit:done`` after the last;
- ``job:<material name>``: when a training job starts (:func:`mtlx2neural.pipeline.jobs.run_job`);
- ``write:<file name>``: before a staged or atomic file is moved into place.
"""

from __future__ import annotations

import errno
import os
import signal

ENV = "MTLX2NEURAL_FAULT"


def _fire(action: str, where: str) -> None:
    if action == "exit":
        os._exit(255)
    if action == "enospc":
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), where)
    os.kill(os.getpid(), getattr(signal, "SIGKILL", signal.SIGTERM))


def fault_point(name: str, detail: object = None) -> None:
    """Fire the fault that ``MTLX2NEURAL_FAULT`` asks for at ``name`` (or ``name:detail``), if any."""
    spec = os.environ.get(ENV)
    if not spec:
        return
    here = {name} if detail is None else {name, f"{name}:{detail}"}
    for item in spec.split(","):
        point, _, action = item.strip().partition("=")
        if point in here:
            _fire(action or "kill", str(detail) if detail is not None else name)
