"""USD-native shader ids (UsdPreviewSurface family) -> MaterialX's own nodedefs.

MaterialX ships nodedefs for the UsdPreviewSurface family in
``libraries/bxdf/usd_preview_surface.mtlx``, so a USD preview network becomes
an ordinary MaterialX network and the same compiler handles it. This module
holds the id table and the few value spellings that differ between the USD
spec and those nodedefs.
"""

from __future__ import annotations

import os

# USD shader id -> MaterialX nodedef name.
USD_TO_NODEDEF = {
    "UsdPreviewSurface": "ND_UsdPreviewSurface_surfaceshader",
    "UsdUVTexture": "ND_UsdUVTexture_23",
    "UsdTransform2d": "ND_UsdTransform2d",
    "UsdPrimvarReader_float": "ND_UsdPrimvarReader_float",
    "UsdPrimvarReader_float2": "ND_UsdPrimvarReader_vector2",
    "UsdPrimvarReader_float3": "ND_UsdPrimvarReader_vector3",
    "UsdPrimvarReader_normal": "ND_UsdPrimvarReader_vector3",
    "UsdPrimvarReader_point": "ND_UsdPrimvarReader_vector3",
    "UsdPrimvarReader_vector": "ND_UsdPrimvarReader_vector3",
    "UsdPrimvarReader_float4": "ND_UsdPrimvarReader_vector4",
    "UsdPrimvarReader_int": "ND_UsdPrimvarReader_integer",
    "UsdPrimvarReader_string": "ND_UsdPrimvarReader_string",
    "UsdPrimvarReader_matrix": "ND_UsdPrimvarReader_matrix44",
}

# UsdUVTexture wrap modes -> the enum of ND_UsdUVTexture_23 (black, clamp, periodic, mirror).
# "useMetadata" has no MaterialX counterpart; USD's own fallback for it is "repeat".
_WRAP = {"repeat": "periodic", "useMetadata": "periodic"}

# Inputs of the USD spec that ND_UsdUVTexture_23 has no input for; handled here instead.
CONSUMED_INPUTS = {"UsdUVTexture": {"sourceColorSpace"}}

# Colour-space names seen in USD files -> MaterialX colour-space names.
_COLOR_SPACES = {
    "sRGB": "srgb_texture",
    "srgb": "srgb_texture",
    "srgb_rec709_scene": "srgb_texture",
    "linear": "lin_rec709",
    "lin_rec709_scene": "lin_rec709",
    "lin_ap1_scene": "acescg",
    "lin_ap1": "acescg",
    "raw": "",
    "Raw": "",
    "data": "",
}

# Image formats USD's "auto" source colour space treats as sRGB-encoded (8-bit formats).
_AUTO_SRGB_EXTENSIONS = {".jpg", ".jpeg", ".png", ".bmp", ".tga", ".gif"}


def nodedef_name(shader_id: str) -> tuple[str, bool]:
    """Map a shader ``info:id`` to a MaterialX nodedef name.

    Returns ``(nodedef name, is_usd_native)``. Ids that are not USD-native are
    assumed to be MaterialX nodedef names already and are returned unchanged.
    """
    if shader_id in USD_TO_NODEDEF:
        return USD_TO_NODEDEF[shader_id], True
    return shader_id, False


def translate_value(shader_id: str, input_name: str, value):
    """Rewrite a USD-spec value into the spelling the MaterialX nodedef expects."""
    if shader_id == "UsdUVTexture" and input_name in ("wrapS", "wrapT") and isinstance(value, str):
        return _WRAP.get(value, value)
    return value


def mx_color_space(name: str) -> str:
    """MaterialX colour-space name for a USD colour-space token ("" = no transform / raw)."""
    return _COLOR_SPACES.get(name, name)


def texture_color_space(source_color_space: str, asset_color_space: str, file_path: str) -> str:
    """Colour space of a UsdUVTexture file input, following USD's rules.

    ``sourceColorSpace`` wins when it is ``raw`` or ``sRGB``. For ``auto``
    (the default) the asset's ``colorSpace`` metadata is used when authored;
    otherwise, as USD's renderers do, 8-bit image formats are sRGB and all
    others are linear (no transform). Returns "" for "no transform".
    """
    if source_color_space in ("raw", "sRGB"):
        return mx_color_space(source_color_space)
    if asset_color_space:
        return mx_color_space(asset_color_space)
    ext = os.path.splitext(file_path)[1].lower()
    return "srgb_texture" if ext in _AUTO_SRGB_EXTENSIONS else ""
