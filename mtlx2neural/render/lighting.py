"""Lights for evaluation renders: directional lights and importance-sampled lat-long environment maps.

Conventions (world space, right-handed, **y up**; directions point *away from*
the surface, towards the light):

- :class:`DirectionalLight`: ``direction`` towards the light (normalised here) and
  ``intensity``, the irradiance it delivers to a surface facing it (linear RGB, a
  scalar or 3 values). Its contribution at a point is ``eval(wi, wo) * intensity``.
- :class:`EnvironmentMap`: an equirectangular (lat-long) radiance image ``[H, W, 3]``,
  linear RGB, row 0 at the top. For a unit direction d: theta = acos(d.y) (0 = up),
  phi = atan2(d.x, -d.z); column coordinate u = 0.5 + phi / 2pi and row coordinate
  v = theta / pi, both in [0, 1]. So the image centre looks along -z, u = 0.75
  along +x, the top row is the zenith. Radiance is piecewise constant per pixel
  (nearest lookup).
- Importance sampling: a pixel is drawn with probability proportional to its
  luminance (Rec. 709) times sin(theta at the pixel centre), then a point is
  drawn uniformly in (u, v) inside the pixel; the solid-angle density is
  ``p_pixel * H * W / (2 pi^2 sin theta)``. :meth:`EnvironmentMap.sample` takes 3
  uniform numbers per sample so a fixed seed gives the same directions to every
  material rendered with it (common random numbers).
- No visibility: every light reaches every point above the local horizon (no
  shadows, no interreflection).

The MaterialX resources ship only pre-filtered ``Lights/irradiance/*.hdr`` maps
(256 x 128); they are smooth but serve as environments all the same.
:meth:`EnvironmentMap.sky` is a procedural fallback (sky gradient, dark ground
and a small sun disc) so nothing depends on files.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import torch

from mtlx2neural.errors import InputError

LUMA = (0.2126, 0.7152, 0.0722)


@dataclass(frozen=True)
class DirectionalLight:
    """A distant light (module docstring): ``direction`` towards the light, irradiance ``intensity``."""

    direction: tuple = (0.4, 0.7, 0.6)
    intensity: float | tuple = 3.0

    def vector(self) -> torch.Tensor:
        return torch.nn.functional.normalize(torch.tensor(self.direction, dtype=torch.float32), dim=0)

    def rgb(self) -> torch.Tensor:
        return torch.as_tensor(self.intensity, dtype=torch.float32).expand(3)


def direction_to_uv(d: torch.Tensor) -> torch.Tensor:
    """Unit directions [N,3] -> lat-long (u, v) [N,2] in [0, 1] (module docstring)."""
    u = 0.5 + torch.atan2(d[:, 0], -d[:, 2]) / (2 * math.pi)
    v = torch.acos(d[:, 1].clamp(-1, 1)) / math.pi
    return torch.stack([u, v], -1)


def uv_to_direction(uv: torch.Tensor) -> torch.Tensor:
    """Lat-long (u, v) [N,2] -> unit directions [N,3]; inverse of :func:`direction_to_uv`."""
    phi = 2 * math.pi * (uv[:, 0] - 0.5)
    theta = math.pi * uv[:, 1]
    s = torch.sin(theta)
    return torch.stack([s * torch.sin(phi), torch.cos(theta), -s * torch.cos(phi)], -1)


class EnvironmentMap:
    """A lat-long environment light with luminance x sin(theta) importance sampling (module docstring)."""

    def __init__(self, image, scale: float = 1.0, name: str = "environment"):
        img = torch.as_tensor(np.asarray(image, dtype=np.float32)).clamp_min(0) * scale
        if img.dim() != 3 or img.shape[2] != 3 or min(img.shape[:2]) < 1:
            raise ValueError(f"{name}: expected an [H, W, 3] image, got {tuple(img.shape)}")
        self.image, self.name = img, name
        self.height, self.width = img.shape[:2]
        theta = (torch.arange(self.height, dtype=torch.float64) + 0.5) / self.height * math.pi
        lum = (img.double() * torch.tensor(LUMA, dtype=torch.float64)).sum(-1)
        w = lum * torch.sin(theta)[:, None]
        if float(w.sum()) <= 0:  # an all-black map: sample uniformly in (u, v) so pdf stays defined
            w = torch.sin(theta)[:, None].expand(self.height, self.width).clone()
        self.p_pixel = (w / w.sum()).reshape(-1)  # float64 [H*W]
        self.cdf = torch.cumsum(self.p_pixel, 0)
        self.cdf[-1] = 1.0

    @classmethod
    def from_file(cls, path, scale: float = 1.0) -> EnvironmentMap:
        """Read an HDR/EXR lat-long map with OpenImageIO (first 3 channels; 1 channel is grey)."""

        path = Path(path)
        if not path.is_file():
            raise InputError(f"{path}: no such environment map; pass an existing .hdr/.exr file or 'sky'")
        inp = oiio.ImageInput.open(str(path))
        if inp is None:
            raise InputError(f"{path}: OpenImageIO cannot open the environment map ({oiio.geterror()})")
        try:
            px = inp.read_image(0, 0, 0, -1, "float")
        finally:
            inp.close()
        if px is None or px.ndim != 3:
            raise InputError(f"{path}: cannot read pixels from the environment map")
        px = np.repeat(px[..., :1], 3, -1) if px.shape[2] < 3 else px[..., :3]
        return cls(px, scale, name=str(path))

    @classmethod
    def sky(cls, height: int = 64, width: int = 128, sun_azimuth: float = 30.0, sun_elevation: float = 45.0,
            sun_radius: float = 4.0, sun_irradiance: float = 2.0) -> EnvironmentMap:
        """A procedural sky: blue-to-white gradient above the horizon, dim ground below, and a sun disc.

        The sun sits at ``sun_azimuth``/``sun_elevation`` degrees (the camera's
        convention: azimuth 0 = +z, 90 = +x) with angular radius ``sun_radius``
        degrees (at least the pixel nearest its centre) and roughly delivers
        ``sun_irradiance`` to a surface facing it.
        """
        v = (torch.arange(height) + 0.5) / height
        u = (torch.arange(width) + 0.5) / width
        uv = torch.stack(torch.meshgrid(u, v, indexing="xy"), -1).reshape(-1, 2)
        d = uv_to_direction(uv)
        y = d[:, 1:2]
        zenith, horizon = torch.tensor([0.25, 0.45, 0.9]), torch.tensor([0.9, 0.9, 0.95])
        up = torch.clamp(y, 0, 1) ** 0.5
        img = torch.where(y > 0, horizon + (zenith - horizon) * up, torch.tensor([0.12, 0.1, 0.08]))
        az, el = math.radians(sun_azimuth), math.radians(sun_elevation)
        s = torch.tensor([math.sin(az) * math.cos(el), math.sin(el), math.cos(az) * math.cos(el)])
        cos_d = d @ s
        disc = cos_d >= math.cos(math.radians(sun_radius))
        disc[torch.argmax(cos_d)] = True
        solid = (2 * math.pi / width) * (math.pi / height) * torch.sin(math.pi * uv[:, 1])
        radiance = sun_irradiance / float(solid[disc].sum())
        img[disc] = torch.tensor([1.0, 0.95, 0.85]) * radiance
        return cls(img.view(height, width, 3).numpy(), name="sky")

    def _pixel(self, d: torch.Tensor) -> torch.Tensor:
        uv = direction_to_uv(d)
        col = (uv[:, 0] * self.width).long().clamp(0, self.width - 1)
        row = (uv[:, 1] * self.height).long().clamp(0, self.height - 1)
        return row * self.width + col

    def radiance(self, d: torch.Tensor) -> torch.Tensor:
        """Radiance [N,3] arriving from unit world directions ``d`` [N,3] (nearest pixel)."""
        return self.image.reshape(-1, 3)[self._pixel(d)]

    def _density(self, pix: torch.Tensor, sin_theta: torch.Tensor) -> torch.Tensor:
        p = self.p_pixel[pix].float() * (self.height * self.width)
        return p / (2 * math.pi ** 2 * sin_theta.clamp_min(1e-7))

    def pdf(self, d: torch.Tensor) -> torch.Tensor:
        """Solid-angle density [N] of :meth:`sample` at unit world directions ``d``."""
        sin_theta = torch.sqrt((1 - d[:, 1] ** 2).clamp_min(0))
        return self._density(self._pixel(d), sin_theta)

    def sample(self, u: torch.Tensor):
        """3 uniforms per sample [N,3] -> (directions [N,3], radiance / pdf [N,3], pdf [N])."""
        pix = torch.searchsorted(self.cdf, u[:, 0].double().clamp(0, 1 - 1e-12), right=True)
        pix = pix.clamp(max=self.height * self.width - 1)
        row, col = pix // self.width, pix % self.width
        uv = torch.stack([(col + u[:, 1]) / self.width, (row + u[:, 2]) / self.height], -1).float()
        d = uv_to_direction(uv)
        pdf = self._density(pix, torch.sin(math.pi * uv[:, 1]))
        weight = self.image.reshape(-1, 3)[pix] / pdf.clamp_min(1e-20)[:, None]
        return d, torch.where(pdf[:, None] > 0, weight, torch.zeros_like(weight)), pdf

    def irradiance(self, normal=(0.0, 1.0, 0.0), n_theta: int = 8, n_phi: int = 8) -> torch.Tensor:
        """Irradiance [3] on a surface with unit world ``normal``: integral of L max(0, cos) dw, by
        a midpoint rule with ``n_theta`` x ``n_phi`` points per pixel (exact up to that quadrature)."""
        h, w = self.height * n_theta, self.width * n_phi
        uv = torch.stack(torch.meshgrid((torch.arange(w, dtype=torch.float64) + 0.5) / w,
                                        (torch.arange(h, dtype=torch.float64) + 0.5) / h, indexing="xy"), -1)
        d = uv_to_direction(uv.reshape(-1, 2))
        cos = (d @ torch.tensor(normal, dtype=torch.float64)).clamp_min(0)
        dw = (2 * math.pi / w) * (math.pi / h) * torch.sin(math.pi * uv.reshape(-1, 2)[:, 1])
        L = self.radiance(d.float()).double()
        return ((cos * dw)[:, None] * L).sum(0).float()
