"""Every training loss: the decoder's BRDF loss, the sampler's KL loss and the albedo head's loss.

Conventions shared by all three (the reference's contract, :mod:`mtlx2neural.contract`):

* BRDF values are *cosine-weighted*: ``f(wi, wo) * max(0, wo.z)``, ``[N, 3]`` linear RGB, as
  :meth:`ReferenceMaterial.eval` and the decoder return them (the trainer's targets are the
  footprint-filtered, mollified reference values of that kind: :mod:`mtlx2neural.train.targets`).
* Directions ``wi`` (to the viewer) and ``wo`` (to the light) are unit ``[N, 3]`` vectors in the
  local shading frame: z the shading normal (z-up), x the tangent.
* Densities are per steradian of ``wo`` (no cosine).
* Each loss is a scalar mean over the batch (the KL: a weighted sum whose weights sum to 1).

**BRDF** (:func:`log_l1`): L1 between log(1 + x / EPS) of prediction and target. The log
compresses the huge dynamic range of near-specular lobes (values of 1e3 and more next to 1e-3),
so one near-delta sample cannot dominate a batch with a gradient spike, and the offset EPS keeps
the log finite and its gradient bounded (<= 1/EPS) where the target is black. Dividing by EPS
makes the loss linear below EPS and logarithmic above it.

**The quantile it seeks** (``tau``): log-L1 is minimised by the median of noisy targets. A textured target
is the mean of a few footprint points, a right-skewed estimate wherever a footprint mixes a lobe's peak with
its surroundings, so its median lies below its mean and the fit loses energy. With ``tau`` the two signs of
the log error weigh ``2 tau`` (prediction below the target) and ``2 (1 - tau)`` (above), which is minimised
by the tau-quantile of the targets (the pinball loss, in log space); tau 0.5 is log-L1 exactly. The quantile
that equals the mean depends on how skewed each level's targets are, so
:mod:`mtlx2neural.train.energy_balance` steers it per MIP level from the energy it measures.

**The lift** (``lift``): below EPS the loss is linear in the prediction, so its gradient with respect to the
decoder's raw (log) output is only prediction / EPS of the log error's. A prediction at the output floor
(``floor_penalty``, 1e-8) under a target over EPS is pulled with 1e-4 of the force that moves it once it is
over EPS. A lobe whose surroundings are black, a perfect mirror's, is then never found: its rows are a tenth
of the batch, and the black rows around it, at the same small gradient, win (MaterialX's
``standard_surface_chrome``, roughness 0, trained black with ``fast``). The lift gives the elements whose
prediction is under EPS and target over it the log error's own gradient, log(prediction) - log(target), the
loss's value unchanged, but only in a batch where the fit is dead: where most of the elements with a target
over EPS (over :data:`LIFT_DEAD_SHARE`) meet a prediction two decades under it (:data:`LIFT_DEAD`). A fit that
finds its lobes by their tails is then left almost as it was (the samples lift in 0-2 of 1000 steps, MaterialX's
gold, roughness 0.02, in 8; the chrome in 22-26); lifting every batch cost
the textured near mirror 17-27 % of HDR FLIP (docs/history/lift-2026-12-07.md). A batch of several materials
(:func:`segment_losses`) asks per material.

**Sampler** (:func:`sampler_kl`): KL(neural BRDF || learned proxy) up to a constant, scored on
the sampler's own directions mixed defensively with cosine ones (``KL_DEFENSIVE``); gradients reach
the sampler only. The uniform-direction estimator it replaced, and the measurement, are in
docs/history/paper-choices-2026-12-02.md.

**Albedo head** (:func:`albedo_loss`): squared error of the predicted directional albedo against
one-sample Monte Carlo estimates of the reference's.

:func:`brdf_and_sampler_losses` is the BRDF and sampler losses of one step together: the unit the
trainer compiles with ``torch.compile``.
"""

from __future__ import annotations

import functools
import math

import torch

from mtlx2neural.formats.weights import OUTPUT_OFFSET
from mtlx2neural.model import proxy
from mtlx2neural.reference.vec import cosine_sample

