"""Per-point node oracle: the value of one node output of a MaterialX document, computed by MaterialX's own
generated Slang code, at many surface points.

:func:`mtlx_node_eval` wires the chosen output into an emission-only probe material (``surface_unlit``
with ``emission = 1`` and ``opacity = 1``, whose colour is ``emission * emission_color * opacity``, so
the value passes through exactly), asks MaterialX's Slang generator for its pixel shader and patches it
(:mod:`mtlx2neural.oracle.source`) into a compute kernel whose threads each get their own vertex data:

* every ``texcoord*`` field is the thread's ``uv`` (MaterialX's convention: (0, 0) the image's lower left);
* every ``position*`` field (object and world space alike: the probe has no transform) is its ``position``,
  and the object-to-world matrices (``u_worldMatrix``, its inverse and transposes) are the identity;
* every ``normal*`` field is its ``normal`` (default +Z); tangent +X, bitangent +Y and vertex colours 1
  stay as in the direction-pair oracle; the viewer sits one unit along the normal.

The probe carries three channels per call of the fragment function.  Several targets (or a four-channel
one) are split into three-channel chunks that a chain of probe ``ifgreater`` nodes selects between (exact
selection, no arithmetic): the kernel calls the fragment function once per chunk, setting the selector
uniforms to the chunk's index, so one compiled shader reads many node outputs.
Kernels are compiled and cached by :mod:`mtlx2neural.oracle.runner`.
"""

from __future__ import annotations

import hashlib
import re
from pathlib import Path

import MaterialX as mx
import numpy as np

from mtlx2neural.oracle.errors import OracleError
from mtlx2neural.oracle.runner import _compile, oracle_available
from mtlx2neural.oracle.source import (
    _generate_pixel_shader,
    _lock,
    _OracleSource,
    _patch_source,
    _standard_libraries,
    kernel_frame,
)

__all__ = ["mtlx_node_eval"]

_PREFIX = "mxo_probe_"
_CHANNELS = {"float": 1, "integer": 1, "boolean": 1, "vector2": 2, "vector3": 3, "color3": 3,
             "vector4": 4, "color4": 4}
_WORLD_MATRIX = re.compile(r"(\bstatic\s+float4x4\s+u_world\w*Matrix\s*=\s*)float4x4\((?:\s*0\.0\s*,){15}\s*0\.0\s*\);")
_sources: dict[tuple, tuple[_OracleSource, int]] = {}  # (XML hash, base dir, target, output) -> (source, C)


def _load(document):
    if isinstance(document, (str, Path)):
        doc = mx.createDocument()
        mx.readFromXmlFile(doc, str(document))
        return doc
    return document


def _target(doc, target: str, output: str | None):
    """(connection attributes for an input reading the target, MaterialX type of the target)."""
    elem = doc.getDescendant(target)
    if elem is None:
        raise OracleError(f"no element {target!r} in the document")
    if elem.isA(mx.NodeGraph):
        outs = elem.getOutputs()
        out = elem.getOutput(output) if output else (outs[0] if len(outs) == 1 else None)
        if out is None:
            raise OracleError(f"nodegraph {target!r} has no output {output!r}")
        return {"nodegraph": elem.getName(), "output": out.getName()}, out.getType()
    if elem.isA(mx.Output) and elem.getParent().isA(mx.NodeGraph):
        return {"nodegraph": elem.getParent().getName(), "output": elem.getName()}, elem.getType()
    if elem.isA(mx.Node):
        if elem.getParent() != doc:
            raise OracleError(f"node {target!r} is inside a nodegraph: name one of the graph's outputs instead")
        if elem.getType() == "multioutput" or output:
            scratch = mx.createDocument()  # the nodedef lives in the standard libraries
            scratch.copyContentFrom(doc)
            scratch.importLibrary(_standard_libraries())
            nodedef = scratch.getDescendant(target).getNodeDef()
            out = nodedef.getActiveOutput(output) if (nodedef is not None and output) else None
            if out is None:
                raise OracleError(f"node {target!r} has no output {output!r}")
            return {"nodename": elem.getName(), "output": out.getName()}, out.getType()
        return {"nodename": elem.getName()}, elem.getType()
    raise OracleError(f"{target!r} is neither a node, a nodegraph nor a nodegraph output")


def _connect(inp, conn: dict):
    if "nodename" in conn:
        inp.setNodeName(conn["nodename"])
    if "nodegraph" in conn:
        inp.setNodeGraphString(conn["nodegraph"])
    if "output" in conn:
        inp.setOutputString(conn["output"])


