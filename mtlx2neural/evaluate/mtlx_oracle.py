"""Oracle: evaluate a MaterialX material with MaterialX's own generated Slang code, on the CPU.

The MaterialX Slang generator (``MaterialX.PyMaterialXGenSlang``) writes a pixel shader for a
``surfacematerial``.  This module patches that pixel shader so that it runs as a compute kernel on
slangpy's CPU device for chosen direction pairs:

* the uniform constant buffer becomes ``static`` globals initialised with the values that the
  generator published for the document; the view position becomes a per-thread global;
* the light loop sees exactly one directional light, whose direction and intensity are per-thread
  globals (``numActiveLightSources()`` and ``sampleLightSource()`` are replaced);
* the specular environment is off (``SPECULAR_ENVIRONMENT_NONE``), so the indirect and refraction
  terms are zero; screen-space derivatives (``fwidth``/``ddx``/``ddy``/``dFdx``/``dFdy``) are zero,
  as on a flat plane, and the subsurface approximation sees zero curvature;
* image textures are read on the host (OpenImageIO), packed into one buffer, and sampled in the
  shader at mip level 0 with the node's address modes and filter (bilinear by default), following
  the MaterialX convention that uv (0, 0) is the lower-left corner of the image.  A file that
  cannot be read is replaced by the image node's ``default`` value, as MaterialX specifies;
* a ``[numthreads(32,1,1)]`` compute kernel fills the vertex data of a flat surface at the origin
  (normal +Z, tangent +X, bitangent +Y, texcoords (0.5, 0.5), vertex colours 1), places the
  viewer along ``wi``, and calls the generated fragment function twice: with the light at
  intensity ``_LIGHT_SCALE`` and at zero.  The difference divided by the (power-of-two) scale is
  the reflected radiance of a unit white directional light from ``wo``; whatever does not depend
  on the light (emission; environment and refraction terms, which are zero here anyway) cancels
  exactly.  The large scale keeps the float32 cancellation accurate when the emission is much
  brighter than the reflection.

The returned value is the linear colour the generated surface shader produces for that light:
``f(wi, wo) * max(0, wo.z)`` weighted by the surface's opacity (MaterialX multiplies the surface
colour by its opacity even when transparency is off).  No output transform is applied
(``hwSrgbEncodeOutput`` is off).  The directional-albedo method is the default analytic fit.
MaterialX's closures clamp N.L and N.V to at least 1e-8 instead of returning zero, so directions
below the horizon give tiny non-zero values (or, for translucent BSDFs, genuine transmission);
pass directions in the upper hemisphere to compare with a reflectance model.
"""

from __future__ import annotations

import hashlib
import os
import re
import threading
import warnings
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mtlx2neural.errors import Mtlx2NeuralError

__all__ = [
    "OracleError",
    "OracleUnsupported",
    "generate_oracle_source",
    "mtlx_slang_eval",
    "oracle_available",
]

# Power of two, so scaling the light is exact in float32.
_LIGHT_SCALE = 65536.0
_ENTRY = "mxo_eval"
_GROUP = 32

# MaterialX image address modes (ImageSamplingProperties::AddressMode) and filter types.
_ADDRESS_CONSTANT, _ADDRESS_CLAMP, _ADDRESS_PERIODIC, _ADDRESS_MIRROR = 0, 1, 2, 3
_FILTER_CLOSEST, _FILTER_LINEAR = 0, 1


class OracleError(Mtlx2NeuralError):
    """The oracle cannot run here, or MaterialX generation or Slang compilation of its shader failed."""


class OracleUnsupported(OracleError):
    """The material uses something the oracle cannot evaluate."""


_lock = threading.RLock()
_stdlib = None  # cached mx.Document with the standard data libraries
_sources: dict[tuple[str, str, str], _OracleSource] = {}  # keyed by (XML hash, base dir, material)
# Compiled kernels keyed by (patched source hash, cache_dir), oldest first.  Kernels of textured
# materials hold their texels (float32 RGBA, 64 MiB for a 2048^2 image); the oldest kernels are
# dropped when the texels of all cached kernels exceed _MAX_CACHED_TEXEL_BYTES.
_kernels: OrderedDict[tuple[str, str | None], _Kernel] = OrderedDict()
_MAX_CACHED_TEXEL_BYTES = 1 << 30
_devices: dict[str | None, object] = {}
_available: tuple[bool, str] | None = None


