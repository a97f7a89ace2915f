"""Fit the environment head: how much of the reflected light each lobe of the environment path carries.

Prefiltered environment lighting (:mod:`mtlx2neural.render.prefiltered`) shades distant light as
sum of c_k(wi) E_k over three lobes: the sharp lobe (:func:`~mtlx2neural.model.proxy.sharp_params`) and
the learned sampler's specular and diffuse lobes. E_k is the incident radiance averaged over lobe k, and
c_k the reflectance that lobe carries in the mixture p = W p_sharp + (1 - W) p_sampler
(W = :data:`~mtlx2neural.model.proxy.SHARP_WEIGHT`),

    c_k(wi) = integral over wo of f(wi, wo) cos(wo) r_k(wo),   r_k = w_k p_k / p,

except that the sharp lobe keeps only the share rho(wo) = clamp(1 - f(ring) / f(wo), 0, 1) of its r_sharp that is
f's own peak (the ring: :data:`RING` sharp alphas from the sharp lobe's centre in slope space, towards wo) and the
specular lobe takes the rest. So the c_k add up to the directional albedo, and a constant environment L gives
albedo x L exactly. The sharp lobe takes what lies in its narrow cone when f peaks there (a coat's near-delta
peak), which the sampler's one specular lobe, fitted to sample a coat and its base together, would spread over its
own width (the sample CarPaint's sun reflection: torch twin HDR FLIP 0.149 with two lobes, 0.098 with three;
docs/history/environment-lighting-2026-12-06.md); it takes nothing of a smooth lobe, where responsibilities alone
gave a rough plastic a sun glint (peak 1.8x the original's; docs/history/environment-lighting-2026-12-07.md).
This module fits the decoder's environment head to c_k after the BRDF and the sampler are trained
(they, and the latents, stay frozen). The targets come from the **reference**, not from the neural
BRDF, so the prefiltered path's error is measured on its own:

- rows: uv and MIP level drawn as the BRDF's rows (``train.targets``), ``wi`` uniform in solid angle
  over the upper hemisphere;
- one direction per row, from the learned sampler, the reference's own sampler or the sharp lobe (a third
  each), with the combined density q = (p_sampler + p_ref + p_sharp) / 3, so a lobe sharper than the learned
  one is still found, and the sharp lobe's narrow cone gets rows of its own;
- one-sample estimates y_k = f_ref(wi, wo) cos(wo) r_k(wo) / q(wo) (the footprint-filtered,
  unmollified reference at textured rows), unbiased for c_k; f at the ring is read only at rows inside the
  sharp lobe's cone (r_sharp above :data:`RING_FROM`);
- the relative squared error (c - y)^2 / (sg(c)^2 + eps) of neural radiance caching, whose
  minimiser is the targets' mean (what c_k is), with the prediction's scale held out of the
  gradient so dark and bright texels weigh alike.

After the fit, a material whose sharp-lobe targets carry almost none of its reflectance (:data:`SHARP_MIN_SHARE`:
a rough plastic, a velvet) gets a silent sharp lobe, which the head could only approach, not reach; a material
that reflects nothing (:data:`BLACK_REFLECTANCE`) gets a silent head.

``TrainConfig.environment_steps`` (``environment_fraction`` of the iterations) batches of ``environment_batch``
rows are drawn, and the head takes :data:`PASSES` Adam steps per batch.
"""

from __future__ import annotations

import math

import torch

from mtlx2neural.contract import ShadingPoint
from mtlx2neural.formats.weights import SILENT_LOGIT
from mtlx2neural.model import proxy
from mtlx2neural.train.adam import Adam

