"""Oracle shader source: MaterialX's Slang pixel shader, patched into a CPU compute kernel.

The MaterialX Slang generator (``MaterialX.PyMaterialXGenSlang``) writes a pixel shader for a
``surfacematerial`` (colour management as MaterialX's viewers set it up; no specular environment,
no output transform).  :func:`generate_oracle_source` patches that pixel shader so that it runs as
a compute kernel on slangpy's CPU device (:mod:`mtlx2neural.oracle.runner` compiles and dispatches it) for
chosen direction pairs:

* the uniform constant buffer becomes ``static`` globals initialised with the values that the
  generator published for the document; the view position becomes a per-thread global;
* the light loop sees exactly one directional light, whose direction and intensity are per-thread
  globals (``numActiveLightSources()`` and ``sampleLightSource()`` are replaced);
* the specular environment is off (``SPECULAR_ENVIRONMENT_NONE``), so the indirect and refraction
  terms are zero; screen-space derivatives (``fwidth``/``ddx``/``ddy``/``dFdx``/``dFdy``) are zero,
  as on a flat plane, and the subsurface approximation sees zero curvature;
* image textures become oracle samplers over one texel buffer (:mod:`mtlx2neural.oracle.textures`);
* a ``[numthreads(32,1,1)]`` compute kernel fills the vertex data of a flat surface at the origin
  (normal +Z, tangent +X, bitangent +Y, texcoords (0.5, 0.5), vertex colours 1; the object-space
  position is (0.5, 0.5, 0), the reference's default (u, v, 0) at that uv, while the world-space
  position, from which the view vector is measured, is the origin), places the
  viewer along ``wi``, and calls the generated fragment function twice: with the light at
  intensity ``_LIGHT_SCALE`` and at zero, writing both colours.  (:mod:`mtlx2neural.oracle.points`
  supplies its own kernel, with per-thread texcoords, positions and normals, to read node values.)

Generated sources are cached per (document content, base directory, material).
"""

from __future__ import annotations

import hashlib
import os
import re
import threading
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mtlx2neural.imaging.resolve import on_disk
from mtlx2neural.oracle.errors import OracleError, OracleUnsupported
from mtlx2neural.oracle.textures import (
    _ADDRESS_PERIODIC,
    _FILTER_CLOSEST,
    _FILTER_LINEAR,
    _TEXTURE_SLANG,
    _image_size,
    _Texture,
)
from mtlx2neural.oracle.units import use_metres

__all__ = ["generate_oracle_source"]

# Power of two, so scaling the light is exact in float32.
_LIGHT_SCALE = 65536.0
_ENTRY = "mxo_eval"
_GROUP = 32

# Shared with oracle.runner (device, kernel cache and dispatch): one lock for the whole oracle.
_lock = threading.RLock()
_stdlib = None  # cached mx.Document with the standard data libraries
_sources: dict[tuple[str, str, str], _OracleSource] = {}  # keyed by (XML hash, base dir, material)


# --------------------------------------------------------------------------------------------
# MaterialX side
# --------------------------------------------------------------------------------------------


def _mx():
    # Local: MaterialX's shader generators load with the first oracle only.
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
    if not doc.getColorSpace():
        # MaterialX's generators convert texture colour spaces only into a declared working
        # space; the specification's default working space is lin_rec709, which the
        # reference uses, so declare it here.
        doc.setColorSpace("lin_rec709")
    cms = mxgen.DefaultColorManagementSystem.create(gen.getTarget())
    cms.loadLibrary(doc)
    gen.setColorManagementSystem(cms)
    ctx = mxgen.GenContext(gen)
    use_metres(gen, ctx, doc)  # distance units as MaterialX's viewers convert them
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
    opts.fileTextureVerticalFlip = False  # the oracle's sampler applies the lower-left uv origin
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
# Texture uniforms
# --------------------------------------------------------------------------------------------


def _value_rgba(value) -> tuple[float, float, float, float]:
    if value is None or value.getTypeString() in ("string", "filename"):
        # (geompropvalueuniform's "default" is the file name, not an image node's fallback colour)
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


def _geomprop_default(geomprop: str, uniforms: dict):
    """The ``default`` value of the ``geompropvalueuniform`` node that reads ``geomprop``, or None.

    MaterialX generates a filename ``geompropvalueuniform`` as a texture uniform ``u_geomprop_<name>``
    that the renderer binds from the geometry; the probe geometry has no primvars, so, as the node
    specifies for a missing property, the oracle binds the node's ``default`` file."""
    for name, (_, value) in uniforms.items():
        if name.endswith("_geomprop") and value is not None and value.getValueString() == geomprop:
            return uniforms.get(name[: -len("_geomprop")] + "_default", (None, None))[1]
    return None


