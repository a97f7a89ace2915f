"""The MERL measured-BRDF file (``.binary``, Matusik et al. 2003): read, write, index and tabulate.

The file is a table of an isotropic BRDF over Rusinkiewicz's half/difference angles:

- header: three little-endian int32, the table's dimensions ``(n_theta_h, n_theta_d, n_phi_d)``;
  the measured set uses ``(90, 90, 180)``;
- then ``3 * n`` float64 values (``n`` the product of the dimensions), channel-major (every red value,
  then every green, then every blue); within a channel ``phi_d`` varies fastest, then ``theta_d``, then
  ``theta_h``;
- a stored value times its channel's scale factor (``SCALE``: 1/1500, 1.15/1500, 1.66/1500) is the BRDF
  f in 1/sr, the cosine *not* included; a negative value marks a configuration that was not measured.

Indexing follows the format's reference reader:

- ``theta_h`` in [0, pi/2] is stored on a square-root scale, index ``sqrt(theta_h / (pi/2)) * n_theta_h``,
  so that the table is dense near the specular peak;
- ``theta_d`` in [0, pi/2] linearly, index ``theta_d / (pi/2) * n_theta_d``;
- ``phi_d`` is folded into [0, pi) (reciprocity: swapping the two directions turns phi_d into
  phi_d + pi), index ``phi_d / pi * n_phi_d``.

The reference reader truncates these indices (a cell's value holds from its node up to the next);
:func:`continuous_index` returns them before truncation, so a caller may also interpolate between nodes.
The half/difference angles of a pair are computed with the *light* direction as the one that is rotated
(the format's ``in`` vector); the fold makes the choice irrelevant to the value.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from mtlx2neural.atomic import atomic_path
from mtlx2neural.errors import InputError

MERL_DIMS = (90, 90, 180)
"""The measured set's table: theta_h, theta_d, phi_d (over [0, pi))."""
SCALE = (1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0)
"""Stored value times this (per RGB channel) = BRDF in 1/sr."""
HEADER_BYTES = 12
MERL_EXTENSIONS = (".binary",)


@dataclass(frozen=True, eq=False)
class MerlTable:
    """A MERL table in BRDF units.

    ``rgb``: float64 ``[3, n_theta_h, n_theta_d, n_phi_d]``, f in 1/sr (scale factors applied), unmeasured
    entries as stored (negative); ``source``: the file it was read from, for messages."""

    rgb: np.ndarray
    source: str = ""

    @property
    def dims(self) -> tuple[int, int, int]:
        return tuple(int(d) for d in self.rgb.shape[1:])

    @property
    def missing(self) -> np.ndarray:
        """bool ``[n_theta_h, n_theta_d, n_phi_d]``: entries unmeasured in some channel (stored negative)."""
        return (self.rgb < 0).any(0)


def read_merl(path) -> MerlTable:
    """Read a MERL ``.binary`` file. ``InputError`` naming the file when it is missing, truncated, has a
    header that disagrees with its size, or holds NaN or infinite values. The file is only read."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as e:
        raise InputError(f"{path}: cannot read the MERL file ({e.strerror or e})") from None
    if len(data) < HEADER_BYTES:
        raise InputError(f"{path}: {len(data)} bytes, too short for a MERL file (a 12-byte header, then the table)")
    dims = tuple(int(d) for d in np.frombuffer(data[:HEADER_BYTES], dtype="<i4"))
    if min(dims) <= 0 or math.prod(dims) > 1 << 28:
        raise InputError(f"{path}: not a MERL file: its header gives table dimensions {dims}")
    n = math.prod(dims)
    expected = HEADER_BYTES + 3 * n * 8
    if len(data) != expected:
        raise InputError(f"{path}: the header gives a {dims[0]}x{dims[1]}x{dims[2]} table, which needs "
                         f"{expected} bytes, but the file has {len(data)} (truncated or not a MERL file)")
    values = np.frombuffer(data[HEADER_BYTES:], dtype="<f8").reshape(3, *dims)
    bad = ~np.isfinite(values)
    if bad.any():
        raise InputError(f"{path}: {int(bad.sum())} table values are NaN or infinite")
    rgb = values * np.asarray(SCALE, dtype=np.float64)[:, None, None, None]
    return MerlTable(rgb=rgb, source=str(path))


def write_merl(path, rgb) -> Path:
    """Write ``rgb`` (``[3, n_theta_h, n_theta_d, n_phi_d]``, BRDF in 1/sr, negative = unmeasured) as a MERL
    file, atomically (a reader never sees half a file). Values are divided by ``SCALE`` and stored as
    float64; :func:`read_merl` returns them within float64 rounding of the scale factors."""
    rgb = np.asarray(rgb, dtype=np.float64)
    if rgb.ndim != 4 or rgb.shape[0] != 3:
        raise ValueError(f"rgb must be [3, n_theta_h, n_theta_d, n_phi_d], got shape {list(rgb.shape)}")
    if not np.isfinite(rgb).all():
        raise ValueError("rgb holds NaN or infinite values")
    stored = rgb / np.asarray(SCALE, dtype=np.float64)[:, None, None, None]
    path = Path(path)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(np.asarray(rgb.shape[1:], dtype="<i4").tobytes())
            f.write(np.ascontiguousarray(stored, dtype="<f8").tobytes())
            f.flush()
            os.fsync(f.fileno())
    return path


# ----------------------------------------------------------------------------- half/difference angles


def half_difference_angles(wi: torch.Tensor, wo: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Rusinkiewicz's ``(theta_h, theta_d, phi_d)`` [N] in radians of unit directions ``wi`` (to the viewer)
    and ``wo`` (to the light), [N,3] in the local frame (z the normal). ``wo`` is the rotated vector:
    the difference vector is ``wo`` rotated by -phi_h about the normal, then by -theta_h about the
    binormal. Polar angles are computed with ``atan2``, exact near the pole where ``acos`` is not."""
    h = wi + wo
    h = h / h.norm(dim=-1, keepdim=True).clamp_min(1e-30)
    rho = torch.hypot(h[:, 0], h[:, 1])
    theta_h = torch.atan2(rho, h[:, 2])
    # cos/sin of phi_h; along the normal the azimuth is arbitrary: take phi_h = 0
    safe = rho > 0
    cp = torch.where(safe, h[:, 0] / rho.clamp_min(1e-30), torch.ones_like(rho))
    sp = torch.where(safe, h[:, 1] / rho.clamp_min(1e-30), torch.zeros_like(rho))
    x = wo[:, 0] * cp + wo[:, 1] * sp  # rotate by -phi_h about z
    y = -wo[:, 0] * sp + wo[:, 1] * cp
    z = wo[:, 2]
    ct, st = h[:, 2], rho  # cos and sin of theta_h
    dx = x * ct - z * st  # rotate by -theta_h about y
    dz = x * st + z * ct
    theta_d = torch.atan2(torch.hypot(dx, y), dz)
    phi_d = torch.atan2(y, dx)
    return theta_h, theta_d, phi_d


