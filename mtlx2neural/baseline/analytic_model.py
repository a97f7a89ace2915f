"""The analytic baseline: a Lambert + isotropic GGX material fitted numerically to the reference.

This is the "distilled" alternative a user would otherwise pick (the paper's
Figure 3): a standard real-time BRDF whose parameters are textures, fitted with
Adam against the same reference, the same footprint-filtered targets and the
same log-L1 loss as the neural material, so the two compare like for like.

The 8 channels (``CHANNELS``), stored unconstrained and mapped to their ranges by
:func:`decode`:

====  ==============  ==================================================================
 0-2  base colour     linear RGB in [0, 1] (sigmoid): the diffuse albedo of a dielectric,
                      F0 of a metal
  3   roughness       perceptual roughness in [0.02, 1] (sigmoid); GGX alpha = roughness^2
  4   metalness       [0, 1] (sigmoid): mixes dielectric and metal
  5   specular        [0, 1] (sigmoid): dielectric F0 = 0.08 * specular (0.5 -> 0.04, IOR 1.5)
 6-7  normal slopes   (sx, sy), unbounded: shading normal n = normalize(-sx, -sy, 1) in the
                      local frame (x tangent, z geometric normal)
====  ==============  ==================================================================

The model, with all cosines taken about the shading normal n and h = normalize(wi + wo)::

    F   = F0 + (1 - F0) (1 - wi.h)^5               F0 = mix(0.08 specular, base, metalness)
    D   = alpha^2 / (pi ((n.h)^2 (alpha^2 - 1) + 1)^2)
    V   = 0.5 / (n.wo sqrt(a2 + (1-a2)(n.wi)^2) + n.wi sqrt(a2 + (1-a2)(n.wo)^2))   Smith height-correlated
    f   = (1 - metalness) base / pi + D F V
    eval = f * max(0, n.wo)      (0 when wi.z <= 0 or wo.z <= 0, as every material here)

``AnalyticMaterial`` implements :class:`mtlx2neural.contract.Material`; its ``sample``/``pdf`` (a
cosine + GGX visible-normal mixture) are in :mod:`.analytic_sampling`.

The channels are a texture pyramid (:class:`~mtlx2neural.model.latent.LatentPyramid`):
1x1 for a uniform material, else the latent grid (``stack.resolution``) halved down
to 1x1; every level is fitted (queries draw levels like the neural training), and
a render picks levels stochastically from its level of detail, as the neural model.

A UDIM material (a :class:`~mtlx2neural.train.udim.TiledStack`) gets one such pyramid per trained tile
(``tiles``, the neural model's addressing: floor(uv) picks the tile, frac(uv) is read in it with
clamp); its UsdPreviewSurface maps are then one file per tile, ``<input>.<UDIM number>.exr``,
referenced as ``<input>.<UDIM>.exr``.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import torch
from torch import nn

from mtlx2neural.atomic import atomic_path
from mtlx2neural.baseline import analytic_sampling
from mtlx2neural.contract import (
    above_horizon,
    estimate_albedo,
    normalize_directions,
    prepare_direction,
    prepare_directions,
    prepare_point,
    prepare_values,
    reject_params,
    zero_below_horizon,
)
from mtlx2neural.model.latent import LatentPyramid
from mtlx2neural.textures.footprint import footprint_targets, sample_levels
from mtlx2neural.textures.surface_maps import ALPHA_CUTOFF, SurfacesBeside
from mtlx2neural.train.adam import Adam, cosine_lr
from mtlx2neural.train.directions import half_difference_pairs
from mtlx2neural.train.losses import log_l1
from mtlx2neural.train.udim import draw_uv, is_udim_stack

CHANNELS = ("base_r", "base_g", "base_b", "roughness", "metalness", "specular", "slope_x", "slope_y")
MIN_ROUGHNESS = 0.02
BASELINE_FILE = "analytic_baseline.pt"
"""Where a conversion keeps a material's fitted baseline, in its material folder (:func:`save_analytic`)."""


