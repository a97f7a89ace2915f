"""DDS container for block-compressed textures with a MIP chain (DX10 extended header).

Layout written (all little-endian): the magic ``b"DDS "``, the 124-byte DDS_HEADER (flags CAPS | HEIGHT |
WIDTH | PIXELFORMAT | MIPMAPCOUNT | LINEARSIZE, pitchOrLinearSize = the finest level's byte size, the
pixel format's fourCC ``"DX10"``, caps TEXTURE, plus COMPLEX | MIPMAP when there is more than one level), the
20-byte DDS_HEADER_DXT10 (dxgiFormat, TEXTURE2D, no misc flags, array size 1), then every level's blocks,
finest first. Level ``j`` is ``max(1, width >> j)`` x ``max(1, height >> j)`` texels (the D3D rule: sizes
round *down*), stored as ``ceil(w/4) * ceil(h/4)`` blocks, row-major, block rows top to bottom. A chain may
stop before 1x1.

Only block-compressed formats are handled (:data:`BLOCK_BYTES`); any malformed file raises
:class:`~mtlx2neural.errors.InputError` naming the file and what is wrong.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

from mtlx2neural.atomic import atomic_path
from mtlx2neural.errors import InputError, missing_reason, unreadable_reason

BLOCK_BYTES = {71: 8, 72: 8, 80: 8, 81: 8, 83: 16, 84: 16, 95: 16, 96: 16, 98: 16, 99: 16}
"""Bytes per 4x4 block of the supported DXGI formats: BC1 (71, 72 sRGB), BC4 (80, 81 signed), BC5 (83, 84
signed), BC6H (95 UF16, 96 SF16), BC7 (98, 99 sRGB)."""

MAGIC = b"DDS "
HEADER_SIZE = 124
DX10_SIZE = 20
DATA_OFFSET = 4 + HEADER_SIZE + DX10_SIZE

_CAPS, _HEIGHT, _WIDTH, _PIXELFORMAT, _MIPMAPCOUNT, _LINEARSIZE = 0x1, 0x2, 0x4, 0x1000, 0x20000, 0x80000
_DDPF_FOURCC = 0x4
_CAPS_COMPLEX, _CAPS_TEXTURE, _CAPS_MIPMAP = 0x8, 0x1000, 0x400000
_TEXTURE2D = 3
_CUBEMAP = 0x4


@dataclass
class DdsImage:
    """A block-compressed 2D texture: ``levels[j]`` holds level j's blocks (finest first)."""

    dxgi_format: int
    width: int
    height: int
    levels: list[bytes]


def level_size(width: int, height: int, level: int) -> tuple[int, int]:
    """Texel size ``(w, h)`` of MIP ``level`` (D3D rule: halve, round down, at least 1)."""
    return max(1, width >> level), max(1, height >> level)


