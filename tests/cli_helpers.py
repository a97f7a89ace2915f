"""Helpers of the command-line tests: run ``main`` in-process, snapshot a folder, check a clean bad-input exit."""

from __future__ import annotations

import hashlib
from pathlib import Path

from mtlx2neural.cli import main


def run_cli(capsys, *argv) -> tuple[int, str, str]:
    """``main(argv)`` in-process: (exit code, stdout, stderr)."""
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def snapshot(folder: Path) -> dict[str, tuple]:
    """Every entry under ``folder``: kind, size, mtime and content hash, by relative path."""
    snap = {}
    for p in sorted(folder.rglob("*")):
        st = p.lstat()
        digest = hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else None
        snap[str(p.relative_to(folder))] = (p.is_dir(), st.st_size, st.st_mtime_ns, digest)
    return snap


def assert_clean_input_error(code: int, out: str, err: str, *expected: str) -> None:
    """Exit 2, no stdout, a one-shot message on stderr naming every ``expected`` string."""
    assert code == 2, f"exit code {code}; stderr:\n{err}"
    assert out == ""
    assert "Traceback" not in err
    assert err.startswith("mtlx2neural: error: "), err
    for s in expected:
        assert s in err, f"{s!r} not in stderr:\n{err}"
