"""Operators whose value varies over the surface: texture lookups and geometric inputs.

They are evaluated per shading point from ``uv``. In the local shading frame
the geometric normal, tangent and bitangent are the constant axes z, x and y,
so where a closure (or ``normalmap``) reads them they are folded as constants;
elsewhere they read the geometry (:mod:`mtlx2neural.graph.geometry`). Position,
texture coordinates, vertex colours and primvars are spatial, read from the
per-sample geometry when the material has one. Any node that depends on one of
these is part of the spatial sub-graph.
"""

from __future__ import annotations

import functools
import os

import torch

from mtlx2neural.errors import InputError
from mtlx2neural.graph.ir import CHANNELS
from mtlx2neural.graph.validate import ADDRESS_ALIASES
from mtlx2neural.imaging.colour import canonical_colorspace, convert_torch, is_data
from mtlx2neural.imaging.image_io import Texture
from mtlx2neural.imaging.texel_lookup import conform_channels

SPATIAL = {"texcoord", "position", "geomcolor", "geompropvalue", "image"}
FRAME_AXES = {"normal": (0.0, 0.0, 1.0), "tangent": (1.0, 0.0, 0.0), "bitangent": (0.0, 1.0, 0.0)}
UV_PRIMVARS = {"st", "uv", "UV0", "uv0", "map1", "st0"}


def texcoord_index(node) -> int:
    """The UV set a ``texcoord`` node reads (its constant ``index`` input, an IR constant tuple; 0 when absent)."""
    value = getattr(node.inputs.get("index"), "value", None)
    return int(value[0]) if isinstance(value, tuple) and value else 0


def texture(path: str, node_path: str) -> Texture:
    """The texture (file or UDIM set) read by image node ``node_path`` (pixels cached by image_io).
    Cached per file version: a file changed or removed since is read (or reported missing) again."""
    try:
        stamp = os.stat(path).st_mtime_ns
    except OSError:  # missing, or a UDIM pattern: Texture reports or resolves it
        stamp = None
    return _texture(path, node_path, stamp)


@functools.lru_cache(maxsize=256)
def _texture(path: str, node_path: str, stamp: int | None) -> Texture:
    return Texture(path, node=node_path)


def texture_colorspaces(node) -> tuple[str, str]:
    """(file colour space, working space) of an image node; the working space
    defaults to lin_rec709, MaterialX's default, when the document declares none."""
    return node.attrs.get("colorspace", ""), node.attrs.get("working_space", "") or "lin_rec709"


def _fit(v: torch.Tensor, c: int) -> torch.Tensor:
    """``v`` [N, K] with ``c`` channels: truncated, or padded with its last channel (a scalar widens)."""
    if v.shape[-1] >= c:
        return v[:, :c]
    return torch.cat([v, v[:, -1:].expand(-1, c - v.shape[-1])], -1)


def needs_conversion(src: str, dst: str) -> bool:

    return bool(src) and not is_data(src) and canonical_colorspace(src) != canonical_colorspace(dst)


def eval_source(node, args: dict, uv: torch.Tensor, geometry: dict | None = None):
    """Value of spatial source ``node`` for texture coordinates ``uv`` [N,2].

    ``geometry`` (or None): ``{key: [N, C]}`` per-sample geometry
    (:class:`mtlx2neural.scene.uv_raster.GeometryMaps` keys: ``position:object``/``position:world`` in
    the scene's units, ``primvar:NAME``). Without it, or without the key a node asks for, position is
    (u, v, 0) (a flat unit square standing in for the surface), ``geomcolor`` is 1 and
    ``geompropvalue`` its default.
    """
    n = uv.shape[0]
    cat = node.category
    geo = geometry or {}
    if cat == "texcoord":
        coords = uv
        primvar = node.attrs.get("primvar")  # another UV set, bound to a mesh primvar (graph.geometry)
        if primvar and not node.attrs.get("layout_uv"):
            coords = geo.get(f"primvar:{primvar}")
            if coords is None:
                raise InputError(f"'{node.path}' reads UV set '{primvar}', which the evaluator was given no "
                                 f"samples of: bind the meshes first (graph.geometry.bind_geometry)", node=node.path)
            coords = _fit(coords, 2)
        elif texcoord_index(node) != 0 and not node.attrs.get("layout_uv"):
            raise InputError(f"'{node.path}' reads texcoord index {texcoord_index(node)}, a second UV set, which "
                             f"only bound meshes provide (graph.geometry.bind_geometry); nothing is bound",
                             node=node.path)
        if CHANNELS.get(node.type, 2) == 3:  # a vector3 texture coordinate: (u, v, 0), as MaterialX's vertex data
            return torch.cat([coords, torch.zeros(n, 1, dtype=uv.dtype, device=uv.device)], -1)
        return coords
    if cat == "position":
        space = args.get("space") if isinstance(args.get("space"), str) else node.attrs.get("space", "")
        got = geo.get("position:world" if space == "world" else "position:object")
        if got is not None:
            return got
        return torch.cat([uv, torch.zeros(n, 1, dtype=uv.dtype, device=uv.device)], -1)
    if cat == "geomcolor":
        c = geo.get("primvar:displayColor")
        if c is None:
            return torch.ones(n, CHANNELS[node.type], dtype=uv.dtype, device=uv.device)
        alpha = geo.get("primvar:displayOpacity")
        if alpha is None:
            alpha = torch.ones(n, 1, dtype=uv.dtype, device=uv.device)
        return _fit(torch.cat([_fit(c, 3), alpha[:, :1]], -1) if CHANNELS[node.type] == 4 else c,
                    CHANNELS[node.type])
    if cat == "geompropvalue":
        if node.type == "vector2" and (args.get("geomprop") in UV_PRIMVARS or node.attrs.get("layout_uv")):
            return uv  # the UV set the layout is drawn from (graph.geometry.check_uv_sets)
        got = geo.get(f"primvar:{args.get('geomprop')}")
        if got is not None:
            return _fit(got, CHANNELS[node.type])
        return args["default"].expand(n, -1)
    if cat == "image":
        path = args["file"]
        default = args["default"]
        if not path or node.attrs.get("missing"):
            return default.expand(n, -1)
        tex = texture(path, node.path)
        modes = [args.get(k) or "periodic" for k in ("uaddressmode", "vaddressmode")]
        border = conform_channels(default, tex.channels)
        if "black" in modes:  # UsdUVTexture's "black" wrap: a constant border of zeros
            border = torch.zeros_like(border)
        raw = tex.sample(args["texcoord"].expand(n, -1), uaddress=ADDRESS_ALIASES.get(modes[0], modes[0]),
                         vaddress=ADDRESS_ALIASES.get(modes[1], modes[1]),
                         filtertype=args.get("filtertype", "linear") or "linear", default=border)
        out = conform_channels(raw, CHANNELS[node.type])
        src, dst = texture_colorspaces(node)
        if out.shape[-1] >= 3 and needs_conversion(src, dst):
            out = torch.cat([convert_torch(out[:, :3], src, dst), out[:, 3:]], -1)
        return out
    raise KeyError(cat)
