"""USD attribute values -> MaterialX value strings, and asset-path resolution.

The MaterialX type always comes from the nodedef input being set, never from
the USD attribute's type name: USD spells the same data several ways
(``color3f``/``float3``/``normal3f``/``double3`` ...), MaterialX once.
"""

from __future__ import annotations

import os

import numpy as np
from pxr import Sdf, Usd

# Number of float components of each MaterialX aggregate type.
_ARITY = {
    "float": 1,
    "vector2": 2,
    "vector3": 3,
    "color3": 3,
    "vector4": 4,
    "color4": 4,
    "matrix33": 9,
    "matrix44": 16,
}
_ARRAY_ELEMENT = {"floatarray": "float", "integerarray": "integer", "stringarray": "string"}


class ValueConversionError(ValueError):
    """A USD value cannot be expressed as the requested MaterialX type."""


def _fmt_float(x) -> str:
    # Shortest string that round-trips the float32 MaterialX will store.
    s = str(np.float32(x))
    return s[:-2] if s.endswith(".0") else s


def _flatten(value) -> list:
    """Flatten Gf vectors/matrices (and nested sequences) into a list of scalars."""
    if isinstance(value, (str, bytes)):
        raise ValueConversionError(f"expected numbers, got the string {value!r}")
    try:
        items = list(value)
    except TypeError:
        return [value]
    out = []
    for item in items:
        out.extend(_flatten(item))
    return out


def _enum_index(value: str, enum: str, enumvalues: str) -> str:
    names = [n.strip() for n in enum.split(",")]
    values = [v.strip() for v in enumvalues.split(",")] if enumvalues else []
    if value not in names:
        raise ValueConversionError(f"{value!r} is not one of {', '.join(names)}")
    i = names.index(value)
    return values[i] if i < len(values) else str(i)


def to_value_string(value, mx_type: str, enum: str = "", enumvalues: str = "") -> str:
    """Format a USD attribute value as a MaterialX value string of type ``mx_type``.

    ``enum``/``enumvalues`` (from the nodedef input) let a USD token select an
    integer enum value. Raises ValueConversionError when the value does not fit.
    """
    if mx_type in ("string", "filename"):
        if isinstance(value, Sdf.AssetPath):
            return value.path
        return str(value)
    if mx_type == "boolean":
        if isinstance(value, str):
            raise ValueConversionError(f"expected a boolean, got the string {value!r}")
        return "true" if bool(value) else "false"
    if mx_type == "integer":
        if isinstance(value, str):
            if enum:
                return _enum_index(value, enum, enumvalues)
            raise ValueConversionError(f"expected an integer, got the string {value!r}")
        flat = _flatten(value)
        if len(flat) != 1:
            raise ValueConversionError(f"expected one integer, got {len(flat)} values")
        return str(int(flat[0]))
    if mx_type in _ARRAY_ELEMENT:
        element = _ARRAY_ELEMENT[mx_type]
        return ", ".join(to_value_string(v, element) for v in list(value))
    if mx_type in _ARITY:
        flat = _flatten(value)
        if len(flat) != _ARITY[mx_type]:
            raise ValueConversionError(f"expected {_ARITY[mx_type]} component(s) for {mx_type}, got {len(flat)}")
        return ", ".join(_fmt_float(x) for x in flat)
    raise ValueConversionError(f"values of MaterialX type {mx_type!r} are not supported")


def authored_value(attr: Usd.Attribute):
    """The attribute's value at the default time, else its earliest time sample, else None."""
    value = attr.Get(Usd.TimeCode.Default())
    if value is None and attr.GetNumTimeSamples() > 0:
        value = attr.Get(Usd.TimeCode.EarliestTime())
    return value


def _authoring_layer(attr: Usd.Attribute) -> "Sdf.Layer | None":
    for spec in attr.GetPropertyStack(Usd.TimeCode.Default()):
        if spec.HasDefaultValue() or spec.layer.ListTimeSamplesForPath(spec.path):
            return spec.layer
    return None


def resolve_asset(attr: Usd.Attribute, asset: Sdf.AssetPath) -> str:
    """Absolute path for an asset-valued attribute; empty when the value is empty.

    Uses USD's resolved path when the asset exists, otherwise anchors the
    authored path to the layer that authored the value (so missing textures
    still get a meaningful absolute path, and ``<UDIM>`` tokens stay intact).
    """
    if not asset.path:
        return ""
    if asset.resolvedPath and "<UDIM>" not in asset.path:
        return os.path.normpath(asset.resolvedPath)
    layer = _authoring_layer(attr)
    if layer is None or layer.anonymous:
        layer = attr.GetStage().GetRootLayer()
    return anchor_to_layer(asset.path, layer)


def anchor_to_layer(path: str, layer: "Sdf.Layer") -> str:
    """Absolute, normalised form of an asset path authored in ``layer``.

    Ar leaves search-path style paths (``textures/a.png``) unanchored when the
    file does not exist; those are joined with the layer's directory here so
    a missing file still gets the absolute path the author meant.
    """
    if not layer.anonymous:
        anchored = layer.ComputeAbsolutePath(path)
        if anchored and os.path.isabs(anchored):
            return os.path.normpath(anchored)
        if not os.path.isabs(path) and layer.realPath:
            return os.path.normpath(os.path.join(os.path.dirname(layer.realPath), path))
    return os.path.normpath(os.path.abspath(path))