RELATIVE_EPS = 1e-3
"""eps of the relative squared error: reflectances far below it weigh as plain squared error."""
AHEAD = 25
"""Steps whose rows are drawn in one call per material. The rows do not depend on the head being fitted
(the sampler, the latents and the rest of the decoder are frozen), so drawing ahead changes only the cost:
the reference's per-call overhead dominates a CPU step, most of all for a group of many materials."""
RING = 8.0
"""Where the sharp lobe's test of f's peak reads f: this many sharp alphas from its centre in slope space (2.3
degrees of normal). A clear coat of alpha 0.0064 falls to under 0.3 % there, a roughness-0.45 lobe by 8 %."""
RING_FROM = 1e-3
"""Rows whose sharp responsibility is at most this keep it unscaled, without reading f at the ring."""
AHEAD_ROWS = 32768
"""At most this many rows drawn ahead (over every material): a large ``environment_batch`` draws fewer steps."""
LR_START, LR_END = 5e-3, 5e-4
"""Adam's learning rate, decayed geometrically over the fit."""
PASSES = 4
"""Adam steps per batch of rows drawn: each chunk drawn ahead (:data:`AHEAD` batches) is gone over this many times
before the next is drawn, so the head takes ``PASSES`` x ``environment_steps`` steps for the reference's targets of
``environment_steps`` (their evaluation is most of a step's time). The head is under-fitted at one step per batch:
the sample CarPaint's prefiltered render against the reference (torch twin, three seeds of the head's fit) 0.1107 at
1, 0.1060 at 4 passes (4000 batches drawn fresh: 0.1046-0.1082), the Plastic 0.0720 and 0.0680, at twice the fit's
time (docs/history/environment-lighting-2026-12-07.md)."""
BLACK_REFLECTANCE = 1e-4
"""Mean directional albedo (over the fit's rows) under which a material's head is silenced whole (:func:`silent_lobes`):
the head's outputs stop around 1e-4 where every target is 0 (a thin-walled subsurface surface, black in reflection:
the viewer figure 0.80 against a black reference)."""
SHARP_MIN_SHARE = 0.01
"""A material whose sharp-lobe targets carry less than this share of its reflectance (summed over the fit's rows)
gets a silent sharp lobe after the fit (:func:`silent_lobes`). The head cannot fit a reflectance of 0: under
the relative error's eps its sharp outputs stop at about 1e-3 of the albedo, which one lookup of a bright sun turns
into a glint the material does not have (an unseen velvet's streak: viewer HDR FLIP 0.35). Shares measured with
``fast``: coats and glazes 7-52 % (by view angle), BrushedMetal 0.3-0.4 %, the Plastic 0.02-0.1 %, the velvet
under 0.02 %."""


def uniform_hemisphere(n: int, generator: torch.Generator, device) -> torch.Tensor:
    """[n, 3] unit directions uniform in solid angle over z > 0 (z = cos theta uniform in (0, 1])."""
    u = torch.rand(n, 2, generator=generator).to(device)
    z = 1.0 - u[:, 0]
    r = torch.sqrt((1.0 - z * z).clamp_min(0.0))
    phi = 2.0 * math.pi * u[:, 1]
    return torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], -1)


def lobe_targets(reference, targets, model, lat, uv, level, wi, generator) -> torch.Tensor:
    """[N, 3, 3] one-sample estimates of (c_sharp, c_spec, c_diff) at the rows (module docstring), from the
    reference ``reference`` filtered as ``targets`` (a ``train.targets`` object) filters it; ``lat`` the
    rows' latents (``model.latents.fetch(uv, level)``), read by ``model``'s sampler."""
    dev, n = wi.device, wi.shape[0]
    params = model.sampler(wi, lat)
    sharp = proxy.sharp_params(params)
    u = torch.rand(n, 3, generator=generator).to(dev)
    at = ShadingPoint(uv=targets.lobe_uv(uv))
    wo_ref, _, _ = reference.sample(wi, u[:, :2], at)
    wo_own = proxy.sample(wi, params, u[:, :2])
    wo_sharp = proxy.sample_specular(wi, sharp, u[:, :2])
    use_ref = (u[:, 2] < 1.0 / 3.0) & torch.isfinite(wo_ref).all(-1)
    wo = torch.where(use_ref[:, None], torch.nan_to_num(wo_ref), torch.where((u[:, 2] < 2.0 / 3.0)[:, None], wo_own, wo_sharp))
    wo = wo / wo.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    p_spec = params.w_spec[:, 0] * proxy.pdf_specular(wi, wo, params)
    p_own = p_spec + (1.0 - params.w_spec[:, 0]) * proxy.pdf_diffuse(wo, params.slope_diff)
    p_sharp_lobe = proxy.pdf_specular(wi, wo, sharp)
    q = (p_own + reference.pdf(wi, wo, at) + p_sharp_lobe) / 3.0
    f = targets.brdf(wi, wo, uv, level, 0.0)
    ok = (wo[:, 2] > 0) & (q > 0) & torch.isfinite(f).all(-1)
    y = torch.where(ok[:, None], f / q.clamp_min(1e-30)[:, None], torch.zeros_like(f))
    # responsibilities in the three-lobe mixture (not q: that is the density the directions were drawn with)
    p_sharp = proxy.SHARP_WEIGHT * p_sharp_lobe
    p_all = p_sharp + (1.0 - proxy.SHARP_WEIGHT) * p_own
    live = p_all > 0
    r_sharp = torch.where(live, p_sharp / p_all.clamp_min(1e-30), torch.zeros_like(p_all))[:, None]
    r_spec = torch.where(live, (1.0 - proxy.SHARP_WEIGHT) * p_spec / p_all.clamp_min(1e-30),
                         torch.zeros_like(p_all))[:, None]
    r_diff = (1.0 - r_sharp - r_spec).clamp_min(0.0)
    # the share of the sharp lobe's responsibility that is f's own peak; the rest is the specular lobe's
    rho = torch.ones_like(f)
    inside = ((r_sharp[:, 0] > RING_FROM) & ok).nonzero()[:, 0]
    if inside.numel():
        ring = ring_direction(wi[inside], wo[inside], sharp.slope_spec[inside])
        f_ring = targets.brdf(wi[inside], ring, uv[inside], None if level is None else level[inside], 0.0)
        f_ring = torch.where((ring[:, 2:] > 0) & torch.isfinite(f_ring), f_ring, torch.zeros_like(f_ring))
        rho[inside] = (1.0 - f_ring / f[inside].clamp_min(1e-30)).clamp(0.0, 1.0)
    return torch.stack([y * r_sharp * rho, y * (r_spec + r_sharp * (1.0 - rho)), y * r_diff], 1)