def continuous_index(theta_h: torch.Tensor, theta_d: torch.Tensor, phi_d: torch.Tensor,
                     dims: tuple[int, int, int] = MERL_DIMS) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The table's indices of the angles before truncation (module docstring): ``theta_h`` on the square-root
    scale, ``theta_d`` linear, ``phi_d`` folded into [0, pi) then linear. Not clamped: the reference
    reader truncates and clamps to ``[0, n - 1]``."""
    half_pi = 0.5 * math.pi
    ih = torch.sqrt((theta_h / half_pi).clamp_min(0.0)) * dims[0]
    idd = theta_d / half_pi * dims[1]
    phi = torch.where(phi_d < 0, phi_d + math.pi, phi_d)
    phi = torch.where(phi >= math.pi, phi - math.pi, phi)
    ip = phi / math.pi * dims[2]
    return ih, idd, ip


def node_angles(dims: tuple[int, int, int] = MERL_DIMS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The angles (radians, float64) of the table's nodes, where the reference reader's cells begin:
    ``theta_h[i] = (i / n)^2 pi/2``, ``theta_d[j] = j / n pi/2``, ``phi_d[k] = k / n pi``."""
    i, j, k = (np.arange(d, dtype=np.float64) for d in dims)
    return (i / dims[0]) ** 2 * (0.5 * math.pi), j / dims[1] * (0.5 * math.pi), k / dims[2] * math.pi


def directions_of(theta_h, theta_d, phi_d) -> tuple[torch.Tensor, torch.Tensor]:
    """The inverse of :func:`half_difference_angles` with phi_h = 0: unit ``(wi, wo)`` [N,3] (float64 for
    float64 input) whose half/difference angles are the given ones. Either may lie below the horizon."""
    th, td, pd = (torch.as_tensor(a, dtype=torch.float64).reshape(-1) for a in (theta_h, theta_d, phi_d))
    d = torch.stack([td.sin() * pd.cos(), td.sin() * pd.sin(), td.cos()], -1)
    ct, st = th.cos(), th.sin()
    wo = torch.stack([d[:, 0] * ct + d[:, 2] * st, d[:, 1], -d[:, 0] * st + d[:, 2] * ct], -1)  # +theta_h about y
    h = torch.stack([st, torch.zeros_like(st), ct], -1)
    wi = 2.0 * (wo * h).sum(-1, keepdim=True) * h - wo
    return wi, wo


def tabulate(brdf, dims: tuple[int, int, int] = MERL_DIMS, chunk: int = 1 << 16) -> np.ndarray:
    """A MERL table ``[3, *dims]`` (1/sr) of ``brdf(wi, wo) -> [N, 3]``, f without the cosine, evaluated at
    every node's directions (:func:`directions_of`, float64). Nodes with a direction at or below the
    horizon are stored as unmeasured (-1), as the measured set does for configurations it could not reach."""
    th, td, pd = node_angles(dims)
    grid = np.stack(np.meshgrid(th, td, pd, indexing="ij"), 0).reshape(3, -1)
    out = np.empty((3, grid.shape[1]), dtype=np.float64)
    for s in range(0, grid.shape[1], chunk):
        wi, wo = directions_of(*grid[:, s:s + chunk])
        f = torch.as_tensor(brdf(wi, wo)).double().reshape(-1, 3)
        above = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        out[:, s:s + chunk] = torch.where(above[:, None], f, torch.full_like(f, -1.0)).T.cpu().numpy()
    return out.reshape(3, *dims)