def level_bytes(dxgi_format: int, width: int, height: int, level: int) -> int:
    """Byte size of MIP ``level`` of a ``width`` x ``height`` texture in ``dxgi_format``."""
    w, h = level_size(width, height, level)
    return -(-w // 4) * -(-h // 4) * BLOCK_BYTES[dxgi_format]


def max_levels(width: int, height: int) -> int:
    """Number of levels of a full chain down to 1x1."""
    return max(width, height).bit_length()


def write_dds(path, levels: list[bytes], width: int, height: int, dxgi_format: int) -> None:
    """Write ``levels`` (finest first, each exactly :func:`level_bytes` long) as a DDS file, atomically.

    Raises ValueError for an unsupported format, a bad size, too many levels or a level of the wrong size."""
    if dxgi_format not in BLOCK_BYTES:
        raise ValueError(f"DXGI format {dxgi_format} is not a supported block-compressed format "
                         f"({sorted(BLOCK_BYTES)})")
    if width < 1 or height < 1:
        raise ValueError(f"texture size {width}x{height} must be at least 1x1")
    if not 1 <= len(levels) <= max_levels(width, height):
        raise ValueError(f"{len(levels)} MIP levels given; a {width}x{height} texture has 1 to "
                         f"{max_levels(width, height)}")
    for j, data in enumerate(levels):
        want = level_bytes(dxgi_format, width, height, j)
        if len(data) != want:
            w, h = level_size(width, height, j)
            raise ValueError(f"MIP level {j} ({w}x{h}) has {len(data)} bytes, expected {want}")
    many = len(levels) > 1
    pixel_format = struct.pack("<II4s5I", 32, _DDPF_FOURCC, b"DX10", 0, 0, 0, 0, 0)
    header = struct.pack(
        "<7I44s32s5I", HEADER_SIZE, _CAPS | _HEIGHT | _WIDTH | _PIXELFORMAT | _MIPMAPCOUNT | _LINEARSIZE,
        height, width, len(levels[0]), 0, len(levels), bytes(44), pixel_format,
        _CAPS_TEXTURE | (_CAPS_COMPLEX | _CAPS_MIPMAP if many else 0), 0, 0, 0, 0)
    dx10 = struct.pack("<5I", dxgi_format, _TEXTURE2D, 0, 1, 0)
    with atomic_path(path) as tmp:
        tmp.write_bytes(MAGIC + header + dx10 + b"".join(bytes(d) for d in levels))


def read_dds(path) -> DdsImage:
    """Read a DDS file written by :func:`write_dds` (or any 2D, single-image, DX10-header DDS of a
    :data:`BLOCK_BYTES` format); trailing bytes after the last level are ignored."""
    path = Path(path)

    def bad(what: str) -> InputError:
        return InputError(f"{path}: {what}; it is not a valid DDS texture, re-export it")

    if not path.is_file():
        raise InputError(f"{path}: cannot read the DDS texture: {missing_reason(path)}")
    reason = unreadable_reason(path)
    if reason:
        raise InputError(f"{path}: cannot read the DDS texture: {reason}")
    data = path.read_bytes()
    if len(data) < 4 or data[:4] != MAGIC:
        raise bad(f"wrong magic {data[:4]!r} (expected {MAGIC!r})")
    if len(data) < 4 + HEADER_SIZE:
        raise bad(f"truncated header ({len(data)} bytes, the DDS header needs {4 + HEADER_SIZE})")
    size, flags, height, width, _, _, mips = struct.unpack_from("<7I", data, 4)
    pf_size, pf_flags, fourcc = struct.unpack_from("<II4s", data, 4 + 72)
    caps2 = struct.unpack_from("<I", data, 4 + 108)[0]
    if size != HEADER_SIZE or pf_size != 32:
        raise bad(f"header size {size} / pixel format size {pf_size} (expected {HEADER_SIZE} / 32)")
    if not pf_flags & _DDPF_FOURCC or fourcc != b"DX10":
        raise bad(f"no DX10 extended header (pixel format fourCC {fourcc!r}); only DX10 DDS files "
                  "of block-compressed formats are read")
    if len(data) < DATA_OFFSET:
        raise bad(f"truncated DX10 header ({len(data)} bytes, the headers need {DATA_OFFSET})")
    dxgi, dim, misc, array, _ = struct.unpack_from("<5I", data, 4 + HEADER_SIZE)
    if dxgi not in BLOCK_BYTES:
        raise bad(f"DXGI format {dxgi} is not a supported block-compressed format ({sorted(BLOCK_BYTES)})")
    if dim != _TEXTURE2D or misc & _CUBEMAP or caps2 & 0x200 or array != 1:
        raise bad(f"not a single 2D texture (dimension {dim}, misc flags {misc:#x}, array size {array})")
    if width < 1 or height < 1:
        raise bad(f"size {width}x{height}")
    mips = mips if flags & _MIPMAPCOUNT and mips else 1
    if mips > max_levels(width, height):
        raise bad(f"{mips} MIP levels for a {width}x{height} texture (at most {max_levels(width, height)})")
    levels, offset = [], DATA_OFFSET
    for j in range(mips):
        n = level_bytes(dxgi, width, height, j)
        if offset + n > len(data):
            w, h = level_size(width, height, j)
            raise bad(f"truncated: MIP level {j} ({w}x{h}) needs {n} bytes at offset {offset}, "
                      f"the file has {len(data)} bytes")
        levels.append(data[offset:offset + n])
        offset += n
    return DdsImage(dxgi, width, height, levels)
