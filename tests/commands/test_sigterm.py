"""SIGTERM (``kill``, a scheduler's time limit, a container stop) stops a conversion as Ctrl-C does: the
running training saves its checkpoint (in the run's work folder, where ``--resume`` continues it),
the exit code is 1, no layer is written and the input is untouched. The signal is real, sent to a CLI process mid-training."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from cli_helpers import snapshot

SAMPLE = Path(__file__).resolve().parents[2] / "samples" / "layered_spheres.usda"


@pytest.mark.slow
def test_sigterm_saves_the_running_trainings_checkpoint(tmp_path):
    asset = tmp_path / "in" / SAMPLE.name
    asset.parent.mkdir()
    shutil.copy(SAMPLE, asset)
    before = snapshot(asset.parent)
    log = tmp_path / "stderr.txt"
    with open(log, "w") as err:
        proc = subprocess.Popen([sys.executable, "-m", "mtlx2neural.cli", str(asset), "-o", str(tmp_path / "out"),
                                 "--material", "Plastic", "--iterations", "100000", "--workers", "1"],
                                stdout=subprocess.DEVNULL, stderr=err, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        deadline = time.time() + 300
        while "phase=" not in log.read_text() and time.time() < deadline and proc.poll() is None:
            time.sleep(0.5)  # until the progress shows training steps
        assert "phase=" in log.read_text(), log.read_text()
        proc.send_signal(signal.SIGTERM)
        rc = proc.wait(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
    text = log.read_text()
    assert rc == 1, text
    assert "checkpoint saved" in text and "--resume" in text
    saved = tmp_path / "out" / ".mtlx2neural-work" / "World.Looks.Plastic" / "checkpoint.pt"  # for --resume
    assert saved.is_file() and str(saved) in text
    assert not (tmp_path / "out.usda").exists()
    assert snapshot(asset.parent) == before
