"""Oracle: evaluate a MaterialX material with MaterialX's own generated Slang code, on the CPU.

MaterialX's Slang generator writes a pixel shader for a ``surfacematerial``;
:mod:`mtlx2neural.oracle.source` patches it into a compute kernel for chosen direction pairs (one
directional light, no specular environment, zero screen-space derivatives, a flat surface at the
origin, textures sampled at uv (0.5, 0.5) as described in :mod:`mtlx2neural.oracle.textures`).  This
module compiles that kernel on slangpy's CPU device, caches it, and dispatches it.

The kernel calls the generated fragment function twice: with the light at intensity
``_LIGHT_SCALE`` and at zero.  The difference divided by the (power-of-two) scale is the reflected
radiance of a unit white directional light from ``wo``; whatever does not depend on the light
(emission; environment and refraction terms, which are zero here anyway) cancels exactly.  The
large scale keeps the float32 cancellation accurate when the emission is much brighter than the
reflection.

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
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mtlx2neural.oracle.errors import OracleError, OracleUnsupported
from mtlx2neural.oracle.source import (
    _ENTRY,
    _LIGHT_SCALE,
    _lock,
    _oracle_source,
    _OracleSource,
    generate_oracle_source,
)

__all__ = [
    "OracleError",
    "OracleUnsupported",
    "generate_oracle_source",
    "mtlx_slang_eval",
    "mtlx_slang_unlit",
    "oracle_available",
]

# Compiled kernels keyed by (patched source hash, cache_dir), oldest first.  Kernels of textured
# materials hold their texels (float32 RGBA, 64 MiB for a 2048^2 image); the oldest kernels are
# dropped when the texels of all cached kernels exceed _MAX_CACHED_TEXEL_BYTES.
_kernels: OrderedDict[tuple[str, str | None], _Kernel] = OrderedDict()
_MAX_CACHED_TEXEL_BYTES = 1 << 30
_devices: dict[str | None, object] = {}
_available: tuple[bool, str] | None = None


# --------------------------------------------------------------------------------------------
# slangpy side
# --------------------------------------------------------------------------------------------


def _device(cache_dir=None):
    # Local: slangpy is optional (the shader harness); callers check oracle_available() first.
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
            # Local: slangpy is optional (the shader harness); importing it is the availability check.
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


def _compile(osrc: _OracleSource, cache_dir=None, inputs=("mxo_wi", "mxo_wo")) -> _Kernel:
    """Compile (or reuse) the kernel of `osrc`; `inputs` name its input buffers (bound, empty, by the
    first dispatch that compiles it)."""
    # Local: slangpy is optional (the shader harness); callers check oracle_available() first.
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
                vars={**{name: dummy for name in inputs}, "mxo_out": dummy, "mxo_texels": tbuf, "mxo_count": 0},
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
    raw = _dispatch(document, material, wi, wo, cache_dir)
    return (raw[:, :3] - raw[:, 3:]) / _LIGHT_SCALE


def mtlx_slang_unlit(document, material: str, wi, *, cache_dir=None) -> np.ndarray:
    """The light-independent colour [N,3] float64 of ``material`` seen from ``wi`` (numpy [N,3], local
    frame) by MaterialX's generated Slang with the light off: its emission times its opacity (the environment
    and refraction terms are zero in the oracle's kernel), at texcoord (0.5, 0.5)."""
    wi = _as_dirs(wi, "wi")
    return _dispatch(document, material, wi, wi, cache_dir)[:, 3:]


def _dispatch(document, material: str, wi, wo, cache_dir=None) -> np.ndarray:
    """[N, 6] float64: MaterialX's generated colour of ``material`` seen from ``wi`` with the light from ``wo``
    at intensity ``_LIGHT_SCALE`` (columns 0-2) and off (columns 3-5); arguments as :func:`mtlx_slang_eval`."""
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
        return np.zeros((0, 6), dtype=np.float64)

    # Local: slangpy is optional (the shader harness); callers check oracle_available() first.
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
    return raw
