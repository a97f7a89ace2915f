"""Operators whose value varies over the surface: texture lookups and geometric inputs.

They are evaluated per shading point from ``uv``. In the local shading frame
the geometric normal, tangent and bitangent are the constant axes z, x and y,
so those are folded as constants; position, texture coordinates, vertex colours
and primvars are spatial. Any node that depends on one of these is part of the
spatial sub-graph.
"""

from __future__ import annotations

import functools

import torch

from mtlx2neural.graph.ir import CHANNELS
from mtlx2neural.graph.validate import ADDRESS_ALIASES
from mtlx2neural.imaging.colour import canonical_colorspace, convert_torch, is_data
from mtlx2neural.imaging.image_io import Texture
from mtlx2neural.imaging.texel_lookup import conform_channels

SPATIAL = {"texcoord", "position", "geomcolor", "geompropvalue", "image"}
FRAME_AXES = {"normal": (0.0, 0.0, 1.0), "tangent": (1.0, 0.0, 0.0), "bitangent": (0.0, 1.0, 0.0)}
UV_PRIMVARS = {"st", "uv", "UV0", "uv0", "map1", "st0"}


@functools.lru_cache(maxsize=256)
def texture(path: str, node_path: str) -> Texture:
    """The texture (file or UDIM set) read by image node ``node_path`` (pixels cached by image_io)."""
    return Texture(path, node=node_path)


def texture_colorspaces(node) -> tuple[str, str]:
    """(file colour space, working space) of an image node; the working space
    defaults to lin_rec709, MaterialX's default, when the document declares none."""
    return node.attrs.get("colorspace", ""), node.attrs.get("working_space", "") or "lin_rec709"


def needs_conversion(src: str, dst: str) -> bool:

    return bool(src) and not is_data(src) and canonical_colorspace(src) != canonical_colorspace(dst)


def eval_source(node, args: dict, uv: torch.Tensor, position: torch.Tensor | None = None):
    """Value of spatial source ``node`` for texture coordinates ``uv`` [N,2].

    ``position`` [N,3] (or None): the surface point, in the document's units; every ``position`` node
    (object, world or model space alike) reads it. Without it, position is (u, v, 0), a flat unit
    square standing in for the surface.
    """
    n = uv.shape[0]
    cat = node.category
    if cat == "texcoord":
        if CHANNELS.get(node.type, 2) == 3:  # a vector3 texture coordinate: (u, v, 0), as MaterialX's vertex data
            return torch.cat([uv, torch.zeros(n, 1, dtype=uv.dtype, device=uv.device)], -1)
        return uv
    if cat == "position":
        if position is not None:
            return position
        return torch.cat([uv, torch.zeros(n, 1, dtype=uv.dtype, device=uv.device)], -1)
    if cat == "geomcolor":
        return torch.ones(n, CHANNELS[node.type], dtype=uv.dtype, device=uv.device)
    if cat == "geompropvalue":
        if node.type == "vector2" and args.get("geomprop") in UV_PRIMVARS:
            return uv
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
