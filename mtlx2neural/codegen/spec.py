"""The renderer-side networks of a neural material as plain arrays, for code generation.

A :class:`NetworkSpec` holds the decoder's frame layer, the decoder MLP, the optional albedo
head, the sampler MLP and the optional environment head of a :class:`~mtlx2neural.model.neural_material.NeuralMaterial`
(the training-only encoder is not part of it), as float32 NumPy arrays with torch's
``nn.Linear`` layout: weight ``[out, in]``, bias ``[out]``.

It is built from a model in memory (float32 weights) or from an export folder (the FP16
values of ``weights.bin``, read through ``weights.json``). :meth:`NetworkSpec.fp16` rounds
every weight to FP16 with the export's range check (:func:`mtlx2neural.formats.fp16.to_fp16`),
so a spec built from a model and one read back from its export hold the same FP16 values.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from mtlx2neural.errors import InputError
from mtlx2neural.formats.fp16 import to_fp16
from mtlx2neural.formats.weights import (
    ENVIRONMENT_OUTPUTS,
    SILENT_LOGIT,
    analytic_cosine_of,
    read_weights,
    upgrade_environment_head,
)
from mtlx2neural.textures.surface_maps import (
    ALPHA_CUTOFF,
    SurfaceMaps,
    read_surface_manifest,
    used_opacity,
)


@dataclass
class Layer:
    weight: np.ndarray  # [out, in] float32
    bias: np.ndarray    # [out] float32

    @property
    def shape(self) -> tuple[int, int]:
        return int(self.weight.shape[0]), int(self.weight.shape[1])


@dataclass
class NetworkSpec:
    latent_channels: int
    frames: int
    frame: np.ndarray | None          # [6 * frames, latent_channels] float32, None when frames = 0
    decoder: list[Layer]
    sampler: list[Layer]
    albedo: list[Layer] | None = None
    notes: list[str] = field(default_factory=list)  # FP16 range-check notes
    analytic_cosine: bool = True      # the decoder's RGB times max(0, wo.z) (model.decoder)
    udim_tiles: list[int] | None = None  # a UDIM material's trained tiles (model.latent), None otherwise
    environment: list[Layer] | None = None  # the prefiltered-lighting head (model.decoder), None without one

    @property
    def sharp_silent(self) -> bool:
        """Whether the environment head's sharp lobe carries nothing: its outputs (the first 3 of the last layer)
        have zero weights and a bias at or below :data:`~mtlx2neural.formats.weights.SILENT_LOGIT` (a legacy head,
        or one the fit silenced: ``train.environment_fit.silence_lobes``), so a shader can skip its lookup.
        False without an environment head."""
        if not self.environment:
            return False
        last = self.environment[-1]
        return bool(np.all(last.weight[:3] == 0.0) and np.all(last.bias[:3] <= SILENT_LOGIT))

    @property
    def decoder_hidden(self) -> list[int]:
        return [l.shape[0] for l in self.decoder[:-1]]

    @property
    def sampler_hidden(self) -> list[int]:
        return [l.shape[0] for l in self.sampler[:-1]]

    @property
    def decoder_inputs(self) -> int:
        return 2 * 3 * max(self.frames, 1) + self.latent_channels

    def networks(self) -> list[tuple[str, list[Layer]]]:
        """(name, layers) of the MLPs in a fixed order: decoder, albedo head (if any), sampler."""
        out = [("decoder", self.decoder)]
        if self.albedo:
            out.append(("albedo", self.albedo))
        out.append(("sampler", self.sampler))
        return out

    def fp16(self) -> NetworkSpec:
        """A copy with every weight rounded to FP16 (range-checked), held as float32."""
        notes: list[str] = []

        def r(a, what):
            h, n = to_fp16(a, what)
            notes.extend(n)
            return h.astype(np.float32)

        def layers(ls, what):
            return [Layer(r(l.weight, f"{what}.{i}.weight"), r(l.bias, f"{what}.{i}.bias")) for i, l in enumerate(ls)]

        return replace(self, frame=None if self.frame is None else r(self.frame, "frame_layer.weight"),
                       decoder=layers(self.decoder, "decoder"), sampler=layers(self.sampler, "sampler"),
                       albedo=layers(self.albedo, "albedo") if self.albedo else None,
                       environment=layers(self.environment, "environment") if self.environment else None, notes=notes)


def _layers(state: dict, prefix: str) -> list[Layer]:
    idx = sorted({int(m.group(1)) for k in state if (m := re.fullmatch(re.escape(prefix) + r"(\d+)\.weight", k))})
    return [Layer(np.asarray(state[f"{prefix}{i}.weight"], np.float32), np.asarray(state[f"{prefix}{i}.bias"], np.float32))
            for i in idx]


def spec_from_state(state: dict, analytic_cosine: bool = True) -> NetworkSpec:
    """A spec from tensors named as in the model's state dict (torch tensors or arrays);
    ``analytic_cosine`` as the model's decoder (the state dict does not record it)."""
    state = {k: (v.detach().cpu().float().numpy() if hasattr(v, "detach") else np.asarray(v, np.float32))
             for k, v in state.items()}
    decoder, sampler = _layers(state, "decoder.net."), _layers(state, "sampler.net.")
    if not decoder or not sampler:
        raise InputError("the weights hold no decoder or sampler network (decoder.net.*, sampler.net.*)")
    frame = state.get("decoder.frame_layer.weight")
    frames = 0 if frame is None else frame.shape[0] // 6
    c = decoder[0].shape[1] - 6 * max(frames, 1)
    if c <= 0 or sampler[0].shape[1] != 3 + c or (frame is not None and frame.shape != (6 * frames, c)):
        raise InputError(f"inconsistent network shapes: decoder input {decoder[0].shape[1]}, "
                         f"sampler input {sampler[0].shape[1]}, frame layer "
                         f"{None if frame is None else frame.shape}")
    if decoder[-1].shape[0] != 3 or sampler[-1].shape[0] != 9:
        raise InputError(f"the decoder must output 3 values and the sampler 9, got {decoder[-1].shape[0]} "
                         f"and {sampler[-1].shape[0]}")
    albedo = _layers(state, "decoder.albedo.") or None
    environment = _layers(upgrade_environment_head(dict(state)), "decoder.environment.") or None
    if environment and (environment[0].shape[1] != 3 * max(frames, 1) + c
                        or environment[-1].shape[0] != ENVIRONMENT_OUTPUTS):
        raise InputError(f"the environment head reads {environment[0].shape[1]} values and outputs "
                         f"{environment[-1].shape[0]}; it must read {3 * max(frames, 1) + c} and output "
                         f"{ENVIRONMENT_OUTPUTS}")
    return NetworkSpec(c, frames, frame, decoder, sampler, albedo, analytic_cosine=bool(analytic_cosine),
                       environment=environment)


