"""Texture input: read image files with OpenImageIO and sample them with MaterialX semantics.

Reading (:func:`read_image`)
    Any format OpenImageIO reads: 8/16-bit PNG, JPEG, 8/16/32-bit TIFF, half and
    float OpenEXR, and ``.tx`` files (tiled, MIP-mapped TIFF as written by
    ``maketx`` / ``ImageBufAlgo.make_texture``). Pixels come back as float32
    ``[H, W, C]`` with the file's channel count. Integer formats are normalised
    by OpenImageIO to ``[0, 1]`` (value / 255 for 8-bit, value / 65535 for
    16-bit); float formats are returned unchanged. Alpha is not applied: files
    with straight alpha (PNG, TGA, ...) come back straight, files with
    premultiplied alpha (EXR, most TIFF) as stored. Row 0 is the *top* scanline
    of the image, as stored in the file. No colour conversion happens here:
    :attr:`ImageData.colorspace` reports the file's own ``oiio:ColorSpace``
    metadata (which OpenImageIO also infers for some formats, e.g. 8-bit PNG and
    JPEG are reported as sRGB) so that the colour stage can decide.

Cache
    Decoded images live in one process-wide LRU cache keyed by
    ``(real path, mtime, subimage, MIP level)``, with a memory budget (default
    2 GiB, :func:`texture_cache`). A file rewritten on disk gets a new mtime and
    so is read again; its stale entries are dropped.

Sampling (:class:`Texture`)
    uv coordinates are MaterialX's: uv ``(0, 0)`` is the bottom-left corner of
    the image and ``(1, 1)`` the top-right, so texel row = ``(1 - v) * height``.
    Texel ``(i, j)`` has its centre at ``((i + 0.5) / W, 1 - (j + 0.5) / H)``.
    Address modes and filters follow MaterialX's ``image`` node; see
    :meth:`Texture.sample`. UDIM sets (``<UDIM>``, ``<UVTILE>``) are handled as
    described in :mod:`mtlx2neural.imaging.udim`.

OpenImageIO's messages
    Errors are retrieved with ``geterror()`` and reported in exceptions (or logged
    when a caller ignores a failure, :func:`pending_oiio_error`). OpenImageIO's own
    habit of printing errors nobody retrieved to *stdout* when the process exits is
    switched off (:func:`openimageio`), so that ``inspect --json`` stdout stays JSON.
"""

from __future__ import annotations

import functools
import logging
import os
import threading
from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np
import OpenImageIO as oiio
import torch

from mtlx2neural.errors import InputError, missing_reason, unreadable_reason
from mtlx2neural.imaging.packages import local_file
from mtlx2neural.imaging.texel_lookup import (
    ADDRESS_MODES,
    FILTER_TYPES,
    address_coord,
    conform_channels,
    finite_texels,
    sample_image,
)
from mtlx2neural.imaging.udim import (
    UdimRange,
    is_tiled_path,
    resolve_udim_set,
    udim_number,
)

log = logging.getLogger(__name__)

DEFAULT_CACHE_BYTES = 2 << 30
"""Default memory budget of the process-wide image cache: 2 GiB."""


def _where(node: str | None) -> str:
    return f" used by node '{node}'" if node else ""


# --------------------------------------------------------------------------- reading


@functools.lru_cache(maxsize=1)
def openimageio():
    """The OpenImageIO module, configured once so that it never writes to stdout.

    By default OpenImageIO prints any error message nobody retrieved with
    ``geterror()`` to stdout when the process exits ("OpenImageIO exited with a
    pending error message ..."), which corrupts machine-readable output such as
    ``inspect --json``. That is switched off; errors are retrieved where they occur.
    """

    oiio.attribute("oiio:print_uncaught_errors", 0)
    return oiio


def pending_oiio_error(context: str) -> str:
    """Retrieve (and clear) OpenImageIO's pending error message, logging it with ``context``; "" when none."""
    message = openimageio().geterror()
    if message:
        log.debug("%s: OpenImageIO: %s", context, message)
    return message