def ring_direction(wi: torch.Tensor, wo: torch.Tensor, centre: torch.Tensor) -> torch.Tensor:
    """[N, 3] the mirror direction of ``wi`` about the normal :data:`RING` sharp alphas from the slope ``centre``
    [N, 2] (the sharp lobe's), on the side of ``wo``'s half vector (along +x where that is the centre itself)."""
    h = wi + wo
    h = h / h.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    z = h[:, 2:].clamp_min(1e-6)
    offset = -h[:, :2] / z - centre
    length = offset.norm(dim=-1, keepdim=True)
    towards = torch.where(length > 1e-9, offset / length.clamp_min(1e-12), torch.tensor([[1.0, 0.0]], device=wi.device))
    return proxy.reflect_about_slope(wi, centre + RING * proxy.SHARP_ALPHA * towards)


def wake_silent_lobes(head) -> bool:
    """Before a head is fitted again, its silent lobes (exp(-103): no gradient reaches them) start anew: the sharp
    lobe's outputs (of a head upgraded from one without it, :func:`~mtlx2neural.formats.weights.upgrade_environment_head`,
    or silenced by a fit) from the specular lobe's, at a tenth of its reflectance; a specular or diffuse lobe
    (silenced with a black material's head) from zero weights and bias, the head's usual scale. Returns whether
    the sharp lobe was silent."""
    last = head[-1]
    with torch.no_grad():
        for k in (1, 2):  # a specular or diffuse lobe silenced with a black material's: the head's usual start
            if bool((last.bias[3 * k:3 * k + 3] <= SILENT_LOGIT).all()):
                last.weight[3 * k:3 * k + 3] = 0.0
                last.bias[3 * k:3 * k + 3] = 0.0
        if not bool((last.bias[:3] <= SILENT_LOGIT).all()):
            return False
        last.weight[:3] = last.weight[3:6]
        last.bias[:3] = last.bias[3:6] - math.log(10.0)
    return True


LOBE_NAMES = ("sharp", "specular", "diffuse")


def silent_lobes(carried: torch.Tensor, rows: int) -> list[int]:
    """The lobes the fit silences, from ``carried`` [materials, 3]: each material's targets summed per lobe
    (sharp, specular, diffuse; mean over RGB) over its ``rows`` rows. The sharp lobe when it carries under
    :data:`SHARP_MIN_SHARE` of every material's reflectance; every lobe when every material reflects under
    :data:`BLACK_REFLECTANCE` on average (a thin-walled translucent surface: its reflection is black)."""
    total = carried.sum(1)
    if bool((total < BLACK_REFLECTANCE * max(rows, 1)).all()):
        return [0, 1, 2]
    return [0] if bool((carried[:, 0] <= SHARP_MIN_SHARE * total).all()) else []  # a black material: 0 <= 0


def silence_lobes(head, lobes=(0,)) -> None:
    """Make the lobes ``lobes`` of ``head`` (0 sharp, 1 specular, 2 diffuse) carry nothing, as a legacy head's sharp
    lobe does (:func:`~mtlx2neural.formats.weights.upgrade_environment_head`): zero weights, bias
    :data:`~mtlx2neural.formats.weights.SILENT_LOGIT` (exp(-103): 0 in FP16). A later fit wakes them again
    (:func:`wake_silent_lobes`)."""
    last = head[-1]
    with torch.no_grad():
        for k in lobes:
            last.weight[3 * k:3 * k + 3] = 0.0
            last.bias[3 * k:3 * k + 3] = SILENT_LOGIT