EPS = 1e-2  # radiance scale (f * cos) below which errors count linearly
KL_DEFENSIVE = 0.5  # share of the sampler's KL batch drawn from the cosine density (defensive mixture)
KL_LOG_FLOOR = 1e-4  # added to the sampler's density inside the KL's log: a sample it cannot reach costs log(1e-4)
LIFT_DEAD = 1e-2
"""A prediction under this times EPS is dead for the lift (module docstring): log-L1 pulls it with 1 % of the log
error's gradient or less."""
LIFT_DEAD_SHARE = 0.5
"""The lift acts in a batch where more than this share of the elements with a target over EPS are dead. Measured
(``fast``): MaterialX's chrome lifts in 22-26 of 1000 steps, its gold in 8, the near mirror and the scene sample's
textured gold in 2, the other materials tried in none."""


def log_l1(pred: torch.Tensor, target: torch.Tensor, eps: float = EPS, tau=None, lift: bool = False,
           lift_groups: int = 1) -> torch.Tensor:
    """Mean |log1p(pred/eps) - log1p(target/eps)| over all elements (inputs must be >= 0; negative
    values are clamped to 0). ``pred`` and ``target`` are cosine-weighted BRDF values f * cos [N, 3],
    linear RGB; ``eps`` is in the same units. ``tau`` (None, a float or [N, 1] per row, in (0, 1)): the
    quantile the loss seeks (module docstring); None or 0.5 is the plain absolute log error. ``lift``: in a
    dead batch, the elements whose prediction is under ``eps`` and target over it get the log error's own
    gradient (:func:`lift_terms`; ``lift_groups`` equal consecutive parts of the rows, each asked on its own);
    the value is the same."""
    return log_l1_terms(pred, target, eps, tau, lift, lift_groups).mean()


def log_l1_terms(pred: torch.Tensor, target: torch.Tensor, eps: float = EPS, tau=None, lift: bool = False,
                 lift_groups: int = 1) -> torch.Tensor:
    """:func:`log_l1` per element, [N, 3] (not averaged)."""
    pred, target = pred.clamp_min(0), target.clamp_min(0)
    d = torch.log1p(pred / eps) - torch.log1p(target / eps)
    if lift:
        d = d + lift_terms(pred, target, eps, lift_groups)
    if tau is None:
        return d.abs()
    return 2.0 * torch.where(d < 0, -tau * d, (1.0 - tau) * d)