def _probe_document(document, targets: list[tuple[str, str | None]]):
    """A copy of `document` with the probe material wired to the targets: (document, material, channel
    count of each target, number of three-channel chunks)."""
    doc = mx.createDocument()
    doc.copyContentFrom(document)
    doc.setSourceUri(document.getSourceUri())
    chunks: list[list[dict | None]] = []  # per chunk: three channel sources (None: zero)
    counts = []
    for j, (target, output) in enumerate(targets):
        conn, mx_type = _target(doc, target, output)
        if mx_type not in _CHANNELS:
            raise OracleError(f"{target!r} has type {mx_type!r}; the node oracle reads {sorted(_CHANNELS)}")
        n = _CHANNELS[mx_type]
        counts.append(n)
        if mx_type in ("integer", "boolean"):
            cv = doc.addNode("convert", f"{_PREFIX}float{j}", "float")
            _connect(cv.addInput("in", mx_type), conn)
            conn, mx_type = {"nodename": cv.getName()}, "float"
        sources: list[dict | None] = []
        for k in range(n):
            if n == 1:
                sources.append(conn)
                continue
            ex = doc.addNode("extract", f"{_PREFIX}t{j}x{k}", "float")
            _connect(ex.addInput("in", mx_type), conn)
            ex.setInputValue("index", k, "integer")
            sources.append({"nodename": ex.getName()})
        sources += [None] * (-len(sources) % 3)
        chunks += [sources[i:i + 3] for i in range(0, len(sources), 3)]

    colour = None
    for c, sources in enumerate(chunks):
        node = doc.addNode("combine3", f"{_PREFIX}c{c}", "color3")
        for slot, src in enumerate(sources, start=1):
            inp = node.addInput(f"in{slot}", "float")
            if src is None:
                inp.setValue(0.0, "float")
            else:
                _connect(inp, src)
        if colour is None:
            colour = node
            continue
        # Chunk c when the selector (a uniform the kernel sets to the chunk index) is >= c: exact selection.
        pick = doc.addNode("ifgreater", f"{_PREFIX}pick{c}", "color3")
        pick.setInputValue("value1", 0.0, "float")
        pick.setInputValue("value2", c - 0.5, "float")
        pick.addInput("in1", "color3").setNodeName(node.getName())
        pick.addInput("in2", "color3").setNodeName(colour.getName())
        colour = pick
    surf = doc.addNode("surface_unlit", _PREFIX + "surface", "surfaceshader")
    surf.addInput("emission_color", "color3").setNodeName(colour.getName())
    mat = doc.addNode("surfacematerial", _PREFIX + "material", "material")
    mat.addInput("surfaceshader", "surfaceshader").setNodeName(surf.getName())
    return doc, mat.getName(), counts, len(chunks)


def _points_kernel(selectors: list[str], n_chunks: int):
    """Kernel writer for :func:`source._patch_source`: per-thread uv, position and normal; one call of
    the fragment function per three-channel chunk, chosen by the `selectors` (static globals)."""

    def write(frag: str, init_src: str, fields) -> str:
        per_thread = []
        for typ, name in fields:
            low = name.lower()
            if low.startswith("texcoord"):
                val = {"float2": "mxo_t", "float3": "float3(mxo_t, 0.0)", "float4": "float4(mxo_t, 0.0, 1.0)"}.get(typ)
            elif low.startswith("position"):
                val = {"float3": "mxo_p", "float4": "float4(mxo_p, 1.0)"}.get(typ)
            elif low.startswith("normal"):
                val = {"float3": "mxo_n", "float4": "float4(mxo_n, 0.0)"}.get(typ)
            else:
                continue
            if val is None:
                raise OracleError(f"unexpected vertex field type {typ} {name}")
            per_thread.append(f"    v.{name} = {val};")
        assigns = "\n".join(per_thread)
        calls = []
        for c in range(n_chunks):
            calls += [f"    {sel} = {float(c)!r};" for sel in selectors]
            calls.append(f"    mxo_c = {frag}(v);")
            calls += [f"    mxo_out[{3 * n_chunks} * i + {3 * c + k}] = mxo_c.{'xyz'[k]};" for k in range(3)]
        body = "\n".join(calls)
        main = f"""    VertexData v = {{}};
{init_src}
{assigns}
    u_viewPosition = mxo_p + mxo_n;
    mxo_lightIntensity = 0.0;
    float4 mxo_c;
{body}"""
        return kernel_frame("mtlx2neural per-point node oracle kernel",
                            [("mxo_uv", "mxo_t", 2), ("mxo_pos", "mxo_p", 3), ("mxo_nrm", "mxo_n", 3)], main)

    return write


