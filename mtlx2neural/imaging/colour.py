"""Texture colour conversion with OpenColorIO.

Textures are converted on load from the colour space that MaterialX (``colorspace``
attribute, inherited down the element tree) or USD (``colorSpace`` metadata,
``sourceColorSpace``) declares, into the document's working space (MaterialX's
default ``lin_rec709``; ``acescg`` is also supported).  Data textures (normal,
roughness, masks: ``raw`` and the empty name) are never converted.

Configuration
-------------
Without ``$OCIO`` the module uses OpenColorIO's built-in CG config
(``ocio://cg-config-latest``), so no config file is needed.  That config has an
alias for every MaterialX colour-space name except ``g18_ap1``, which is added to
a private copy of it (gamma 1.8 over ACEScg, as its ``g22_ap1`` is gamma 2.2 over
ACEScg).  With ``$OCIO`` set, OpenColorIO's current config is used instead; a
MaterialX name is looked up in it as itself, then as each known alias (the names
the ACES 1.x and CG/studio configs use).  A gamma- or sRGB-encoded space the
config lacks is built from its linear space when that one exists.  The module
notices when ``$OCIO`` changes and re-reads it.

Canonical names
---------------
:func:`canonical_colorspace` maps every accepted spelling (case-insensitive) to a
canonical key, the MaterialX name where MaterialX has one:

=================  ==============================================================
canonical key      also accepted
=================  ==============================================================
``raw``            ``""``, ``data``, ``none``, ``identity``, ``Utility - Raw``
``lin_rec709``     ``lin_srgb``, ``lin_rec709_scene``, ``linear``, ``sRGB-linear``,
                   ``Linear Rec.709 (sRGB)``, ``Utility - Linear - sRGB``
``srgb_texture``   ``sRGB`` (USD), ``srgb_rec709_scene``, ``srgb_tx``,
                   ``sRGB - Texture``, ``sRGB Encoded Rec.709 (sRGB)``
``acescg``         ``lin_ap1``, ``lin_ap1_scene``, ``ACEScg``, ``ACES - ACEScg``
``g22_rec709``     ``g22_rec709_scene``, ``Gamma 2.2 Encoded Rec.709``
``g18_rec709``     ``g18_rec709_scene``, ``Gamma 1.8 Encoded Rec.709``
``rec709_display`` ``g24_rec709``, ``g24_rec709_scene``, ``Gamma 2.4 Encoded Rec.709``
``g22_ap1``        ``g22_ap1_scene``, ``Gamma 2.2 Encoded AP1``
``g18_ap1``        ``g18_ap1_scene``, ``Gamma 1.8 Encoded AP1``
``srgb_ap1``       ``srgb_ap1_scene``, ``sRGB Encoded AP1``
``adobergb``       ``g22_adobergb_scene``, ``Gamma 2.2 Encoded AdobeRGB``
``lin_adobergb``   ``lin_adobergb_scene``, ``Linear AdobeRGB``
``srgb_displayp3`` ``srgb_p3d65``, ``srgb_p3d65_scene``, ``sRGB Encoded P3-D65``
``lin_displayp3``  ``lin_p3d65``, ``lin_p3d65_scene``, ``Linear P3-D65``
``lin_rec2020``    ``lin_rec2020_scene``, ``Linear Rec.2020``
``aces2065_1``     ``ACES2065-1``, ``aces``, ``lin_ap0``, ``lin_ap0_scene``
``lin_ciexyzd65``  ``lin_ciexyzd65_scene``, ``CIE XYZ-D65 - Scene-referred``
``auto``           USD's "decide from the file"; resolve it before converting
                   (``scene.usd_preview.texture_color_space``)
=================  ==============================================================

Differences from MaterialX's own ``cmlib`` graphs: OpenColorIO's pure-gamma spaces
pass negative values through unchanged where MaterialX clamps them to 0, and the
colour matrices go through ACES2065-1 (agreeing with MaterialX's matrices to about
3e-7; 1.5e-5 for Display P3, whose cmlib matrix has 8 digits).  For texture values
in [0, 1] the results agree to float precision.

Every public function returns finite values: NaN becomes 0 and +-Inf the largest
finite float32 of that sign.
"""

