"""Image textures of the MaterialX Slang oracle: reading images on the host, sampling them in Slang.

Image textures are read on the host (OpenImageIO), packed into one buffer of float32 RGBA texels,
and sampled in the shader at mip level 0 with the node's address modes and filter (bilinear by
default), following the MaterialX convention that uv (0, 0) is the lower-left corner of the image.
``_TEXTURE_SLANG`` replaces the generator's ``SamplerTexture2D`` and its sampling helpers.
Which uniforms become textures, and with which sampling properties, is decided where the uniforms
are patched (:mod:`mtlx2neural.oracle.source`); a file that cannot be read is replaced by the image
node's ``default`` value, as MaterialX specifies.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mtlx2neural.oracle.errors import OracleUnsupported

# MaterialX image address modes (ImageSamplingProperties::AddressMode) and filter types.
_ADDRESS_CONSTANT, _ADDRESS_CLAMP, _ADDRESS_PERIODIC, _ADDRESS_MIRROR = 0, 1, 2, 3
_FILTER_CLOSEST, _FILTER_LINEAR = 0, 1


@dataclass
class _Texture:
    uniform: str
    path: str | None  # resolved file, or None when it cannot be read (the default is used)
    width: int
    height: int
    uaddress: int
    vaddress: int
    filter: int
    default: tuple[float, float, float, float]
    offset: int = 0

    def texels(self) -> np.ndarray:
        """[height, width, 4] float32 RGBA, top row first (read now; not kept in memory)."""
        if self.path is not None:
            pix = _read_image(Path(self.path))
            if pix is not None and pix.shape[:2] == (self.height, self.width):
                return pix
            warnings.warn(
                f"MaterialX oracle: image {self.path} changed or became unreadable; using its default",
                stacklevel=2,
            )
        return np.broadcast_to(np.asarray(self.default, dtype=np.float32), (self.height, self.width, 4))


def _oiio():
    try:
        # Local: OpenImageIO is checked here so that a missing module is named.
        import OpenImageIO as oiio
    except ImportError as exc:  # pragma: no cover - OpenImageIO is a project dependency
        raise OracleUnsupported(f"reading image textures needs OpenImageIO: {exc}") from exc
    return oiio


def _image_size(path: Path) -> tuple[int, int] | None:
    """(width, height) of an image file, reading only its header; None if unreadable."""
    oiio = _oiio()
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        oiio.geterror()  # clear the pending error message
        return None
    try:
        spec = inp.spec()
        return int(spec.width), int(spec.height)
    finally:
        inp.close()


def _read_image(path: Path) -> np.ndarray | None:
    oiio = _oiio()
    buf = oiio.ImageBuf(str(path))
    if buf.has_error:
        return None
    pix = np.asarray(buf.get_pixels(oiio.FLOAT), dtype=np.float32)
    if pix.ndim == 2:
        pix = pix[:, :, None]
    h, w, c = pix.shape
    out = np.ones((h, w, 4), dtype=np.float32)
    if c == 1:
        out[..., :3] = pix[..., :1]
    elif c == 2:  # luminance + alpha
        out[..., :3] = pix[..., :1]
        out[..., 3] = pix[..., 1]
    else:
        out[..., : min(c, 4)] = pix[..., :4]
    return out


_TEXTURE_SLANG = """
// mtlx2neural oracle: image textures live in one buffer of RGBA texels (top row first).
struct SamplerTexture2D
{
    int offset;
    int width;
    int height;
    int uaddress;   // 0 constant, 1 clamp, 2 periodic, 3 mirror
    int vaddress;
    int filter;     // 0 closest, otherwise bilinear
    float4 fallback;

    int get_width(int mipLevel = 0) { return width; }
    int get_height(int mipLevel = 0) { return height; }
    int get_num_mip_levels() { return 1; }
};

StructuredBuffer<float4> mxo_texels;

int mxo_address(int i, int n, int mode, inout bool outside)
{
    if (mode == 2)
    {
        int m = i % n;
        return m < 0 ? m + n : m;
    }
    if (mode == 3)
    {
        int p = 2 * n;
        int m = i % p;
        if (m < 0)
            m += p;
        return m < n ? m : p - 1 - m;
    }
    if (mode == 0 && (i < 0 || i >= n))
        outside = true;
    return clamp(i, 0, n - 1);
}

// x counts columns from the left, y rows from the bottom (uv origin is the lower-left corner).
float4 mxo_fetch(SamplerTexture2D t, int x, int y)
{
    bool outside = false;
    int xi = mxo_address(x, t.width, t.uaddress, outside);
    int yi = mxo_address(y, t.height, t.vaddress, outside);
    if (outside)
        return t.fallback;
    return mxo_texels[t.offset + (t.height - 1 - yi) * t.width + xi];
}

float4 mxo_sample(SamplerTexture2D t, float2 uv)
{
    float x = uv.x * float(t.width) - 0.5;
    float y = uv.y * float(t.height) - 0.5;
    if (t.filter == 0)
        return mxo_fetch(t, int(floor(x + 0.5)), int(floor(y + 0.5)));
    float x0 = floor(x);
    float y0 = floor(y);
    float fx = x - x0;
    float fy = y - y0;
    int ix = int(x0);
    int iy = int(y0);
    float4 bottom = lerp(mxo_fetch(t, ix, iy), mxo_fetch(t, ix + 1, iy), fx);
    float4 top = lerp(mxo_fetch(t, ix, iy + 1), mxo_fetch(t, ix + 1, iy + 1), fx);
    return lerp(bottom, top, fy);
}

float4 textureLod(SamplerTexture2D tex, float2 uv, float lod) { return mxo_sample(tex, uv); }
float4 texture(SamplerTexture2D tex, float2 uv) { return mxo_sample(tex, uv); }
float4 textureGrad(SamplerTexture2D tex, float2 uv, float2 ddx_, float2 ddy_) { return mxo_sample(tex, uv); }
int2 textureSize(SamplerTexture2D tex, int mipLevel) { return int2(tex.width, tex.height); }
"""