# --------------------------------------------------------------------------------------------
# MaterialX side
# --------------------------------------------------------------------------------------------


def _mx():
    import MaterialX as mx
    import MaterialX.PyMaterialXGenShader as mxgen
    import MaterialX.PyMaterialXGenSlang as mxslang

    return mx, mxgen, mxslang


def _library_root() -> Path:
    mx, _, _ = _mx()
    return Path(os.path.dirname(mx.__file__))


def _standard_libraries():
    global _stdlib
    with _lock:
        if _stdlib is None:
            mx, _, _ = _mx()
            lib = mx.createDocument()
            search = mx.FileSearchPath(str(_library_root()))
            mx.loadLibraries(mx.getDefaultDataLibraryFolders(), search, lib)
            _stdlib = lib
        return _stdlib


def _find_material(doc, material: str):
    mx, _, _ = _mx()
    node = doc.getNode(material)
    if node is None:
        elem = doc.getDescendant(material)
        node = elem if elem is not None and elem.isA(mx.Node) else None
    if node is None:
        names = [m.getName() for m in doc.getMaterialNodes()]
        raise OracleError(f"no material node {material!r} in document (materials: {names})")
    if node.getCategory() != "surfacematerial":
        raise OracleError(f"{material!r} is a {node.getCategory()!r} node, not a surfacematerial")
    return node


def _generate_pixel_shader(document, material: str):
    """MaterialX's Slang pixel shader for `material`: (source, {variable: (mx type, value)})."""
    mx, mxgen, mxslang = _mx()
    doc = document.copy()
    doc.importLibrary(_standard_libraries())
    node = _find_material(doc, material)

    gen = mxslang.SlangShaderGenerator.create()
    # Colour management as MaterialX's viewers set it up: texture colour spaces
    # (srgb_texture, ...) are converted to the document's working space.
    cms = mxgen.DefaultColorManagementSystem.create(gen.getTarget())
    cms.loadLibrary(doc)
    gen.setColorManagementSystem(cms)
    ctx = mxgen.GenContext(gen)
    ctx.registerSourceCodeSearchPath(mx.FileSearchPath(str(_library_root())))
    opts = ctx.getOptions()
    opts.hwSpecularEnvironmentMethod = mxgen.HwSpecularEnvironmentMethod.SPECULAR_ENVIRONMENT_NONE
    opts.hwSrgbEncodeOutput = False
    opts.hwTransparency = False
    opts.hwShadowMap = False
    opts.hwAmbientOcclusion = False
    opts.hwWriteDepthMoments = False
    opts.hwWriteAlbedoTable = False
    opts.hwWriteEnvPrefilter = False
    opts.fileTextureVerticalFlip = False  # the sampler below applies the lower-left uv origin
    # hwDirectionalAlbedoMethod and hwTransmissionRenderMethod are not exposed to Python.  Their
    # defaults are the analytic albedo fit and refraction; with no specular environment the
    # refraction term is zero, so the transmission method does not change the result.
    try:
        shader = gen.generate("mxo_" + re.sub(r"\W", "_", material), node, ctx)
    except Exception as exc:  # MaterialX raises ExceptionShaderGenError
        raise OracleError(f"MaterialX Slang generation failed for {material!r}: {exc}") from exc
    stage = shader.getStage(mxgen.PIXEL_STAGE)
    uniforms: dict[str, tuple[str, object]] = {}
    for block in stage.getUniformBlocks().values():
        for i in range(block.size()):
            port = block[i]
            uniforms[port.getVariable()] = (port.getType().getName(), port.getValue())
    return shader.getSourceCode(mxgen.PIXEL_STAGE), uniforms


# --------------------------------------------------------------------------------------------
# Textures
# --------------------------------------------------------------------------------------------


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


