"""Every setting is checked before any work (``mtlx2neural ASSET``): exit 2 and a message
naming the flag, the value and what to do; never a traceback, never a late failure
after training. Also the progress output when stderr is not a terminal.
"""

from __future__ import annotations

import io

import pytest
import torch
from cli_helpers import assert_clean_input_error, run_cli, snapshot  # noqa: E402  (the CLI tests' helpers)
from conftest import SIMPLE_MTLX

from mtlx2neural.progress import LogLines, progress_bar

BASE = ("--batch", "64", "--quiet", "--workers", "1")


@pytest.fixture
def red(tmp_path):
    asset = tmp_path / "red.mtlx"
    asset.write_text(SIMPLE_MTLX)
    return asset


BAD = {
    "cuda without CUDA": (("--device", "cuda"), "CUDA is not available"),
    "not a device": (("--device", "gpu0"), "not a device"),
    "batch 0": (("--batch", "0"), "--batch"),
    "frames -1": (("--frames", "-1"), "--frames"),
    "iterations 0": (("--iterations", "0"), "--allow-untrained"),
    "iterations -5": (("--iterations", "-5"), "--iterations"),
    "negative seed": (("--seed", "-1"), "--seed"),
    "lift fraction over 1": (("--lift-fraction", "1.5"), "lift_fraction"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_settings_exit_2_before_any_work(case, red, tmp_path, capsys):
    argv, expected = BAD[case]
    if case == "cuda without CUDA" and torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    before = snapshot(tmp_path)
    code, out, err = run_cli(capsys, red, *BASE, *argv)
    assert_clean_input_error(code, out, err, expected)
    assert snapshot(tmp_path) == before  # not even the output folder


def test_resume_refuses_another_network_and_a_truncated_checkpoint(red, tmp_path, capsys):
    code, _, err = run_cli(capsys, red, *BASE, "--iterations", "2", "--decoder", "2x16", "--device", "cpu")
    assert code == 0, err
    ckpt = tmp_path / "red_neural" / "Red" / "checkpoint.pt"
    # Another decoder: the checkpoint cannot be continued; said before training, naming both sizes.
    code, out, err = run_cli(capsys, red, *BASE, "--iterations", "4", "--decoder", "3x64", "--resume")
    assert_clean_input_error(code, out, err, str(ckpt), "decoder: checkpoint '2x16', this run '3x64'")
    # A truncated checkpoint is named as such, not as an output that cannot be written.
    data = ckpt.read_bytes()
    ckpt.write_bytes(data[: len(data) // 3])
    code, out, err = run_cli(capsys, red, *BASE, "--iterations", "4", "--decoder", "2x16", "--resume")
    assert_clean_input_error(code, out, err, str(ckpt), "truncated", "without --resume")
    assert "cannot write" not in err
    assert ckpt.read_bytes() == data[: len(data) // 3]  # left for the user to inspect


# ----------------------------------------------------------------------------- progress off a terminal


def test_progress_off_a_terminal_is_plain_periodic_lines():
    buf = io.StringIO()  # not a terminal
    bar = progress_bar(100, desc="/World/Looks/Red", file=buf)
    assert isinstance(bar, LogLines)
    now = [0.0]
    bar = LogLines(100, desc="Red", file=buf, every_seconds=10.0, clock=lambda: now[0])
    for _ in range(40):  # 40 steps at 0.5 s each: one line at 10 s, one at 20 s
        now[0] += 0.5
        bar.update(1)
        bar.set_postfix(phase="encoder", loss="0.1234")
    bar.close()  # and one at the end
    lines = buf.getvalue().splitlines()
    assert len(lines) == 3 and "\r" not in buf.getvalue()
    assert lines[0] == "Red: 20/100 (20%), phase=encoder, loss=0.1234, elapsed 00:10, ETA 00:40"
    assert lines[-1].startswith("Red: 40/100 (40%)") and lines[-1].endswith("ETA 00:30")


def test_training_progress_in_a_log_is_lines_with_loss_and_eta(red, tmp_path, capsys):
    code, out, err = run_cli(capsys, red, "--batch", "64", "--workers", "1", "--iterations", "30", "--device", "cpu")
    assert code == 0, err
    assert "\r" not in err  # capsys is not a terminal: no bar redraws
    final = [line for line in err.splitlines() if line.startswith("Red: 30/30 (100%)")]
    assert final and "loss=" in final[-1] and "ETA" in final[-1]


def test_an_unknown_command_is_an_error_not_an_asset(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, out, err = run_cli(capsys, "bogus", "--help")
    assert_clean_input_error(code, out, err, "unknown command 'bogus'", "inspect, convert, render, report, bench")
    # A missing asset is still named as a missing asset (by its suffix), and so is an existing path.
    code, out, err = run_cli(capsys, "nope.usda")
    assert code == 2 and "nope.usda" in err and "unknown command" not in err


def test_ray_workers_without_ray_exit_2_before_any_work(red, tmp_path, capsys, monkeypatch):
    """Ray is an optional extra: a run asking for it where it is not installed (simulated by hiding
    the module from importlib's finder) must say how to get it before reading or writing anything."""
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "ray" else real(name, *a))
    before = snapshot(tmp_path)
    code, out, err = run_cli(capsys, red, *BASE, "--workers", "ray", "--iterations", "2")
    assert_clean_input_error(code, out, err, "--workers ray needs Ray", "mtlx2neural[ray]")
    assert snapshot(tmp_path) == before


@pytest.mark.parametrize("kind", ["folder", "loop", "dangling"])
def test_a_folder_a_link_loop_or_a_dangling_link_is_named_as_such(tmp_path, capsys, kind):
    asset = tmp_path / "scene.usda"
    if kind == "folder":
        asset.mkdir()
    elif kind == "loop":
        asset.symlink_to(asset)
    else:
        asset.symlink_to(tmp_path / "gone.usda")
    code, out, err = run_cli(capsys, asset)
    expected = {"folder": "is a folder, not a file", "loop": "symbolic link that loops",
                "dangling": "symbolic link to a missing file"}[kind]
    assert_clean_input_error(code, out, err, str(asset), expected)


def test_contradictory_or_unwritable_options_are_refused(tmp_path, capsys):
    (tmp_path / "red.mtlx").write_text(SIMPLE_MTLX)
    code, out, err = run_cli(capsys, tmp_path / "red.mtlx", "--resume", "--force")
    assert_clean_input_error(code, out, err, "--resume", "--force")
    code, out, err = run_cli(capsys, tmp_path / "red.mtlx", "-o", tmp_path / "x.usdz")
    assert_clean_input_error(code, out, err, "x.usdz", ".usda")
    assert not (tmp_path / "x.usdz").exists() and not (tmp_path / "red_neural").exists()


def test_convert_says_what_it_takes():
    import mtlx2neural as m2n

    with pytest.raises(TypeError, match=r"convert\(\) takes a Usd\.Stage or a path.*not int"):
        m2n.convert(12345)
