"""Training configuration: a dataclass with a docstring per field, and named presets."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

from mtlx2neural.errors import InputError


@dataclass
class TrainConfig:
    """Training settings. Each field's docstring is its documentation (the command line's help
    and docs/cli.md's option table, :mod:`mtlx2neural.commands.options_cli`); ``metadata`` gives the
    flag where it differs from ``--field-name``, a metavar, or the choices the command line offers."""

    iterations: int = field(default=2000, metadata={"metavar": "N"})
    """Total optimisation steps over all three phases (0 exports an untrained network: only with
    ``allow_untrained``)."""
    batch: int = field(default=4096, metadata={"metavar": "N"})
    """Samples per batch; two batches (BRDF and sampler) per step."""
    decoder: str = field(default="2x32", metadata={"choices": ("2x16", "2x32", "3x64")})
    """Decoder hidden layers: 2x16, 2x32 or 3x64."""
    brdf_loss: str = field(default="log_l1", metadata={"choices": ("log_l1", "relative_l2", "log_l1+relative_l2")})
    """The decoder's loss on f * cos (``train.losses``): log_l1 (log-compressed L1, follows the median of
    noisy targets), relative_l2 (squared error relative to the prediction, follows their mean, so sharp
    lobes keep their energy, but overshoots it), or log_l1 plus a tenth of relative_l2 (keeps a decoder
    whose targets are mostly black from collapsing to zero)."""
    brdf_eps: float = field(default=1e-4, metadata={"metavar": "X"})
    """log_l1's radiance scale (f * cos, linear RGB): errors below it count linearly, above it by their ratio
    (``train.losses.log_l1``). HDR FLIP exposes an image down to a luminance of about 1e-7, so the dim tails of
    a near mirror's lobe, 1e-8 to 1e-3 of its peak, fill most of its figure: with :attr:`brdf_floor` under
    them, 1e-4 fits them well enough, and 1e-6 slightly better at a cost to the other samples' held-out error
    and to the near mirror's energy (docs/history/near-mirror-tails-2026-12-07.md). The held-out figure
    (``held_out_log_l1``) keeps 1e-2."""
    brdf_floor: float = field(default=1e-8, metadata={"metavar": "F"})
    """The smallest f (linear RGB, before the cosine) the decoder predicts without a penalty
    (``train.losses.floor_penalty``): it keeps a fit whose targets are mostly black from dying, and it
    must lie under the dim tails the loss should fit (:attr:`brdf_eps`)."""
    energy_gain: float = field(default=0.3, metadata={"metavar": "G"})
    """How fast each MIP level's BRDF loss moves towards the quantile of its targets that keeps the reference's
    energy (``train.energy_balance``): log_l1 follows the median of the footprint-averaged targets, which lies
    below their mean, so a level whose directional albedo falls short of the reference's moves its quantile up
    by this times log(ratio) per update (every twentieth of the run, from 30 % on), and one too bright moves it
    down; after the last step the latent codes of each level under the reference's energy are shifted up to it
    (``EnergyBalance.calibrate``; a universal fine-tune, which does not update the balance, ends with it too).
    0: log_l1's median throughout and no calibration (the textured samples then keep 85-93 % of their energy with
    fast, the near mirror 79-81 %). fast: 0.5, its 2000 short steps' energy drifting further between updates (0.3
    left the CarPaint at 0.93, seed 1). Not used with relative_l2, which follows the mean already."""
    lift_fraction: float = 1.0
    """Share of the run, from its start, in which the BRDF loss may lift (``train.losses``, "the lift"): in a
    batch where most predictions under a target over ``brdf_eps`` are dead (two decades under it), those
    predictions get the log error's whole gradient, not log-L1's prediction / brdf_eps of it. Without it a lobe
    whose surroundings are black is never found: MaterialX's standard_surface_chrome (roughness 0) trained black
    with fast and keeps 127-136 % of its energy with it (lifting in 22-26 of 1000 steps; the samples in 0-2).
    0: never."""
    frames: int = field(default=2, metadata={"metavar": "N"})
    """Learned shading frames; 0 feeds the decoder raw local directions (ablation)."""
    latent_dim: int = 8
    """Latent channels."""
    encoder_input: str = field(default="normalized", metadata={"choices": ("raw", "normalized")})
    """What the material's own encoder reads of a texel (:mod:`mtlx2neural.train.encoder_input`): normalized
    (each channel standardised over the finest level, plus log(alpha) of each LEAN lobe's roughness) or raw
    (the parameter stack's channels as they are). A universal network reads what it was trained on, whatever
    this says (its atlas's statistics: :mod:`mtlx2neural.universal.weights`).
    Measured with `fast`, seed 0 (docs/history/energy-and-loss-2026-12-06.md): HDR FLIP against raw 0.079 /
    0.086 on the GlazedCeramic, 0.151 / 0.160 on the BrushedMetal, 0.35 / 0.46 on the near mirror; a uniform
    material has no channels, so both read nothing."""
    latent_format: str = field(default="exr", metadata={"choices": ("exr", "bc6h", "bc1")})
    """How the latent textures ship (:mod:`mtlx2neural.formats.latent_codec`): exr (half-float OpenEXR,
    16 bytes per texel for 8 channels), bc6h (signed BC6H DDS, 3 channels per texture, 3 bytes per texel)
    or bc1 (BC1 DDS with a per-channel scale and offset, 1.5 bytes per texel). With bc6h or bc1 every
    step of the run's last ``block_fraction`` trains through an exact emulation of the block decoder, so
    the network expects what a GPU's texture unit returns."""
    block_fraction: float = 0.2
    """Share of the steps, at the end of the run and after the encoder phase, that read the latents through
    the block decoder's emulation (bc6h, bc1; each such step costs 2-4x an uncompressed one on a 256² grid,
    BENCHMARKS.md, "Latent formats"). 0 compresses the trained latents once, at the end."""
    analytic_cosine: bool = True
    """The decoder predicts f and multiplies by max(0, wo.z) itself (``model.decoder``); False: the
    network learns f * cos, as models made before this option did."""
    encoder_fraction: float = 0.6
    """Share of iterations for phase 1 (encoder end to end); the rest fine-tunes baked latents.
    0 skips the encoder: latents start from noise and are optimised directly (ablation)."""
    lr_start: float = 1e-3
    """Adam learning rate at the start; cosine decay to ``lr_end``."""
    lr_end: float = 1e-4
    """Adam learning rate at the end of the cosine decay from ``lr_start``."""
    mollify_degrees: float = 10.0
    """Initial half-angle of the mollification cone; decays to 0 with the paper's cosine schedule."""
    mollify_min_degrees: float = 0.0
    """Floor of the cone's half-angle once it has narrowed: the decoder then learns the BRDF
    mollified at that scale, which keeps a near-specular lobe's energy (0: the paper's exact BRDF)."""
    mollify_mis: bool = False
    """Estimate the mollified targets by MIS (uniform in the cone plus the reference's sampler,
    ``train.mollify.cone_mean``) instead of plain jittered directions: the mean over the cone, not
    a sample of it, so a lobe much narrower than the cone still carries its energy."""
    grazing_fraction: float = 0.0
    """Extra BRDF rows per step, as a share of ``batch``, whose ``wi`` (the viewer) is uniform in
    azimuth with cos(theta_i) uniform in (0, 0.25], within ~14 degrees of the horizon: half/difference
    pairs rarely land there, and a coat's Fresnel darkens the base within a few degrees of it (the
    rim). Extra rather than in place of half/difference rows, which the specular lobes need; with
    ``lobe_fraction`` half of them take ``wo`` near the reference's lobes. 0 (off) in every preset."""
    lobe_fraction: float = 0.0
    """Share of each BRDF batch whose ``wo`` comes from the reference's sampler (spread over the
    current cone) instead of uniform half/difference angles, so narrow lobes are trained on."""
    mollify_fraction: float = 0.1
    """Share of iterations over which mollification decays (paper: 20k of 300k)."""
    mollify_samples: int = 4
    """Cone samples per target while mollifying (paper: 256); with ``mollify_mis``, half of them
    uniform in the cone and half from the reference's sampler (uniform materials; a textured one
    takes one pair per footprint point)."""
    footprint_samples: int = 16
    """Cap on reference samples (a Latin hypercube over the footprint) per footprint-filtered target
    (fast and standard: 8), in training and in the fit of the UsdPreviewSurface fallback. Fewer points make
    each step cheaper and each target noisier, and keep less of a sparse bright footprint's energy: the
    textured BrushedMetal keeps 0.86-0.88 of its directional albedo with 8 and 0.95 with 32, for 2.1x the training
    time (BENCHMARKS.md, "Energy and the BRDF loss")."""
    target_reuse: int = field(default=1, metadata={"metavar": "K"})
    """Steps each training row (its directions, point and reference target) is trained on: each step
    draws a K-th of the batch fresh and reuses the rest from the K - 1 steps before
    (:mod:`mtlx2neural.train.replay`), so the reference is called for a K-th of the rows. 1: every row
    fresh, the paper's loop."""
    target_prefetch: int = field(default=1, metadata={"metavar": "P"})
    """Steps whose fresh training rows are drawn in one call to the reference, then served a P-th per step
    (:mod:`mtlx2neural.train.replay`): the same rows' distribution at a lower cost per row, each drawn at
    most P - 1 steps early. 1: one call per step, the paper's loop."""
    level_rate: float = 1.0
    """Level distribution P(k) ~ exp(-rate k): larger favours fine levels more."""
    albedo_head: bool = False
    """Train the optional albedo head (L2 against one-sample Monte Carlo estimates)."""
    environment_fraction: float = 0.0
    """Adam steps fitting the environment head after the BRDF (``train.environment_fit``), as a share of
    ``iterations`` (:attr:`environment_steps`): the reflectance of a sharp near-mirror lobe and of each lobe
    of the learned sampler, which prefiltered environment lighting shades with (``render --env-mode
    prefiltered``, the MaterialX node's default). 0: no head; viewers then sample the environment with the
    decoder."""
    environment_batch: int = field(default=1024, metadata={"metavar": "N"})
    """Rows per environment-head step (one reference direction each)."""
    checkpoint_every: int = 500
    """Steps between checkpoints."""
    max_resolution: int | None = field(default=256, metadata={"flag": "--max-texels", "metavar": "N"})
    """Cap on the latent/parameter pyramid's finest level (texels per side); None (``--max-texels 0``):
    the textures' own grid. A cap below the textures' grid prefilters their finer detail, with a
    warning."""
    seed: int = field(default=0, metadata={"metavar": "N"})
    """Seed of the initial weights and of the training data (0 to 2^63 - 1)."""
    preview_iterations: int = field(default=200, metadata={"metavar": "N"})
    """Adam steps of the analytic Lambert + GGX fit behind the layer's UsdPreviewSurface fallback
    (fast: 100; 0: no fallback, so no ``NeuralPreview`` shader and no ``previewFlip``). A USD Material whose
    surface is its own UsdPreviewSurface keeps that shader as the fallback, with nothing fitted."""
    probe_every: int = 0
    """Steps between quality probes during training (:class:`~mtlx2neural.render.flip_probe.FlipProbe`:
    HDR FLIP of the current model in three small views), written to ``training_curves.csv`` as
    ``flip_probe`` and plotted against training seconds in the report; the last step is always probed.
    Their time is left out of the curves' ``seconds``, and they draw none of the training's random
    numbers, so a run is the same with or without them. 0: none. A probe costs about 0.2 CPU s
    (BENCHMARKS.md, "Setting notes")."""
    @property
    def environment_steps(self) -> int:
        """Steps of the environment head's fit: ``environment_fraction`` of ``iterations``, rounded."""
        return round(self.environment_fraction * self.iterations)

    compile: bool = False
    """torch.compile the decoder/sampler losses (and a uniform material's reference): faster
    steps after tens of seconds of compilation; worth it for long runs only."""


_FAST = TrainConfig(iterations=2000, batch=1024, decoder="3x64", lr_start=5e-3, mollify_samples=8,
                    mollify_min_degrees=1.0, mollify_mis=True, lobe_fraction=0.1, preview_iterations=100,
                    probe_every=250, footprint_samples=8, environment_fraction=0.5, energy_gain=0.5)

PRESETS = {
    # fast: a 2-core CPU in a couple of minutes per material: 2000 steps of 1024 rows. A step is overhead-bound
    # (half the rows cost about two thirds of the time), and the sharpest lobes need steps more than rows: against
    # 1000 x 2048, the near mirror's HDR FLIP 0.187 / 0.200 -> 0.158 / 0.163 and its energy 0.85 -> 0.945 / 1.012, every
    # sample's held-out error lower, for 20-45 % more training time; the balance's gain 0.5 (0.3 left the CarPaint at
    # 0.93, docs/history/fast-schedule-2026-12-07.md). So few steps need a higher
    # learning rate than the paper's 1e-3 (sample CarPaint, 3x64: HDR FLIP 0.45 at 1e-3,
    # 0.07 at 5e-3, 0.09 at 1e-2; docs/history/BENCHMARKS-2026-12-01.md).
    # fast and balanced keep a 1-degree mollification floor, estimated by MIS, with a tenth of the
    # directions drawn near the reference's lobes: without it a sharp clear coat lost most of its
    # grazing energy (CarPaint: albedo 0.19 instead of 0.81 at 5 degrees elevation). More lobe
    # directions overshoot at grazing angles (docs/history/BENCHMARKS-2026-12-01.md has the sweep).
    "fast": _FAST,
    # fast and standard average 8 footprint points per textured target, not 16: a step 1.5x cheaper at
    # the same FLIP (GlazedCeramic, BrushedMetal); 4 points are cheaper still and reach the
    # GlazedCeramic's 0.05 in 8.2 min, but stall the BrushedMetal at a higher error
    # (docs/history/time-to-quality-2026-12-03.md, section 8).
    # standard: fast's settings for 8x the rows (8000 steps of 2048), the CPU's quality setting (one thread:
    # about 8 min for a uniform material, about 11 for a 256² textured one). On the sample CarPaint (3x64,
    # HDR FLIP, sky / directional light) 1000 steps of 2048 gave 0.101 / 0.061 and 8000 give 0.075-0.088 /
    # 0.018-0.020, 4.3-5.0x better than the analytic fit (BENCHMARKS.md, "Accuracy against the analytic fit").
    # standard fits the preview fallback for the default 200 steps (fast: 100).
    # Every preset fits the environment head (prefiltered environment lighting): 1000 steps in fast (half its
    # 2000; 300 left the three-lobe head under-fitted: the sample Plastic's prefiltered render 0.063 against 0.057 at 1000,
    # docs/history/environment-lighting-2026-12-06.md); standard 2000, balanced 2000, paper 6000.
    # standard keeps the 2048 rows and the gain of 0.3 it was measured with (the near mirror: 0.144, energy 0.97-1.08).
    "standard": dataclasses.replace(_FAST, iterations=8000, batch=2048, energy_gain=0.3, preview_iterations=200,
                                    probe_every=500, environment_fraction=0.25),
    "balanced": TrainConfig(iterations=20_000, batch=16_384, decoder="3x64", lr_start=2e-3, mollify_samples=16,
                            max_resolution=1024, compile=True, mollify_min_degrees=1.0, mollify_mis=True,
                            lobe_fraction=0.1, probe_every=2000, environment_fraction=0.1, environment_batch=4096),
    "paper": TrainConfig(iterations=300_000, batch=65_536, mollify_fraction=20_000 / 300_000,
                         mollify_samples=256, footprint_samples=64, decoder="3x64", max_resolution=None,
                         compile=True, probe_every=10_000, environment_fraction=0.02, environment_batch=16_384),
}


def preset(name: str, **overrides) -> TrainConfig:
    """A preset with explicit overrides (``None`` values are ignored)."""
    if name not in PRESETS:
        raise ValueError(f"unknown preset '{name}': choose one of {', '.join(PRESETS)}")
    return dataclasses.replace(PRESETS[name], **{k: v for k, v in overrides.items() if v is not None})


_COUNTS = {"batch": 1, "latent_dim": 1, "mollify_samples": 1, "footprint_samples": 1, "checkpoint_every": 1,
           "frames": 0, "iterations": 0, "preview_iterations": 0, "probe_every": 0, "target_reuse": 1, "target_prefetch": 1,
           "environment_batch": 1}
"""Integer settings and their smallest valid value."""
_SHARES = ("encoder_fraction", "grazing_fraction", "lobe_fraction", "mollify_fraction", "block_fraction",
           "environment_fraction", "lift_fraction")
"""Settings that are a share of something, in [0, 1]."""
_FLAGS = {"batch": "--batch", "frames": "--frames", "iterations": "--iterations", "decoder": "--decoder",
          "max_resolution": "--max-texels", "seed": "--seed", "preview_iterations": "--preview-iterations"}


def validate_config(cfg: TrainConfig, allow_untrained: bool = False) -> None:
    """Raise :class:`~mtlx2neural.errors.InputError` naming the first invalid setting of ``cfg``
    (and the command-line flag that sets it), before any work.

    ``iterations = 0`` would export an untrained network: refused unless ``allow_untrained``.
    """
    import math

    # Local: the CLI's parser imports this module, and mlp imports torch.
    from mtlx2neural.model.mlp import parse_hidden

    def bad(name: str, why: str) -> InputError:
        flag = _FLAGS.get(name)
        return InputError(f"{flag + ' (' + name + ')' if flag else 'setting ' + name} = {getattr(cfg, name)!r}: "
                          f"{why}")

    for name, least in _COUNTS.items():
        v = getattr(cfg, name)
        if isinstance(v, bool) or not isinstance(v, int) or v < least:
            raise bad(name, f"must be a whole number of at least {least}")
    if cfg.target_reuse > cfg.batch:
        raise bad("target_reuse", f"must be at most the batch ({cfg.batch}): each step draws a K-th of it fresh")
    if cfg.iterations == 0 and not allow_untrained:
        raise bad("iterations", "0 steps would export an untrained network; give at least 1, or pass "
                                "--allow-untrained (allow_untrained=True) to export one on purpose")
    for name in _SHARES:
        v = getattr(cfg, name)
        if not (isinstance(v, (int, float)) and 0.0 <= v <= 1.0):
            raise bad(name, "must be a share between 0 and 1")
    for name in ("lr_start", "lr_end"):
        v = getattr(cfg, name)
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise bad(name, "must be a positive learning rate")
    if not (isinstance(cfg.brdf_eps, (int, float)) and math.isfinite(cfg.brdf_eps) and cfg.brdf_eps > 0):
        raise bad("brdf_eps", "must be a positive radiance scale (f * cos), e.g. 1e-4")
    if not (isinstance(cfg.brdf_floor, (int, float)) and math.isfinite(cfg.brdf_floor) and 1e-30 < cfg.brdf_floor < 1):
        raise bad("brdf_floor", "must be a BRDF value between 1e-30 and 1, e.g. 1e-8")
    for name in ("mollify_degrees", "mollify_min_degrees", "level_rate", "energy_gain"):
        v = getattr(cfg, name)
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
            raise bad(name, "must be a finite number >= 0")
    if cfg.max_resolution is not None and (not isinstance(cfg.max_resolution, int) or cfg.max_resolution < 1):
        raise bad("max_resolution", "must be None (no cap) or at least 1 texel")
    if isinstance(cfg.seed, bool) or not isinstance(cfg.seed, int) or not 0 <= cfg.seed < 2 ** 63:
        raise bad("seed", "must be a whole number between 0 and 2^63 - 1")
    for name in ("brdf_loss", "latent_format", "encoder_input"):
        choices = next(f.metadata["choices"] for f in dataclasses.fields(TrainConfig) if f.name == name)
        if getattr(cfg, name) not in choices:
            raise bad(name, f"must be one of {', '.join(choices)}")
    try:
        hidden = parse_hidden(cfg.decoder)
    except (ValueError, TypeError, AttributeError):
        hidden = ()
    if not hidden or any(w < 1 for w in hidden):
        raise bad("decoder", "must be hidden layers as LAYERSxWIDTH, e.g. 2x16, 2x32 or 3x64")