from __future__ import annotations

import copy
import functools
import logging
import os
import threading
from dataclasses import dataclass

import numpy as np
import PyOpenColorIO as OCIO
import torch

from mtlx2neural.errors import InputError

__all__ = [
    "DEFAULT_WORKING_SPACE",
    "canonical_colorspace",
    "config_source",
    "convert",
    "convert_torch",
    "declared_colorspace",
    "is_data",
    "known_colorspaces",
    "processor",
    "working_space",
]

log = logging.getLogger(__name__)

DEFAULT_WORKING_SPACE = "lin_rec709"
"""MaterialX's default working colour space."""

BUILTIN_CONFIG = "cg-config-latest"
"""The OpenColorIO built-in config used when ``$OCIO`` is not set."""

# canonical key -> the other names accepted for it.  The first entries are the
# MaterialX / USD / colour-interop names; the rest are the names and aliases the
# OCIO CG/studio configs and the ACES 1.x configs use for the same space (checked
# against the colour spaces and aliases of cg-config-v5.0.0 and studio-config-v5.0.0).
# Lookups in an OCIO config try the canonical key first, then these in order.
_ALIASES: dict[str, tuple[str, ...]] = {
    "raw": ("", "data", "none", "identity", "Raw", "Utility - Raw"),
    "lin_rec709": (
        "lin_srgb", "lin_rec709_scene", "lin_rec709_srgb", "Linear Rec.709 (sRGB)",
        "Utility - Linear - sRGB", "Utility - Linear - Rec.709",
        # OpenImageIO's older names for the same space.
        "linear", "sRGB-linear",
    ),
    "srgb_texture": (
        "sRGB", "srgb_rec709_scene", "srgb_tx", "srgb_encoded_rec709_srgb",
        "sRGB Encoded Rec.709 (sRGB)", "sRGB - Texture", "Utility - sRGB - Texture",
        "Input - Generic - sRGB - Texture",
    ),
    "acescg": ("lin_ap1", "lin_ap1_scene", "ACEScg", "ACES - ACEScg"),
    "g22_rec709": (
        "gamma22",  # MaterialX's legacy (1.38) name
        "g22_rec709_scene", "g22_encoded_rec709", "Gamma 2.2 Encoded Rec.709",
        "Gamma 2.2 Rec.709 - Texture", "Utility - Gamma 2.2 - Rec.709 - Texture", "g22_rec709_tx",
    ),
    "g18_rec709": (
        "gamma18",  # MaterialX's legacy (1.38) name
        "g18_rec709_scene", "g18_encoded_rec709", "Gamma 1.8 Encoded Rec.709",
        "Gamma 1.8 Rec.709 - Texture", "Utility - Gamma 1.8 - Rec.709 - Texture", "g18_rec709_tx",
    ),
    "rec709_display": (
        "gamma24",  # MaterialX's legacy (1.38) name
        "g24_rec709", "g24_rec709_scene", "g24_encoded_rec709", "Gamma 2.4 Encoded Rec.709",
        "Gamma 2.4 Rec.709 - Texture", "Utility - Rec.709 - Display", "g24_rec709_tx",
    ),
    "g22_ap1": (
        "g22_ap1_scene", "g22_encoded_ap1", "Gamma 2.2 Encoded AP1", "Gamma 2.2 AP1 - Texture",
        "Utility - Gamma 2.2 - AP1 - Texture", "g22_ap1_tx",
    ),
    "g18_ap1": (
        "g18_ap1_scene", "g18_encoded_ap1", "Gamma 1.8 Encoded AP1", "Gamma 1.8 AP1 - Texture",
        "Utility - Gamma 1.8 - AP1 - Texture", "g18_ap1_tx",
    ),
    "srgb_ap1": (
        "srgb_ap1_scene", "srgb_encoded_ap1", "sRGB Encoded AP1", "sRGB Encoded AP1 - Texture",
        "srgb_encoded_ap1_tx",
    ),
    "adobergb": (
        "g22_adobergb_scene", "g22_encoded_adobergb", "Gamma 2.2 Encoded AdobeRGB",
    ),
    "lin_adobergb": (
        "lin_adobergb_scene", "Linear AdobeRGB", "Utility - Linear - Adobe RGB",
    ),
    "srgb_displayp3": (
        "srgb_p3d65", "srgb_p3d65_scene", "srgb_encoded_p3d65", "sRGB Encoded P3-D65",
        "sRGB Encoded P3-D65 - Texture", "srgb_encoded_p3d65_tx",
    ),
    "lin_displayp3": (
        "lin_p3d65", "lin_p3d65_scene", "Linear P3-D65", "Linear Display P3",
        "Utility - Linear - P3-D65",
    ),
    "lin_rec2020": ("lin_rec2020_scene", "Linear Rec.2020", "Utility - Linear - Rec.2020"),
    "aces2065_1": ("ACES2065-1", "aces", "lin_ap0", "lin_ap0_scene", "ACES - ACES2065-1"),
    "lin_ciexyzd65": ("lin_ciexyzd65_scene", "CIE XYZ-D65 - Scene-referred"),
    "auto": (),
}

