"""Textures stage at scale: parameter pyramid of a material with five large textures.

Run:  python benchmarks/bench_textures.py [--res 8192] [--footprint]

Writes five procedural textures (base colour sRGB, roughness, metalness, normal
map, coat colour) of RES x RES into a temporary folder, compiles a
standard_surface that uses them, builds the LEAN parameter pyramid at full
resolution, and reports wall time and peak RSS (ru_maxrss) of each step. With
--footprint it also times footprint-filtered target generation.
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import tempfile
import time
from pathlib import Path

import MaterialX as mx
import numpy as np
import OpenImageIO as oiio
import torch


def _rss_gib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / (1 << 20)


def _write(path: Path, img: np.ndarray) -> None:
    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), oiio.ImageSpec(img.shape[1], img.shape[0], img.shape[2], "uint8"))
    out.write_image(img)
    out.close()


def make_textures(folder: Path, res: int) -> dict:
    """Five 8-bit textures, written row band by row band to keep memory low."""
    x = np.linspace(0, 1, res, dtype=np.float32)
    files = {}
    specs = {"base": 3, "rough": 1, "metal": 1, "normal": 3, "coat": 3}
    for name, ch in specs.items():
        img = np.empty((res, res, ch), np.uint8)
        for r0 in range(0, res, 1024):
            y = x[r0:r0 + 1024, None]
            if name == "normal":
                band = np.stack([0.5 + 0.3 * np.sin(40 * x[None] + 0 * y), 0.5 + 0.3 * np.cos(37 * y + 0 * x[None]),
                                 np.full((y.shape[0], res), 0.9, np.float32)], -1)
            else:
                f = {"base": 5, "rough": 9, "metal": 3, "coat": 7}[name]
                v = 0.5 + 0.45 * np.sin(f * 6.28 * x[None]) * np.cos(f * 6.28 * y)
                band = np.repeat(v[..., None], ch, -1) * np.linspace(0.6, 1.0, ch, dtype=np.float32)
            img[r0:r0 + 1024] = (np.clip(band, 0, 1) * 255).astype(np.uint8)
        path = folder / f"{name}.png"
        _write(path, img)
        files[name] = str(path)
    return files


def make_material(files: dict) -> mx.Document:
    doc = mx.createDocument()
    doc.setColorSpace("lin_rec709")
    sh = doc.addNode("standard_surface", "sh", "surfaceshader")

    def image(name, typ, cs=None):
        n = doc.addNode("image", f"tex_{name}", typ)
        f = n.setInputValue("file", files[name], "filename")
        if cs:
            f.setColorSpace(cs)
        return n

    sh.setConnectedNode("base_color", image("base", "color3", "srgb_texture"))
    sh.setConnectedNode("specular_roughness", image("rough", "float"))
    sh.setConnectedNode("metalness", image("metal", "float"))
    nm = doc.addNode("normalmap", "nm", "vector3")
    nm.setConnectedNode("in", image("normal", "vector3"))
    sh.setConnectedNode("normal", nm)
    sh.setInputValue("coat", 0.5, "float")
    sh.setConnectedNode("coat_color", image("coat", "color3", "srgb_texture"))
    doc.addMaterialNode("M", sh)
    return doc


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--res", type=int, default=8192)
    ap.add_argument("--footprint", action="store_true")
    args = ap.parse_args()
    from mtlx2neural.graph import compile_material
    from mtlx2neural.reference import ReferenceMaterial
    from mtlx2neural.textures.footprint import footprint_targets, sample_levels
    from mtlx2neural.textures.parameter_stack import build_parameter_stack

    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, torch {torch.__version__}, "
          f"{torch.get_num_threads()} threads")
    with tempfile.TemporaryDirectory() as tmp:
        t = time.perf_counter()
        files = make_textures(Path(tmp), args.res)
        print(f"wrote 5 textures of {args.res}^2 in {time.perf_counter() - t:.1f} s (rss {_rss_gib():.2f} GiB)")
        t = time.perf_counter()
        compiled = compile_material(make_material(files), "M")
        print(f"compile_material (reads textures): {time.perf_counter() - t:.1f} s, peak rss {_rss_gib():.2f} GiB")
        t = time.perf_counter()
        stack = build_parameter_stack(compiled)
        dt = time.perf_counter() - t
        nbytes = sum(lv.numel() * lv.element_size() for lv in stack.levels)
        print(f"build_parameter_stack: {stack.resolution[1]}x{stack.resolution[0]}, {len(stack.channels)} channel "
              f"groups, {stack.levels[0].shape[0]} channels, {stack.levels[0].dtype}, pyramid {nbytes / (1 << 30):.2f} GiB, "
              f"{dt:.1f} s, peak rss {_rss_gib():.2f} GiB; notes: {stack.notes}")
        if args.footprint:
            ref = ReferenceMaterial(compiled)
            n = 1 << 14
            g = torch.Generator().manual_seed(0)
            wi = torch.nn.functional.normalize(torch.rand(n, 3, generator=g) + 0.05, dim=1)
            wo = torch.nn.functional.normalize(torch.rand(n, 3, generator=g) + 0.05, dim=1)
            uv = torch.rand(n, 2, generator=g)
            for max_samples in (1, 16):
                lv = sample_levels(n, len(stack.levels), generator=g)
                t = time.perf_counter()
                footprint_targets(ref, stack, wi, wo, uv, lv, max_samples=max_samples, generator=g)
                dt = time.perf_counter() - t
                print(f"footprint targets (max {max_samples} samples/query): {n / dt / 1e3:.1f} k queries/s")


if __name__ == "__main__":
    main()
