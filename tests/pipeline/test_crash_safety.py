"""A conversion survives what kills processes: a worker that dies abruptly fails only its own
material, and a conversion killed inside its commit leaves the previous export whole for the next
run to restore (which says so). The kills are real (:mod:`mtlx2neural.faults`: SIGKILL, or
``os._exit(255)`` as a C library's ``exit()``); the input is hashed before and after.

These conversions train nothing (``--iterations 0 --allow-untrained``): they check what is
written and what exits, not fidelity.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from cli_helpers import snapshot

from mtlx2neural.staging import PREFIX, recover

SAMPLE = Path(__file__).resolve().parents[2] / "samples" / "layered_spheres.usda"
TINY = ["--iterations", "0", "--allow-untrained", "--quiet"]


def _cli(*argv, fault: str | None = None) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != "MTLX2NEURAL_FAULT"}
    if fault:
        env["MTLX2NEURAL_FAULT"] = fault
    return subprocess.run([sys.executable, "-m", "mtlx2neural.cli", *map(str, argv)], capture_output=True,
                          text=True, env=env, timeout=600)


def _sample(tmp_path: Path) -> Path:
    asset = tmp_path / "in" / SAMPLE.name
    shutil.copytree(SAMPLE.parent, asset.parent, ignore=shutil.ignore_patterns("*_neural*", "textured", "udim",
                                                                              "rotated"))
    return asset


@pytest.mark.slow
def test_a_worker_that_exits_abruptly_fails_only_its_own_material(tmp_path):
    asset = _sample(tmp_path)
    before = snapshot(asset.parent)
    r = _cli(asset, "-o", tmp_path / "out", "--workers", "2", *TINY, fault="job:/World/Looks/CarPaint=exit")
    assert r.returncode == 3, r.stderr  # some converted, one skipped
    assert "skipped /World/Looks/CarPaint" in r.stderr and "ended abruptly" in r.stderr
    assert "Plastic" not in r.stderr.split("skipped", 1)[1], "only the material whose worker died is skipped"
    assert (tmp_path / "out" / "World.Looks.Plastic" / "neural" / "weights.bin").is_file()
    assert not (tmp_path / "out" / "World.Looks.CarPaint" / "neural").exists()
    assert snapshot(asset.parent) == before


def _exports(out: Path, layer: Path) -> dict:
    """The layer's bytes and every file of every material's ``neural/`` export (kind, size, mtime, hash)."""
    snap = {"layer": layer.read_bytes()}
    for neural in sorted(out.glob("*/neural")):
        snap.update({f"{neural.parent.name}/{k}": v for k, v in snapshot(neural).items()})
    return snap


@pytest.mark.slow
def test_a_conversion_killed_in_its_commit_keeps_the_previous_export(tmp_path):
    asset = _sample(tmp_path)
    out, layer = tmp_path / "out", tmp_path / "out.usda"
    assert _cli(asset, "-o", out, "--workers", "1", *TINY).returncode == 0
    previous = _exports(out, layer)
    before = snapshot(asset.parent)
    # --force retrains and exports again; killed after the first export folder was set aside (rename 1),
    # when the layer still points at a neural/ folder that is not there.
    r = _cli(asset, "-o", out, "--workers", "1", "--force", *TINY, "--seed", "7", fault="commit:1")
    assert r.returncode == -signal.SIGKILL, r.stderr
    assert not (out / "World.Looks.CarPaint" / "neural").exists()
    with pytest.warns(UserWarning, match="previous outputs were put back"):
        recover(tmp_path)  # what the next run does first
    assert _exports(out, layer) == previous, "the previous export and layer are back, byte for byte"
    # Killed again later in the commit (rename 3); the next conversion restores, says so, and exports.
    r = _cli(asset, "-o", out, "--workers", "1", "--force", *TINY, "--seed", "7", fault="commit:3")
    assert r.returncode == -signal.SIGKILL, r.stderr
    r = _cli(asset, "-o", out, "--workers", "1", *TINY, "--seed", "7")
    assert r.returncode == 0, r.stderr
    assert "previous outputs were put back" in r.stderr
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(PREFIX)]
    for name in ("World.Looks.CarPaint", "World.Looks.Plastic"):
        assert (out / name / "neural" / "weights.bin").is_file() and (out / name / "neural" / "export.json").is_file()
    assert snapshot(asset.parent) == before


@pytest.mark.slow
def test_a_full_disk_exits_1_naming_the_file_and_keeps_the_previous_export_and_records(tmp_path):
    asset = _sample(tmp_path)
    out, layer = tmp_path / "out", tmp_path / "out.usda"
    # A fresh run whose checkpoint cannot be written: exit 1 (not a material's "training failed"), the
    # file named, and no layer nor material folder.
    r = _cli(asset, "-o", out, "--workers", "1", *TINY, fault="write:checkpoint.pt=enospc")
    assert r.returncode == 1, r.stderr
    assert "No space left on device" in r.stderr and "checkpoint.pt" in r.stderr
    assert not layer.exists() and not [p for p in out.iterdir() if not p.name.startswith(".mtlx2neural")]
    assert _cli(asset, "-o", out, "--workers", "1", *TINY).returncode == 0
    before = {**snapshot(out), "layer": layer.read_bytes()}
    # A --force rerun that trains anew, then finds the disk full while exporting: every previous file
    # (checkpoints, summaries, PNGs, the export, the layer) is as it was.
    r = _cli(asset, "-o", out, "--workers", "1", "--force", "--seed", "3", *TINY, fault="write:latents_0.exr=enospc")
    assert r.returncode == 1, r.stderr
    assert "latents_0.exr" in r.stderr and "unchanged" in r.stderr
    after = {**snapshot(out), "layer": layer.read_bytes()}
    changed = sorted(k for k in set(before) | set(after)
                     if before.get(k) != after.get(k) and not k.startswith(".mtlx2neural"))
    assert changed == [], changed  # (the lock and the work folder are the run's own)