# Encoded spaces that can be built from their linear space when a config lacks them:
# canonical key -> (linear canonical key, transfer).  A transfer is ("gamma", g) for a
# pure power law (MaterialX: out = in ** g) or ("srgb",) for the piecewise sRGB curve.
_SYNTHESIS: dict[str, tuple[str, tuple]] = {
    "srgb_texture": ("lin_rec709", ("srgb",)),
    "g22_rec709": ("lin_rec709", ("gamma", 2.2)),
    "g18_rec709": ("lin_rec709", ("gamma", 1.8)),
    "rec709_display": ("lin_rec709", ("gamma", 2.4)),
    "g22_ap1": ("acescg", ("gamma", 2.2)),
    "g18_ap1": ("acescg", ("gamma", 1.8)),
    "srgb_ap1": ("acescg", ("srgb",)),
    "adobergb": ("lin_adobergb", ("gamma", 563.0 / 256.0)),  # Adobe RGB (1998): 2 + 51/256
    "srgb_displayp3": ("lin_displayp3", ("srgb",)),
}

_DATA = frozenset({"raw"})
# ExceptionMissingFile does not derive from OCIO.Exception in the Python bindings.
_OCIO_ERRORS = (OCIO.Exception, OCIO.ExceptionMissingFile)
_UNRESOLVED = frozenset({"auto"})


def _norm(name: str) -> str:
    return " ".join(str(name).split()).lower()


_LOOKUP: dict[str, str] = {}
for _key, _names in _ALIASES.items():
    for _n in (_key, *_names):
        _LOOKUP.setdefault(_norm(_n), _key)
del _key, _names, _n


def known_colorspaces() -> list[str]:
    """The canonical colour-space keys :func:`canonical_colorspace` can return."""
    return list(_ALIASES)


def canonical_colorspace(name: str) -> str:
    """Normalise a MaterialX or USD colour-space name to its canonical key.

    Case and surrounding whitespace are ignored; ``None`` and ``""`` mean ``raw``.
    Raises :class:`InputError` for a name this module does not know, listing the
    known ones.
    """
    if name is None:
        return "raw"
    key = _LOOKUP.get(_norm(name))
    if key is None:
        raise InputError(
            f"unknown colour space {name!r}: expected a MaterialX or USD colour-space name, one of "
            f"{', '.join(k for k in _ALIASES)} (or an alias such as lin_srgb, lin_ap1, sRGB, "
            f"srgb_rec709_scene); declare one of these on the texture, or 'raw' for data")
    return key