def _value_rgba(value) -> tuple[float, float, float, float]:
    if value is None:
        return (0.0, 0.0, 0.0, 0.0)
    comps = _components(value, 1)
    if len(comps) == 1:
        return (comps[0], comps[0], comps[0], comps[0])
    comps = (comps + [0.0, 0.0, 1.0])[:3] + ([comps[3]] if len(comps) > 3 else [1.0])
    return tuple(float(c) for c in comps)


def _int_uniform(uniforms: dict, name: str, fallback: int) -> int:
    _, value = uniforms.get(name, (None, None))
    if value is None:
        return fallback
    data = value.getData()
    return int(data) if isinstance(data, (int, np.integer)) and not isinstance(data, bool) else fallback


def _oiio():
    try:
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


def _make_texture(uniform: str, uniforms: dict, base_dir: Path) -> _Texture:
    # Sampling properties come from the uniforms next to "<root>_file", as MaterialX's renderers
    # find them (ImageSamplingProperties); absent ones mean periodic addressing and linear filtering.
    root = uniform.rsplit("_", 1)[0] if "_" in uniform else uniform
    _, file_value = uniforms.get(uniform, (None, None))
    default = _value_rgba(uniforms.get(root + "_default", (None, None))[1])
    umode = _int_uniform(uniforms, root + "_uaddressmode", _ADDRESS_PERIODIC)
    vmode = _int_uniform(uniforms, root + "_vaddressmode", _ADDRESS_PERIODIC)
    filt = _int_uniform(uniforms, root + "_filtertype", _FILTER_LINEAR)
    umode = umode if umode in (0, 1, 2, 3) else _ADDRESS_PERIODIC
    vmode = vmode if vmode in (0, 1, 2, 3) else _ADDRESS_PERIODIC
    filt = _FILTER_CLOSEST if filt == _FILTER_CLOSEST else _FILTER_LINEAR  # cubic -> linear
    name = file_value.getValueString() if file_value is not None else ""
    if name:
        if "<UDIM>" in name or "<UVTILE>" in name:
            raise OracleUnsupported(f"image {name!r} uses UDIM/UV tiles, which the oracle does not support")
        p = Path(name)
        candidates = [p] if p.is_absolute() else [base_dir / p, Path.cwd() / p]
        for cand in candidates:
            size = _image_size(cand) if cand.is_file() else None
            if size is not None:
                return _Texture(uniform, str(cand.resolve()), size[0], size[1], umode, vmode, filt, default)
        warnings.warn(
            f"MaterialX oracle: image {name!r} ({uniform}) cannot be read; using the node's default value",
            stacklevel=2,
        )
    return _Texture(uniform, None, 1, 1, umode, vmode, filt, default)


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


def _patch_textures(src: str) -> str:
    """Replace the generated SamplerTexture2D struct and its sampling helpers with ours."""
    m = re.search(r"^struct\s+SamplerTexture2D\s*$", src, flags=re.MULTILINE)
    if m is None:
        raise OracleError("generated pixel shader has no SamplerTexture2D struct")
    close_idx = _matching_brace(src, src.index("{", m.end()))
    end = close_idx + 1
    if src[end : end + 1] == ";":
        end += 1
    src = src[: m.start()] + "// (SamplerTexture2D: see the oracle's definition below the uniforms)" + src[end:]
    for fn in ("textureLod", "texture", "textureGrad", "textureSize"):
        src = _replace_function(src, rf"^\w+\s+{fn}\s*\(\s*SamplerTexture2D\b[^)]*\)", "", required=False)
    return src


# --------------------------------------------------------------------------------------------
# Source patching
# --------------------------------------------------------------------------------------------


def _matching_brace(src: str, open_idx: int) -> int:
    """Index of the '}' that closes the '{' at `open_idx`."""
    depth = 0
    for i in range(open_idx, len(src)):
        c = src[i]
        if c == "{":
            depth += 1
        elif c == "}":
            depth -= 1
            if depth == 0:
                return i
    raise OracleError("unbalanced braces in generated shader")


