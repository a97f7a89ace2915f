"""Error types shared by every stage.

``InputError`` means the user's input is wrong (missing file, malformed document,
unsupported node, ...). The CLI maps it to exit code 2 (a conversion that skips some materials
for it, and converts the others, exits 3); every other ``Mtlx2NeuralError`` maps to exit code 1. Messages name the file, prim or node,
say what is wrong, and say what to do about it.
"""


class Mtlx2NeuralError(Exception):
    """Base class for errors that mtlx2neural reports to the user."""

    exit_code = 1


class InputError(Mtlx2NeuralError):
    """The input asset is missing, malformed or uses something unsupported.

    ``node``: the MaterialX node path (or USD prim) at fault, when one is (for per-material
    failure reports); the message names it too.
    """

    exit_code = 2

    def __init__(self, *args, node: str | None = None):
        super().__init__(*args)
        self.node = node


class UnsupportedNodeError(InputError):
    """A node whose nodedef has no torch implementation and no nodegraph to expand."""


def unreadable_reason(path) -> str | None:
    """Why the existing file ``path`` cannot be opened for reading (``"permission denied"``, or the
    operating system's reason), for error messages; None when it can be read."""
    try:
        with open(path, "rb"):
            return None
    except PermissionError:
        return "permission denied"
    except OSError as exc:
        return exc.strerror or str(exc)


def missing_reason(path, missing: str = "does not exist") -> str:
    """Why ``path``, which is not a readable file, cannot be read, for error messages: ``"is a folder, not a
    file"``, ``"is a symbolic link that loops"``, ``"is a symbolic link to a missing file (TARGET)"`` or
    ``missing``."""
    import errno
    import os

    path = os.fspath(path)
    if os.path.isdir(path):
        return "is a folder, not a file"
    try:
        os.stat(path)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            return "is a symbolic link that loops (it resolves to itself)"
        if os.path.islink(path):
            return f"is a symbolic link to a missing file ({os.readlink(path)})"
        return missing
    return "is not a regular file"


WRITE_ERRNOS = ("ENOSPC", "EDQUOT", "EROFS", "EFBIG", "EIO")
"""``errno`` names of failures to write (a full disk or quota, a read-only or failing file system)."""


def write_failure(exc: BaseException, where) -> OSError | None:
    """``exc`` as an :class:`OSError` naming ``where`` when it is a failure to write (a full disk...),
    whatever layer raised it (torch reports one as a ``RuntimeError``: "file write failed"); else None.
    Such a failure is the machine's, not one material's: it ends the run (exit 1)."""
    import errno
    import os

    codes = {getattr(errno, n) for n in WRITE_ERRNOS if hasattr(errno, n)}
    if isinstance(exc, OSError) and exc.errno in codes:
        name = os.fspath(exc.filename) if exc.filename else ""
        name = name if os.path.isabs(name) else os.path.join(os.fspath(where), os.path.basename(name))
        return OSError(exc.errno, exc.strerror or os.strerror(exc.errno), name)
    text = str(exc)
    if "No space left on device" in text or "file write failed" in text:
        code = errno.ENOSPC if "No space left" in text else errno.EIO
        return OSError(code, f"{os.strerror(code)} ({text.strip().splitlines()[-1][:200]})", str(where))
    return None
