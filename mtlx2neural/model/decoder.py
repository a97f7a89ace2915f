"""The neural BRDF decoder with learned shading frames.

A linear layer (no bias, no activation) maps the latent code to 6 numbers per
frame. Frame k has normal n = normalize(v0 + (0, 0, 1)) and tangent
t = normalize(v1 + (1, 0, 0)) with (v0, v1) its six numbers, and bitangent
b = n x t; the frame is deliberately not orthogonalised. ``wi`` and ``wo`` are
projected on (t, b, n) of every frame, and the projections plus the latent feed
an MLP with ReLU hidden layers whose 3 outputs pass through exp(x - 3).

``frames=0`` is the ablation without learned frames (the paper's Table 2):
the MLP sees ``wi`` and ``wo`` in the local frame as they are. The paper gives those variants "an extra
first layer with 8 neurons to roughly match the number of parameters of the full model" (its Figure 8);
``NO_FRAME_LATENT_LAYER`` (measurement only, 0 by default) is that layer here: ``latent_layer``, a Linear
+ ReLU from the latent to that many units whose outputs join the MLP's input beside the latent, in place
of the frame layer, which also reads only the latent. (Appended rather than replacing the latent, it
matches the full 3x64 decoder's parameter count to 1%: 10059 against 9955, 9475 without it; the
paper does not say which.) Such a model is not exportable (``formats.weights`` refuses it).

``forward`` returns f(wi, wo) * cos(wo) in linear RGB, for directions in the
local frame (z the geometric normal, as the reference's ``eval``). With
``analytic_cosine`` (the default for new models) the network predicts f alone and
the decoder multiplies by max(0, wo.z), so the foreshortening is exact: a learned
cosine fell off too slowly at grazing light (3-4x too bright at 89 degrees, the
terminator; docs/history/BENCHMARKS-2026-12-01.md). ``analytic_cosine=False`` is the original form, where
the network learns f * cos itself; checkpoints and exports made before the option
read as that.

``albedo_head`` adds a separate small MLP (one hidden layer as wide as the decoder's last) from
(``wi`` in the learned frames, latent) to the directional albedo at ``wi``: f * cos integrated over
``wo``, linear RGB, through exp(x - 3), no cosine factor. It takes no ``wo``, so the albedo does not
depend on the integrated direction by construction. The paper instead makes the albedo 3 more outputs
of the BRDF decoder MLP. Measured on the quality guard's material (seeds 1-4,
docs/history/paper-choices-2026-12-03.md), those outputs fit the albedo 2-6x worse (mean absolute
error 0.05-0.21 against 0.03-0.07) and the BRDF trains worse with them (HDR FLIP 0.15-0.44 against
0.11-0.28), so the separate head is kept.

``environment_head`` adds the prefiltered-lighting head (:mod:`mtlx2neural.render.prefiltered`): a
small MLP of the albedo head's shape from (``wi`` in the learned frames, latent) to 9 numbers through
exp(x - 3): the reflectance (RGB each) carried by the sharp lobe (:func:`~mtlx2neural.model.proxy.sharp_params`),
the learned sampler's specular lobe and its diffuse lobe. Lobe k's reflectance is c_k(wi) = integral of
f * cos(wo) * r_k(wo) over wo, with r_k the lobe's responsibility w_k p_k / p in the mixture of the sharp
lobe (weight :data:`~mtlx2neural.model.proxy.SHARP_WEIGHT`) and the sampler's two, the sharp lobe's kept only
where f peaks inside its cone (``train.environment_fit``); the three add up to the directional albedo. Under
distant light, outgoing radiance ~= sum of c_k E_k, with E_k the incident radiance averaged over lobe k's density
(exact when f * cos is proportional to each lobe's share of the mixture). It is fitted after the BRDF, against the reference (``train.environment_fit``). A head of
6 outputs (no sharp lobe, written before it existed) reads as one whose sharp lobe carries nothing
(:func:`mtlx2neural.formats.weights.upgrade_environment_head`).
"""

from __future__ import annotations

import torch
from torch import nn

from mtlx2neural.formats.weights import (
    ENVIRONMENT_OUTPUTS,
    OUTPUT_OFFSET,
    upgrade_environment_head,
)
from mtlx2neural.model.mlp import mlp, parse_hidden

NO_FRAME_LATENT_LAYER = 0
"""Measurement only (ablation): units of the extra latent layer of a ``frames=0`` decoder, 0 for none."""


def _upgrade_legacy_environment_head(module, state_dict, prefix, *_):
    """``load_state_dict`` pre-hook: :func:`~mtlx2neural.formats.weights.upgrade_environment_head` on the state
    being loaded (torch's own copy of it; the caller's dict is left as it was)."""
    upgrade_environment_head(state_dict, prefix + "environment.")


