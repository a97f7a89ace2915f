"""Prefiltered environment lighting: shade distant light from the model's lobes, no noise.

A neural material with an environment head (:mod:`mtlx2neural.model.decoder`) shades an environment as

    L_out(wi) = c_sharp(wi) E_sharp + c_spec(wi) E_spec + c_diff(wi) E_diff,

with c_k the reflectance that lobe k carries (linear RGB, fitted against the reference:
``train.environment_fit``) and E_k the incident radiance averaged over lobe k's density
(:mod:`mtlx2neural.model.proxy`: the sharp lobe, the learned sampler's anisotropic GGX lobe reflected
about ``wi``, its tilted cosine lobe).
A lobe direction below the geometric horizon reads the environment at its mirror image above it
(z -> -z): the material reflects nothing from below, and a grazing lobe then still averages all its
lookups (the few directions left above the horizon alone flicker on a bright source; the mirror images
lie near the horizon, where the grazing lobe's reflection looks).

E_sharp is one filtered lookup along the sharp lobe's centre (:func:`~mtlx2neural.model.proxy.sharp_direction`)
over :data:`~mtlx2neural.model.proxy.SHARP_SOLID_ANGLE`: a near-mirror reflection of the environment.
E_spec is a deterministic quadrature, the same at every pixel (no per-pixel random numbers, so no
sparkle): ``samples`` directions of the specular lobe from a rank-1 lattice (the R2 sequence), each read from a
prefiltered copy of the environment at the level whose texels cover the direction's share of the lobe
(filtered importance sampling: a sample stands for the solid angle 1 / (samples * pdf), read
:data:`LOD_BIAS` levels coarser), but no finer than the level :data:`LATTICE_FINEST_WIDTH` texels wide. The MaterialX
node (``codegen/templates/neural_bsdf.glsl.in``) does the same with the viewer's MIP chain; this module is
its torch twin, for ``render --env-mode prefiltered`` and for the measurements. E_diff is the map's irradiance /
pi along the diffuse lobe's axis, from the map convolved with the clamped cosine (:func:`irradiance_image`),
what the node reads from the viewer's irradiance map (a 16-direction lattice over the cosine lobe instead showed
the sky's horizon as a band: HDR FLIP 0.108 against 0.073 on the sample Plastic).

:class:`EnvironmentPyramid`: the lat-long map (:class:`.lighting.EnvironmentMap`'s conventions) and
coarser levels, each texel the solid-angle weighted mean of the 2 x 2 texels below (rows weighted by
their exact solid angle, :func:`row_solid_angles`), so every level keeps the map's integral exactly; lookups are bilinear within a level (wrapping in
longitude, clamped at the poles) and linear between levels.

:class:`PrefilteredEnvironment` is a light for :func:`.renderer.render_scene`: materials with an
environment head are shaded by :func:`prefiltered_radiance`, the others (a reference) by the map's
usual Monte-Carlo estimate.
"""

from __future__ import annotations

import math

import torch

from mtlx2neural.model import proxy
from mtlx2neural.render.lighting import EnvironmentMap, direction_to_uv, uv_to_direction

LATTICE = (0.7548776662466927, 0.5698402909980532)
"""The R2 sequence's increments: point j of a lattice is frac(0.5 + j * LATTICE)."""
DEFAULT_SAMPLES = 16
"""Lattice directions per lobe (the MaterialX node's ``env_samples`` default)."""
MIN_WIDTH = 8
"""The coarsest pyramid level is at least this many texels wide."""
LOD_BIAS = 1.0
"""Levels added to each lookup's footprint level: a texel then covers about twice the sample's share of
the lobe on each axis, so neighbouring samples' footprints overlap and a small bright source spreads
over the lobe instead of showing as separate spots (filtered importance sampling's usual +1)."""
LATTICE_FINEST_WIDTH = 64
"""E_spec's lookups read no finer level than the one this many texels wide (5.6 degrees a texel): the MaterialX
node then reads two levels per lookup, not every level (its frame time halves on the sample Plastic), and
what is narrower is the sharp lobe's to carry."""