def spec_from_model(model) -> NetworkSpec:
    """The spec of a NeuralMaterial (float32 weights as trained)."""
    spec = spec_from_state({k: v for k, v in model.state_dict().items() if k.startswith(("decoder.", "sampler."))},
                           model.decoder.analytic_cosine)
    return replace(spec, udim_tiles=getattr(getattr(model, "latents", None), "tile_list", None))


def spec_from_export(folder) -> NetworkSpec:
    """The spec of an export folder (``weights.json`` + ``weights.bin``: FP16 values)."""

    folder = Path(folder)
    manifest = folder / "weights.json" if folder.is_dir() else folder
    meta, tensors = read_weights(manifest)
    spec = spec_from_state(tensors, analytic_cosine_of(meta["architecture"], manifest))
    return replace(spec, udim_tiles=meta["architecture"].get("udim_tiles"))


def as_spec(model_or_export) -> NetworkSpec:
    """A spec from a NetworkSpec, a NeuralMaterial, or an export folder / weights manifest path."""
    if isinstance(model_or_export, NetworkSpec):
        return model_or_export
    if isinstance(model_or_export, (str, Path)):
        return spec_from_export(model_or_export)
    if hasattr(model_or_export, "state_dict"):
        return spec_from_model(model_or_export)
    raise TypeError(f"expected a NeuralMaterial, an export folder or a NetworkSpec, got {type(model_or_export)!r}")


# ------------------------------------------------------------------------------ emission and opacity