def _replace_function(src: str, signature_regex: str, new_def: str, *, required: bool = True) -> str:
    m = re.search(signature_regex, src, flags=re.MULTILINE)
    if m is None:
        if required:
            raise OracleError(f"generated shader has no function matching {signature_regex!r}")
        return src
    open_idx = src.index("{", m.end())
    close_idx = _matching_brace(src, open_idx)
    return src[: m.start()] + new_def + src[close_idx + 1 :]


def _components(value, n: int) -> list[float]:
    if value is None:
        return [0.0] * n
    data = value.getData()
    if isinstance(data, (bool, int, float, np.integer, np.floating)):
        comps = [float(data)]
    elif hasattr(data, "asTuple"):
        comps = list(data.asTuple())
    else:
        comps = [float(x) for x in re.split(r"[,\s]+", value.getValueString().strip()) if x]
    if len(comps) == 1 and n > 1:
        comps = comps * n
    return [float(c) for c in comps]


def _fmt(x: float) -> str:
    if not np.isfinite(x):
        raise OracleError(f"non-finite uniform value {x}")
    return repr(float(x))


_VEC_RE = re.compile(r"^(float|int|uint|bool)([234])$")
_MAT_RE = re.compile(r"^float([234])x([234])$")


def _static_initializer(slang_type: str, mx_type: str, value) -> str:
    """A Slang initializer expression for a uniform of `slang_type` holding MaterialX `value`."""
    if slang_type == "float":
        return _fmt(_components(value, 1)[0])
    if slang_type in ("int", "uint"):
        if mx_type in ("string", "filename") or value is None:
            return "0"
        data = value.getData()
        return "0" if isinstance(data, str) else str(int(data))
    if slang_type == "bool":
        return "true" if (value is not None and bool(value.getData())) else "false"
    m = _VEC_RE.match(slang_type)
    if m:
        n = int(m.group(2))
        comps = _components(value, n)
        if len(comps) != n:
            raise OracleError(f"uniform of type {slang_type} got {len(comps)} components")
        return f"{slang_type}({', '.join(_fmt(c) for c in comps)})"
    m = _MAT_RE.match(slang_type)
    if m:
        n = int(m.group(1)) * int(m.group(2))
        if value is None:
            comps = [0.0] * n
        else:
            comps = [float(x) for x in re.split(r"[,\s]+", value.getValueString().strip()) if x]
        if len(comps) != n:
            raise OracleError(f"uniform of type {slang_type} got {len(comps)} components")
        # Same element order as the generator's matrix constants (mx_matrix_mul compensates).
        return f"{slang_type}({', '.join(_fmt(c) for c in comps)})"
    # Structs (surfaceshader, displacementshader, ...): zero-initialised.
    return "{}"


_UNIFORM_LINE = re.compile(
    r"^\s*uniform\s+(?P<type>[A-Za-z_]\w*)\s+(?P<name>[A-Za-z_]\w*)\s*(?P<array>\[[^\]]*\])?\s*;"
)


