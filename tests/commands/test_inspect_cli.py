"""``mtlx2neural inspect`` (mtlx2neural.commands.inspection): ``--coverage`` and the ASSET rule."""

from __future__ import annotations

import pytest

from mtlx2neural.cli import main


def test_coverage_prints_the_table_and_exits_0(capsys):
    assert main(["inspect", "--coverage"]) == 0
    out = capsys.readouterr().out
    lines = out.splitlines()
    assert lines[0].split()[:3] == ["category", "library", "status"]
    assert any(line.split()[:3] == ["image", "stdlib", "supported"] for line in lines)
    assert "in-scope categories supported" in lines[-1]


def test_asset_is_required_without_coverage(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["inspect"])
    assert exc.value.code == 2
    assert "ASSET" in capsys.readouterr().err


def test_coverage_takes_no_asset(capsys, tmp_path):
    with pytest.raises(SystemExit) as exc:
        main(["inspect", "--coverage", str(tmp_path / "a.mtlx")])
    assert exc.value.code == 2
    assert "--coverage takes no ASSET" in capsys.readouterr().err