def is_data(name: str) -> bool:
    """True for data (non-colour) spaces, which are never converted: ``raw`` and ``""``."""
    return canonical_colorspace(name) in _DATA


# --------------------------------------------------------------------------- config
@dataclass(frozen=True, eq=False)  # hashed by identity: one per (re)load
class _ConfigState:
    config: OCIO.Config  # the config conversions use (with any synthesised spaces)
    names: dict  # canonical key -> colour-space name in ``config``
    source: str  # "$OCIO=<value>" or "built-in <name>"


_lock = threading.RLock()
_state: _ConfigState | None = None
_state_env: str | None = None


def _builtin_config() -> tuple[OCIO.Config, str]:
    try:
        return OCIO.Config.CreateFromBuiltinConfig(BUILTIN_CONFIG), BUILTIN_CONFIG
    except _OCIO_ERRORS:
        # Older OpenColorIO without the "-latest" shortcut: newest built-in CG config.
        names = [n for n, *_ in OCIO.BuiltinConfigRegistry().getBuiltinConfigs() if n.startswith("cg-config")]
        if not names:
            raise
        return OCIO.Config.CreateFromBuiltinConfig(names[-1]), names[-1]


def _find(cfg: OCIO.Config, key: str) -> str | None:
    """Name in ``cfg`` of the space ``key``: tried as itself, then as each alias."""
    for n in (key, *_ALIASES[key]):
        cs = cfg.getColorSpace(n) if n else None
        if cs is not None:
            return cs.getName()
    return None


def _to_reference(cfg: OCIO.Config, cs_name: str) -> OCIO.Transform:
    cs = cfg.getColorSpace(cs_name)
    t = cs.getTransform(OCIO.COLORSPACE_DIR_TO_REFERENCE)
    if t is not None:
        return t
    t = cs.getTransform(OCIO.COLORSPACE_DIR_FROM_REFERENCE)
    if t is None:  # the reference space itself
        return OCIO.MatrixTransform()
    t = copy.deepcopy(t)
    t.setDirection(OCIO.TRANSFORM_DIR_INVERSE if t.getDirection() == OCIO.TRANSFORM_DIR_FORWARD
                   else OCIO.TRANSFORM_DIR_FORWARD)
    return t


def _decode_transform(transfer: tuple) -> OCIO.Transform:
    """Encoded -> linear, as MaterialX's cmlib graphs define it."""
    if transfer[0] == "srgb":
        return OCIO.ExponentWithLinearTransform(gamma=[2.4, 2.4, 2.4, 1.0], offset=[0.055, 0.055, 0.055, 0.0])
    g = float(transfer[1])
    return OCIO.ExponentTransform(value=[g, g, g, 1.0], negativeStyle=OCIO.NEGATIVE_PASS_THRU)


def _resolve(cfg: OCIO.Config, source: str) -> _ConfigState:
    """Map every canonical key to a colour space of ``cfg``, building missing encoded ones."""
    names: dict[str, str] = {}
    for key in _ALIASES:
        if key in _DATA or key in _UNRESOLVED:
            continue
        found = _find(cfg, key)
        if found is not None:
            names[key] = found
    buildable = [k for k in _SYNTHESIS if k not in names and _SYNTHESIS[k][0] in names]
    if buildable:
        cfg = copy.deepcopy(cfg)  # never modify OpenColorIO's current config
        for key in buildable:
            lin_key, transfer = _SYNTHESIS[key]
            group = OCIO.GroupTransform()
            group.appendTransform(_decode_transform(transfer))
            group.appendTransform(_to_reference(cfg, names[lin_key]))
            cs = OCIO.ColorSpace(OCIO.REFERENCE_SPACE_SCENE, name=f"mtlx2neural:{key}",
                                 family="mtlx2neural", encoding="sdr-video",
                                 description=f"{key}: {transfer} over {names[lin_key]} (added by mtlx2neural)",
                                 bitDepth=OCIO.BIT_DEPTH_F32, toReference=group)
            cfg.addColorSpace(cs)
            names[key] = cs.getName()
            log.debug("colour space %s is not in %s; built it from %s", key, source, names[lin_key])
    return _ConfigState(cfg, names, source)