def _rows_ahead(trainers, per: int, steps: int) -> list[tuple[torch.Tensor, ...]]:
    """The rows of ``steps`` steps (each: ``per`` rows of every trainer's material), drawn in one call per
    material (:data:`AHEAD`)."""
    drawn = [_rows(t, per * steps) for t in trainers]
    return [tuple(torch.cat([part[k * per:(k + 1) * per] for part in parts]) for parts in zip(*drawn))
            for k in range(steps)]


def _rows(trainer, batch: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``batch`` rows of ``trainer``'s material: (latents, wi, the reference's per-lobe reflectance), where the
    material has surface (``Trainer.surface_uv``: a cut-out's empty texels hold dilated latents, not its look)."""
    model, dev, g = trainer.model, trainer.device, trainer.gen
    with torch.no_grad():
        uv = trainer.surface_uv(batch).to(dev)
        level = trainer.targets.levels(batch, dev)
        wi = uniform_hemisphere(batch, g, dev)
        lat = model.latents.fetch(uv, level)
        y = lobe_targets(trainer.ref, trainer.targets, model, lat, uv, level, wi, g)
    return lat, wi, y


def fit_environment_head(trainer, steps: int, batch: int, listener=None) -> list[dict]:
    """Fit ``trainer.model``'s environment head for ``steps`` Adam steps of ``batch`` rows each (module
    docstring), drawing from ``trainer.gen``; the other networks and the latents are not changed.
    ``trainer`` may be a list of trainers whose models share one decoder (:mod:`.shared`): each step then
    takes ``batch // len(trainers)`` rows (at least 64) of every material. Rows are drawn :data:`AHEAD`
    steps at a time, and each chunk is gone over :data:`PASSES` times (``steps`` x ``PASSES`` Adam steps). After the
    fit, the sharp lobe is silenced (:func:`silence_lobes`) when its targets carry
    under :data:`SHARP_MIN_SHARE` of every material's reflectance, and every lobe when the materials reflect nothing
    (:func:`silent_lobes`). Returns one record per 25 Adam steps (``step``, ``loss_environment``; the last adds
    ``sharp_share``, the largest material's share, and ``silent_lobes``, the names of those silenced);
    ``listener(step, steps * PASSES, record)`` is called with each."""
    trainers = list(trainer) if isinstance(trainer, (list, tuple)) else [trainer]
    model = trainers[0].model
    head = model.decoder.environment
    if head is None:
        raise RuntimeError("the model has no environment head to fit")
    per = batch if len(trainers) == 1 else max(64, batch // len(trainers))
    wake_silent_lobes(head)
    opt = Adam(head.parameters(), lr=LR_START, betas=(0.9, 0.999), eps=1e-7)
    history, chunk, ahead, passes = [], [], [], 0
    carried = torch.zeros(len(trainers), 3, dtype=torch.float64)  # per material: each lobe's targets, summed
    drawn, updates = 0, steps * PASSES
    for step in range(1, updates + 1):
        if not ahead:
            if not chunk or passes == PASSES:  # the next chunk of rows, gone over PASSES times
                chunk = _rows_ahead(trainers, per, max(1, min(AHEAD, AHEAD_ROWS // (per * len(trainers)),
                                                              steps - drawn)))
                drawn, passes = drawn + len(chunk), 0
                for _, _, y in chunk:
                    by_material = y.double().view(len(trainers), per, 3, 3)
                    carried += by_material.mean(-1).sum(1).cpu()
            ahead, passes = list(chunk), passes + 1
        lat, wi, y = ahead.pop(0)
        c = model.decoder.predict_lobe_reflectance(lat, wi)
        loss = ((c - y) ** 2 / (c.detach() ** 2 + RELATIVE_EPS)).mean()
        for group in opt.param_groups:
            group["lr"] = LR_START * (LR_END / LR_START) ** ((step - 1) / max(1, updates - 1))
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        if not math.isfinite(loss.item()):
            raise FloatingPointError(f"non-finite environment-head loss at step {step}")
        if step % 25 == 0 or step == updates:
            rec = {"step": step, "loss_environment": round(loss.item(), 6)}
            history.append(rec)
            if listener is not None:
                listener(step, updates, rec)
    silent = silent_lobes(carried, drawn * per) if steps else []
    silence_lobes(head, silent)
    if history:
        total = carried.sum(1).clamp_min(1e-30)
        history[-1].update(sharp_share=round(float((carried[:, 0] / total).max()), 5),
                           silent_lobes=[LOBE_NAMES[k] for k in silent])
    return history