def lattice(samples: int, device=None) -> torch.Tensor:
    """[samples, 2] points of the rank-1 lattice in [0, 1)^2 (the R2 sequence from 0.5)."""
    j = torch.arange(samples, dtype=torch.float64, device=device)[:, None]
    return torch.frac(0.5 + j * torch.tensor(LATTICE, dtype=torch.float64, device=device)).float()


IRRADIANCE_SIZE = (64, 128)
"""Rows and columns of the irradiance map (:func:`irradiance_image`): what the torch twin reads and what
``glsl_render.irradiance_map`` writes for the MaterialX viewer, bilinear in both."""
IRRADIANCE_SOURCE_WIDTH = 128
"""The radiance map is averaged down to at most this width (solid-angle weighted) before the cosine
convolution: the clamped cosine is smooth, so coarser texels change the result by far less than 1 %."""


def irradiance_image(image, height: int = IRRADIANCE_SIZE[0], width: int = IRRADIANCE_SIZE[1]) -> torch.Tensor:
    """[height, width, 3] float32: a lat-long radiance map's ([H, W, 3], :class:`.lighting.EnvironmentMap`'s
    layout) irradiance / pi on a surface facing each texel centre's direction, by direct quadrature: the
    texels' radiance times max(0, n . d) times their exact solid angle, normalised by the same sum over
    the clamped cosine alone (pi analytically), so that a constant map gives its radiance exactly.

    Direct quadrature, not the usual order-2 spherical harmonics: their truncation gives a surface facing
    away from a small bright source (the sky's sun) about 6 % of the sun's peak irradiance, where the
    answer is 0 (a visibly bright band across a sphere's dark side)."""
    img = torch.as_tensor(image, dtype=torch.float32)[..., :3]
    while img.shape[1] > IRRADIANCE_SOURCE_WIDTH and img.shape[0] % 2 == 0 and img.shape[1] % 2 == 0:
        img = halve(img)
    h, w = img.shape[:2]
    d_src = _texel_directions(h, w)
    area = (row_solid_angles(h)[:, None] * (2.0 * math.pi / w)).expand(h, w).reshape(-1)
    n = _texel_directions(height, width)
    kernel = (n @ d_src.T).clamp_min(0.0) * area  # [height * width, h * w]
    irr = (kernel @ img.reshape(-1, 3)) / kernel.sum(1, keepdim=True).clamp_min(1e-12)
    return irr.reshape(height, width, 3)


def _texel_directions(height: int, width: int) -> torch.Tensor:
    """[height * width, 3] unit directions of a lat-long map's texel centres (row-major)."""
    v, u = torch.meshgrid((torch.arange(height, dtype=torch.float64) + 0.5) / height,
                          (torch.arange(width, dtype=torch.float64) + 0.5) / width, indexing="ij")
    return uv_to_direction(torch.stack([u, v], -1).reshape(-1, 2)).float()


