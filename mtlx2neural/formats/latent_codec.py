"""Block-compressed latent textures: how a latent pyramid is stored as BC6H or BC1 textures.

A latent level [C, H, W] is split into textures of three channels each: texture g holds channels
3g, 3g + 1, 3g + 2 as R, G, B (the last texture's missing channels are 0), one 4x4 block per
16 texels, row 0 the top row, as :mod:`.bc6h` and :mod:`.bc1` lay them out. Each MIP level of the
pyramid is compressed on its own (level j is the pyramid's trained level j, not a downsampled
level 0), so a texture's MIP chain is the pyramid.

Formats (``FORMATS``):

- ``exr``: no block compression (the half-float OpenEXR textures of :mod:`mtlx2neural.export.latents`).
- ``bc6h``: signed half-float BC6H (``BC6H_SF16``), 1 byte per texel per texture; the latents are
  stored as they are (no scale).
- ``bc1``: BC1 (``BC1_UNORM``), half a byte per texel per texture. BC1 holds [0, 1], so each latent
  channel c is stored as ``(x - offset[c]) / scale[c]`` and read back as ``offset[c] + scale[c] * t``;
  the offsets and scales are fitted to the latents' range over every level when the fine-tune through
  the codec starts (:meth:`LatentCodec.fit`), with a margin of ``AFFINE_MARGIN`` each side.

:meth:`LatentCodec.emulate` is what a GPU's texture unit returns for a texel of the compressed level
(the codec modules' decode of their own encode, exactly), differentiable so that training through it
fine-tunes the latents and the decoder for the compressed values. The trainer turns it on for the run's
last ``TrainConfig.block_fraction`` of the steps (``TrainConfig.latent_format``); from then on the model
only ever sees decoded latents, and the exported files decode to exactly the values it was trained on
last and is evaluated on.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from mtlx2neural.errors import InputError
from mtlx2neural.formats import bc1, bc6h
from mtlx2neural.formats.dds import level_size, read_dds, write_dds

CHANNELS_PER_TEXTURE = 3
AFFINE_MARGIN = 0.05
"""BC1 only: share of a channel's range added below and above it when the offsets and scales are fitted,
so that latents may move a little during the fine-tune before they clamp."""
AFFINE_MIN_RANGE = 0.25
"""BC1 only: the narrowest range a channel's offset and scale cover (latent units; the latents' spread is
about 1), so that a nearly constant channel (a uniform material's single texel) can still move in the
fine-tune, in steps of 0.25 / 63 at most."""


@dataclass(frozen=True)
class BlockFormat:
    """One block-compressed texture format: its name (``--latent-format``), DXGI format number (the DDS
    header's), bytes per 4x4 block, and whether the latents are stored through a per-channel affine map."""

    name: str
    dxgi: int
    block_bytes: int
    affine: bool

    @property
    def bytes_per_texel(self) -> float:
        """Bytes per texel of one texture (three latent channels)."""
        return self.block_bytes / 16.0

    def encode(self, rgb: np.ndarray) -> bytes:
        """[H, W, 3] float32 (already mapped into the format's range) -> the level's blocks."""
        return bc6h.encode(rgb, signed=True) if self.name == "bc6h" else bc1.encode(rgb)

    def decode(self, data: bytes, height: int, width: int) -> np.ndarray:
        """The level's blocks -> [H, W, 3] float32, as a GPU returns them."""
        return bc6h.decode(data, height, width, signed=True) if self.name == "bc6h" else bc1.decode(data, height, width)

    def emulate(self, x: torch.Tensor) -> torch.Tensor:
        """[3, H, W] -> decode(encode(x)) as a differentiable torch function (the codec modules')."""
        return bc6h.emulate(x, signed=True) if self.name == "bc6h" else bc1.emulate(x)


FORMATS = {"exr": None,
           "bc6h": BlockFormat("bc6h", bc6h.DXGI_SIGNED, bc6h.BYTES_PER_BLOCK, affine=False),
           "bc1": BlockFormat("bc1", bc1.DXGI_UNORM, bc1.BYTES_PER_BLOCK, affine=True)}
"""``--latent-format`` choices; ``exr`` is uncompressed (no :class:`BlockFormat`)."""

FORMAT_CODES = {"exr": 0, "bc6h": 1, "bc1": 2}
"""The format's number in a model's state dict (``latents.codec_format``)."""


def format_of_code(code) -> str:
    """The format name of a state dict's ``codec_format`` number (None, no codec: ``exr``)."""
    if code is None:
        return "exr"
    return next(k for k, v in FORMAT_CODES.items() if v == int(code))


def texture_count(channels: int) -> int:
    """How many three-channel textures ``channels`` latent channels need."""
    return math.ceil(channels / CHANNELS_PER_TEXTURE)


def block_texture_names(channels: int, stem: str = "latents", udim: bool = False) -> list[str]:
    """The DDS file names of ``channels`` block-compressed latent channels, in channel order:
    ``<stem>_<k>.dds`` (``udim``: the ``<stem>_<k>.<UDIM>.dds`` patterns of a UDIM material's tiles)."""
    tag = ".<UDIM>" if udim else ""
    return [f"{stem}_{k}{tag}.dds" for k in range(texture_count(channels))]


def latent_bytes_per_texel(name: str, channels: int) -> float:
    """GPU bytes per level-0 texel of ``channels`` latents in format ``name`` (MIP chain not included):
    ``exr`` is half-float RGBA (8 bytes per four channels), a block format its bytes per texel per
    three-channel texture."""
    fmt = FORMATS[name]
    if fmt is None:
        return 8.0 * math.ceil(channels / 4)
    return fmt.bytes_per_texel * texture_count(channels)


class LatentCodec(torch.nn.Module):
    """A latent pyramid's block format and (BC1) per-channel affine map; both are buffers, so they are
    saved in the model's state dict (``codec_format``, ``codec_offset``, ``codec_scale``). BC6H keeps
    offset 0 and scale 1."""

    def __init__(self, name: str, channels: int):
        super().__init__()
        if FORMATS.get(name) is None:
            raise ValueError(f"latent format {name!r} is not block-compressed; choose one of "
                             f"{[k for k, v in FORMATS.items() if v is not None]}")
        self.channels = channels
        self.register_buffer("codec_format", torch.tensor(FORMAT_CODES[name], dtype=torch.long))
        self.register_buffer("codec_offset", torch.zeros(channels))
        self.register_buffer("codec_scale", torch.ones(channels))

    @property
    def format(self) -> BlockFormat:
        return FORMATS[format_of_code(self.codec_format)]

    def fit(self, levels) -> None:
        """BC1: set each channel's offset and scale to its range over ``levels`` ([C, H, W] or UDIM
        [T, C, H, W] each), widened by ``AFFINE_MARGIN`` each side and to at least ``AFFINE_MIN_RANGE``
        about its middle. BC6H: nothing to fit."""
        if not self.format.affine:
            return
        with torch.no_grad():
            flat = torch.cat([lv.detach().movedim(-3, 0).reshape(self.channels, -1) for lv in levels], 1)
            lo, hi = flat.min(1).values, flat.max(1).values
            scale = ((hi - lo) * (1 + 2 * AFFINE_MARGIN)).clamp_min(AFFINE_MIN_RANGE)
            self.codec_offset.copy_((lo + hi) / 2 - scale / 2)
            self.codec_scale.copy_(scale)

    def _groups(self, level: torch.Tensor) -> list[torch.Tensor]:
        """[C, H, W] -> three-channel groups in the format's range (the last one zero-padded)."""
        c, h, w = level.shape
        x = level
        if self.format.affine:
            x = (x - self.codec_offset.to(x)[:, None, None]) / self.codec_scale.to(x)[:, None, None]
        pad = texture_count(c) * CHANNELS_PER_TEXTURE - c
        if pad:
            x = torch.cat([x, x.new_zeros(pad, h, w)])
        return list(x.split(CHANNELS_PER_TEXTURE))

    def _from_groups(self, groups, channels: int) -> torch.Tensor:
        x = torch.cat(list(groups))[:channels]
        if self.format.affine:
            x = self.codec_offset.to(x)[:, None, None] + self.codec_scale.to(x)[:, None, None] * x
        return x

    def emulate(self, level: torch.Tensor) -> torch.Tensor:
        """The latents a GPU reads from the compressed ``level`` ([C, H, W], or UDIM [T, C, H, W]):
        differentiable, and exactly :meth:`decode` of :meth:`encode` in value (float32)."""
        if level.dim() == 4:
            return torch.stack([self.emulate(t) for t in level])
        fmt = self.format
        out = [fmt.emulate(g.float()) for g in self._groups(level)]
        return self._from_groups(out, level.shape[0]).to(level.dtype)

    def encode(self, level: torch.Tensor) -> list[bytes]:
        """One [C, H, W] level -> the blocks of each of its textures, in texture order."""
        with torch.no_grad():
            return [self.format.encode(g.float().permute(1, 2, 0).cpu().numpy()) for g in self._groups(level)]

    def decode(self, blobs: list[bytes], height: int, width: int) -> torch.Tensor:
        """The blocks of each texture of one level -> its latents [C, H, W] float32 (C = ``channels``)."""
        fmt = self.format
        groups = [torch.from_numpy(np.ascontiguousarray(fmt.decode(b, height, width))).permute(2, 0, 1)
                  for b in blobs]
        return self._from_groups(groups, self.channels).float()


def codec_from_architecture(arch: dict) -> LatentCodec | None:
    """The codec a weights manifest's ``architecture`` describes (``latent_format``, and for BC1
    ``latent_offset`` / ``latent_scale``); None for ``exr`` or a manifest without the key. A missing or
    malformed entry raises KeyError, TypeError or ValueError, which the reader names the file for."""
    name = arch.get("latent_format", "exr")
    if name not in FORMATS:
        raise ValueError(f"unknown latent_format {name!r}")
    if FORMATS[name] is None:
        return None
    codec = LatentCodec(name, int(arch["latent_channels"]))
    if codec.format.affine:
        codec.codec_offset.copy_(torch.tensor([float(v) for v in arch["latent_offset"]]))
        codec.codec_scale.copy_(torch.tensor([float(v) for v in arch["latent_scale"]]))
    return codec


def architecture_entries(codec: LatentCodec | None) -> dict:
    """The manifest ``architecture`` entries of ``codec``: ``latent_format`` and, for a block format,
    ``latent_texture_channels`` (3) and (BC1) ``latent_offset`` / ``latent_scale`` (texture value t reads
    as offset + scale * t per latent channel)."""
    if codec is None:
        return {"latent_format": "exr"}
    out = {"latent_format": codec.format.name, "latent_texture_channels": CHANNELS_PER_TEXTURE}
    if codec.format.affine:
        out["latent_offset"] = [float(v) for v in codec.codec_offset]
        out["latent_scale"] = [float(v) for v in codec.codec_scale]
    return out


def check_block_shapes(shapes) -> None:
    """``ValueError`` unless the pyramid level sizes ``shapes`` ([(H_j, W_j)], finest first) are a DDS MIP
    chain's (halved, rounded down; every power-of-two grid is)."""
    h, w = shapes[0]
    want = [level_size(w, h, j)[::-1] for j in range(len(shapes))]
    if [tuple(s) for s in shapes] != want:
        raise ValueError(f"a {w}x{h} latent grid halves to {[tuple(s) for s in shapes]} by rounding up; block-"
                         f"compressed latents need DDS's rounding down ({want}): use a power-of-two grid "
                         f"(--max-texels) or --latent-format exr")


def write_block_textures(levels: list[torch.Tensor], codec: LatentCodec, folder, stem: str = "latents",
                         tiles=None) -> list[Path]:
    """Write the pyramid ``levels`` (the *uncompressed* parameters, finest first, [C, H, W] each, or
    [T, C, H, W] with ``tiles``) through ``codec`` as DDS MIP chains into ``folder``; the files decode to
    exactly ``codec.emulate`` of the levels. Returns the paths in channel order (``<UDIM>`` patterns for
    tiles)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    channels = int(levels[0].shape[-3])
    check_block_shapes([tuple(lv.shape[-2:]) for lv in levels])
    names = block_texture_names(channels, stem, udim=tiles is not None)
    for t, udim in enumerate(tiles if tiles is not None else [None]):
        per_level = [codec.encode(lv[t] if udim is not None else lv) for lv in levels]
        h, w = (int(s) for s in levels[0].shape[-2:])
        for k, name in enumerate(names):
            path = folder / (name if udim is None else name.replace("<UDIM>", str(int(udim))))
            write_dds(path, [blobs[k] for blobs in per_level], w, h, codec.format.dxgi)
    return [folder / n for n in names]


def read_block_textures(paths, codec: LatentCodec) -> list[torch.Tensor]:
    """The latent pyramid (float32 [C, H_j, W_j] per level, finest first, C = ``codec.channels``) decoded from
    DDS textures ``paths`` (channel order); :class:`InputError` naming a file of another format or size."""
    images = [read_dds(p) for p in paths]  # InputError: missing, truncated, not DDS
    if len(images) != texture_count(codec.channels):
        raise InputError(f"{codec.channels} latent channels need {texture_count(codec.channels)} DDS textures, got "
                         f"{len(images)}: {', '.join(map(str, paths))}")
    for p, img in zip(paths, images):
        if img.dxgi_format != codec.format.dxgi:
            raise InputError(f"{p}: DXGI format {img.dxgi_format}, but the weights manifest says "
                             f"{codec.format.name} ({codec.format.dxgi}); export the material again")
        if (img.width, img.height, len(img.levels)) != (images[0].width, images[0].height, len(images[0].levels)):
            raise InputError(f"{p}: {img.width}x{img.height} with {len(img.levels)} MIP levels differs from "
                             f"{paths[0]}; export the material again")
    out = []
    for j in range(len(images[0].levels)):
        w, h = level_size(images[0].width, images[0].height, j)
        out.append(codec.decode([img.levels[j] for img in images], h, w))
    return out


def codec_of(model_or_export) -> LatentCodec | None:
    """The block codec of a model's latents, or of an export folder's (or ``weights.json``'s) manifest;
    None for ``exr`` latents or an unreadable manifest (whose reader reports it)."""
    if isinstance(model_or_export, (str, Path)):
        p = Path(model_or_export)
        try:
            arch = json.loads((p / "weights.json" if p.is_dir() else p).read_text())["architecture"]
            return codec_from_architecture(arch)
        except (OSError, ValueError, KeyError, TypeError):
            return None
    return getattr(getattr(model_or_export, "latents", None), "codec", None)


def binding_comment(codec: LatentCodec | None, channels: int) -> str:
    """One comment line for generated shaders: which files hold the latents and how to bind them."""
    if codec is None:
        return (f"// Latent textures: latents_<k>.exr, half-float RGBA, channels 4k..4k+3 of {channels}, MIP chain = "
                f"the pyramid (NMTextureLatents8 binds 8 channels).")
    fmt = codec.format
    affine = ("; texel t reads as offset + scale * t, offset {" + ", ".join(f"{v:.9g}" for v in codec.codec_offset)
              + "}, scale {" + ", ".join(f"{v:.9g}" for v in codec.codec_scale) + "}") if fmt.affine else ""
    return (f"// Latent textures: latents_<k>.dds, {fmt.name.upper()} (DXGI {fmt.dxgi}), channels 3k..3k+2 of "
            f"{channels} as RGB, MIP chain = the pyramid (NMBlockTextureLatents8 binds 8 channels){affine}.")