def _patch_uniforms(src: str, uniforms: dict, base_dir: Path) -> tuple[str, list[_Texture]]:
    m = re.search(r"^cbuffer\s+\w+\s*$", src, flags=re.MULTILINE)
    if m is None:
        raise OracleError("generated pixel shader has no uniform cbuffer")
    open_idx = src.index("{", m.end())
    close_idx = _matching_brace(src, open_idx)
    body = src[open_idx + 1 : close_idx]
    out = [_TEXTURE_SLANG, "// mtlx2neural oracle: uniforms as static globals"]
    declared = set()
    textures: list[_Texture] = []
    offset = 0
    for line in body.splitlines():
        s = line.strip()
        if not s or s.startswith("//"):
            continue
        um = _UNIFORM_LINE.match(line)
        if um is None:
            raise OracleError(f"cannot parse uniform declaration: {s!r}")
        typ, name, array = um.group("type"), um.group("name"), um.group("array") or ""
        declared.add(name)
        if typ == "SamplerTexture2D":
            if array:
                raise OracleUnsupported(f"texture array uniform {name!r} is not supported")
            tex = _make_texture(name, uniforms, base_dir)
            tex.offset = offset
            h, w = tex.height, tex.width
            offset += h * w
            textures.append(tex)
            stamp = ""
            if tex.path:
                st = os.stat(tex.path)
                stamp = f" {tex.path} ({st.st_size} bytes, mtime {st.st_mtime_ns})"
            out.append(f"// image{stamp or ' not found: default value'}")
            fallback = ", ".join(_fmt(c) for c in tex.default)
            out.append(
                f"static SamplerTexture2D {name} = {{ {tex.offset}, {w}, {h}, {tex.uaddress}, "
                f"{tex.vaddress}, {tex.filter}, float4({fallback}) }};"
            )
            continue
        if name == "u_viewPosition":
            out.append(f"static {typ} {name};  // set per thread from wi")
            continue
        if name == "u_numActiveLightSources":
            out.append(f"static {typ} {name} = 1;")
            continue
        if array:
            out.append(f"static {typ} {name}{array} = {{}};")
            continue
        mx_type, value = uniforms.get(name, ("", None))
        out.append(f"static {typ} {name} = {_static_initializer(typ, mx_type, value)};")
    if "u_viewPosition" not in declared:  # e.g. unlit shaders; the kernel still sets it
        out.append("static float3 u_viewPosition;")
    if "u_refractionTwoSided" not in declared:
        out.append("static bool u_refractionTwoSided = false;")
    out.append("static float3 mxo_lightDirection = float3(0.0, 0.0, 1.0);")
    out.append("static float mxo_lightIntensity = 0.0;")
    out.append(
        "float mxo_zero(float x) { return 0.0; }\n"
        "float2 mxo_zero(float2 x) { return float2(0.0); }\n"
        "float3 mxo_zero(float3 x) { return float3(0.0); }\n"
        "float4 mxo_zero(float4 x) { return float4(0.0); }"
    )
    return src[: m.start()] + "\n".join(out) + "\n" + src[close_idx + 1 :], textures


_VD_FIELD = re.compile(r"^\s*(?P<type>\w+)\s+(?P<name>\w+)\s*(?::\s*\w+)?\s*;")


def _vertex_fields(src: str) -> list[tuple[str, str]]:
    m = re.search(r"^struct\s+VertexData\s*$", src, flags=re.MULTILINE)
    if m is None:
        raise OracleError("generated pixel shader has no VertexData struct")
    open_idx = src.index("{", m.end())
    body = src[open_idx + 1 : _matching_brace(src, open_idx)]
    fields = []
    for line in body.splitlines():
        fm = _VD_FIELD.match(line)
        if fm:
            fields.append((fm.group("type"), fm.group("name")))
    return fields


def _vertex_value(typ: str, name: str) -> str | None:
    """Value of a VertexData field for a flat surface at the origin; None means zero."""
    vm = _VEC_RE.match(typ)
    n = int(vm.group(2)) if vm else 1
    low = name.lower()
    if low.startswith(("sv_", "position")):
        return None
    if low.startswith("bitangent"):
        v = [0.0, 1.0, 0.0]
    elif low.startswith("normal"):
        v = [0.0, 0.0, 1.0]
    elif low.startswith("tangent"):
        v = [1.0, 0.0, 0.0]
    elif low.startswith("texcoord"):
        v = [0.5, 0.5, 0.0]
    elif low.startswith("color"):
        v = [1.0, 1.0, 1.0, 1.0]
    else:
        return None
    v = (v + [0.0, 0.0, 0.0, 0.0])[:n]
    if n == 1:
        return f"{typ}({_fmt(v[0])})"
    return f"{typ}({', '.join(_fmt(c) for c in v)})"