def lift_terms(pred: torch.Tensor, target: torch.Tensor, eps: float, groups: int = 1) -> torch.Tensor:
    """[N, 3] zeros whose gradient is that of log(pred) where ``pred`` < ``eps`` < ``target``, in each of ``groups``
    equal consecutive parts of the rows whose fit is dead (more than :data:`LIFT_DEAD_SHARE` of its elements with a
    target over ``eps`` have a prediction under :data:`LIFT_DEAD` ``eps``); 0 elsewhere. Added to log-L1's log
    error, it gives those elements the log error's own gradient (module docstring, "the lift"). Inputs >= 0, as
    :func:`log_l1_terms` has them. No data-dependent branch (``torch.compile`` keeps one graph)."""
    bright = target > eps
    dead = (pred < LIFT_DEAD * eps) & bright
    per_group = (dead.reshape(groups, -1).sum(1) > LIFT_DEAD_SHARE * bright.reshape(groups, -1).sum(1))
    lifted = per_group.repeat_interleave(pred.shape[0] // groups)[:, None] & (pred < eps) & bright
    log_pred = torch.log(pred.clamp_min(1e-30))
    return torch.where(lifted, log_pred - log_pred.detach(), torch.zeros_like(log_pred))


def relative_l2(pred: torch.Tensor, target: torch.Tensor, eps: float = EPS, tau=None, lift: bool = False,
                lift_groups: int = 1) -> torch.Tensor:
    """Mean of (pred - target)^2 / (sg(pred)^2 + eps^2) over all elements: the relative L2 of neural
    radiance caching (Müller et al. 2021), the prediction's scale held out of the gradient (sg: detached).

    Its minimiser over noisy targets is their *mean* (for a fixed denominator it is an ordinary
    squared error), so a sharp lobe that only a few targets hit keeps its energy, where log-L1 follows
    the median and drops it. Dividing by the prediction's own square weighs dark and bright values
    alike (a relative error), and ``eps`` (f * cos units, squared) keeps black predictions from
    dividing by zero. Inputs as :func:`log_l1`: cosine-weighted BRDF values f * cos [N, 3], linear RGB;
    negative values are clamped to 0. ``tau`` and the lift are ignored (it is mean-seeking already, and its
    gradient does not vanish under ``eps``)."""
    return relative_l2_terms(pred, target, eps).mean()


def relative_l2_terms(pred: torch.Tensor, target: torch.Tensor, eps: float = EPS, tau=None, lift: bool = False,
                      lift_groups: int = 1) -> torch.Tensor:
    """:func:`relative_l2` per element, [N, 3] (not averaged)."""
    pred = pred.clamp_min(0)
    return (pred - target.clamp_min(0)) ** 2 / (pred.detach() ** 2 + eps * eps)


MIXED_RELATIVE_WEIGHT = 0.1
"""Weight of relative_l2 in ``log_l1+relative_l2``: at 1 it overshoots the energy as relative_l2 does
(CarPaint 1.19, HDR FLIP 0.130 against 0.045); at 0.1 CarPaint keeps 1.03 at 0.044 and BrushedMetal 0.89
at 0.187 (log_l1: 0.96 / 0.85 at 0.045 / 0.174; BENCHMARKS.md, "Energy and the BRDF loss")."""


def mixed_log_l1(pred: torch.Tensor, target: torch.Tensor, eps: float = EPS, tau=None, lift: bool = False,
                 lift_groups: int = 1) -> torch.Tensor:
    """:func:`log_l1` (its scale ``eps``, its quantile ``tau``, its ``lift``) plus :data:`MIXED_RELATIVE_WEIGHT`
    times :func:`relative_l2`: log-L1's shape, and a mean-seeking pull that keeps the prediction from collapsing
    where most targets are black."""
    return log_l1(pred, target, eps, tau, lift, lift_groups) + MIXED_RELATIVE_WEIGHT * relative_l2(pred, target)


def mixed_log_l1_terms(pred: torch.Tensor, target: torch.Tensor, eps: float = EPS, tau=None, lift: bool = False,
                       lift_groups: int = 1) -> torch.Tensor:
    """:func:`mixed_log_l1` per element, [N, 3] (not averaged)."""
    return (log_l1_terms(pred, target, eps, tau, lift, lift_groups)
            + MIXED_RELATIVE_WEIGHT * relative_l2_terms(pred, target))


BRDF_LOSSES = {"log_l1": log_l1, "relative_l2": relative_l2, "log_l1+relative_l2": mixed_log_l1}
"""The decoder's losses by ``TrainConfig.brdf_loss`` name."""
BRDF_LOSS_TERMS = {"log_l1": log_l1_terms, "relative_l2": relative_l2_terms, "log_l1+relative_l2": mixed_log_l1_terms}
"""The same losses per element (``[N, 3]``, not averaged): for :func:`segment_losses`."""


def brdf_loss_of(name: str, eps: float = EPS, terms: bool = False):
    """The decoder's loss ``(pred, target) -> scalar`` named ``name`` (:data:`BRDF_LOSSES`; ``terms``: per
    element, :data:`BRDF_LOSS_TERMS`), its log-L1 part at the radiance scale ``eps``
    (``TrainConfig.brdf_eps``); relative_l2 keeps its own :data:`EPS`."""
    loss = (BRDF_LOSS_TERMS if terms else BRDF_LOSSES)[name]
    return loss if loss in (relative_l2, relative_l2_terms) else functools.partial(loss, eps=eps)


def sampler_kl(decoder, sampler, latent: torch.Tensor, wi: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """The sampler's loss: KL(neural BRDF || learned proxy) up to a constant (a scalar, in nats).

    Scored on directions drawn from the sampler itself (the paper's estimator), mixed defensively with
    cosine sampling: each row's ``wo`` comes from the learned proxy (detached) or, where
    ``u[:, 2] < KL_DEFENSIVE``, from the cosine density, and is weighted by f / r with f the decoder's
    cosine-weighted BRDF (mean over RGB) and r = (1 - KL_DEFENSIVE) q + KL_DEFENSIVE cos / pi the
    mixture's density per steradian; the weights are normalised over the batch, and rows whose ``wo``
    falls at or below the horizon or whose density is not positive weigh 0. The loss is
    ``-sum(w * log(q(wo) + KL_LOG_FLOOR))`` with q the sampler's density.

    ``decoder`` and ``sampler`` are the model's networks; ``latent`` [N, D] the rows' latents (detached
    here, so the sampler cannot pull the latents towards what it can sample; the decoder runs without
    gradient); ``wi`` [N, 3] unit, local frame; ``u`` [N, 3] uniform random numbers in [0, 1). The
    gradient reaches the sampler's parameters only.
    """
    lat_d, wo_s, w = _kl_rows(decoder, sampler, latent, wi, u)
    w = w / w.sum().clamp_min(1e-12)
    q = sampler.pdf(wi, wo_s, lat_d)
    return -(w * torch.log(q + KL_LOG_FLOOR)).sum()


def _kl_rows(decoder, sampler, latent, wi, u):
    """:func:`sampler_kl`'s rows: (detached latents, the sampled ``wo``, each row's weight f / r before the
    normalisation), without gradients."""
    lat_d = latent.detach()
    with torch.no_grad():
        params_d = sampler(wi, lat_d)
        wo_s = torch.where((u[:, 2] < KL_DEFENSIVE)[:, None], cosine_sample(u[:, :2]),
                           proxy.sample(wi, params_d, u[:, :2]))
        wo_s = torch.nn.functional.normalize(torch.nan_to_num(wo_s, nan=0.0), dim=-1)
        density = ((1.0 - KL_DEFENSIVE) * proxy.pdf(wi, wo_s, params_d)
                   + KL_DEFENSIVE * wo_s[:, 2].clamp_min(0.0) / math.pi)
        ok = (wo_s[:, 2] > 0) & (density > 0) & torch.isfinite(density)
        w = torch.where(ok, decoder(lat_d, wi, wo_s).mean(-1) / density.clamp_min(1e-12), torch.zeros_like(density))
    return lat_d, wo_s, w


def raw_floor(brdf_floor: float) -> float:
    """The raw decoder output (before exp(x - :data:`~mtlx2neural.formats.weights.OUTPUT_OFFSET`)) at which
    f equals ``brdf_floor`` (linear RGB, before the cosine): the ``floor`` of :func:`floor_penalty`."""
    return math.log(brdf_floor) + OUTPUT_OFFSET


OUTPUT_FLOOR = raw_floor(1e-8)
"""Lowest raw decoder output (before exp(x - 3): f = 1e-8, ``TrainConfig.brdf_floor``'s default) the
training leaves unpenalised. Without a floor the near-mirror PolishedMetal trained to black; at -6 the
sample CarPaint lost HDR FLIP (0.058 against 0.045, seed 0; docs/history/energy-and-loss-2026-12-04.md).
-9 (f = 6e-6) held that near mirror's dim tails, which HDR FLIP sees down to about 1e-7, 3x too bright
(docs/history/near-mirror-tails-2026-12-07.md)."""


def floor_penalty(raw: torch.Tensor, wo: torch.Tensor | None = None, floor: float = OUTPUT_FLOOR) -> torch.Tensor:
    """mean(relu(floor - raw)^2) over the decoder's raw outputs ``raw`` [N, 3] (before the exp), rows whose
    ``wo`` is at or below the horizon weighing 0 (the cosine makes their value 0 whatever ``raw`` is; a
    penalty there would only spend the network's capacity).

    Keeps the decoder alive where most targets are black. log-L1's gradient there shrinks with the
    prediction, but Adam normalises it and keeps stepping the same way, until exp() underflows to 0 in
    float32 and every gradient is exactly 0: the near-mirror sample trained to black that way within 50
    steps (docs/history/energy-and-loss-2026-12-04.md). Below the floor the penalty's gradient wins and
    the raw output stays near it; a black value is still predicted as about the floor's f, far under
    log-L1's scale."""
    return floor_terms(raw, wo, floor).mean()


def floor_terms(raw: torch.Tensor, wo: torch.Tensor | None = None, floor: float = OUTPUT_FLOOR) -> torch.Tensor:
    """:func:`floor_penalty` per element, [N, 3] (not averaged)."""
    below = torch.relu(floor - raw).square()
    return below * (wo[:, 2:3] > 0) if wo is not None else below


def brdf_and_sampler_losses(decoder, sampler, latent, wi, wo, target, u, brdf_loss=log_l1, floor=OUTPUT_FLOOR,
                            tau=None, lift: bool = False):
    """(BRDF loss, sampler loss) of one step's batch, given the latents: ``brdf_loss`` (one of
    :data:`BRDF_LOSSES`) between the decoder's f * cos at (``wi``, ``wo``) and ``target`` [N, 3] (the
    filtered reference, f * cos, linear RGB) plus :func:`floor_penalty` of its raw outputs at ``floor``
    (a raw output, :func:`raw_floor`), then
    :func:`sampler_kl` with the uniform numbers ``u`` [N, 3]. Directions unit, local frame. ``tau`` (None or
    [N] per row): the quantile the BRDF loss seeks; ``lift``: its lift (module docstring)."""
    raw = decoder.logits(latent, wi, wo)
    tau = None if tau is None else tau[:, None]
    loss_brdf = brdf_loss(decoder.activate(raw, wo), target, tau=tau, lift=lift) + floor_penalty(
        raw, wo if decoder.analytic_cosine else None, floor)
    return loss_brdf, sampler_kl(decoder, sampler, latent, wi, u)


def segment_losses(decoder, sampler, latent, wi, wo, target, u, segments: int, brdf_terms=log_l1_terms,
                   floor=OUTPUT_FLOOR, tau=None, lift: bool = False):
    """:func:`brdf_and_sampler_losses` of ``segments`` equal consecutive parts of the rows at once (several
    materials' batches through one shared decoder and sampler): ``(BRDF loss [S], sampler loss [S])``, each
    part's as if it were a batch of its own (means over the part; the KL's weights normalised within it).
    ``brdf_terms``: the BRDF loss per element (:data:`BRDF_LOSS_TERMS`); ``floor``, ``tau`` (per row) and ``lift``:
    as there, the lift's dead batch asked per part."""
    raw = decoder.logits(latent, wi, wo)
    tau = None if tau is None else tau[:, None]
    terms = brdf_terms(decoder.activate(raw, wo), target, tau=tau, lift=lift, lift_groups=segments) + floor_terms(
        raw, wo if decoder.analytic_cosine else None, floor)
    lat_d, wo_s, w = _kl_rows(decoder, sampler, latent, wi, u)
    w = w.view(segments, -1)
    w = w / w.sum(1, keepdim=True).clamp_min(1e-12)
    q = sampler.pdf(wi, wo_s, lat_d).view(segments, -1)
    return terms.view(segments, -1).mean(1), -(w * torch.log(q + KL_LOG_FLOOR)).sum(1)


def albedo_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """The albedo head's loss: mean squared error over rows and channels between the predicted
    directional albedo ``pred`` [N, 3] (f * cos integrated over wo, linear RGB, at each row's ``wi``) and
    ``target`` [N, 3], one-sample Monte Carlo estimates of the reference's (its sample weight, so
    unbiased but noisy: the squared error's minimiser is their mean)."""
    return ((pred - target) ** 2).mean()