def _load(env: str | None) -> _ConfigState:
    if env:
        try:
            # OpenColorIO caches its current config from the first $OCIO it saw; make it
            # match $OCIO as it is now, then use it.
            OCIO.ClearAllCaches()
            OCIO.SetCurrentConfig(OCIO.Config.CreateFromEnv())
            cfg = OCIO.GetCurrentConfig()
        except _OCIO_ERRORS as exc:
            raise InputError(f"the OpenColorIO config named by $OCIO ({env!r}) cannot be loaded: {exc}; "
                             f"fix it or unset $OCIO to use the built-in config") from exc
        return _resolve(cfg, f"$OCIO={env}")
    cfg, name = _builtin_config()
    return _resolve(cfg, f"built-in {name}")


def _current() -> _ConfigState:
    """The config to use now; re-read when ``$OCIO`` has changed since the last call."""
    global _state, _state_env
    env = os.environ.get("OCIO") or None
    with _lock:
        if _state is None or env != _state_env:
            _cached_processor.cache_clear()
            _state, _state_env = _load(env), env
        return _state


def config_source() -> str:
    """Which OpenColorIO config conversions use: ``"$OCIO=..."`` or ``"built-in <name>"``."""
    return _current().source


@functools.lru_cache(maxsize=256)
def _cached_processor(src: str, dst: str, state: _ConfigState) -> OCIO.CPUProcessor:
    cfg = state.config
    if src in _DATA or dst in _DATA or src == dst:
        proc = cfg.getProcessor(OCIO.MatrixTransform())  # identity
    else:
        for key in (src, dst):
            if key not in state.names:
                raise InputError(
                    f"colour space {key!r} is not in the OpenColorIO config ({state.source}); tried the "
                    f"names {', '.join(repr(n) for n in (key, *_ALIASES[key]))}. Add one of them as a colour "
                    f"space or alias to the config, or unset $OCIO to use the built-in config")
        try:
            proc = cfg.getProcessor(state.names[src], state.names[dst])
        except _OCIO_ERRORS as exc:
            raise InputError(f"OpenColorIO cannot convert {src!r} ({state.names[src]}) to {dst!r} "
                             f"({state.names[dst]}) with {state.source}: {exc}") from exc
    # Lossless: the default optimisation uses fast pow/exp approximations (~2e-5 error).
    return proc.getOptimizedCPUProcessor(OCIO.BIT_DEPTH_F32, OCIO.BIT_DEPTH_F32, OCIO.OPTIMIZATION_LOSSLESS)


def _check_resolved(key: str, name: str) -> None:
    if key in _UNRESOLVED:
        raise InputError(
            f"colour space {name!r} must be resolved from the image file before converting "
            f"(USD's rules: mtlx2neural.scene.usd_preview.texture_color_space)")


def processor(src: str, dst: str = DEFAULT_WORKING_SPACE) -> OCIO.CPUProcessor:
    """Cached float32 OpenColorIO CPU processor from ``src`` to ``dst``.

    Names are canonicalised first; data spaces give an identity processor.  The
    cache is keyed on the current config too and emptied when ``$OCIO`` changes;
    ``processor.cache_clear()`` empties it and forgets the config.
    """
    s, d = canonical_colorspace(src), canonical_colorspace(dst)
    _check_resolved(s, src)
    _check_resolved(d, dst)
    return _cached_processor(s, d, _current())


def _cache_clear() -> None:
    global _state, _state_env
    with _lock:
        _cached_processor.cache_clear()
        _state, _state_env = None, None


processor.cache_clear = _cache_clear  # type: ignore[attr-defined]
processor.cache_info = _cached_processor.cache_info  # type: ignore[attr-defined]