def _patch_source(src: str, uniforms: dict, base_dir: Path) -> tuple[str, list[_Texture]]:
    src = _patch_textures(src)
    src, textures = _patch_uniforms(src, uniforms, base_dir)

    # One directional light; direction and intensity come from per-thread globals.  (Shaders
    # without lighting, such as surface_unlit, have neither function and reflect nothing.)
    src = _replace_function(
        src,
        r"^int\s+numActiveLightSources\s*\(\s*\)",
        "int numActiveLightSources()\n{\n    return 1;\n}",
        required=False,  # unlit shaders have no light loop
    )
    src = _replace_function(
        src,
        r"^void\s+sampleLightSource\s*\(\s*LightData\s+\w+\s*,\s*float3\s+\w+\s*,\s*out\s+lightshader\s+\w+\s*\)",
        "void sampleLightSource(LightData light, float3 position, out lightshader result)\n"
        "{\n"
        "    result.direction = mxo_lightDirection;\n"
        "    result.intensity = float3(mxo_lightIntensity);\n"
        "}",
        required=False,
    )

    # Slang rejects global constants without `static` (MaterialX emits some, e.g. for blackbody).
    src = re.sub(r"^const\s+(?=\w)", "static const ", src, flags=re.MULTILINE)

    # Screen-space derivatives are zero, as on a flat plane; the subsurface approximation divides
    # two of them to get the curvature, which is zero on a plane.
    src = re.sub(r"\bfloat\s+curvature\s*=\s*[^;]*fwidth[^;]*;", "float curvature = 0.0;", src)
    src = re.sub(r"\b(fwidth|ddx|ddy|dFdx|dFdy|ddx_fine|ddy_fine|ddx_coarse|ddy_coarse)\s*\(", "mxo_zero(", src)

    # The fragment entry point becomes an ordinary function.
    fm = re.search(
        r"\[shader\(\"fragment\"\)\]\s*\n\s*float4\s+(\w+)\s*\(\s*VertexData\s+\w+\s*\)\s*:\s*SV_Target", src
    )
    if fm is None:
        raise OracleError("generated pixel shader has no recognisable fragment entry point")
    frag = fm.group(1)
    src = src[: fm.start()] + f"float4 {frag}(VertexData _vd)" + src[fm.end() :]

    init = []
    for typ, name in _vertex_fields(src):
        val = _vertex_value(typ, name)
        if val is not None:
            init.append(f"    v.{name} = {val};")
    init_src = "\n".join(init)

    kernel = f"""
// ---- mtlx2neural oracle kernel ----
StructuredBuffer<float> mxo_wi;
StructuredBuffer<float> mxo_wo;
RWStructuredBuffer<float> mxo_out;
uniform uint mxo_count;

[shader("compute")]
[numthreads({_GROUP}, 1, 1)]
void {_ENTRY}(uint3 tid : SV_DispatchThreadID)
{{
    uint i = tid.x;
    if (i >= mxo_count)
        return;
    float3 wi = float3(mxo_wi[3 * i], mxo_wi[3 * i + 1], mxo_wi[3 * i + 2]);
    float3 wo = float3(mxo_wo[3 * i], mxo_wo[3 * i + 1], mxo_wo[3 * i + 2]);
    VertexData v = {{}};
{init_src}
    u_viewPosition = wi;  // positionWorld is the origin, so V = wi
    mxo_lightDirection = wo;
    mxo_lightIntensity = {_fmt(_LIGHT_SCALE)};
    float4 lit = {frag}(v);
    mxo_lightIntensity = 0.0;
    float4 unlit = {frag}(v);
    mxo_out[6 * i + 0] = lit.x;
    mxo_out[6 * i + 1] = lit.y;
    mxo_out[6 * i + 2] = lit.z;
    mxo_out[6 * i + 3] = unlit.x;
    mxo_out[6 * i + 4] = unlit.y;
    mxo_out[6 * i + 5] = unlit.z;
}}
"""
    header = "// Generated by mtlx2neural.evaluate.mtlx_oracle from MaterialX's Slang pixel shader.\n"
    if "DIRECTIONAL_ALBEDO_METHOD" in src and "#define DIRECTIONAL_ALBEDO_METHOD" not in src:
        header += "#define DIRECTIONAL_ALBEDO_METHOD 0\n"
    return header + src + kernel, textures


@dataclass
class _OracleSource:
    source: str
    textures: list[_Texture] = field(default_factory=list)


def _oracle_source(document, material: str) -> _OracleSource:
    import MaterialX as mx

    uri = document.getSourceUri()
    base_dir = Path(uri).resolve().parent if uri else Path.cwd()
    key = (hashlib.sha256(mx.writeToXmlString(document).encode()).hexdigest(), str(base_dir), material)
    with _lock:
        cached = _sources.get(key)
    if cached is not None:
        return cached
    src, uniforms = _generate_pixel_shader(document, material)
    patched, textures = _patch_source(src, uniforms, base_dir)
    result = _OracleSource(patched, textures)
    with _lock:
        _sources[key] = result
    return result