class BrdfDecoder(nn.Module):
    def __init__(self, latent_dim: int = 8, frames: int = 2, hidden="2x32", albedo_head: bool = False,
                 analytic_cosine: bool = True, environment_head: bool = False):
        super().__init__()
        self.latent_dim, self.frames = latent_dim, frames
        self.analytic_cosine = bool(analytic_cosine)
        self.hidden = parse_hidden(hidden)
        self.frame_layer = nn.Linear(latent_dim, 6 * frames, bias=False) if frames > 0 else None
        per_dir = 3 * max(frames, 1)  # frames=0: the raw local direction
        extra = NO_FRAME_LATENT_LAYER if frames == 0 else 0
        self.latent_layer = nn.Sequential(nn.Linear(latent_dim, extra), nn.ReLU()) if extra else None
        self.net = mlp(2 * per_dir + latent_dim + extra, self.hidden, 3)
        # Optional albedo head: directional albedo from (latent, wi in the learned frames).
        self.albedo = mlp(per_dir + latent_dim, (self.hidden[-1],), 3) if albedo_head else None
        self.environment = None
        if environment_head:
            self.add_environment_head()
        # A state written before the sharp lobe (a 6-output environment head: checkpoints, exports, the shipped
        # universal networks) loads as one whose sharp lobe carries nothing, whoever loads it.
        self.register_load_state_dict_pre_hook(_upgrade_legacy_environment_head)

    def add_environment_head(self) -> None:
        """Build the environment head (module docstring): (latent, wi in the learned frames) -> 9 values.
        ``NeuralMaterial`` calls it after building its other networks, so their initial weights (drawn
        from torch's global generator) are the same with or without it."""
        per_dir = 3 * max(self.frames, 1)
        self.environment = mlp(per_dir + self.latent_dim, (self.hidden[-1],), ENVIRONMENT_OUTPUTS)

    def shading_frames(self, latent: torch.Tensor):
        """(t, b, n), each [N, frames, 3], from the latent [N, latent_dim]."""
        v = self.frame_layer(latent).view(-1, self.frames, 6)
        n = v[..., 0:3] + v.new_tensor([0.0, 0.0, 1.0])
        t = v[..., 3:6] + v.new_tensor([1.0, 0.0, 0.0])
        n = n / n.norm(dim=-1, keepdim=True).clamp_min(1e-6)
        t = t / t.norm(dim=-1, keepdim=True).clamp_min(1e-6)
        return t, torch.linalg.cross(n, t, dim=-1), n

    @staticmethod
    def project(w: torch.Tensor, frame) -> torch.Tensor:
        """[N,3] direction -> [N, 3*frames] coordinates (t, b, n) in every frame."""
        t, b, n = frame
        w = w[:, None, :]
        return torch.stack([(w * t).sum(-1), (w * b).sum(-1), (w * n).sum(-1)], -1).flatten(1)

    def _directions(self, latent: torch.Tensor, *ws: torch.Tensor) -> list[torch.Tensor]:
        if self.frames == 0:
            return list(ws)
        frame = self.shading_frames(latent)
        return [self.project(w, frame) for w in ws]

    def forward(self, latent: torch.Tensor, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        """f(wi, wo) * max(0, wo.z) [N,3] (no horizon test on ``wi``: ``NeuralMaterial.eval`` applies it)."""
        return self.activate(self.logits(latent, wi, wo), wo)

    def logits(self, latent: torch.Tensor, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        """The MLP's raw outputs [N,3] before the output activation (:meth:`activate`)."""
        x = torch.cat([*self._directions(latent, wi, wo), latent], -1)
        if self.latent_layer is not None:  # the ablation's parameter-matching layer
            x = torch.cat([x, self.latent_layer(latent)], -1)
        return self.net(x)

    def activate(self, raw: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        """exp(min(raw, 30) - OUTPUT_OFFSET), times max(0, wo.z) with ``analytic_cosine``: f * cos [N,3]."""
        y = torch.exp(raw.clamp(max=30.0) - OUTPUT_OFFSET)
        return y * wo[:, 2:3].clamp_min(0.0) if self.analytic_cosine else y

    def predict_albedo(self, latent: torch.Tensor, wi: torch.Tensor) -> torch.Tensor:
        """Directional albedo [N,3] at ``wi`` (local frame; f * cos integrated over wo, linear RGB) from
        the separate albedo head; no ``wo`` input. RuntimeError without an albedo head."""
        if self.albedo is None:
            raise RuntimeError("this decoder was built without an albedo head")
        x = torch.cat([*self._directions(latent, wi), latent], -1)
        return torch.exp(self.albedo(x).clamp(max=30.0) - OUTPUT_OFFSET)

    def predict_lobe_reflectance(self, latent: torch.Tensor, wi: torch.Tensor) -> torch.Tensor:
        """[N, 3, 3]: the reflectance (linear RGB, no unit: f * cos integrated over wo) that the sharp lobe
        (index 0), the learned sampler's specular lobe (1) and its diffuse lobe (2) carry at ``wi`` (local
        frame), from the environment head (module docstring). RuntimeError without one."""
        if self.environment is None:
            raise RuntimeError("this decoder was built without an environment head")
        x = torch.cat([*self._directions(latent, wi), latent], -1)
        return torch.exp(self.environment(x).clamp(max=30.0) - OUTPUT_OFFSET).view(-1, 3, 3)