# Storage of decoded pixels: integer files stay integers (a quarter of the memory of
# float32 for 8-bit files); texels are converted when sampled.
_STORAGE = {"uint8": (np.uint8, 1.0 / 255.0), "uint16": (np.uint16, 1.0 / 65535.0), "half": (np.float16, 1.0)}


@dataclass(frozen=True, eq=False)
class ImageData:
    """One decoded image (one MIP level of one subimage).

    Pixels are kept in the file's own precision (``raw``: uint8, uint16, float16
    or float32, ``[H, W, C]``, row 0 = top of the image) and read as float32
    through ``pixels`` / ``tensor()``. ``raw`` may be shared with the
    process-wide cache: treat it as read-only.
    """

    path: str
    """The file that was read."""
    raw: np.ndarray = field(repr=False)
    """``[H, W, C]`` in storage precision; value = raw * ``scale``."""
    scale: float
    """1/255 for 8-bit, 1/65535 for 16-bit integer files, 1 otherwise."""
    colorspace: str | None
    """The file's ``oiio:ColorSpace`` metadata, or None when it has none."""
    channel_names: tuple[str, ...]
    """Channel names from the file (``R, G, B, A``, ``Y``, ...)."""
    file_format: str
    """The file's per-channel data type as OpenImageIO names it: ``uint8``, ``uint16``, ``half``, ``float``."""
    miplevel: int
    """The MIP level these pixels are (0 = full resolution)."""
    mip_levels: int
    """How many MIP levels the file has (1 for an ordinary image)."""

    @property
    def pixels(self) -> np.ndarray:
        """float32 ``[H, W, C]``; integer formats normalised to [0, 1] (a new array for non-float storage)."""
        if self.raw.dtype == np.float32:
            return self.raw
        return self.raw.astype(np.float32) * np.float32(self.scale) if self.scale != 1.0 else \
            self.raw.astype(np.float32)

    @property
    def height(self) -> int:
        """Rows, in texels."""
        return int(self.raw.shape[0])

    @property
    def width(self) -> int:
        """Columns, in texels."""
        return int(self.raw.shape[1])

    @property
    def channels(self) -> int:
        """Channel count, as stored in the file."""
        return int(self.raw.shape[2])

    @property
    def nbytes(self) -> int:
        """Memory held by the stored pixels, in bytes."""
        return int(self.raw.nbytes)

    def tensor(self) -> torch.Tensor:
        """Pixels as a CPU float32 torch tensor ``[H, W, C]`` (do not modify)."""
        return torch.from_numpy(self.pixels)

    def storage_tensor(self) -> torch.Tensor:
        """``raw`` as a torch tensor (shares memory); multiply sampled texels by ``scale``."""
        return torch.from_numpy(self.raw)


class TextureCache:
    """LRU cache of decoded images with a memory budget in bytes. Thread-safe.

    An image larger than the whole budget is returned but not kept.
    """

    def __init__(self, budget_bytes: int = DEFAULT_CACHE_BYTES):
        self.budget_bytes = int(budget_bytes)
        self._items: OrderedDict[tuple, ImageData] = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()
        self.hits = 0
        self.misses = 0

    @property
    def nbytes(self) -> int:
        """Bytes currently held."""
        return self._bytes

    def __len__(self) -> int:
        return len(self._items)

    def set_budget(self, budget_bytes: int) -> None:
        """Change the budget (bytes) and evict down to it."""
        with self._lock:
            self.budget_bytes = int(budget_bytes)
            self._evict(0)

    def clear(self) -> None:
        """Drop every entry."""
        with self._lock:
            self._items.clear()
            self._bytes = 0

    def _evict(self, incoming: int) -> None:
        while self._items and self._bytes + incoming > self.budget_bytes:
            _, old = self._items.popitem(last=False)
            self._bytes -= old.nbytes

    def get(self, key: tuple) -> ImageData | None:
        """The entry for ``key`` (marked most recently used), or None."""
        with self._lock:
            item = self._items.get(key)
            if item is None:
                self.misses += 1
                return None
            self._items.move_to_end(key)
            self.hits += 1
            return item

    def put(self, key: tuple, item: ImageData) -> None:
        """Insert ``item``, dropping stale entries of the same path and least recently used ones."""
        with self._lock:
            for k in [k for k in self._items if k[0] == key[0] and k[1] != key[1]]:
                self._bytes -= self._items.pop(k).nbytes
            if key in self._items:
                self._bytes -= self._items.pop(key).nbytes
            if item.nbytes > self.budget_bytes:
                return
            self._evict(item.nbytes)
            self._items[key] = item
            self._bytes += item.nbytes