@dataclass(frozen=True)
class SurfaceSpec:
    """A material's emission and opacity as the shader generators need them: each a constant, a
    texture (its file name in ``folder``, with ``levels`` MIP levels and a ``size`` (width, height) level
    0) or absent, and the alpha mode (``opaque``, ``mask``: alpha-tested at ``alpha_cutoff``, or
    ``blend``). Built by :func:`surface_spec` from an export's ``surface.json`` or from a model's
    :class:`~mtlx2neural.textures.surface_maps.SurfaceMaps` (``folder`` None: maps in memory)."""

    emission_constant: tuple[float, float, float] | None = None
    emission_file: str | None = None
    opacity_constant: float | None = None
    opacity_file: str | None = None
    alpha_mode: str = "opaque"
    levels: int = 0
    size: tuple[int, int] | None = None
    folder: Path | None = None

    @property
    def alpha_cutoff(self) -> float | None:
        return ALPHA_CUTOFF if self.alpha_mode == "mask" else None

    @property
    def emits(self) -> bool:
        return self.emission_constant is not None or self.emission_file is not None

    @property
    def textured(self) -> bool:
        return self.emission_file is not None or self.opacity_file is not None

    @property
    def coverage_constant(self) -> float | None:
        """The constant coverage a consumer uses (a mask's constant alpha-tested), None unless constant."""
        return None if self.opacity_constant is None else used_opacity(self.opacity_constant, self.alpha_mode)


def _image_size(path: Path) -> tuple[int, int] | None:
    """(width, height) of level 0 of the image at ``path``, None when it cannot be opened (the
    generators that read the file report that)."""
    # Local: OpenImageIO only where a map's size is needed (imaging.image_io loads it on demand).
    from mtlx2neural.imaging.image_io import openimageio

    oiio = openimageio()
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        oiio.geterror()
        return None
    try:
        return int(inp.spec().width), int(inp.spec().height)
    finally:
        inp.close()


def _from_manifest(manifest: dict, folder: Path) -> SurfaceSpec:
    e, o = manifest.get("emission") or {}, manifest.get("opacity") or {}
    files = [x["file"] for x in (e, o) if "file" in x]
    levels = max([int(x.get("levels", 0)) for x in (e, o) if "file" in x], default=0)
    return SurfaceSpec(
        emission_constant=tuple(float(v) for v in e["constant"]) if "constant" in e else None,
        emission_file=e.get("file"), opacity_constant=float(o["constant"]) if "constant" in o else None,
        opacity_file=o.get("file"), alpha_mode=str(manifest.get("alpha_mode", "opaque")), levels=levels,
        size=_image_size(folder / files[0]) if files else None, folder=folder)


def _from_maps(maps: SurfaceMaps) -> SurfaceSpec:
    """From a :class:`~mtlx2neural.textures.surface_maps.SurfaceMaps`."""
    em, op = maps.emission_levels, maps.opacity_levels
    levels = em if em is not None else op
    return SurfaceSpec(
        emission_constant=None if maps.emission_constant is None else tuple(float(v) for v in maps.emission_constant),
        emission_file="emission.exr" if em is not None else None,
        opacity_constant=None if maps.opacity_constant is None else float(maps.opacity_constant),
        opacity_file="opacity.exr" if op is not None else None, alpha_mode=maps.alpha_mode,
        levels=len(levels) if levels is not None else 0,
        size=(int(levels[0].shape[-1]), int(levels[0].shape[-2])) if levels is not None else None)


def read_surface_spec(folder) -> SurfaceSpec | None:
    """The :class:`SurfaceSpec` of the export ``folder`` (or of the folder of a ``weights.json``) from its
    ``surface.json``; None when there is none (the material emits nothing and is opaque)."""
    folder = Path(folder)
    folder = folder.parent if folder.is_file() else folder
    manifest = read_surface_manifest(folder)
    if manifest is None:
        return None
    spec = _from_manifest(manifest or {}, folder)
    return spec if spec.emits or spec.alpha_mode != "opaque" else None


def surface_spec(source) -> SurfaceSpec | None:
    """The emission and opacity of ``source``: a :class:`SurfaceSpec` (as it is), an export folder or
    ``weights.json`` (:func:`read_surface_spec`), a ``surface.json`` manifest (dict, files in the current
    folder), a SurfaceMaps, or a model with a ``surface`` attribute; None when it emits nothing and is
    opaque, or holds no such information (a NetworkSpec)."""
    if source is None or isinstance(source, SurfaceSpec):
        return source
    if isinstance(source, (str, Path)):
        return read_surface_spec(source)
    if isinstance(source, dict):
        spec = _from_manifest(source, Path("."))
    elif isinstance(source, SurfaceMaps):
        spec = _from_maps(source)
    elif hasattr(source, "surface") and not isinstance(source, NetworkSpec):
        return surface_spec(source.surface)
    else:
        return None
    return spec if spec.emits or spec.alpha_mode != "opaque" else None