# --------------------------------------------------------------------------- conversion
_F32_MAX = float(np.finfo(np.float32).max)


def _finite(a: np.ndarray) -> np.ndarray:
    if not np.isfinite(a).all():
        np.nan_to_num(a, copy=False, nan=0.0, posinf=_F32_MAX, neginf=-_F32_MAX)
    return a


def convert(pixels: np.ndarray, src: str, dst: str = DEFAULT_WORKING_SPACE) -> np.ndarray:
    """Convert colours from ``src`` into ``dst`` (by default MaterialX's working space).

    ``pixels`` is a float array ``[..., 3]`` or ``[..., 4]``; alpha is copied
    unchanged.  Returns a new float32 array.  Identity (a copy) when ``src`` and
    ``dst`` name the same space or either is a data space (``raw``, ``""``).
    """
    a = np.asarray(pixels)
    if a.dtype.kind != "f":
        raise TypeError(f"convert() expects float pixels, got dtype {a.dtype} (normalise integers to [0, 1] first)")
    s, d = canonical_colorspace(src), canonical_colorspace(dst)
    _check_resolved(s, src)
    _check_resolved(d, dst)
    out = np.array(a, dtype=np.float32, copy=True, order="C")
    if s == d or s in _DATA or d in _DATA:
        return _finite(out)
    if out.ndim == 0 or out.shape[-1] not in (3, 4):
        raise ValueError(f"convert() expects [..., 3] or [..., 4] pixels, got shape {tuple(out.shape)}")
    cpu = processor(s, d)
    if out.shape[-1] == 3:
        if out.size:
            cpu.applyRGB(out)  # in place on the contiguous copy
    else:
        rgb = np.ascontiguousarray(out[..., :3])
        if rgb.size:
            cpu.applyRGB(rgb)
        out[..., :3] = rgb
    return _finite(out)


def convert_torch(x, src: str, dst: str = DEFAULT_WORKING_SPACE):
    """:func:`convert` for a ``[N, 3]`` or ``[N, 4]`` tensor; float32 on ``x``'s device.

    The conversion runs on the CPU (OpenColorIO); gradients do not flow through it.
    """

    s, d = canonical_colorspace(src), canonical_colorspace(dst)
    _check_resolved(s, src)
    _check_resolved(d, dst)
    if s == d or s in _DATA or d in _DATA:
        y = x.detach().to(torch.float32).clone()
        return torch.nan_to_num(y, nan=0.0, posinf=_F32_MAX, neginf=-_F32_MAX)
    if x.ndim != 2 or x.shape[-1] not in (3, 4):
        raise ValueError(f"convert_torch() expects an [N, 3] or [N, 4] tensor, got shape {tuple(x.shape)}")
    arr = x.detach().to(device="cpu", dtype=torch.float32).numpy()
    out = convert(arr, s, d)
    return torch.from_numpy(out).to(x.device)


# --------------------------------------------------------------------------- MaterialX
def working_space(document) -> str:
    """Canonical working space of a MaterialX document (or element): its ``colorspace``, else lin_rec709.

    Raises :class:`InputError` when the declared space is a data space or unknown.
    """
    doc = document.getDocument() if hasattr(document, "getDocument") else document
    declared = doc.getColorSpace() or DEFAULT_WORKING_SPACE
    key = canonical_colorspace(declared)
    if key in _DATA or key in _UNRESOLVED:
        raise InputError(f"document {doc.getSourceUri() or '<memory>'}: colorspace {declared!r} cannot be "
                         f"a working space; use lin_rec709 or acescg")
    return key


def declared_colorspace(element) -> str:
    """Canonical colour space a MaterialX element declares, inherited from its ancestors.

    An element with no ``colorspace`` on it or any ancestor is in MaterialX's
    default space, ``lin_rec709``.
    """
    name = element.getActiveColorSpace()
    return canonical_colorspace(name) if name else DEFAULT_WORKING_SPACE
