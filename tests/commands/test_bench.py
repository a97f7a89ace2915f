"""``mtlx2neural bench``: lists and runs the benchmarks of a source checkout; from an installed
wheel (no ``benchmarks/`` folder) a clear exit 2. No benchmark is fast enough for a unit test
(each trains or times for minutes), so the run itself is checked by the command it starts."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from cli_helpers import assert_clean_input_error, run_cli

from mtlx2neural.commands import bench

ROOT = Path(__file__).resolve().parents[2]


def _names_from_run_all() -> list[str]:
    r = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "run_all.py"), "--list"], capture_output=True,
                       text=True, timeout=120, check=True)
    return [line.split()[0] for line in r.stdout.splitlines() if line.strip()]


def test_list_names_every_benchmark_of_run_all(capsys):
    if not (ROOT / "benchmarks" / "run_all.py").is_file():
        pytest.skip("not a source checkout: no benchmarks/run_all.py")
    code, out, err = run_cli(capsys, "bench", "--list")
    assert code == 0, err
    listed = [line.split()[0] for line in out.splitlines()]
    assert listed == _names_from_run_all() and "training" in listed
    assert "benchmarks/bench_training.py --steps 30" in out
    assert "OMP_NUM_THREADS=1 benchmarks/bench_shaders.py" in out
    code, out, _ = run_cli(capsys, "bench", "--list", "sampler")
    assert code == 0 and [line.split()[0] for line in out.splitlines()] == ["sampler"]


def test_unknown_benchmark_is_exit_2(capsys):
    if bench.benchmarks_folder() is None:
        pytest.skip("not a source checkout")
    code, out, err = run_cli(capsys, "bench", "training", "nope")
    assert_clean_input_error(code, out, err, "unknown benchmark 'nope'", "training", "--list")


def test_run_starts_run_all_with_the_names(monkeypatch, capsys):
    if bench.benchmarks_folder() is None:
        pytest.skip("not a source checkout")
    calls = []

    def fake_run(cmd, cwd=None, check=False):
        calls.append((cmd, cwd))
        return subprocess.CompletedProcess(cmd, 3)

    monkeypatch.setattr(bench.subprocess, "run", fake_run)
    code, _, _ = run_cli(capsys, "bench", "sampler", "reference")
    assert code == 3  # run_all's exit code (1 when a benchmark failed) is the command's
    assert calls == [([sys.executable, str(ROOT / "benchmarks" / "run_all.py"), "--only", "sampler,reference"],
                      ROOT)]
    run_cli(capsys, "bench")
    assert calls[-1][0] == [sys.executable, str(ROOT / "benchmarks" / "run_all.py")]  # all


def test_installed_without_benchmarks_says_to_use_a_checkout(tmp_path, monkeypatch, capsys):
    # An installed layout: site-packages/mtlx2neural/commands/bench.py, no benchmarks/ beside the package.
    fake = tmp_path / "site-packages" / "mtlx2neural" / "commands" / "bench.py"
    fake.parent.mkdir(parents=True)
    monkeypatch.setattr(bench, "__file__", str(fake))
    assert bench.benchmarks_folder() is None
    for argv in (["bench", "--list"], ["bench", "training"]):
        code, out, err = run_cli(capsys, *argv)
        assert_clean_input_error(code, out, err, "source checkout", "git clone", "pip install -e .")
    # A benchmarks/ folder without the repository's pyproject.toml is not a checkout either.
    (tmp_path / "site-packages" / "benchmarks").mkdir()
    (tmp_path / "site-packages" / "benchmarks" / "run_all.py").write_text("BENCHMARKS = {}\n")
    assert bench.benchmarks_folder() is None
