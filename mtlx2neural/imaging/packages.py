"""Textures packed inside a USDZ package: ``/path/asset.usdz[textures/albedo.png]``.

USD names a file inside a package with the package's path followed by the member's path in
square brackets (nested packages nest the brackets). A USDZ package is an uncompressed zip
archive (the USDZ specification), so a member's bytes are read with :mod:`zipfile`, and the
member is written once, per package version, into a private temporary folder that the
process removes when it exits. OpenImageIO then reads that copy like any other file; errors
still name the package path.
"""

from __future__ import annotations

import atexit
import hashlib
import os
import re
import shutil
import tempfile
import threading
import zipfile

from mtlx2neural.errors import InputError

_PACKAGE = re.compile(r"^(?P<package>.+?\.usdz)\[(?P<member>.+)\]$", re.IGNORECASE)
_LOCK = threading.Lock()
_FOLDER: list[str] = []


def is_package_path(path: str) -> bool:
    """Does ``path`` name a file inside a USDZ package (``pkg.usdz[member]``)?"""
    return bool(_PACKAGE.match(os.fspath(path)))


def _folder() -> str:
    with _LOCK:
        if not _FOLDER:
            _FOLDER.append(tempfile.mkdtemp(prefix="mtlx2neural-usdz-"))
            atexit.register(shutil.rmtree, _FOLDER[0], True)
        return _FOLDER[0]


def local_file(path, node: str | None = None) -> str:
    """``path`` itself, or for a member of a USDZ package, a local copy of that member's bytes
    (an :class:`InputError` naming the package when it or the member cannot be read)."""
    path = os.fspath(path)
    m = _PACKAGE.match(path)
    if not m:
        return path
    package, member = local_file(m["package"], node), m["member"]
    inner = _PACKAGE.match(member)  # a package inside the package: extract the inner package first
    name = inner["package"] if inner else member
    where = f" used by node '{node}'" if node else ""
    try:
        stat = os.stat(package)
        key = hashlib.sha256(f"{os.path.realpath(package)}\0{stat.st_mtime_ns}\0{name}".encode()).hexdigest()[:24]
        target = os.path.join(_folder(), key + os.path.splitext(name)[1])
        if not os.path.isfile(target):
            with zipfile.ZipFile(package) as z, z.open(name.replace("\\", "/")) as src:
                tmp = f"{target}.{os.getpid()}.{threading.get_ident()}.tmp"
                with open(tmp, "wb") as dst:
                    shutil.copyfileobj(src, dst)
                os.replace(tmp, target)
    except KeyError:
        raise InputError(f"texture file '{path}'{where}: the package {m['package']} holds no member "
                         f"'{name}'. Fix the path or repackage the asset.") from None
    except (OSError, zipfile.BadZipFile) as exc:
        raise InputError(f"texture file '{path}'{where}: cannot read the package {m['package']} "
                         f"({getattr(exc, 'strerror', None) or exc})") from None
    return local_file(f"{target}[{inner['member']}]", node) if inner else target