_CACHE = TextureCache()


def texture_cache() -> TextureCache:
    """The process-wide image cache (default budget :data:`DEFAULT_CACHE_BYTES`)."""
    return _CACHE


def _check_file(path: str, node: str | None) -> None:
    if not os.path.isfile(path):
        what = missing_reason(path)
        raise InputError(f"texture file '{path}'{_where(node)} {what}. Fix the path or provide the file.")


def _open(path: str, node: str | None):
    oiio = openimageio()
    _check_file(path, node)
    # Keep straight (unassociated) alpha as the file stores it: a texture's colour
    # channels are data, not to be premultiplied (OIIO would for PNG, GIF, ...).
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)
    inp = oiio.ImageInput.open(path, config)
    if inp is None:
        message = oiio.geterror() or "unknown format"
        if unreadable_reason(path) == "permission denied":
            message = "permission denied. Give the current user read access to the file."
        raise InputError(f"cannot read texture file '{path}'{_where(node)}: {message}")
    return inp


def _count_mips(inp, subimage: int) -> int:
    n = 0
    while inp.seek_subimage(subimage, n):
        n += 1
    return n


def read_image(path, *, miplevel: int = 0, subimage: int = 0, node: str | None = None,
               cache: TextureCache | None = None) -> ImageData:
    """Read one MIP level of an image file into float32 ``[H, W, C]`` (row 0 = top).

    ``miplevel`` 0 is full resolution; level k of a MIP-mapped file (``.tx``,
    tiled TIFF/EXR with MIP levels) is ``ceil(W / 2^k) x ceil(H / 2^k)`` as the
    file stores it. ``node`` names the MaterialX / USD node for error messages.
    Results are cached in ``cache`` (default: the process-wide cache).

    Raises InputError naming the file (and node) when it is missing, unreadable, truncated or
    corrupt (OpenImageIO reports an error, even where it decoded part of the pixels: libjpeg
    fills a truncated JPEG with grey), holds NaN or infinite texels (float files), or lacks the
    requested subimage / MIP level.
    """
    shown = os.fspath(path)
    path = local_file(path, node)  # a member of a USDZ package: its bytes, in a local file
    if path != shown:  # errors name the package member, not the private copy
        try:
            return read_image(path, miplevel=miplevel, subimage=subimage, node=node, cache=cache)
        except InputError as exc:
            raise InputError(str(exc).replace(path, shown), node=exc.node) from None
    _check_file(path, node)
    real = os.path.realpath(path)
    cache = _CACHE if cache is None else cache
    key = (real, os.stat(real).st_mtime_ns, int(subimage), int(miplevel))
    hit = cache.get(key)
    if hit is not None:
        return hit
    inp = _open(path, node)
    try:
        nmips = _count_mips(inp, subimage)
        if nmips == 0:
            raise InputError(f"texture file '{path}'{_where(node)} has no subimage {subimage}.")
        if not 0 <= miplevel < nmips or not inp.seek_subimage(subimage, miplevel):
            raise InputError(f"texture file '{path}'{_where(node)} has {nmips} MIP level(s); "
                             f"level {miplevel} was requested.")
        spec = inp.spec()
        fmt = str(spec.format)
        dtype, scale = _STORAGE.get(fmt, (np.float32, 1.0))
        inp.geterror()  # clears what probing the MIP levels left (seeking past the last level is an error)
        pixels = inp.read_image(subimage, miplevel, 0, spec.nchannels, fmt if fmt in _STORAGE else "float")
        failed = inp.has_error() if callable(inp.has_error) else inp.has_error
        if pixels is None or failed:  # a truncated JPEG decodes, with libjpeg's grey fill and an error
            message = inp.geterror() or "no pixels"
            raise InputError(f"cannot decode texture file '{path}'{_where(node)}: it is truncated or corrupt "
                             f"({message.strip()}). Replace it with a complete file.")
        if dtype in (np.float16, np.float32):
            _check_finite(path, node, np.asarray(pixels).reshape(spec.height, spec.width, spec.nchannels))
        cs = spec.getattribute("oiio:ColorSpace")
        data = ImageData(
            path=path,
            raw=np.ascontiguousarray(np.asarray(pixels, dtype=dtype).reshape(
                spec.height, spec.width, spec.nchannels)),
            scale=scale,
            colorspace=str(cs) if cs else None,
            channel_names=tuple(spec.channelnames),
            file_format=str(spec.format),
            miplevel=int(miplevel),
            mip_levels=nmips,
        )
    finally:
        inp.close()
    cache.put(key, data)
    return data


