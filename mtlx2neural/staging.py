"""All-or-nothing, crash-safe writes: stage files in a hidden folder, then move them into place.

Usage::

    with Staging(root) as st:
        write(st.stage(final_dir) / "file.exr")   # a staged copy of final_dir
        st.stage_file(final_usda).write_text(...)
    # leaving the block without an exception commits; with one, nothing is moved

The staging folder is ``root/.mtlx2neural-staging-<pid>-<random>`` (on the same file system
as the targets, so moves are renames). Its ``owner.lock`` is locked (:mod:`.file_lock`) by the
process that stages, for as long as it lives.

**Commit.** :meth:`Staging.commit` first writes ``journal.json`` (state ``committing``, and per
entry: staged name, target path, name of the set-aside copy, whether the target existed), then
per entry, in the order staged: renames an existing target aside into the staging folder,
renames the staged entry over the target. After the last rename the journal's state becomes
``committed`` and the folder (now holding only the old copies) is removed. An exception during
the renames rolls every entry back, so the targets end either all new or all as before.

**Crash recovery.** A SIGKILL (or power cut) can stop the commit between any two renames. The
next :class:`Staging` on the same ``root``, and a conversion before it reads its output
(:func:`recover`), finds staging folders whose ``owner.lock`` can be taken (their owner is
gone) and settles them: ``committing`` is rolled back (each set-aside copy is renamed back over
its target, a new entry without a previous one is withdrawn), so the targets hold the previous
files again, complete; any other state, or no journal (the crash came before the commit, or
during the final clean-up), holds nothing of value and is removed. Each settled folder is
reported (a :func:`warnings.warn` naming it and what was done). Every step of the roll-back is
a rename that can be repeated, so a crash during recovery is recovered by the next one.

``MTLX2NEURAL_FAULT=commit:<k>`` kills the process before the k-th rename (:mod:`.faults`).
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import warnings
from pathlib import Path

from mtlx2neural.faults import fault_point
from mtlx2neural.file_lock import try_lock

PREFIX = ".mtlx2neural-staging-"
"""Name prefix of every staging folder."""
JOURNAL = "journal.json"
OWNER = "owner.lock"


class Staging:
    def __init__(self, root):
        self.root = Path(root)
        self.dir: Path | None = None
        self.recovered: list[str] = []
        """Messages of the staging folders of crashed runs that :meth:`__enter__` settled."""
        self._entries: list[tuple[Path, Path]] = []  # (staged, final)
        self._owner: int | None = None

    def __enter__(self) -> Staging:  # noqa: PYI034 - not meant for subclassing
        self.root.mkdir(parents=True, exist_ok=True)
        self.recovered = recover(self.root)
        self.dir = Path(tempfile.mkdtemp(prefix=f"{PREFIX}{os.getpid()}-", dir=self.root))
        self._owner = os.open(self.dir / OWNER, os.O_RDWR | os.O_CREAT, 0o644)
        try_lock(self._owner)  # a new file: nobody else holds it
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
        """Move every staged entry over its target (module docstring); all or nothing."""
        plan = [{"staged": staged.name, "final": str(final), "old": f"old_{i}_{final.name}",
                 "existed": _exists(final)} for i, (staged, final) in enumerate(self._entries)]
        _write_journal(self.dir, "committing", plan)
        k = 0
        try:
            for e in plan:
                final = Path(e["final"])
                final.parent.mkdir(parents=True, exist_ok=True)
                if e["existed"]:  # 1. the previous target aside
                    fault_point("commit", k)
                    k += 1
                    os.replace(final, self.dir / e["old"])
                fault_point("commit", k)  # 2. the new entry in
                k += 1
                os.replace(self.dir / e["staged"], final)
            fault_point("commit", "done")
            _write_journal(self.dir, "committed", plan)
        except BaseException:
            _roll_back(self.dir, plan)
            _write_journal(self.dir, "rolled back", plan)
            raise

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            if exc_type is None:
                self.commit()
        finally:
            settled = _state(self.dir) != "committing"  # else a failed roll-back: the next run's
            os.close(self._owner)
            if settled:
                shutil.rmtree(self.dir, ignore_errors=True)


def _exists(path: Path) -> bool:
    return path.exists() or path.is_symlink()


def _write_journal(folder: Path, state: str, plan: list[dict]) -> None:
    tmp = folder / f"{JOURNAL}.tmp"
    with open(tmp, "w") as f:
        json.dump({"state": state, "entries": plan}, f)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, folder / JOURNAL)


def _read_journal(folder: Path) -> dict | None:
    try:
        return json.loads((folder / JOURNAL).read_text())
    except (OSError, ValueError):
        return None


def _state(folder: Path) -> str | None:
    journal = _read_journal(folder)
    return journal.get("state") if journal else None


def _roll_back(folder: Path, plan: list[dict]) -> list[str]:
    """Put every target of ``plan`` back as it was before the commit; the targets restored or withdrawn.
    Each step is a rename, and the rules hold after any prefix of them, so this can be repeated."""
    done = []
    for e in reversed(plan):
        final, staged, old = Path(e["final"]), folder / e["staged"], folder / e["old"]
        if _exists(old):  # the previous target was set aside: the new one (if in) goes back first
            if _exists(final):
                _withdraw(final, staged)
            os.replace(old, final)
            done.append(f"restored {final}")
        elif not e["existed"] and _exists(final) and not _exists(staged):  # new, with no previous one
            _withdraw(final, staged)
            done.append(f"withdrew {final}")
    return done


def _withdraw(final: Path, staged: Path) -> None:
    if _exists(staged):
        _remove(final)
    else:
        os.replace(final, staged)


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError):
        return True
    return True


def recover(root) -> list[str]:
    """Settle the staging folders in ``root`` left by runs that died (module docstring); a message
    per folder, also given as a warning. Folders of live runs are left alone."""
    root = Path(root)
    messages = []
    try:
        folders = sorted(p for p in root.iterdir() if p.name.startswith(PREFIX) and p.is_dir())
    except OSError:
        return messages
    for folder in folders:
        message = _recover_one(folder)
        if message:
            messages.append(message)
            warnings.warn(message, stacklevel=3)
    return messages


def _recover_one(folder: Path) -> str | None:
    owner = folder / OWNER
    if not owner.is_file():  # made by an older version, or a run between mkdtemp and its lock
        pid = folder.name[len(PREFIX):].split("-", 1)[0]
        if not pid.isdigit() or _pid_alive(int(pid)):
            return None
        if any(p.name.startswith("old_") for p in folder.iterdir()):
            return (f"{folder}: a crashed run of an older mtlx2neural left previous outputs here; it has no "
                    f"journal to restore them from, so it was left in place for you to inspect")
        shutil.rmtree(folder, ignore_errors=True)
        return f"{folder}: removed the staging folder of an interrupted run (nothing had been moved)"
    try:
        fd = os.open(owner, os.O_RDWR)
    except OSError:
        return None
    try:
        if not try_lock(fd):
            return None  # its owner is alive
        journal = _read_journal(folder)
        state = journal.get("state") if journal else None
        if state == "committing":
            done = _roll_back(folder, journal["entries"])
            _write_journal(folder, "rolled back", journal["entries"])
            what = "; ".join(done) or "no target had been replaced yet"
            message = (f"{folder}: an earlier run was killed while moving its outputs into place; the previous "
                       f"outputs were put back ({what})")
        elif state == "committed":
            message = f"{folder}: removed the previous outputs that a completed commit had set aside"
        else:
            message = f"{folder}: removed the staging folder of an interrupted run (nothing had been moved)"
    finally:
        os.close(fd)
    shutil.rmtree(folder, ignore_errors=True)
    return message


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    elif _exists(path):
        path.unlink()