def generate_oracle_source(document, material: str) -> str:
    """The patched Slang source that :func:`mtlx_slang_eval` compiles for `material`."""
    return _oracle_source(document, material).source


# --------------------------------------------------------------------------------------------
# slangpy side
# --------------------------------------------------------------------------------------------


def _device(cache_dir=None):
    import slangpy as spy

    key = None if cache_dir is None else str(Path(cache_dir).resolve())
    with _lock:
        dev = _devices.get(key)
        if dev is None:
            kwargs = {"type": spy.DeviceType.cpu, "enable_hot_reload": False}
            if key is not None:
                Path(key).mkdir(parents=True, exist_ok=True)
                kwargs["shader_cache_path"] = str(Path(key) / "shader_cache")
            dev = spy.Device(**kwargs)
            _devices[key] = dev
        return dev


def oracle_available() -> tuple[bool, str]:
    """Whether MaterialX's Slang generator and slangpy's CPU device work here: (ok, reason)."""
    global _available
    with _lock:
        if _available is not None:
            return _available
        try:
            import MaterialX.PyMaterialXGenSlang  # noqa: F401
        except Exception as exc:  # pragma: no cover - depends on the environment
            _available = (False, f"MaterialX Slang generator unavailable: {exc}")
            return _available
        try:
            import slangpy as spy
        except Exception as exc:  # pragma: no cover
            _available = (False, f"slangpy not importable: {exc}")
            return _available
        try:
            dev = _device(None)
            src = (
                "RWStructuredBuffer<float> o;\n"
                '[shader("compute")][numthreads(1,1,1)]\n'
                "void probe(uint3 t : SV_DispatchThreadID) { o[t.x] = 2.0 * float(t.x) + 1.0; }\n"
            )
            mod = dev.load_module_from_source("mxo_probe", src)
            prog = dev.link_program([mod], [mod.entry_point("probe")])
            k = dev.create_compute_kernel(prog)
            buf = dev.create_buffer(
                element_count=4,
                struct_size=4,
                usage=spy.BufferUsage.shader_resource | spy.BufferUsage.unordered_access,
            )
            k.dispatch(thread_count=[4, 1, 1], vars={"o": buf})
            got = buf.to_numpy().view(np.float32)[:4]
            if not np.allclose(got, [1, 3, 5, 7]):
                _available = (False, f"slangpy CPU device returned wrong values {got}")
            else:
                _available = (True, f"slangpy {getattr(spy, '__version__', '?')} CPU device")
        except Exception as exc:  # pragma: no cover
            _available = (False, f"slangpy CPU device unusable: {type(exc).__name__}: {exc}")
        return _available


@dataclass
class _Kernel:
    device: object
    kernel: object
    texels: object  # slangpy buffer with every texture's RGBA texels
    texel_bytes: int
    source_hash: str