def halve(level: torch.Tensor) -> torch.Tensor:
    """A lat-long map [H, W, 3] (H, W even) at half its size, each texel the solid-angle weighted mean of the
    2 x 2 below (rows weighted by their exact solid angle), so the map's integral is kept exactly."""
    rows = row_solid_angles(level.shape[0])[:, None, None]
    weighted = (level * rows).view(level.shape[0] // 2, 2, level.shape[1] // 2, 2, 3).sum((1, 3))
    norm = 2.0 * rows.view(-1, 2, 1, 1).sum(1)  # two texels per row
    return weighted / norm.clamp_min(1e-12)


def bilinear(img: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
    """[N, 3] bilinear lookup of a lat-long map [H, W, 3] at ``uv`` [N, 2] (texel centres at half-integers),
    wrapping in longitude and clamped at the poles."""
    h, w = img.shape[:2]
    x = uv[:, 0] * w - 0.5
    y = (uv[:, 1] * h - 0.5).clamp(0.0, h - 1.0)
    x0, y0 = torch.floor(x), torch.floor(y)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    x0, y0 = x0.long(), y0.long()
    x1, y1 = (x0 + 1) % w, (y0 + 1).clamp(max=h - 1)
    x0 = x0 % w
    top = img[y0, x0] * (1 - fx) + img[y0, x1] * fx
    bottom = img[y1, x0] * (1 - fx) + img[y1, x1] * fx
    return top * (1 - fy) + bottom * fy


def row_solid_angles(height: int) -> torch.Tensor:
    """[height] the solid angle of one texel's row band of a lat-long map, per unit of longitude
    (cos theta_top - cos theta_bottom, row 0 at the zenith): a row of ``width`` texels covers
    2 pi / width times this each."""
    edges = torch.cos(torch.arange(height + 1, dtype=torch.float64) / height * math.pi)
    return (edges[:-1] - edges[1:]).float()


class EnvironmentPyramid:
    """A lat-long environment and its solid-angle-weighted coarser levels (module docstring)."""

    def __init__(self, env: EnvironmentMap):
        self.env = env
        self.irradiance_map = irradiance_image(env.image)
        level = env.image
        self.levels = [level]
        while level.shape[0] % 2 == 0 and level.shape[1] % 2 == 0 and level.shape[1] // 2 >= MIN_WIDTH:
            level = halve(level)
            self.levels.append(level)

    def level_of(self, d: torch.Tensor, solid_angle: torch.Tensor) -> torch.Tensor:
        """[N] the fractional level whose texels at unit world directions ``d`` [N,3] cover ``solid_angle``
        [N] steradians (0: the map itself), clamped to the pyramid."""
        h, w = self.levels[0].shape[:2]
        sin = torch.sqrt((1.0 - d[:, 1] ** 2).clamp_min(0.0)).clamp_min(1.0 / h)
        texel = (2.0 * math.pi / w) * (math.pi / h) * sin
        lod = 0.5 * torch.log2((solid_angle / texel).clamp_min(1e-30)) + LOD_BIAS
        return lod.clamp(0.0, len(self.levels) - 1.0)

    def finest_for_width(self, width: int) -> int:
        """The index of the finest level at most ``width`` texels wide (the coarsest level if none is)."""
        return next((k for k, level in enumerate(self.levels) if level.shape[1] <= width), len(self.levels) - 1)

    def irradiance(self, d: torch.Tensor) -> torch.Tensor:
        """[N,3] irradiance / pi on surfaces facing unit world directions ``d`` [N,3]: a bilinear lookup of
        :func:`irradiance_image`, as the MaterialX node reads the viewer's irradiance map
        (``glsl_render.irradiance_map`` writes the same image)."""
        return bilinear(self.irradiance_map, direction_to_uv(d.float())).to(d.dtype)

    def lookup(self, d: torch.Tensor, lod: torch.Tensor) -> torch.Tensor:
        """Radiance [N,3] along unit world directions ``d`` [N,3] at fractional levels ``lod`` [N]."""
        uv = direction_to_uv(d)
        lod = lod.clamp(0.0, len(self.levels) - 1.0)
        k0 = torch.floor(lod).long()
        out = torch.zeros(d.shape[0], 3, dtype=self.levels[0].dtype)
        for k in torch.unique(k0).tolist():
            rows = (k0 == k).nonzero()[:, 0]
            f = (lod[rows] - k)[:, None]
            value = bilinear(self.levels[k], uv[rows])
            if k + 1 < len(self.levels):
                value = value * (1 - f) + bilinear(self.levels[k + 1], uv[rows]) * f
            out[rows] = value
        return out


def _lobe_mean(pyramid: EnvironmentPyramid, basis, wo: torch.Tensor, pdf: torch.Tensor, samples: int,
               finest: int = 0) -> torch.Tensor:
    """[N,3] mean radiance over a lobe's ``samples`` directions per point (``wo`` [N, S, 3] local, ``pdf``
    [N, S] their density in the lobe), those below the horizon mirrored above it, read no finer than level
    ``finest``; 0 where none has a density."""
    t, b, n = basis
    wo = torch.cat([wo[..., :2], wo[..., 2:].abs()], -1)
    world = wo[..., 0:1] * t[:, None] + wo[..., 1:2] * b[:, None] + wo[..., 2:3] * n[:, None]
    world = world / world.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    flat = world.reshape(-1, 3)
    lod = pyramid.level_of(flat, 1.0 / (samples * pdf.reshape(-1).clamp_min(1e-12))).clamp_min(float(finest))
    radiance = pyramid.lookup(flat.to(pyramid.levels[0].dtype), lod).view(*wo.shape[:2], 3)
    valid = (pdf > 0).to(radiance.dtype)
    count = valid.sum(1, keepdim=True)
    return (radiance.to(wo.dtype) * valid[..., None]).sum(1) / count.clamp_min(1.0)


def lobe_means(pyramid: EnvironmentPyramid, basis, wi: torch.Tensor, params: proxy.ProxyParams,
               samples: int = DEFAULT_SAMPLES) -> torch.Tensor:
    """[N, 3, 3]: E_sharp, E_spec and E_diff (module docstring) at the points whose shading frames are
    ``basis`` = (tangent, bitangent, normal) [N,3] each in world space, viewer ``wi`` [N,3] local. E_diff is the
    map's irradiance / pi along the diffuse lobe's axis (:meth:`EnvironmentPyramid.irradiance`: the cosine
    lobe's mean, up to the lobe's part below the horizon), as the MaterialX node reads the viewer's irradiance map."""
    n, s = wi.shape[0], samples
    u = lattice(s, wi.device).to(wi.dtype).repeat(n, 1)
    rep = proxy.ProxyParams(*(v.repeat_interleave(s, 0) for v in (params.alpha, params.rho, params.slope_spec,
                                                                 params.slope_diff, params.w_spec)))
    wi_r = wi.repeat_interleave(s, 0)
    spec = proxy.sample_specular(wi_r, rep, u)
    spec = spec / spec.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    e_spec = _lobe_mean(pyramid, basis, spec.view(n, s, 3), proxy.pdf_specular(wi_r, spec, rep).view(n, s), s,
                        finest=pyramid.finest_for_width(LATTICE_FINEST_WIDTH))
    sharp = proxy.sharp_direction(wi, params)
    sharp = sharp / sharp.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    e_sharp = _lobe_mean(pyramid, basis, sharp[:, None], torch.full_like(sharp[:, :1], 1.0 / proxy.SHARP_SOLID_ANGLE), 1)
    t, b, nrm = basis
    axis = proxy.slope_axis(params.slope_diff)
    e_diff = pyramid.irradiance(axis[:, :1] * t + axis[:, 1:2] * b + axis[:, 2:] * nrm)
    return torch.stack([e_sharp, e_spec, e_diff.to(e_spec.dtype)], 1)


def prefiltered_radiance(material, pyramid: EnvironmentPyramid, basis, wi: torch.Tensor, at=None,
                         samples: int = DEFAULT_SAMPLES) -> torch.Tensor:
    """[N,3] radiance towards ``wi`` (local, to the viewer) reflected from the environment by ``material``
    (a model with an environment head: :meth:`~mtlx2neural.model.neural_material.NeuralMaterial.environment_lobes`)
    at ``at``; ``basis`` as :func:`lobe_means`. 0 where wi is at or below the horizon."""
    with torch.no_grad():
        wi, params, c = material.environment_lobes(wi, at)
        e = lobe_means(pyramid, basis, wi, params, samples)
    return (c * e.to(c.dtype)).sum(1)


def has_environment_head(material) -> bool:
    """Whether ``material`` can be shaded by :func:`prefiltered_radiance`."""
    return bool(getattr(material, "has_environment_head", False))


class PrefilteredEnvironment:
    """An environment light that materials with an environment head shade by :func:`prefiltered_radiance`
    (``samples`` lattice directions per lobe) and the others by ``env``'s Monte-Carlo estimate."""

    def __init__(self, env: EnvironmentMap, samples: int = DEFAULT_SAMPLES):
        self.env, self.samples = env, int(samples)
        self.pyramid = EnvironmentPyramid(env)
        self.name = env.name

    def shade(self, material, frame, wi: torch.Tensor, at) -> torch.Tensor:
        """[N,3] :func:`prefiltered_radiance` at the hits ``frame`` (a :class:`.geometry.Hits`)."""
        basis = (frame.tangent, frame.bitangent, frame.normal)
        return prefiltered_radiance(material, self.pyramid, basis, wi, at, self.samples)
