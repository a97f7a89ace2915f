"""DDS container (mtlx2neural.formats.dds): MIP chain round trips, the header fields other readers
rely on, and an InputError naming the file for each kind of malformed file."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from mtlx2neural.errors import InputError
from mtlx2neural.formats import dds


def _levels(fmt: int, width: int, height: int, count: int, seed: int = 0) -> list[bytes]:
    rng = np.random.default_rng(seed)
    return [rng.integers(0, 256, dds.level_bytes(fmt, width, height, j), dtype=np.uint8).tobytes()
            for j in range(count)]


@pytest.mark.parametrize("fmt", [71, 80, 83, 95, 96, 98])
def test_round_trip_with_mip_chain(tmp_path, fmt):
    width, height = 13, 6  # 13x6, 6x3, 3x1, 1x1: partial blocks and levels under 4x4
    assert dds.max_levels(width, height) == 4
    assert [dds.level_size(width, height, j) for j in range(4)] == [(13, 6), (6, 3), (3, 1), (1, 1)]
    levels = _levels(fmt, width, height, 4)
    assert [len(b) for b in levels] == [v * dds.BLOCK_BYTES[fmt] for v in (8, 2, 1, 1)]
    path = tmp_path / "t.dds"
    dds.write_dds(path, levels, width, height, fmt)
    assert [p.name for p in tmp_path.iterdir()] == ["t.dds"]  # no temporary left behind
    img = dds.read_dds(path)
    assert (img.dxgi_format, img.width, img.height, img.levels) == (fmt, width, height, levels)
    # a partial chain (two levels) is legal too
    dds.write_dds(path, levels[:2], width, height, fmt)
    assert dds.read_dds(path).levels == levels[:2]


def test_header_fields(tmp_path):
    levels = _levels(96, 16, 8, 5)
    path = tmp_path / "h.dds"
    dds.write_dds(path, levels, 16, 8, 96)
    raw = path.read_bytes()
    assert raw[:4] == b"DDS "
    size, flags, height, width, linear, depth, mips = struct.unpack_from("<7I", raw, 4)
    assert (size, height, width, linear, depth, mips) == (124, 8, 16, 4 * 2 * 16, 0, 5)
    assert flags == 0x1 | 0x2 | 0x4 | 0x1000 | 0x20000 | 0x80000
    assert struct.unpack_from("<II4s", raw, 4 + 72) == (32, 0x4, b"DX10")
    assert struct.unpack_from("<I", raw, 4 + 104)[0] == 0x1000 | 0x8 | 0x400000  # TEXTURE|COMPLEX|MIPMAP
    assert struct.unpack_from("<5I", raw, 128) == (96, 3, 0, 1, 0)  # BC6H_SF16, TEXTURE2D, array size 1
    assert len(raw) == 148 + sum(len(b) for b in levels)


def test_write_rejects_bad_arguments(tmp_path):
    levels = _levels(96, 8, 8, 4)
    with pytest.raises(ValueError, match="level 1"):
        dds.write_dds(tmp_path / "a.dds", [levels[0], levels[1][:-16]], 8, 8, 96)
    with pytest.raises(ValueError, match="MIP levels"):
        dds.write_dds(tmp_path / "a.dds", levels + levels[-1:], 8, 8, 96)
    with pytest.raises(ValueError, match="DXGI format 2"):
        dds.write_dds(tmp_path / "a.dds", levels, 8, 8, 2)
    assert not list(tmp_path.iterdir())


def _corrupt(raw: bytes, case: str) -> bytes:
    if case == "wrong magic":
        return b"DDX " + raw[4:]
    if case == "truncated header":
        return raw[:60]
    if case == "missing DX10 header":
        return raw[:4 + 80] + b"DXT5" + raw[4 + 84:]
    if case == "truncated DX10 header":
        return raw[:140]
    if case == "level bytes missing":
        return raw[:-1]
    if case == "no level data":
        return raw[:148]
    if case == "bad header size":
        return raw[:4] + struct.pack("<I", 100) + raw[8:]
    if case == "unknown format":
        return raw[:128] + struct.pack("<I", 28) + raw[132:]
    if case == "texture array":
        return raw[:128 + 12] + struct.pack("<I", 6) + raw[128 + 16:]
    if case == "too many levels":
        return raw[:4 + 24] + struct.pack("<I", 9) + raw[4 + 28:]
    raise AssertionError(case)


@pytest.mark.parametrize("case, says", [
    ("wrong magic", "magic"), ("truncated header", "truncated header"), ("missing DX10 header", "DX10"),
    ("truncated DX10 header", "DX10"), ("level bytes missing", "MIP level 3"), ("no level data", "MIP level 0"),
    ("bad header size", "header size"), ("unknown format", "DXGI format 28"), ("texture array", "single 2D"),
    ("too many levels", "9 MIP levels"),
])
def test_malformed_files_raise_input_error_naming_the_file(tmp_path, case, says):
    good = tmp_path / "good.dds"
    dds.write_dds(good, _levels(96, 8, 8, 4), 8, 8, 96)
    bad = tmp_path / f"{case.replace(' ', '_')}.dds"
    bad.write_bytes(_corrupt(good.read_bytes(), case))
    with pytest.raises(InputError) as err:
        dds.read_dds(bad)
    assert str(bad) in str(err.value) and says in str(err.value)


def test_missing_file(tmp_path):
    with pytest.raises(InputError, match="does not exist") as err:
        dds.read_dds(tmp_path / "nope.dds")
    assert "nope.dds" in str(err.value)
    with pytest.raises(InputError, match="folder"):
        dds.read_dds(tmp_path)
