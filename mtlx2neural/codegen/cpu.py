"""Run a generated material module on slangpy's CPU device (tests, benchmarks).

:class:`CpuMaterial` writes the module into a temporary folder, compiles the harness kernel
(``codegen/templates/cpu_harness.slang.in``) for one network variant and evaluates
``eval`` / ``evalPdf`` / ``sample`` / ``albedo`` for batches of (latent, wi, wo, u) given as
float32 NumPy arrays, plus the latent fetch (and, for a UDIM material's module, the tile lookup,
per-tile fetch and eval of ``codegen/templates/cpu_harness_udim.slang.in``:
:meth:`CpuMaterial.udim_fetch_eval`; the module's emission and opacity,
``codegen/templates/cpu_harness_surface.slang.in``: :meth:`CpuMaterial.surface`). Buffers are passed through ``dispatch(vars=...)``
(docs/ARCHITECTURE.md, "Verification"). The CPU back end compiles the C++ on first dispatch.

Variants: ``"FP32"``, ``"FP16"``, ``"FP16Buffer"``, ``"CoopVec"``, ``"Auto"`` (the per-warp
selector; on the CPU its choice is the NM_CPU_COHERENT define, 1 = coherent).
"""

from __future__ import annotations

import hashlib
import shutil
import tempfile
import threading
import weakref
from pathlib import Path
from string import Template

import numpy as np

from mtlx2neural.codegen.generate import identifier
from mtlx2neural.codegen.paths import runtime_path, template
from mtlx2neural.codegen.weight_layout import coopvec_blob, fp16_blob

OPS = {"eval": 0, "pdf": 1, "sample": 2, "albedo": 3, "lobes": 4, "environment": 5}
ROW = 9
"""Floats per query in the harness's output (the three lobes' reflectance is the widest result)."""
_lock = threading.Lock()
_devices: dict[tuple, object] = {}


def slangpy_available() -> tuple[bool, str]:
    """(ok, reason): whether slangpy imports and has a CPU device type."""
    try:
        # Local: slangpy is optional (the shader harness); importing it is the availability check.
        import slangpy as spy
    except Exception as exc:  # noqa: BLE001  # pragma: no cover - any import failure means "unavailable"
        return False, f"slangpy is not importable ({type(exc).__name__}: {exc}); pip install 'mtlx2neural[shaders]'"
    if not hasattr(spy, "DeviceType") or not hasattr(spy.DeviceType, "cpu"):
        return False, "this slangpy has no CPU device type"
    return True, f"slangpy {getattr(spy, '__version__', '?')}"


def device(include: Path, defines: dict[str, str]):
    """A slangpy CPU device with ``include`` and the runtime on its include path (cached)."""
    # Local: slangpy is optional (the shader harness); callers check slangpy_available() first.
    import slangpy as spy

    key = (str(include), tuple(sorted(defines.items())))
    with _lock:
        dev = _devices.get(key)
        if dev is None:
            opts = {"include_paths": [str(include), str(runtime_path())], "defines": dict(defines)}
            dev = spy.Device(type=spy.DeviceType.cpu, enable_hot_reload=False, compiler_options=opts)
            _devices[key] = dev
        return dev


def float_buffer(dev, a):
    """A read-only structured buffer of ``a`` as float32 (one zero when empty)."""
    # Local: slangpy is optional (the shader harness); callers check slangpy_available() first.
    import slangpy as spy

    a = np.array(a, np.float32, copy=True).reshape(-1)
    if a.size == 0:
        a = np.zeros(1, np.float32)
    return dev.create_buffer(usage=spy.BufferUsage.shader_resource, struct_size=4, data=a)


def out_buffer(dev, n: int):
    """A read-write float buffer of ``n`` elements."""
    # Local: slangpy is optional (the shader harness); callers check slangpy_available() first.
    import slangpy as spy

    usage = spy.BufferUsage.shader_resource | spy.BufferUsage.unordered_access
    return dev.create_buffer(element_count=max(n, 1), struct_size=4, usage=usage)


