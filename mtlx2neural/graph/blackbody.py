"""Torch operator for MaterialX's ``blackbody`` node (pbrlib): the colour of a blackbody radiator.

``temperature`` in kelvin, clamped to [800, 25000].  The chromaticity (x, y) on the Planckian locus comes
from the cubic fits of Kang et al. (2002) in 1000/T and in x (three pieces, split at 2222 K and 4000 K),
the colour is XYZ = (x / y, 1, (1 - x - y) / y), i.e. luminance Y = 1, converted to linear Rec.709 RGB with
the sRGB (D65) matrix, negative channels clamped to 0.  A non-positive y gives white (1, 1, 1).  The
result is a relative colour (Y = 1), not a radiance: MaterialX's node is the same.  Float32 throughout,
with the coefficients as MaterialX's code writes them.
"""

from __future__ import annotations

import torch

from mtlx2neural.graph.ops import op

# Kang et al. (2002): x(t), t = 1000 / T, for T < 4000 K and T >= 4000 K (cubic, constant last).
_X_LOW = (-0.2661239, -0.2343580, 0.8776956, 0.179910)
_X_HIGH = (-3.0258469, 2.1070379, 0.2226347, 0.240390)
# y(x) for T < 2222 K, 2222 K <= T < 4000 K, T >= 4000 K.
_Y_LOW = (-1.1063814, -1.34811020, 2.18555832, -0.20219683)
_Y_MID = (-0.9549476, -1.37418593, 2.09137015, -0.16748867)
_Y_HIGH = (3.0817580, -5.87338670, 3.75112997, -0.37001483)
# CIE XYZ -> linear Rec.709 (rows: R, G, B).
_XYZ_TO_REC709 = ((3.2406, -1.5372, -0.4986), (-0.9689, 1.8758, 0.0415), (0.0557, -0.2040, 1.0570))


def _cubic(c, x, x2, x3):
    return c[0] * x3 + c[1] * x2 + c[2] * x + c[3]


def blackbody(temperature: torch.Tensor) -> torch.Tensor:
    """Linear Rec.709 colour [B, 3] (luminance-normalised, Y = 1) of a blackbody at ``temperature`` [B, 1]
    kelvin (clamped to [800, 25000])."""
    T = temperature.clamp(800.0, 25000.0)
    t = 1000.0 / T
    t2 = t * t
    t3 = t * t * t
    xc = torch.where(T < 4000.0, _cubic(_X_LOW, t, t2, t3), _cubic(_X_HIGH, t, t2, t3))
    x2 = xc * xc
    x3 = xc * xc * xc
    yc = torch.where(T < 2222.0, _cubic(_Y_LOW, xc, x2, x3),
                     torch.where(T < 4000.0, _cubic(_Y_MID, xc, x2, x3), _cubic(_Y_HIGH, xc, x2, x3)))
    ok = yc > 0.0
    y_safe = torch.where(ok, yc, torch.ones_like(yc))
    xyz = torch.cat([xc / y_safe, torch.ones_like(xc), (1.0 - xc - yc) / y_safe], -1)
    m = torch.tensor(_XYZ_TO_REC709, dtype=xyz.dtype, device=xyz.device)
    rgb = (xyz[:, None, :] * m[None]).sum(-1).clamp_min(0.0)
    return torch.where(ok, rgb, torch.ones_like(rgb))


op("blackbody")(lambda a, n: blackbody(a["temperature"]))