def _compile(osrc: _OracleSource, cache_dir=None) -> _Kernel:
    import slangpy as spy

    digest = hashlib.sha256(osrc.source.encode()).hexdigest()
    key = (digest, None if cache_dir is None else str(Path(cache_dir).resolve()))
    with _lock:
        k = _kernels.get(key)
        if k is not None:
            _kernels.move_to_end(key)
            return k
        dev = _device(cache_dir)
        if cache_dir is not None:
            Path(cache_dir).mkdir(parents=True, exist_ok=True)
            Path(cache_dir, f"mxo_{digest[:16]}.slang").write_text(osrc.source)
        if osrc.textures:
            texels = np.concatenate([t.texels().reshape(-1, 4) for t in osrc.textures])
        else:
            texels = np.zeros((1, 4), dtype=np.float32)
        tbuf = dev.create_buffer(
            usage=spy.BufferUsage.shader_resource,
            struct_size=16,
            data=np.ascontiguousarray(texels, dtype=np.float32).reshape(-1),
        )
        try:
            mod = dev.load_module_from_source(f"mxo_{digest[:16]}", osrc.source)
            prog = dev.link_program([mod], [mod.entry_point(_ENTRY)])
            kernel = dev.create_compute_kernel(prog)
            # The CPU back end compiles on first dispatch: do it now, with no work, so that
            # compilation errors surface here.
            dummy = dev.create_buffer(
                element_count=8,
                struct_size=4,
                usage=spy.BufferUsage.shader_resource | spy.BufferUsage.unordered_access,
            )
            kernel.dispatch(
                thread_count=[1, 1, 1],
                vars={"mxo_wi": dummy, "mxo_wo": dummy, "mxo_out": dummy, "mxo_texels": tbuf, "mxo_count": 0},
            )
        except Exception as exc:
            raise OracleError(f"Slang compilation of the oracle shader failed: {exc}") from exc
        k = _Kernel(dev, kernel, tbuf, int(texels.nbytes), digest)
        _kernels[key] = k
        total = sum(v.texel_bytes for v in _kernels.values())
        while total > _MAX_CACHED_TEXEL_BYTES and len(_kernels) > 1:
            _, old = _kernels.popitem(last=False)
            total -= old.texel_bytes
        return k


def _as_dirs(a, name: str) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    if a.ndim == 1:
        a = a[None, :]
    if a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"{name} must have shape [N, 3], got {a.shape}")
    return a


def mtlx_slang_eval(document, material: str, wi, wo, *, cache_dir=None) -> np.ndarray:
    """Reflected radiance [N,3] float64 of `material` (name of a surfacematerial node in the MaterialX
    `document`, an mx.Document WITHOUT the standard libraries imported; they are imported into a copy)
    for one unit-intensity white directional light arriving from direction `wo` and seen from
    direction `wi`.

    wi, wo: numpy [N,3] unit vectors in the local shading frame: normal = (0,0,1), tangent = (1,0,0),
    bitangent = (0,1,0), both pointing away from the surface.  The result equals
    f(wi,wo)*max(0,wo.z) (cosine included), computed in float32 by MaterialX's generated Slang code
    at texcoord (0.5, 0.5) and weighted by the surface opacity, as MaterialX's surface shader does.
    Emission is not included: the light-independent part of the shader output is subtracted.
    The shader is generated once per (document content, material) and compiled once per generated
    source (cached by its hash); later calls only dispatch.  `cache_dir`, if given, receives the
    patched Slang source and slangpy's shader cache.
    """
    wi = _as_dirs(wi, "wi")
    wo = _as_dirs(wo, "wo")
    if wi.shape != wo.shape:
        raise ValueError(f"wi and wo must have the same shape, got {wi.shape} and {wo.shape}")
    ok, reason = oracle_available()
    if not ok:
        raise OracleError(f"oracle unavailable: {reason}")
    k = _compile(_oracle_source(document, material), cache_dir)
    n = wi.shape[0]
    if n == 0:
        return np.zeros((0, 3), dtype=np.float64)

    import slangpy as spy

    usage_in = spy.BufferUsage.shader_resource
    usage_out = spy.BufferUsage.shader_resource | spy.BufferUsage.unordered_access
    dev = k.device
    with _lock:  # one dispatch at a time per process
        b_wi = dev.create_buffer(
            usage=usage_in, struct_size=4, data=np.ascontiguousarray(wi, dtype=np.float32).reshape(-1)
        )
        b_wo = dev.create_buffer(
            usage=usage_in, struct_size=4, data=np.ascontiguousarray(wo, dtype=np.float32).reshape(-1)
        )
        b_out = dev.create_buffer(element_count=6 * n, struct_size=4, usage=usage_out)
        k.kernel.dispatch(
            thread_count=[n, 1, 1],
            vars={
                "mxo_wi": b_wi,
                "mxo_wo": b_wo,
                "mxo_out": b_out,
                "mxo_texels": k.texels,
                "mxo_count": n,
            },
        )
        raw = b_out.to_numpy().view(np.float32)[: 6 * n].reshape(n, 6).astype(np.float64)
    return (raw[:, :3] - raw[:, 3:]) / _LIGHT_SCALE
