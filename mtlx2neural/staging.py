"""All-or-nothing writes: stage files in a hidden folder, then move them into place.

Usage::

    with Staging(root) as st:
        write(st.stage(final_dir) / "file.exr")   # a staged copy of final_dir
        st.stage_file(final_usda).write_text(...)
    # leaving the block without an exception commits; with one, nothing is moved

The staging folder is ``root/.mtlx2neural-staging-<pid>-<random>`` (on the same file
system as the targets, so moves are renames). ``commit`` moves each staged entry
over its target in the order staged (folders replace whole folders); an entry that
already exists is first renamed aside and restored if a later move fails, so the
targets end either all new or all as before. The staging folder and the set-aside
copies are always removed.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path


class Staging:
    def __init__(self, root):
        self.root = Path(root)
        self.dir: Path | None = None
        self._entries: list[tuple[Path, Path]] = []  # (staged, final)

    def __enter__(self) -> Staging:  # noqa: PYI034 - not meant for subclassing
        self.root.mkdir(parents=True, exist_ok=True)
        self.dir = Path(tempfile.mkdtemp(prefix=f".mtlx2neural-staging-{os.getpid()}-", dir=self.root))
        return self

    def _add(self, final) -> Path:
        final = Path(final).resolve()
        staged = self.dir / f"{len(self._entries)}_{final.name}"
        self._entries.append((staged, final))
        return staged

    def stage(self, final_dir) -> Path:
        """A new empty folder that replaces ``final_dir`` on commit."""
        staged = self._add(final_dir)
        staged.mkdir()
        return staged

    def stage_file(self, final_file) -> Path:
        """A path to write; the file replaces ``final_file`` on commit."""
        return self._add(final_file)

    def commit(self) -> None:
        moved: list[tuple[Path, Path | None]] = []  # (final, set-aside old copy or None)
        try:
            for staged, final in self._entries:
                final.parent.mkdir(parents=True, exist_ok=True)
                old = None
                if final.exists() or final.is_symlink():
                    old = self.dir / f"old_{len(moved)}_{final.name}"
                    os.replace(final, old)
                moved.append((final, old))
                os.replace(staged, final)
        except BaseException:
            for final, old in reversed(moved):
                _remove(final)
                if old is not None:
                    os.replace(old, final)
            raise

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            if exc_type is None:
                self.commit()
        finally:
            shutil.rmtree(self.dir, ignore_errors=True)


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    elif path.exists() or path.is_symlink():
        path.unlink()