def _node_source(document, targets: list[tuple[str, str | None]]) -> tuple[_OracleSource, list[int], int]:
    uri = document.getSourceUri()
    base_dir = Path(uri).resolve().parent if uri else Path.cwd()
    xml_hash = hashlib.sha256(mx.writeToXmlString(document).encode()).hexdigest()
    key = (xml_hash, str(base_dir), tuple(targets))
    with _lock:
        cached = _sources.get(key)
    if cached is not None:
        return cached
    doc, material, counts, n_chunks = _probe_document(document, targets)
    src, uniforms = _generate_pixel_shader(doc, material)
    selectors = [f"{_PREFIX}pick{c}_value1" for c in range(1, n_chunks)]
    missing = [sel for sel in selectors if sel not in uniforms]
    if missing:
        raise OracleError(f"probe selector uniforms {missing} not found among {sorted(uniforms)}")
    patched, textures = _patch_source(src, uniforms, base_dir, kernel=_points_kernel(selectors, n_chunks))
    # The generator publishes no value for the object-to-world matrices (they would stay zero): object
    # space is world space here, so they and their inverses and transposes are the identity.
    patched = _WORLD_MATRIX.sub(r"\1float4x4(1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, "
                                r"0.0, 0.0, 0.0, 1.0);", patched)
    for sel in selectors:
        if not re.search(rf"\bstatic\s+float\s+{sel}\b", patched):
            raise OracleError(f"probe selector {sel} is not a patchable global")
    result = (_OracleSource(patched, textures), counts, n_chunks)
    with _lock:
        _sources[key] = result
    return result


def _rows(a, width: int, name: str, n: int | None) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    if a.ndim == 1:
        a = a[None, :]
    if a.ndim != 2 or a.shape[1] != width or (n is not None and a.shape[0] != n):
        want = f"[{n if n is not None else 'N'}, {width}]"
        raise ValueError(f"{name} must have shape {want}, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} holds NaN or Inf")
    return a


def mtlx_node_eval(document, target, uv, position, *, normal=None, output: str | None = None,
                   cache_dir=None):
    """Value [N, C] (float64 holding MaterialX's float32 results) of one output of a MaterialX document,
    computed by MaterialX's generated Slang code at N surface points.

    `document`: an mx.Document without the standard libraries imported, or a path to a .mtlx file.
    `target`: the name of a top-level node, of a nodegraph (then `output` names its output unless it has
    only one), or the path "graph/output" of a nodegraph output; `output` also names the output of a
    multi-output node.  C is the output type's channel count (float, integer, boolean: 1; vector2: 2;
    vector3, color3: 3; vector4, color4: 4); integers and booleans come back as floats.
    `target` may also be a list of such names or (name, output) pairs: then the result is a list of
    arrays, one per target, from one shader (one compilation for all).
    `uv` [N, 2]: texture coordinates (MaterialX's convention).  `position` [N, 3]: the point, used as
    both object- and world-space position (units of the document).  `normal` [N, 3] (default +Z for every
    point): the surface normal, object and world space alike; it is used as given (not normalised).
    Colour values are as the generated shader computes them (in the working colour space, no output
    transform).  Each (document, targets) is generated and compiled once.
    """
    single = isinstance(target, str)
    if single:
        targets = [(target, output)]
    else:
        targets = [(t, None) if isinstance(t, str) else (t[0], t[1]) for t in target]
    document = _load(document)
    uv = _rows(uv, 2, "uv", None)
    n = uv.shape[0]
    position = _rows(position, 3, "position", n)
    normal = np.tile([0.0, 0.0, 1.0], (n, 1)) if normal is None else _rows(normal, 3, "normal", n)
    ok, reason = oracle_available()
    if not ok:
        raise OracleError(f"oracle unavailable: {reason}")
    osrc, counts, n_chunks = _node_source(document, targets)
    k = _compile(osrc, cache_dir, inputs=("mxo_uv", "mxo_pos", "mxo_nrm"))
    raw = np.zeros((n, 3 * n_chunks), dtype=np.float64)
    if n:
        # Local: slangpy is optional; oracle_available() has checked it
        import slangpy as spy

        usage_in = spy.BufferUsage.shader_resource
        usage_out = spy.BufferUsage.shader_resource | spy.BufferUsage.unordered_access
        dev = k.device

        def buf(a):
            return dev.create_buffer(usage=usage_in, struct_size=4,
                                     data=np.ascontiguousarray(a, np.float32).reshape(-1))

        with _lock:  # one dispatch at a time per process
            b_out = dev.create_buffer(element_count=3 * n_chunks * n, struct_size=4, usage=usage_out)
            k.kernel.dispatch(
                thread_count=[n, 1, 1],
                vars={"mxo_uv": buf(uv), "mxo_pos": buf(position), "mxo_nrm": buf(normal), "mxo_out": b_out,
                      "mxo_texels": k.texels, "mxo_count": n},
            )
            raw = b_out.to_numpy().view(np.float32)[: 3 * n_chunks * n].reshape(n, 3 * n_chunks).astype(np.float64)
    results, col = [], 0
    for c in counts:
        results.append(raw[:, col:col + c])
        col += 3 * -(-c // 3)
    return results[0] if single else results