def _make_texture(uniform: str, uniforms: dict, base_dir: Path) -> _Texture:
    # Sampling properties come from the uniforms next to "<root>_file", as MaterialX's renderers
    # find them (ImageSamplingProperties); absent ones mean periodic addressing and linear filtering.
    root = uniform.rsplit("_", 1)[0] if "_" in uniform else uniform
    _, file_value = uniforms.get(uniform, (None, None))
    if file_value is None and uniform.startswith("u_geomprop_"):
        file_value = _geomprop_default(uniform[len("u_geomprop_"):], uniforms)
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
            # A library authored on a case-insensitive file system may name the file with
            # another case; read the one file that matches (as the graph compiler does).
            cand = Path(on_disk(str(cand)))
            size = _image_size(cand) if cand.is_file() else None
            if size is not None:
                return _Texture(uniform, str(cand.resolve()), size[0], size[1], umode, vmode, filt, default)
        warnings.warn(
            f"MaterialX oracle: image {name!r} ({uniform}) cannot be read; using the node's default value",
            stacklevel=2,
        )
    return _Texture(uniform, None, 1, 1, umode, vmode, filt, default)


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
    if low.startswith("sv_"):
        return None
    if low.startswith("position"):
        # The object-space position is the reference's default for a point, (u, v, 0) at the oracle's
        # uv; the world-space position stays at the origin, where the view vector is measured from.
        if low != "positionobject":
            return None
        v = [0.5, 0.5, 0.0]
    elif low.startswith("bitangent"):
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


def kernel_frame(title: str, inputs, body: str) -> str:
    """The Slang text of an oracle compute kernel: one float StructuredBuffer per ``(buffer, variable,
    channels)`` of ``inputs``, read into ``float<channels> variable`` for thread ``i``; the output
    buffer ``mxo_out`` and the thread count ``mxo_count``; then ``body`` (indented Slang lines)."""
    buffers = "".join(f"StructuredBuffer<float> {buf};\n" for buf, _, _ in inputs)
    loads = "".join(
        f"    float{c} {var} = float{c}({', '.join(f'{buf}[{c} * i + {k}]' if k else f'{buf}[{c} * i]' for k in range(c))});\n"
        for buf, var, c in inputs)
    return f"""
// ---- {title} ----
{buffers}RWStructuredBuffer<float> mxo_out;
uniform uint mxo_count;

[shader("compute")]
[numthreads({_GROUP}, 1, 1)]
void {_ENTRY}(uint3 tid : SV_DispatchThreadID)
{{
    uint i = tid.x;
    if (i >= mxo_count)
        return;
{loads}{body}
}}
"""


def _direction_kernel(frag: str, init_src: str, fields=()) -> str:
    """The direction-pair kernel: one flat surface point, the light at _LIGHT_SCALE and at zero."""
    body = f"""    VertexData v = {{}};
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
    mxo_out[6 * i + 5] = unlit.z;"""
    return kernel_frame("mtlx2neural oracle kernel", [("mxo_wi", "wi", 3), ("mxo_wo", "wo", 3)], body)


def _patch_flake(src: str) -> str:
    """MaterialX 1.39.5's Slang generator emits the flake nodes' GLSL library code unchanged, which Slang
    rejects: ``mx_rotate_flake`` multiplies a matrix built with ``mat3(...)``-style arguments by a vector
    with ``*``, and ``M_PI`` (defined by the GLSL library only) is undefined (added to the header by
    :func:`_patch_source`).  In GLSL those nine arguments are the matrix's columns and ``m * p`` is the sum
    of the columns weighted by p; Slang's constructor takes rows, so the same value is ``mul(p, m)``.
    Nothing else changes (no-op for shaders without flakes)."""
    fm = re.search(r"^float3\s+mx_rotate_flake\s*\(", src, flags=re.MULTILINE)
    if fm is None:
        return src
    close = _matching_brace(src, src.index("{", fm.end()))
    body = src[fm.start():close + 1]
    fixed, count = re.subn(r"return\s+m\s*\*\s*p\s*;", "return mul(p, m);", body)
    if count != 1:
        raise OracleError("mx_rotate_flake in the generated shader is not the one the oracle knows how to patch")
    return src[:fm.start()] + fixed + src[close + 1:]


def _patch_source(src: str, uniforms: dict, base_dir: Path, kernel=None) -> tuple[str, list[_Texture]]:
    """Patch MaterialX's pixel shader `src` into a compute kernel; `kernel(frag, init_src, fields)`
    writes the kernel's Slang text around the fragment function `frag`, given the vertex initialisation
    `init_src` and the VertexData `fields` [(type, name)] (default: :func:`_direction_kernel`)."""
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

    src = _patch_flake(src)

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

    kernel = (kernel or _direction_kernel)(frag, init_src, _vertex_fields(src))
    header = "// Generated by mtlx2neural.oracle.runner from MaterialX's Slang pixel shader.\n"
    if "DIRECTIONAL_ALBEDO_METHOD" in src and "#define DIRECTIONAL_ALBEDO_METHOD" not in src:
        header += "#define DIRECTIONAL_ALBEDO_METHOD 0\n"
    if re.search(r"\bM_PI\b", src) and not re.search(r"#define\s+M_PI\b", src):
        header += "#define M_PI 3.1415926535897932\n"  # the flake code uses GLSL's mx_math constant
    return header + src + kernel, textures


@dataclass
class _OracleSource:
    source: str
    textures: list[_Texture] = field(default_factory=list)


def _oracle_source(document, material: str) -> _OracleSource:
    # Local: MaterialX's shader generators load with the first oracle only.
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