def _logit(p: torch.Tensor) -> torch.Tensor:
    p = p.clamp(1e-3, 1 - 1e-3)
    return torch.log(p / (1 - p))


def decode(raw: torch.Tensor) -> dict:
    """Unconstrained channels [N, 8] -> {base [N,3], roughness [N,1], metalness [N,1], specular [N,1],
    normal [N,3] (unit, local frame)}."""
    s = torch.sigmoid(raw[:, :6])
    slope = raw[:, 6:8]
    n = torch.cat([-slope, torch.ones_like(slope[:, :1])], -1)
    return {"base": s[:, 0:3], "roughness": MIN_ROUGHNESS + (1 - MIN_ROUGHNESS) * s[:, 3:4],
            "metalness": s[:, 4:5], "specular": s[:, 5:6],
            "normal": n / n.norm(dim=-1, keepdim=True).clamp_min(1e-12)}


def brdf(p: dict, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
    """f * max(0, n.wo) [N,3] for decoded parameters ``p``; finite for any unit directions."""
    n = p["normal"]
    nv = (wi * n).sum(-1, keepdim=True).clamp(1e-4, 1.0)
    nl_raw = (wo * n).sum(-1, keepdim=True)
    nl = nl_raw.clamp(1e-4, 1.0)
    h = wi + wo
    h = h / h.norm(dim=-1, keepdim=True).clamp_min(1e-8)
    nh = (h * n).sum(-1, keepdim=True).clamp(0.0, 1.0)
    vh = (wi * h).sum(-1, keepdim=True).clamp(0.0, 1.0)
    a2 = (p["roughness"] ** 2) ** 2
    d = a2 / (math.pi * ((nh * nh) * (a2 - 1) + 1).clamp_min(1e-12) ** 2)
    vis = 0.5 / (nl * (a2 + (1 - a2) * nv * nv).sqrt() + nv * (a2 + (1 - a2) * nl * nl).sqrt()).clamp_min(1e-12)
    f0 = (1 - p["metalness"]) * 0.08 * p["specular"] + p["metalness"] * p["base"]
    fres = f0 + (1 - f0) * (1 - vh) ** 5
    f = (1 - p["metalness"]) * p["base"] / math.pi + d * fres * vis
    out = f * nl_raw.clamp_min(0.0)
    ok = (wi[:, 2:3] > 0) & (wo[:, 2:3] > 0)
    return torch.where(ok & torch.isfinite(out), out, torch.zeros_like(out))


class AnalyticMaterial(SurfacesBeside, nn.Module):
    """Lambert + GGX with 8 channels per texel in a MIP pyramid; a :class:`~mtlx2neural.contract.Material`
    (eval / sample / pdf / albedo / describe) with the contract's input rules: directions in the local
    frame (z the geometric normal, x the tangent; ``wi`` to the viewer, ``wo`` to the light, both away
    from the surface) of any length and real dtype, normalised; NaN/Inf raise ``ValueError``; everything
    is 0 at or below the horizon; results in the model's dtype. ``at``: a ShadingPoint (``uv`` [N,2],
    default (0, 0); ``lod`` [N] in finest-level texels, log2; ``u_level`` [N] uniform, choosing between
    the two nearest levels; no named ``params``) or a [N,2] uv tensor. Sampling:
    :mod:`.analytic_sampling`. ``tiles``: the UDIM tiles of a UDIM material (one pyramid each; a uv
    outside them is a ``ValueError``, as for the neural model)."""

    def __init__(self, resolution: tuple[int, int] = (1, 1), tiles=None):
        super().__init__()
        self.maps = LatentPyramid(*resolution, channels=len(CHANNELS), tiles=tiles)
        self.surface = None  # emission and opacity beside the maps (SurfacesBeside)

    @property
    def resolution(self) -> tuple[int, int]:
        """(H, W) of level 0 (per tile for a UDIM material)."""
        return tuple(self.maps.levels[0].shape[-2:])

    @property
    def tiles(self) -> list[int] | None:
        """The UDIM tiles (sorted UDIM numbers), or None for one map over [0,1]^2."""
        return self.maps.tile_list

    @property
    def dtype(self) -> torch.dtype:
        """The maps' dtype, in which inputs are converted and results returned."""
        return self.maps.levels[0].dtype

    @property
    def device(self) -> torch.device:
        return self.maps.levels[0].device

    def raw(self, n: int, uv=None, lod=None, u_level=None, device=None) -> torch.Tensor:
        """Unconstrained channels [N, 8] at ``uv``/``lod``/``u_level`` (None: (0, 0), level 0, 0);
        ``device`` defaults to the maps'."""
        kw = {"dtype": self.dtype, "device": self.device if device is None else device}
        uv = torch.zeros(n, 2, **kw) if uv is None else uv
        lod = torch.zeros(n, **kw) if lod is None else lod
        u_level = torch.zeros(n, **kw) if u_level is None else u_level
        return self.maps(uv, lod, u_level)

    def parameters_at(self, uv=None, lod=None, u_level=None, n: int = 1) -> dict:
        """Decoded parameters (see :func:`decode`) at ``uv`` [N,2] (default: one query at uv (0,0))."""
        n = uv.shape[0] if uv is not None else n
        return decode(self.raw(n, uv, lod, u_level))

    def _params_at(self, n: int, at) -> dict:
        p = prepare_point(at, self.dtype, self.device)
        reject_params(p, "AnalyticMaterial")
        return decode(self.raw(n, p.uv, p.lod, p.u_level))

    def eval(self, wi, wo, at=None):
        """f(wi, wo) * max(0, n.wo) [N,3], linear RGB, the cosine included about the shading normal n (the
        slopes); 0 when wi or wo is at or below the (geometric) horizon."""
        wi, wo = prepare_directions(wi, wo, self.dtype, self.device)
        return brdf(self._params_at(wi.shape[0], at), wi, wo)

    def pdf(self, wi, wo, at=None):
        """Solid-angle density [N] (1/sr, no cosine) of :meth:`sample` at ``wo``, the exact mixture of
        :mod:`.analytic_sampling`; 0 when wi or wo is at or below the horizon."""
        wi, wo = prepare_directions(wi, wo, self.dtype, self.device)
        return zero_below_horizon(analytic_sampling.pdf(self._params_at(wi.shape[0], at), wi, wo), wi, wo)

    def sample(self, wi, u, at=None):
        """(wo [N,3] unit; weight [N,3] = eval / pdf, the cosine included; pdf [N] = ``pdf(wi, wo)`` per
        steradian) from ``u`` [N,2] (or [N,3], the third number picking diffuse or specular sampling);
        weight and pdf 0 where wi or the sampled wo is at or below the horizon."""
        wi = prepare_direction("wi", wi, self.dtype, self.device)
        n = wi.shape[0]
        u = prepare_values("u", u, self.dtype, self.device, rows=n, width=(2, 3))
        p = self._params_at(n, at)
        wo = normalize_directions(analytic_sampling.sample(p, wi, u))  # a failed (zero) sample is below
        pdf = zero_below_horizon(analytic_sampling.pdf(p, wi, wo), wi, wo)
        f = brdf(p, wi, wo)
        ok = above_horizon(wi, wo) & (pdf[:, None] > 0)
        weight = torch.where(ok, f / pdf.clamp_min(1e-30)[:, None], torch.zeros_like(f))
        weight = torch.where(torch.isfinite(weight), weight, torch.zeros_like(weight))
        return wo, weight, pdf

    def albedo(self, wi, at=None, samples: int = 256, seed: int = 0):
        """Directional albedo [N,3] (eval integrated over wo, cosine included):
        :func:`~mtlx2neural.contract.estimate_albedo` with :meth:`sample`; 0 when wi is at or below the
        horizon. ``wi`` and ``at`` as for :meth:`eval`."""
        return estimate_albedo(self, prepare_direction("wi", wi, self.dtype, self.device), at, samples, seed)

    def describe(self) -> dict:
        """What the model is: Lambert + isotropic GGX, its channels, the map resolution (h, w) and levels,
        the final fitting loss when fitted, and the mean decoded parameters of the finest level."""
        mean = {k: [round(float(x), 4) for x in v.reshape(-1, v.shape[-1]).mean(0)]
                for k, v in self.level_maps(0).items()}
        loss = getattr(self, "final_loss", None)
        return {"kind": "analytic", "model": "Lambert + isotropic GGX (Smith height-correlated, Schlick)",
                "channels": list(CHANNELS), "resolution": list(self.resolution), "levels": self.maps.num_levels,
                "sampling": "cosine about the shading normal + GGX visible normals, mixed by lobe energy",
                "final_loss": None if loss is None or math.isnan(loss) else float(loss), "mean": mean,
                "dtype": str(self.dtype).removeprefix("torch."), "device": str(self.device)}

    def level_maps(self, level: int = 0, tile: int = 0) -> dict:
        """Decoded maps of ``level`` as [H, W, C] numpy arrays (row 0 = top, v = 1); of the ``tile``-th
        trained tile for a UDIM material."""
        lv = self.maps.levels[level].detach()
        lv = lv[tile] if self.tiles else lv
        c, h, w = lv.shape
        p = decode(lv.reshape(c, -1).T)
        return {k: v.reshape(h, w, -1).cpu().numpy().astype(np.float32) for k, v in p.items()}


def _initial_raw(reference, stack) -> torch.Tensor:
    """Level-0 initial channels [8, H, W] ([T, 8, H, W] for a UDIM stack, tile by tile): base colour from the reference's off-specular response
    (pi * f*cos / cos at wi = normal, wo 60 degrees off), roughness 0.5, metalness 0.1, specular 0.5,
    flat normal."""
    if is_udim_stack(stack):  # each tile's stack holds its own texels (params override the uv)
        return torch.stack([_initial_raw(reference, tile_stack) for tile_stack in stack.stacks])
    h, w = stack.resolution
    n = h * w
    wi = torch.tensor([[0.0, 0.0, 1.0]]).expand(n, 3)
    wo = torch.tensor([[math.sin(math.pi / 3), 0.0, 0.5]]).expand(n, 3)
    with torch.no_grad():
        if stack.channels:
            vals = reference.eval(wi, wo, params=stack.texel_values(0))
        else:
            vals = reference.eval(wi[:1], wo[:1]).expand(n, 3)
    base = (vals * math.pi / 0.5).clamp(0.02, 0.98)
    raw = torch.zeros(n, len(CHANNELS))
    raw[:, 0:3] = _logit(base)
    raw[:, 3] = _logit(torch.tensor((0.5 - MIN_ROUGHNESS) / (1 - MIN_ROUGHNESS)))
    raw[:, 4] = _logit(torch.tensor(0.1))
    raw[:, 5] = 0.0
    return raw.T.reshape(len(CHANNELS), h, w).contiguous()


def fit_analytic(reference, stack, iterations: int = 300, batch: int = 4096, seed: int = 0,
                 lr: float = 3e-2, max_samples: int = 16) -> AnalyticMaterial:
    """Fit an :class:`AnalyticMaterial` to ``reference`` on ``stack``'s grid with Adam.

    Each step draws ``batch`` (wi, wo) pairs uniform in half/difference angles, uv uniform (over the
    trained tiles of a UDIM ``stack``, which gives the model one pyramid per tile) and
    MIP levels favouring fine ones; targets are the footprint-averaged reference (``max_samples``
    points at most per query), the loss the neural training's log-L1. The learning rate decays
    on a cosine from ``lr`` to ``lr/10``. Coarser levels start as box-averages of level 0.
    """

    g = torch.Generator().manual_seed(seed)
    tiles = list(stack.tiles) if is_udim_stack(stack) else None
    model = AnalyticMaterial(stack.resolution, tiles)
    init = _initial_raw(reference, stack)
    with torch.no_grad():
        for k, lv in enumerate(model.maps.levels):
            batched = init if tiles else init[None]
            src = batched if k == 0 else torch.nn.functional.adaptive_avg_pool2d(batched, lv.shape[-2:])
            lv.copy_(src if tiles else src[0])
    opt = Adam(model.parameters(), lr=lr)
    levels = model.maps.num_levels
    for step in range(iterations):
        wi, wo = half_difference_pairs(batch, g)
        uv = draw_uv(batch, tiles, g)  # uniform in [0,1]^2, or over the trained tiles (true uv)
        level = sample_levels(batch, levels, generator=g)
        with torch.no_grad():
            if stack.channels:  # every level's points in one call to the reference (its cost is per call)
                target = footprint_targets(reference, stack, wi, wo, uv, level, max_samples, g, one_call=True)
            else:
                target = reference.eval(wi, wo)
        pred = brdf(decode(model.maps.fetch(uv, level)), wi, wo)
        loss = log_l1(pred, target)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.param_groups[0]["lr"] = cosine_lr(lr, lr / 10, step, iterations)
        opt.step()
    model.final_loss = float(loss.detach()) if iterations else math.nan
    return model.train(False)


# ----------------------------------------------------------------------------- UsdPreviewSurface export


def _write_image(path: Path, img: np.ndarray) -> None:
    """Write [H, W, C] float32 as a half-float EXR (linear, raw)."""

    out = oiio.ImageOutput.create(str(path))
    if out is None:
        raise OSError(f"{path}: cannot create an image writer ({oiio.geterror()})")
    spec = oiio.ImageSpec(img.shape[1], img.shape[0], img.shape[2], "half")
    spec.attribute("oiio:ColorSpace", "Linear")
    if not out.open(str(path), spec) or not out.write_image(np.ascontiguousarray(img, dtype=np.float32)):
        raise OSError(f"{path}: cannot write ({out.geterror()})")
    out.close()


PREVIEW_TEXTURES = ("diffuseColor", "roughness", "metallic", "normal")
"""The UsdPreviewSurface inputs read from the baked maps (:func:`write_preview_textures`)."""


def author_preview_surface(stage, material_path, textures: dict, ior: float, prefix: str = "PreviewSurface",
                           render_context: str = "", surface: dict | None = None):
    """Author a UsdPreviewSurface network under ``material_path`` on ``stage`` (at its edit target) and
    connect the Material's ``outputs:surface`` (``outputs:<render_context>:surface`` when given) to it.

    ``textures``: {UsdPreviewSurface input (:data:`PREVIEW_TEXTURES`): asset path string, as the
    layer states it}. Shaders: ``<prefix>`` (UsdPreviewSurface, uniform ``ior``), ``<prefix>_st``
    (``UsdPrimvarReader_float2`` of the primvar ``st``) and ``<prefix>_<input>Texture`` (UsdUVTexture,
    ``sourceColorSpace = raw``: the maps are linear; the normal map's scale 2 / bias -1 undo its
    n * 0.5 + 0.5 encoding, tangent space). Ancestors missing on the stage are authored as ``over``.
    ``surface``: the material's emission and opacity, the manifest of
    :func:`mtlx2neural.export.surface_files.write_surface_files` with each ``file`` as the layer states it
    (None: neither), authored by :func:`_preview_surface_terms`. Returns the UsdPreviewSurface shader.
    """
    # Local: pxr loads USD's plugins on import (about 0.15 s); only USD work needs it.
    from pxr import Sdf, UsdShade

    t = Sdf.ValueTypeNames

    def shader(name):
        prim = stage.OverridePrim(Sdf.Path(str(material_path)).AppendChild(name))
        prim.SetSpecifier(Sdf.SpecifierDef)
        prim.SetTypeName("Shader")
        return UsdShade.Shader(prim)

    material = UsdShade.Material(stage.GetPrimAtPath(str(material_path)))
    surf = shader(prefix)
    surf.CreateIdAttr("UsdPreviewSurface")
    surf.CreateInput("ior", t.Float).Set(float(ior))
    material.CreateSurfaceOutput(render_context).ConnectToSource(surf.ConnectableAPI(), "surface")
    st = shader(f"{prefix}_st")
    st.CreateIdAttr("UsdPrimvarReader_float2")
    st.CreateInput("varname", t.String).Set("st")
    st_out = st.CreateOutput("result", t.Float2)

    def texture(name, asset):
        tex = shader(f"{prefix}_{name}Texture")
        tex.CreateIdAttr("UsdUVTexture")
        tex.CreateInput("file", t.Asset).Set(Sdf.AssetPath(asset))
        tex.CreateInput("sourceColorSpace", t.Token).Set("raw")
        tex.CreateInput("st", t.Float2).ConnectToSource(st_out)
        return tex

    wiring = {"diffuseColor": ("rgb", t.Color3f, t.Float3), "roughness": ("r", t.Float, t.Float),
              "metallic": ("r", t.Float, t.Float), "normal": ("rgb", t.Normal3f, t.Float3)}
    for name in PREVIEW_TEXTURES:
        out_name, in_type, out_type = wiring[name]
        tex = texture(name, textures[name])
        if name == "normal":  # stored as n * 0.5 + 0.5
            tex.CreateInput("scale", t.Float4).Set((2.0, 2.0, 2.0, 1.0))
            tex.CreateInput("bias", t.Float4).Set((-1.0, -1.0, -1.0, 0.0))
        surf.CreateInput(name, in_type).ConnectToSource(tex.CreateOutput(out_name, out_type))
    if surface:
        _preview_surface_terms(surf, surface, texture)
    return surf


def _preview_surface_terms(surf, surface: dict, texture) -> None:
    """``emissiveColor``, ``opacity`` and ``opacityThreshold`` of the UsdPreviewSurface ``surf`` from
    ``surface`` (:func:`author_preview_surface`), only what the material has.

    ``emissiveColor``: the emission map through ``<prefix>_emissionTexture`` (UsdUVTexture, ``raw``:
    linear radiance, ``outputs:rgb``), or the constant. ``opacity``: ``<prefix>_opacityTexture``'s
    ``outputs:r``, or the constant; ``opacityThreshold``: the cutoff (0.5) of a mask (a cut-out, which
    UsdPreviewSurface renderers alpha-test), 0 for a blend (a fraction). The maps wrap (``repeat``), as
    the latents do. ``texture(name, asset)`` makes the UsdUVTexture reader ``<prefix>_<name>Texture``."""
    # Local: pxr loads USD's plugins on import (about 0.15 s); only USD work needs it.
    from pxr import Gf, Sdf

    t = Sdf.ValueTypeNames

    def wrapped(name, asset):
        tex = texture(name, asset)
        for axis in ("wrapS", "wrapT"):
            tex.CreateInput(axis, t.Token).Set("repeat")
        return tex

    emission, opacity = surface.get("emission"), surface.get("opacity")
    if emission:
        emissive = surf.CreateInput("emissiveColor", t.Color3f)
        if "file" in emission:
            emissive.ConnectToSource(wrapped("emission", emission["file"]).CreateOutput("rgb", t.Float3))
        else:
            emissive.Set(Gf.Vec3f(*(float(x) for x in emission["constant"])))
    if opacity:
        value = surf.CreateInput("opacity", t.Float)
        if "file" in opacity:
            value.ConnectToSource(wrapped("opacity", opacity["file"]).CreateOutput("r", t.Float))
        else:
            value.Set(float(opacity["constant"]))
        mask = surface.get("alpha_mode") == "mask"
        surf.CreateInput("opacityThreshold", t.Float).Set(ALPHA_CUTOFF if mask else 0.0)


def write_preview_textures(model: AnalyticMaterial, folder) -> dict:
    """Bake ``model``'s level-0 maps into ``folder`` (created if needed) for a UsdPreviewSurface.

    Half-float EXR, linear (``sourceColorSpace = raw``), row 0 the top (v = 1): ``diffuseColor.exr``
    (base colour), ``roughness.exr`` (perceptual), ``metallic.exr``, ``normal.exr`` (tangent-space
    n * 0.5 + 0.5: x tangent, z the geometric normal); for a UDIM material one file per tile
    (``diffuseColor.1001.exr`` ...), returned as the ``<UDIM>`` pattern. UsdPreviewSurface has no per-texel dielectric
    F0, so the mean ``specular`` becomes its uniform ``ior`` (F0 = ((ior - 1)/(ior + 1))^2 = 0.08
    specular). Returns ``{"textures": {input: Path}, "ior": float}``.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    tiles = model.tiles or [None]
    per_tile = [model.level_maps(0, k) for k in range(len(tiles))]
    f0 = float(np.clip(0.08 * np.mean([maps["specular"].mean() for maps in per_tile]), 1e-4, 0.5))
    ior = (1 + math.sqrt(f0)) / (1 - math.sqrt(f0))
    files = {}
    for tile, maps in zip(tiles, per_tile):
        images = {"diffuseColor": maps["base"], "roughness": maps["roughness"], "metallic": maps["metalness"],
                  "normal": maps["normal"] * 0.5 + 0.5}
        for name in PREVIEW_TEXTURES:  # a UDIM material: <input>.<tile>.exr, referenced as <input>.<UDIM>.exr
            files[name] = folder / (f"{name}.exr" if tile is None else f"{name}.<UDIM>.exr")
            _write_image(folder / (f"{name}.exr" if tile is None else f"{name}.{tile}.exr"), images[name])
    return {"textures": files, "ior": ior}


# ----------------------------------------------------------------------------- saving a fitted baseline


def save_analytic(model: AnalyticMaterial, path) -> Path:
    """Save a fitted ``model`` (its maps, resolution and final loss) to ``path`` (torch format)
    atomically; :func:`load_analytic` reads it back."""
    path = Path(path)
    state = {"format": 1, "resolution": list(model.resolution), "tiles": model.tiles,
             "levels": [lv.detach().cpu().float() for lv in model.maps.levels],
             "final_loss": getattr(model, "final_loss", math.nan)}
    with atomic_path(path) as tmp:
        torch.save(state, tmp)
    return path


def load_analytic(path) -> AnalyticMaterial:
    """The :class:`AnalyticMaterial` saved at ``path`` by :func:`save_analytic` (CPU, float32);
    ``ValueError`` naming the file when it is not one."""
    try:
        state = torch.load(Path(path), map_location="cpu", weights_only=True)
        model = AnalyticMaterial(tuple(state["resolution"]), state.get("tiles"))
        with torch.no_grad():
            if len(state["levels"]) != model.maps.num_levels:
                raise ValueError(f"{len(state['levels'])} levels, expected {model.maps.num_levels}")
            for lv, saved in zip(model.maps.levels, state["levels"]):
                lv.copy_(saved)
    except (OSError, KeyError, TypeError, ValueError, RuntimeError) as exc:
        raise ValueError(f"{path}: not a saved analytic baseline ({exc})") from None
    model.final_loss = float(state.get("final_loss", math.nan))
    return model.train(False)
