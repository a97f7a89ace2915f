"""The analytic baseline's shader (``codegen/slang/AnalyticMaterial.slang``) on slangpy's CPU device.

The baseline (:mod:`mtlx2neural.baseline.analytic_model`, Lambert + GGX with 8 channels) has a
hand-written Slang twin, so it can be timed in the same harness as the generated neural
modules (``benchmarks/bench_shaders.py``, ``benchmarks/bench_tradeoff.py``) and checked against
its torch model (``tests/baseline/test_shader_harness.py``).

The shader reads **decoded** channels, as the exported textures store them
(:func:`decoded_channels`): base RGB, roughness, metalness, specular, normal slopes (x, y).
The torch model filters its unconstrained channels and decodes after, the shader filters the
decoded ones: the two agree exactly at texel centres and differ slightly between texels.
"""

from __future__ import annotations

import threading

import numpy as np
import torch

from mtlx2neural.baseline.analytic_model import decode
from mtlx2neural.codegen.cpu import (
    device,
    float_buffer,
    out_buffer,
    pyramid_buffers,
    query_array,
)
from mtlx2neural.codegen.paths import codegen_path

_lock = threading.Lock()


def decoded_channels(params: dict) -> torch.Tensor:
    """[N, 8] (base RGB, roughness, metalness, specular, slope x, slope y) from
    :func:`mtlx2neural.baseline.analytic_model.decode`'s dict; the slopes are recovered from the unit
    normal as (-n.x / n.z, -n.y / n.z)."""
    n = params["normal"]
    slope = -n[:, :2] / n[:, 2:3].clamp_min(1e-12)
    return torch.cat([params["base"], params["roughness"], params["metalness"], params["specular"], slope], -1)


def decoded_levels(model) -> list[np.ndarray]:
    """Every level of an :class:`~mtlx2neural.baseline.analytic_model.AnalyticMaterial` as decoded
    channels [8, H, W] (finest first): the shader's texture pyramid."""

    out = []
    for lv in model.maps.levels:
        c, h, w = lv.shape
        dec = decoded_channels(decode(lv.detach().reshape(c, -1).T))
        out.append(dec.T.reshape(8, h, w).numpy().astype(np.float32))
    return out


class CpuAnalytic:
    """``AnalyticMaterial.slang`` compiled for slangpy's CPU device: ``eval`` per query and
    ``fetch_eval`` (channel fetch + eval in one thread)."""

    def __init__(self):
        root = codegen_path()
        self.dev = device(root / "templates", {})
        harness = (root / "templates" / "analytic_cpu_harness.slang").read_text()
        mod = self.dev.load_module_from_source("m2n_analytic_harness", harness)
        self._kernels = {name: self.dev.create_compute_kernel(self.dev.link_program([mod], [mod.entry_point(name)]))
                         for name in ("amHarness", "amHarnessFetchEval")}
        self._dummy = float_buffer(self.dev, np.zeros(4, np.float32))
        self._dummy4 = pyramid_buffers(self.dev, [np.zeros((8, 1, 1), np.float32)])[1]

    def _run(self, kernel: str, n: int, **buffers) -> np.ndarray:
        out = out_buffer(self.dev, 3 * n)
        args = {"gParams": self._dummy, "gQuery": self._dummy, "gTexels": self._dummy, "gLevels": self._dummy4,
                "gNumLevels": 0, **buffers, "gOut": out, "gCount": n}
        with _lock:
            self._kernels[kernel].dispatch(thread_count=[max(n, 1), 1, 1], vars=args)
            return out.to_numpy().view(np.float32)[: 3 * n].reshape(n, 3).copy()

    def eval(self, channels, wi, wo) -> np.ndarray:
        """f * max(0, n.wo) [N, 3] for decoded ``channels`` [N, 8] and unit ``wi``, ``wo`` [N, 3]."""
        n = int(wi.shape[0])
        return self._run("amHarness", n, gParams=float_buffer(self.dev, channels),
                         gWi=float_buffer(self.dev, wi), gWo=float_buffer(self.dev, wo))

    def pyramid(self, levels: list[np.ndarray]) -> tuple:
        """Upload decoded channel ``levels`` (:func:`decoded_levels`) for :meth:`fetch_eval`."""
        return (*pyramid_buffers(self.dev, levels), len(levels))

    def fetch_eval(self, pyramid, uv, lod, u, wi, wo) -> np.ndarray:
        """eval [N, 3] after a stochastic-level bilinear fetch at uv [N,2], lod [N], u [N]."""
        n = int(wi.shape[0])
        return self._run("amHarnessFetchEval", n, gTexels=pyramid[0], gLevels=pyramid[1], gNumLevels=pyramid[2],
                         gQuery=float_buffer(self.dev, query_array(uv, lod, u)),
                         gWi=float_buffer(self.dev, wi), gWo=float_buffer(self.dev, wo))