def _check_finite(path: str, node: str | None, pixels: np.ndarray) -> None:
    """A float image with NaN or infinite texels is an :class:`InputError` naming the file and the count:
    every filter would spread them, and the trained model with them."""
    bad = ~np.isfinite(pixels)
    if bad.any():
        texels = bad.any(axis=-1)
        row, col = (int(i[0]) for i in np.nonzero(texels))
        raise InputError(f"texture file '{path}'{_where(node)} has {int(texels.sum())} texel(s) that are NaN or "
                         f"infinite (the first at column {col}, row {row} from the top). Replace them with finite "
                         f"values (e.g. OpenImageIO: oiiotool in.exr --fixnan black -o out.exr).")


def mip_level_count(path, *, subimage: int = 0, node: str | None = None) -> int:
    """How many MIP levels the file stores (1 for an ordinary, non-MIP-mapped image)."""
    inp = _open(local_file(path, node), node)
    try:
        return _count_mips(inp, subimage)
    finally:
        inp.close()


# --------------------------------------------------------------------------- Texture


class Texture:
    """One image file or one UDIM set, sampled with MaterialX ``image`` node semantics.

    ``path`` is a file, or a pattern with a ``<UDIM>`` / ``<UVTILE>`` token.
    ``miplevel`` picks the MIP level to sample (0 = full resolution).
    ``udimset`` optionally declares a UDIM set's tiles (UDIM numbers); otherwise
    the tiles on disk are used. ``node`` names the node for error messages.

    Pixels stay on the CPU and are copied to a sample's device on first use.
    Non-finite texels are sampled as NaN -> 0, +-Inf -> +-65504.
    A UDIM set whose tiles differ in channel count is sampled with the largest
    count: 1-channel tiles broadcast to RGB, missing channels read 1.
    """

    def __init__(self, path, *, miplevel: int = 0, udimset=None, node: str | None = None,
                 cache: TextureCache | None = None):
        self.path = os.fspath(path)
        self.node = node
        self.is_udim = is_tiled_path(self.path)
        if self.is_udim:
            tiles = resolve_udim_set(self.path, udimset=udimset, node=node)
        else:
            tiles = {(0, 0): self.path}
        self.images: dict[tuple[int, int], ImageData | None] = {
            t: (read_image(p, miplevel=miplevel, node=node, cache=cache) if p is not None else None)
            for t, p in tiles.items()}
        present = [im for im in self.images.values() if im is not None]
        self.channels = max(im.channels for im in present)
        """Channel count of :meth:`sample`'s output."""
        self.range = UdimRange.of_tiles(tiles) if self.is_udim else UdimRange(0, 0, 1, 1)
        """uv rectangle the texture covers (``[0,1]^2`` for a single image)."""
        self._device_tiles: dict[torch.device, dict[tuple[int, int], torch.Tensor]] = {}

    @classmethod
    def from_array(cls, pixels, *, colorspace: str | None = None, name: str = "<array>") -> Texture:
        """A single-image texture from an array ``[H, W, C]`` or ``[H, W]`` (row 0 = top)."""
        arr = np.asarray(pixels, dtype=np.float32)
        if arr.ndim == 2:
            arr = arr[..., None]
        if arr.ndim != 3 or arr.shape[0] < 1 or arr.shape[1] < 1 or arr.shape[2] < 1:
            raise ValueError(f"texture pixels must be [H, W, C], got shape {arr.shape}.")
        self = cls.__new__(cls)
        self.path, self.node, self.is_udim = name, None, False
        self.images = {(0, 0): ImageData(name, np.ascontiguousarray(arr), 1.0, colorspace,
                                         tuple("RGBA"[: arr.shape[2]]) if arr.shape[2] <= 4 else (),
                                         "float", 0, 1)}
        self.channels = arr.shape[2]
        self.range = UdimRange(0, 0, 1, 1)
        self._device_tiles = {}
        return self

    @property
    def tiles(self) -> dict[int, str | None]:
        """``{UDIM number: file path or None when missing}`` (``{1001: path}`` for a single image)."""
        return {udim_number(*t): (im.path if im is not None else None) for t, im in self.images.items()}

    @property
    def colorspace(self) -> str | None:
        """The files' ``oiio:ColorSpace`` (the first tile's for a UDIM set), or None."""
        return next((im.colorspace for im in self.images.values() if im is not None), None)

    def _tiles_on(self, device: torch.device) -> dict[tuple[int, int], torch.Tensor]:
        tiles = self._device_tiles.get(device)
        if tiles is None:
            tiles = {}
            for t, im in self.images.items():
                if im is None:
                    continue
                if im.channels == self.channels and im.raw.dtype != np.float32:
                    # Integer/half storage: converted per sampled texel (half may hold Inf/NaN).
                    st = im.storage_tensor()
                    tiles[t] = (finite_texels(st.float()) if st.dtype == torch.float16 and
                                not bool(torch.isfinite(st).all()) else st, im.scale)
                else:
                    tiles[t] = (conform_channels(finite_texels(im.tensor()), self.channels), 1.0)
                tiles[t] = (tiles[t][0].to(device), tiles[t][1])
            self._device_tiles[device] = tiles
            self._device_tiles[device] = tiles
        return tiles

    def sample(self, uv: torch.Tensor, *, uaddress: str = "periodic", vaddress: str = "periodic",
               filtertype: str = "linear", default: torch.Tensor | None = None) -> torch.Tensor:
        """Texture values ``[N, C]`` float32 at uv ``[N, 2]``, on ``uv``'s device.

        * uv ``(0, 0)`` is the bottom-left corner, ``(1, 1)`` the top-right
          (for a UDIM set, tile ``(tu, tv)`` covers ``[tu, tu+1] x [tv, tv+1]``).
        * ``uaddress`` / ``vaddress`` (MaterialX ``uaddressmode`` /
          ``vaddressmode``): ``periodic`` repeats, ``clamp`` repeats the edge
          texels, ``mirror`` repeats with every other copy reflected (GL
          ``MIRRORED_REPEAT``), ``constant`` returns ``default`` for coordinates
          outside the covered range (``[0, 1]`` for one image, inclusive);
          inside it, filter taps that fall outside the image read ``default``
          (a GPU sampler's CLAMP_TO_BORDER with the default as border colour,
          which is how MaterialX's GLSL renderer binds ``constant``; OSL/OIIO's
          ``black`` wrap is the same with a zero default).
        * ``filtertype``: ``closest`` (the texel containing uv), ``linear``
          (bilinear between the four nearest texel centres), ``cubic`` (bicubic
          *uniform cubic B-spline* over 4x4 texels). The B-spline is what
          OpenImageIO's ``bicubic`` interpolation (MaterialX's OSL ``image``
          implementation) computes; its weights are non-negative, so results stay
          within the range of the texels (no overshoot: roughness stays >= 0,
          colours stay in gamut, normal maps do not ring). It smooths rather than
          interpolates: at a texel centre it returns (1/6, 4/6, 1/6) of the
          neighbours along each axis. MaterialX's GLSL / MSL / Slang generators
          bind "cubic" to the GPU's bilinear sampler, so for parity with those
          renderers pass ``linear``.
        * ``default`` ``[C]``, ``[N, C]`` or a scalar: the value outside a
          ``constant`` range, in missing UDIM tiles and for non-finite uv;
          zeros when None.

        UDIM sets are one texture over the bounding box of their tiles (see
        :class:`mtlx2neural.imaging.udim.UdimRange`): ``periodic`` and
        ``mirror`` fold uv into that box, ``clamp`` clamps to its edge texels,
        ``constant`` returns ``default`` outside it. The tile is
        ``(floor(u), floor(v))`` (clamped into the box) and the in-tile uv is
        the fractional part. Filter taps do not cross tile borders: they clamp
        to the tile's edge texels, except along an axis where the set is one
        tile wide, where the address mode applies (so a one-tile set samples
        exactly like the image itself). Clamping is per filter tap (clamp to
        edge, as OpenImageIO and GPU samplers do).
        """
        for name, mode in (("uaddress", uaddress), ("vaddress", vaddress)):
            if mode not in ADDRESS_MODES:
                raise ValueError(f"{name} must be one of {ADDRESS_MODES}, got {mode!r}.")
        if filtertype not in FILTER_TYPES:
            raise ValueError(f"filtertype must be one of {FILTER_TYPES}, got {filtertype!r}.")
        if uv.dim() != 2 or uv.shape[-1] != 2:
            raise ValueError(f"uv must be [N, 2], got shape {tuple(uv.shape)}.")
        device, n = uv.device, uv.shape[0]
        out = self._default(default, n, device)
        if n == 0:
            return out
        cdtype = uv.dtype if uv.dtype == torch.float64 else torch.float32
        uv = uv.to(cdtype)
        valid = torch.isfinite(uv).all(-1)
        uv = torch.where(valid[:, None], uv, torch.zeros_like(uv))
        r = self.range
        u, v = uv[:, 0], uv[:, 1]
        if uaddress == "constant":
            valid &= (u >= r.u0) & (u <= r.u1)
        if vaddress == "constant":
            valid &= (v >= r.v0) & (v <= r.v1)
        # periodic / mirror fold into the range; clamp / constant clamp per tap, and a
        # margin of 4 uv (>= 4 texels, wider than any filter) keeps the result exact.
        u = address_coord(u, r.u0, r.u1, uaddress).clamp(r.u0 - 4, r.u1 + 4)
        v = address_coord(v, r.v0, r.v1, vaddress).clamp(r.v0 - 4, r.v1 + 4)
        tu = u.floor().clamp(r.u0, r.u1 - 1)
        tv = v.floor().clamp(r.v0, r.v1 - 1)
        lu, lv = u - tu, v - tv
        umode_tap = "clamp" if r.u1 - r.u0 > 1 else uaddress
        vmode_tap = "clamp" if r.v1 - r.v0 > 1 else vaddress
        tiles = self._tiles_on(device)
        if not self.is_udim:
            img, scale = tiles[(0, 0)]
            val = sample_image(img, lu, lv, umode_tap, vmode_tap, filtertype, border=out, scale=scale)
            return torch.where(valid[:, None], val, out)
        tu_i, tv_i = tu.long(), tv.long()
        for (ku, kv), (img, scale) in tiles.items():
            sel = valid & (tu_i == ku) & (tv_i == kv)
            idx = sel.nonzero().squeeze(1)
            if idx.numel():
                out[idx] = sample_image(img, lu[idx], lv[idx], umode_tap, vmode_tap, filtertype, border=out[idx],
                                        scale=scale)
        return out

    def _default(self, default, n: int, device: torch.device) -> torch.Tensor:
        c = self.channels
        if default is None:
            return torch.zeros(n, c, dtype=torch.float32, device=device)
        d = torch.as_tensor(default, dtype=torch.float32, device=device)
        if d.dim() == 0:
            d = d.expand(1)
        if d.shape[-1] not in (1, c):
            raise ValueError(f"default has {d.shape[-1]} channels; the texture '{self.path}' has {c}.")
        d = torch.nan_to_num(d, nan=0.0, posinf=0.0, neginf=0.0)
        return d.expand(n, c).clone()

    def __repr__(self) -> str:
        im = next(im for im in self.images.values() if im is not None)
        kind = f"UDIM set of {sum(i is not None for i in self.images.values())} tile(s)" if self.is_udim else "image"
        return f"Texture('{self.path}', {kind}, {im.width}x{im.height}x{self.channels})"