def pyramid_buffers(dev, levels: list[np.ndarray]) -> tuple[object, object]:
    """(texels, level table) buffers of ``NMBufferLatents<C>`` for ``levels`` (each [C, H, W],
    finest first): texels row-major (row 0 = top), C floats each; table rows (w, h, offset, 0)."""
    # Local: slangpy is optional (the shader harness); callers check slangpy_available() first.
    import slangpy as spy

    texels, table, off = [], [], 0
    for lv in levels:
        c, h, w = lv.shape
        texels.append(np.ascontiguousarray(np.transpose(lv, (1, 2, 0)), np.float32).ravel())
        table.append([w, h, off, 0])
        off += h * w * c
    lv_buf = dev.create_buffer(usage=spy.BufferUsage.shader_resource, struct_size=16,
                               data=np.asarray(table, np.uint32).ravel())
    return float_buffer(dev, np.concatenate(texels)), lv_buf


def query_array(uv, lod, u) -> np.ndarray:
    """[N, 4] float32 rows (u, v, lod, level-selection random number) for the fetch kernels."""
    return np.concatenate([np.asarray(uv, np.float32), np.asarray(lod, np.float32)[:, None],
                           np.asarray(u, np.float32)[:, None]], 1)


class CpuMaterial:
    """A generated module ``source`` for material ``name``, compiled for one ``variant``.

    ``unroll=False`` compiles with ``NM_UNROLL`` empty (loops kept: the same arithmetic, much
    faster C++ compilation); ``spec`` (the NetworkSpec) supplies the weight binaries for the
    buffer-reading variants; ``workdir`` is the folder the module's source is written to (None: a
    temporary one, removed when the object is collected or at exit)."""

    def __init__(self, source: str, name: str, spec, variant: str = "FP32", *, unroll: bool = False,
                 cpu_coherent: bool = True, workdir=None):
        # Local: slangpy is optional (the shader harness); callers check slangpy_available() first.
        import slangpy as spy

        self.spy = spy
        self.ident = identifier(name)
        self.module = f"NeuralMaterial_{self.ident}"
        self.channels = spec.latent_channels
        digest = hashlib.sha256(source.encode()).hexdigest()[:12]
        self.workdir = Path(workdir or tempfile.mkdtemp(prefix="m2n_cg_"))
        self.workdir.mkdir(parents=True, exist_ok=True)
        if workdir is None:  # a folder of our own: removed with this object (or at exit), not left in the temp dir
            weakref.finalize(self, shutil.rmtree, str(self.workdir), True)
        (self.workdir / f"{self.module}.slang").write_text(source)
        defines = {"NM_CPU_COHERENT": "1" if cpu_coherent else "0"}
        if not unroll:
            defines["NM_UNROLL"] = ""
        self.dev = device(self.workdir, defines)
        net = f"NM_{self.ident}" if variant == "Auto" else f"NM_{self.ident}_{variant}"
        init = ""
        if variant in ("CoopVec", "Auto", "FP16Buffer"):
            init = "    n.weights = gWeights;\n    n.base = 0;"
            if variant == "Auto":
                init += "\n    n.materialId = 0;"
        blob = fp16_blob(spec)[0] if variant == "FP16Buffer" else coopvec_blob(spec)[0]
        harness = Template(template("cpu_harness.slang.in")).substitute(
            module=self.module, net_type=net, net_init=init, channels=self.channels)
        mod = self.dev.load_module_from_source(f"m2n_harness_{variant}_{digest}", harness)
        self._module, self._fetch_eval_kernel = mod, None
        self._udim = None  # the UDIM harness (udim_fetch_eval), compiled on first use
        self._surface = None  # the emission / opacity harness (surface), compiled on first use
        self._harness_args = {"module": self.module, "net_type": net, "net_init": init, "channels": self.channels,
                              "prefix": f"NM_{self.ident}", "tag": f"{variant}_{digest}"}
        self.kernel = self.dev.create_compute_kernel(self.dev.link_program([mod], [mod.entry_point("nmHarness")]))
        self.fetch_kernel = self.dev.create_compute_kernel(
            self.dev.link_program([mod], [mod.entry_point("nmHarnessFetch")]))
        self.weights = self._buf(np.frombuffer(blob, np.uint8).view(np.float32))
        self._dummy = self._buf(np.zeros(4, np.float32))
        self._dummy4 = self.dev.create_buffer(usage=spy.BufferUsage.shader_resource, struct_size=16,
                                              data=np.zeros(4, np.uint32))
        self.run("eval", np.zeros((1, self.channels), np.float32), np.zeros((1, 3), np.float32))  # compile now

    def _buf(self, a: np.ndarray):
        return float_buffer(self.dev, a)

    def _out(self, n: int):
        return out_buffer(self.dev, n)

    def run(self, op: str, latent, wi, wo=None, u=None) -> np.ndarray:
        """[N, 9] float32 results: eval/albedo in [:, :3]; pdf in [:, 0]; sample: wo [:, :3],
        weight [:, 3:6], pdf [:, 6]; lobes: the three lobes' reflectance."""
        n = int(wi.shape[0])
        wo = np.zeros((n, 3), np.float32) if wo is None else wo
        u = np.zeros((n, 2), np.float32) if u is None else u
        out = self._out(ROW * n)
        with _lock:
            self.kernel.dispatch(thread_count=[max(n, 1), 1, 1], vars={
                "gLatent": self._buf(latent), "gWi": self._buf(wi), "gWo": self._buf(wo), "gU": self._buf(u),
                "gWeights": self.weights, "gOut": out, "gCount": n, "gOp": OPS[op],
                "gTexels": self._dummy, "gLevels": self._dummy4, "gNumLevels": 0})
            return out.to_numpy().view(np.float32)[: ROW * n].reshape(n, ROW).copy()

    def eval(self, latent, wi, wo):
        return self.run("eval", latent, wi, wo)[:, :3]

    def pdf(self, latent, wi, wo):
        return self.run("pdf", latent, wi, wo)[:, 0]

    def sample(self, latent, wi, u):
        r = self.run("sample", latent, wi, None, u)
        return r[:, :3], r[:, 3:6], r[:, 6]

    def albedo(self, latent, wi):
        return self.run("albedo", latent, wi)[:, :3]

    def lobe_reflectance(self, latent, wi):
        """[N, 3, 3]: the sharp, specular and diffuse lobes' reflectance from the environment head (zero without one)."""
        return self.run("lobes", latent, wi)[:, :9].reshape(-1, 3, 3)

    def shade_environment(self, latent, wi):
        """[N, 3] ``shadeEnvironment`` under the harness's linear probe, L(d) = 1 + (0.3, 0.5, -0.2) . d
        (local frame = world; its irradiance / pi along n is 1 + (2/3) (0.3, 0.5, -0.2) . n)."""
        return self.run("environment", latent, wi)[:, :3]

    def fetch(self, levels: list[np.ndarray], uv, lod, u) -> np.ndarray:
        """Latents [N, C] from pyramid ``levels`` (each [C, H, W], finest first) at uv [N,2],
        level of detail lod [N] and level-selection random numbers u [N]."""
        n = int(uv.shape[0])
        q = np.concatenate([uv, lod[:, None]], 1).astype(np.float32)
        uu = np.stack([u, np.zeros_like(u)], 1).astype(np.float32)
        texels, lv_buf = pyramid_buffers(self.dev, levels)
        out = self._out(self.channels * n)
        with _lock:
            self.fetch_kernel.dispatch(thread_count=[max(n, 1), 1, 1], vars={
                "gTexels": texels, "gLevels": lv_buf, "gNumLevels": len(levels),
                "gWi": self._buf(q), "gU": self._buf(uu), "gOut": out, "gCount": n,
                "gLatent": self._dummy, "gWo": self._dummy, "gWeights": self.weights, "gOp": 0})
            return out.to_numpy().view(np.float32)[: self.channels * n].reshape(n, self.channels).copy()

    def fetch_eval(self, pyramid, uv, lod, u, wi, wo) -> np.ndarray:
        """eval [N, 3] after fetching each query's latent in the same thread, as a renderer does.

        ``pyramid``: the (texels, table) buffers of :func:`pyramid_buffers` for this device
        (:meth:`pyramid`), built once so that repeated calls time the shader, not the upload."""
        n = int(wi.shape[0])
        if self._fetch_eval_kernel is None:
            self._fetch_eval_kernel = self.dev.create_compute_kernel(
                self.dev.link_program([self._module], [self._module.entry_point("nmHarnessFetchEval")]))
        out = self._out(3 * n)
        with _lock:
            self._fetch_eval_kernel.dispatch(thread_count=[max(n, 1), 1, 1], vars={
                "gTexels": pyramid[0], "gLevels": pyramid[1], "gNumLevels": pyramid[2],
                "gQuery": self._buf(query_array(uv, lod, u)), "gWi": self._buf(wi), "gWo": self._buf(wo),
                "gOut": out, "gCount": n, "gWeights": self.weights, "gLatent": self._dummy,
                "gU": self._dummy, "gOp": 0})
            return out.to_numpy().view(np.float32)[: 3 * n].reshape(n, 3).copy()

    def udim_fetch_eval(self, tiles: list[list[np.ndarray]], uv, lod, u, wi, wo) -> tuple[np.ndarray, np.ndarray]:
        """(eval [N, 3], slot [N]) of a UDIM module (``codegen/templates/cpu_harness_udim.slang.in``):
        per query the module's ``udimSlot(uv)``, the tile's latent (``NMBufferTiledLatents``: ``tiles[k]``
        the pyramid of slot k, each level [C, H, W], finest first) and eval; slot -1 gives black."""
        # Local: slangpy is optional (the shader harness); callers check slangpy_available() first.
        import slangpy as spy

        n = int(wi.shape[0])
        if self._udim is None:
            a = dict(self._harness_args)
            text = Template(template("cpu_harness_udim.slang.in")).substitute(a)
            mod = self.dev.load_module_from_source(f"m2n_harness_udim_{a['tag']}", text)
            self._udim = self.dev.create_compute_kernel(
                self.dev.link_program([mod], [mod.entry_point("nmHarnessUdimFetchEval")]))
        texels, table, off = [], [], 0
        for levels in tiles:  # slot-major: levels[slot * numLevels + j]
            for lv in levels:
                c, h, w = lv.shape
                texels.append(np.ascontiguousarray(np.transpose(lv, (1, 2, 0)), np.float32).ravel())
                table.append([w, h, off, 0])
                off += h * w * c
        lv_buf = self.dev.create_buffer(usage=spy.BufferUsage.shader_resource, struct_size=16,
                                        data=np.asarray(table, np.uint32).ravel())
        out = self._out(4 * n)
        with _lock:
            self._udim.dispatch(thread_count=[max(n, 1), 1, 1], vars={
                "gTexels": self._buf(np.concatenate(texels)), "gLevels": lv_buf, "gNumLevels": len(tiles[0]),
                "gQuery": self._buf(query_array(uv, lod, u)), "gWi": self._buf(wi), "gWo": self._buf(wo),
                "gOut": out, "gCount": n, "gWeights": self.weights})
            r = out.to_numpy().view(np.float32)[: 4 * n].reshape(n, 4).copy()
        return r[:, :3], r[:, 3].astype(np.int64)

    def surface(self, emission_levels, opacity_levels, uv, lod) -> tuple[np.ndarray, np.ndarray]:
        """(emission [N, 3], opacity [N]) of the module's ``<prefix>_Surface`` over ``NMBufferSurfaceMap``s
        holding ``emission_levels`` (each [3, H, W]) and ``opacity_levels`` (each [1, H, W]), finest first
        (None: no map, for a material whose emission or opacity is constant), at uv [N, 2] and lod [N]."""
        if self._surface is None:
            a = dict(self._harness_args)
            text = Template(template("cpu_harness_surface.slang.in")).substitute(a)
            mod = self.dev.load_module_from_source(f"m2n_harness_surface_{a['tag']}", text)
            self._surface = self.dev.create_compute_kernel(
                self.dev.link_program([mod], [mod.entry_point("nmHarnessSurface")]))
        n = int(np.asarray(uv).shape[0])
        maps = {}
        for tag, levels, c in (("Emission", emission_levels, 3), ("Opacity", opacity_levels, 1)):
            levels = [np.zeros((c, 1, 1), np.float32)] if levels is None else [np.asarray(lv, np.float32) for lv in levels]
            texels, table = pyramid_buffers(self.dev, levels)
            maps.update({f"g{tag}Texels": texels, f"g{tag}Levels": table, f"g{tag}NumLevels": len(levels)})
        query = np.concatenate([np.asarray(uv, np.float32), np.asarray(lod, np.float32)[:, None]], 1)
        out = self._out(4 * n)
        with _lock:
            self._surface.dispatch(thread_count=[max(n, 1), 1, 1], vars={
                **maps, "gQuery": self._buf(query), "gOut": out, "gCount": n})
            r = out.to_numpy().view(np.float32)[: 4 * n].reshape(n, 4).copy()
        return r[:, :3], r[:, 3]

    def pyramid(self, levels: list[np.ndarray]) -> tuple:
        """Upload latent ``levels`` (each [C, H, W], finest first) for :meth:`fetch_eval`."""
        return (*pyramid_buffers(self.dev, levels), len(levels))
