"""The parameter atlas: one synthetic material that spans a shading model's parameter space.

A universal encoder and its decoder are trained as one material is (:class:`~mtlx2neural.train.trainer.
Trainer`), on a material whose textures draw the model's inputs at random, so its texels cover the
space the paper suggests sampling uniformly, and its MIP levels cover the filtered mixtures a real
material's coarse levels hold.

Layout of each input's texture (``size`` x ``size`` texels, EXR, linear): four quadrants, each made
of square cells of one value, the cell sizes 1, 2, 8 and 32 texels spread over the quadrants by a
per-input permutation. Inputs so vary at different rates in one region: a smooth colour over
per-texel bumps, a per-texel roughness over a flat normal, and so on. At a cell size of 2^k the
levels below k hold pure parameter vectors, the levels above it LEAN/box mixtures of neighbours.

Values per cell (:data:`DISTRIBUTIONS`, per shading model): uniform over each input's range, except the
inputs that production maps hold mostly at their ends (metalness: 0 or 1 four times in five; a coat's
weight: 0 half the time; Standard Surface's ``base`` and ``specular`` 1 and its tints white half the time, as
glTF's specular factor and colour)
and the normal, flat half the time and else tilted uniformly in angle up to :data:`MAX_TILT_DEGREES`
(a model whose normal input is world-space reads it through a ``normalmap`` of the texture's encoded
tangent-space normal, :attr:`~.canonical.ShadingModel.normal_map`).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from mtlx2neural.universal.canonical import SHADING_MODELS

CELL_SIZES = (1, 2, 8, 32)
MAX_TILT_DEGREES = 45.0
ATLAS_MATERIAL = "M_atlas"


def _ends(rng, n, p0, p1):
    """Values in [0, 1]: 0 with probability p0, 1 with p1, else uniform."""
    u = rng.random(n)
    v = rng.random(n)
    return np.where(u < p0, 0.0, np.where(u < p0 + p1, 1.0, v))


def _normal(rng, n):
    tilt = np.radians(MAX_TILT_DEGREES) * rng.random(n) * (rng.random(n) < 0.5)
    phi = 2 * math.pi * rng.random(n)
    return np.stack([np.sin(tilt) * np.cos(phi), np.sin(tilt) * np.sin(phi), np.cos(tilt)], -1)


def _white_or(rng, n, p_white):
    """[n, 3] colours: white with probability ``p_white``, else uniform."""
    return np.where((rng.random(n) < p_white)[:, None], 1.0, rng.random((n, 3)))


DISTRIBUTIONS = {
    "UsdPreviewSurface": {
        "diffuseColor": lambda rng, n: rng.random((n, 3)),
        "metallic": lambda rng, n: _ends(rng, n, 0.4, 0.4),
        "roughness": lambda rng, n: rng.random(n),
        "clearcoat": lambda rng, n: _ends(rng, n, 0.5, 0.0),
        "clearcoatRoughness": lambda rng, n: rng.random(n),
        "ior": lambda rng, n: 1.1 + 1.4 * rng.random(n),
        "normal": _normal,
    },
    "standard_surface": {
        "base": lambda rng, n: _ends(rng, n, 0.0, 0.5),
        "base_color": lambda rng, n: rng.random((n, 3)),
        "metalness": lambda rng, n: _ends(rng, n, 0.4, 0.4),
        "specular": lambda rng, n: _ends(rng, n, 0.1, 0.5),
        "specular_color": lambda rng, n: _white_or(rng, n, 0.5),
        "specular_roughness": lambda rng, n: rng.random(n),
        "specular_IOR": lambda rng, n: 1.1 + 1.4 * rng.random(n),
        "coat": lambda rng, n: _ends(rng, n, 0.5, 0.0),
        "coat_color": lambda rng, n: _white_or(rng, n, 0.5),
        "coat_roughness": lambda rng, n: rng.random(n),
        "coat_IOR": lambda rng, n: 1.1 + 1.4 * rng.random(n),
        "normal": _normal,
    },
}
# OpenPBR's opaque inputs are Standard Surface's under other names: the same distributions.
DISTRIBUTIONS["open_pbr_surface"] = {openpbr: DISTRIBUTIONS["standard_surface"][ss] for openpbr, ss in (
    ("base_weight", "base"), ("base_color", "base_color"), ("base_metalness", "metalness"),
    ("specular_weight", "specular"), ("specular_color", "specular_color"), ("specular_roughness", "specular_roughness"),
    ("specular_ior", "specular_IOR"), ("coat_weight", "coat"), ("coat_color", "coat_color"),
    ("coat_roughness", "coat_roughness"), ("coat_ior", "coat_IOR"), ("geometry_normal", "normal"))}
# glTF PBR: KHR_materials_specular's factor is 1 and its colour white unless the extension is used, so half the time.
DISTRIBUTIONS["gltf_pbr"] = {
    "base_color": lambda rng, n: rng.random((n, 3)),
    "metallic": lambda rng, n: _ends(rng, n, 0.4, 0.4),
    "roughness": lambda rng, n: rng.random(n),
    "specular": lambda rng, n: _ends(rng, n, 0.1, 0.5),
    "specular_color": lambda rng, n: _white_or(rng, n, 0.5),
    "ior": lambda rng, n: 1.1 + 1.4 * rng.random(n),
    "clearcoat": lambda rng, n: _ends(rng, n, 0.5, 0.0),
    "clearcoat_roughness": lambda rng, n: rng.random(n),
    "normal": _normal,
}
"""Per shading model and input: ``(generator, n) -> [n] or [n, 3]`` values of n cells."""


def input_texture(name: str, size: int, rng: np.random.Generator, model: str = "UsdPreviewSurface") -> np.ndarray:
    """[size, size, 3] float32 texture of ``model``'s input ``name`` (module docstring; a scalar in every
    channel; a normal as the tangent-space vector itself)."""
    half = size // 2
    out = np.zeros((size, size, 3), np.float32)
    sizes = rng.permutation(CELL_SIZES)
    for q, cell in enumerate(sizes):
        cell = int(min(cell, half))
        cells = math.ceil(half / cell)
        values = np.asarray(DISTRIBUTIONS[model][name](rng, cells * cells), np.float32).reshape(cells, cells, -1)
        block = np.repeat(np.repeat(values, cell, 0), cell, 1)[:half, :half]
        r, c = divmod(q, 2)
        out[r * half:(r + 1) * half, c * half:(c + 1) * half] = block  # a scalar broadcasts to RGB
    return out


def _write_exr(path: Path, img: np.ndarray) -> None:
    import OpenImageIO as oiio  # Local: OpenImageIO only where the atlas is written

    out = oiio.ImageOutput.create(str(path))
    if out is None or not out.open(str(path), oiio.ImageSpec(img.shape[1], img.shape[0], img.shape[2], "float")):
        raise OSError(f"{path}: cannot write ({oiio.geterror()})")
    try:
        out.write_image(np.ascontiguousarray(img, np.float32))
    finally:
        out.close()


def write_atlas(folder, model: str = "UsdPreviewSurface", size: int = 512, seed: int = 0) -> Path:
    """Write the atlas of ``model`` into ``folder`` (one EXR per varying input and ``atlas.mtlx``, whose
    material is :data:`ATLAS_MATERIAL`); returns the document's path. Seeded: the same arguments write
    the same files."""
    from mtlx2neural.scene import mxlib  # Local: the nodedef's input types

    spec = SHADING_MODELS[model]
    nodedef = mxlib.nodedef(spec.nodedef)
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    images, inputs = [], []
    for name in spec.varying:
        img = input_texture(name, size, rng, model)
        mx_type = nodedef.getActiveInput(name).getType()
        source = f"img_{name}"
        if name == spec.normal_map:  # encoded for a normalmap node: 0.5 * n + 0.5
            img = 0.5 * img + 0.5
            images.append(f'  <normalmap name="nm_{name}" type="vector3">\n'
                          f'    <input name="in" type="vector3" nodename="img_{name}" />\n  </normalmap>')
            source = f"nm_{name}"
        _write_exr(folder / f"{name}.exr", img)
        images.append(f'  <image name="img_{name}" type="{mx_type}">\n'
                      f'    <input name="file" type="filename" value="{(folder / name).resolve()}.exr" />\n  </image>')
        inputs.append(f'    <input name="{name}" type="{mx_type}" nodename="{source}" />')
    images, inputs = "\n".join(images), "\n".join(inputs)
    text = (f'<?xml version="1.0"?>\n<materialx version="1.39" colorspace="lin_rec709">\n{images}\n'
            f'  <{spec.category} name="SR_atlas" type="surfaceshader">\n{inputs}\n  </{spec.category}>\n'
            f'  <surfacematerial name="{ATLAS_MATERIAL}" type="material">\n'
            f'    <input name="surfaceshader" type="surfaceshader" nodename="SR_atlas" />\n'
            f'  </surfacematerial>\n</materialx>\n')
    path = folder / "atlas.mtlx"
    path.write_text(text)
    return path
