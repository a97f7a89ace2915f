"""Crash-safe commit (:mod:`mtlx2neural.staging`): a process killed (SIGKILL) before any rename of
the commit, or after the last, leaves targets that the next run settles to either all previous or
all new files, complete, and no staging folder behind; a live run's staging folder is never touched.

The kill is real: a child process stages an "export" (a folder with files, a layer file, and a
folder that did not exist before) and ``MTLX2NEURAL_FAULT=commit:<k>`` SIGKILLs it before the k-th
rename (:mod:`mtlx2neural.faults`).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from mtlx2neural.staging import PREFIX, Staging, recover

CHILD = textwrap.dedent("""
    import sys
    from pathlib import Path
    from mtlx2neural.staging import Staging
    root = Path(sys.argv[1])
    with Staging(root) as st:
        d = st.stage(root / "out" / "mat" / "neural")
        (d / "latents.exr").write_text("new latents")
        (d / "weights.bin").write_text("new weights")
        st.stage(root / "out" / "fresh").joinpath("a.txt").write_text("new fresh")
        st.stage_file(root / "layer.usda").write_text("new layer -> out/mat/neural")
""")
RENAMES = 5  # two existing targets (aside + in each) and one new target (in)


def _old_export(root: Path) -> None:
    (root / "out" / "mat" / "neural").mkdir(parents=True)
    (root / "out" / "mat" / "neural" / "latents.exr").write_text("old latents")
    (root / "out" / "mat" / "neural" / "weights.bin").write_text("old weights")
    (root / "layer.usda").write_text("old layer -> out/mat/neural")


def _state(root: Path) -> str:
    """"old" or "new" when every target is wholly one or the other; else a description of the mix."""
    neural = root / "out" / "mat" / "neural"
    files = sorted(p.name for p in neural.iterdir()) if neural.is_dir() else []
    texts = {(neural / f).read_text().split()[0] for f in files}
    layer = (root / "layer.usda").read_text().split()[0] if (root / "layer.usda").is_file() else None
    fresh = (root / "out" / "fresh").exists()
    if files == ["latents.exr", "weights.bin"] and texts == {"old"} and layer == "old" and not fresh:
        return "old"
    if files == ["latents.exr", "weights.bin"] and texts == {"new"} and layer == "new" and fresh:
        return "new"
    return f"mixed: neural {files} {texts}, layer {layer}, fresh {fresh}"


def _run_child(root: Path, fault: str | None) -> int:
    env = {**os.environ}
    env.pop("MTLX2NEURAL_FAULT", None)
    if fault:
        env["MTLX2NEURAL_FAULT"] = fault
    return subprocess.run([sys.executable, "-c", CHILD, str(root)], env=env, timeout=120).returncode


@pytest.mark.parametrize("k", [*range(RENAMES), "done"])
def test_a_kill_at_any_rename_of_the_commit_is_recovered_to_old_or_new(tmp_path, k):
    _old_export(tmp_path)
    rc = _run_child(tmp_path, f"commit:{k}")
    assert rc == -signal.SIGKILL, f"the child was to be killed at rename {k} (rc {rc})"
    left = [p for p in tmp_path.iterdir() if p.name.startswith(PREFIX)]
    assert len(left) == 1, "the killed run leaves its staging folder"
    with pytest.warns(UserWarning, match="killed while moving|removed the previous outputs"):
        messages = recover(tmp_path)
    assert len(messages) == 1 and str(left[0]) in messages[0]
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(PREFIX)], "recovery removes the folder"
    # Before the last rename nothing is committed: the previous export is back, whole. After it
    # ("done": killed before the journal said so) recovery may roll back too; either is complete.
    assert _state(tmp_path) == ("new" if k == "done" and messages[0].startswith("removed") else "old")
    # A later run commits normally over the recovered state.
    assert _run_child(tmp_path, None) == 0
    assert _state(tmp_path) == "new"


def test_the_next_staging_recovers_and_says_so(tmp_path):
    _old_export(tmp_path)
    assert _run_child(tmp_path, "commit:2") == -signal.SIGKILL
    assert _state(tmp_path) != "old", "killed mid-commit, the targets are mixed until recovered"
    with pytest.warns(UserWarning, match="previous outputs were put back"):
        with Staging(tmp_path) as st:
            assert len(st.recovered) == 1
            assert _state(tmp_path) == "old"
            st.stage_file(tmp_path / "other.txt").write_text("x")
    assert (tmp_path / "other.txt").read_text() == "x"


def test_a_live_runs_staging_folder_is_left_alone(tmp_path):
    _old_export(tmp_path)
    with Staging(tmp_path) as st:
        st.stage_file(tmp_path / "layer.usda").write_text("new layer")
        assert recover(tmp_path) == []  # its owner (this process) holds owner.lock
        assert st.dir.is_dir()
    assert (tmp_path / "layer.usda").read_text() == "new layer"


def test_an_error_during_the_commit_rolls_back(tmp_path, monkeypatch):
    _old_export(tmp_path)
    monkeypatch.setenv("MTLX2NEURAL_FAULT", "commit:3=enospc")
    with pytest.raises(OSError, match="No space left"):
        with Staging(tmp_path) as st:
            st.stage(tmp_path / "out" / "mat" / "neural").joinpath("latents.exr").write_text("new latents")
            st.stage_file(tmp_path / "layer.usda").write_text("new layer")
    assert (tmp_path / "layer.usda").read_text().startswith("old")
    assert (tmp_path / "out" / "mat" / "neural" / "latents.exr").read_text() == "old latents"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(PREFIX)]
