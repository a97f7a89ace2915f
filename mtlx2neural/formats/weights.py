"""Network weights as one FP16 binary plus a JSON manifest.

``weights.bin``: IEEE binary16, little endian. Every Linear layer of the
renderer-side networks, in this order: the decoder's frame layer (weight only,
it has no bias; absent when frames = 0), the decoder MLP, the optional albedo
head, the sampler MLP, the optional environment head (per-lobe reflectance for prefiltered
lighting, ``model.decoder``). Each weight is row-major [out_features, in_features] and
is followed by its bias [out_features]. Every tensor starts at a byte offset
that is a multiple of 16; the gaps are zero. The training-only encoder is not
exported.

``weights.json``: the manifest. ``tensors`` lists name (the torch state-dict
name, e.g. ``decoder.net.0.weight``), shape, dtype ("float16"), byte offset and
byte length; ``architecture`` describes how the tensors compose into the networks
(input layouts, activations, the proxy's parameter order); ``sha256`` is the
binary's digest; ``notes`` are the FP16 range-check notes. Both files are
written under a temporary name and renamed.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import torch
from torch import nn

from mtlx2neural.atomic import atomic_path
from mtlx2neural.errors import InputError
from mtlx2neural.formats.fp16 import to_fp16
from mtlx2neural.formats.latent_codec import architecture_entries

OUTPUT_OFFSET = 3.0
"""The decoder's output activation is exp(x - OUTPUT_OFFSET); the manifest records it for the shaders."""

ENVIRONMENT_OUTPUTS = 9
"""The environment head's outputs: the reflectance (RGB) of the sharp, the specular and the diffuse lobe."""
LEGACY_ENVIRONMENT_OUTPUTS = 6
"""An environment head written before the sharp lobe: the specular and the diffuse lobe only."""
SILENT_LOGIT = -100.0
"""The raw output that :func:`upgrade_environment_head` gives the sharp lobe of a legacy head: exp(-103) is
0 in FP16 and about 1e-45 in FP32, so that lobe carries nothing and the shading is the legacy one."""

FORMAT = "mtlx2neural-weights"
VERSION = 1
ALIGN = 16
LAYOUT = "row_major_fp16"
PREFIXES = ("decoder.frame_layer.", "decoder.net.", "decoder.albedo.", "sampler.net.", "decoder.environment.")
# The decoder's output activation token (USD ``neural:outputActivation``) -> whether the cosine is analytic.
OUTPUT_ACTIVATIONS = {"exp_minus_3_cos": True, "exp_minus_3": False}


def upgrade_environment_head(state: dict, prefix: str = "decoder.environment.") -> dict:
    """``state`` (a state dict of tensors or arrays, changed in place and returned) with a legacy environment head of
    :data:`LEGACY_ENVIRONMENT_OUTPUTS` outputs grown to :data:`ENVIRONMENT_OUTPUTS`: three new first outputs,
    the sharp lobe's, with zero weights and bias :data:`SILENT_LOGIT`, so every consumer reads three lobes and
    the legacy model shades as before. Other states are returned unchanged."""
    layers = sorted(int(k[len(prefix):].split(".")[0]) for k in state if k.startswith(prefix) and k.endswith(".weight"))
    if not layers:
        return state
    w_key, b_key = f"{prefix}{layers[-1]}.weight", f"{prefix}{layers[-1]}.bias"
    w, b = state[w_key], state[b_key]
    if w.shape[0] != LEGACY_ENVIRONMENT_OUTPUTS:
        return state
    if isinstance(w, np.ndarray):  # the shader generators' arrays
        state[w_key] = np.concatenate([np.zeros((3, w.shape[1]), w.dtype), w])
        state[b_key] = np.concatenate([np.full(3, SILENT_LOGIT, b.dtype), b])
    else:
        state[w_key] = torch.cat([w.new_zeros(3, w.shape[1]), w])
        state[b_key] = torch.cat([b.new_full((3,), SILENT_LOGIT), b])
    return state


def output_activation_token(analytic_cosine: bool) -> str:
    """``exp_minus_3_cos``: rgb = exp(min(x, 30) - 3) * max(0, wo.z); ``exp_minus_3``: without the cosine."""
    return next(token for token, cos in OUTPUT_ACTIVATIONS.items() if cos == bool(analytic_cosine))


def analytic_cosine_of(arch: dict, where) -> bool:
    """Whether the manifest architecture ``arch`` (read from ``where``) multiplies the decoder by the cosine."""
    token = arch.get("output_activation")
    if token not in OUTPUT_ACTIVATIONS:
        raise InputError(f"{where}: unknown decoder output_activation {token!r} (this mtlx2neural reads "
                         f"{', '.join(OUTPUT_ACTIVATIONS)}); re-export with this version")
    return OUTPUT_ACTIVATIONS[token]


def _hidden(seq: nn.Sequential | None) -> list[int]:
    if seq is None:
        return []
    return [m.out_features for m in seq if isinstance(m, nn.Linear)][:-1]


def exported_tensors(model) -> list[tuple[str, torch.Tensor]]:
    """(state-dict name, tensor) of every exported tensor, in file order."""
    state = model.state_dict()
    left = [k for k in state if k.startswith(("decoder.", "sampler.")) and not k.startswith(PREFIXES)]
    if left or getattr(getattr(model, "sampler", None), "isotropic", False):
        raise ValueError(f"an ablation model (tensors {left}, isotropic sampler "
                         f"{getattr(model.sampler, 'isotropic', False)}) cannot be exported: the shaders "
                         f"do not implement it")
    return [(k, state[k]) for p in PREFIXES for k in state if k.startswith(p)]


def architecture(model) -> dict:
    """The networks' shapes and conventions, for the manifest and the USD attributes."""
    dec, lat = model.decoder, model.latents
    c = int(lat.channels)
    per_dir = 3 * max(dec.frames, 1)
    return {
        "latent_channels": c,
        "frames": int(dec.frames),
        "decoder_hidden": list(dec.hidden),
        "sampler_hidden": _hidden(model.sampler.net),
        "encoder_hidden": _hidden(model.encoder.net),
        "albedo_head": dec.albedo is not None,
        "environment_head": dec.environment is not None,
        "activation": "relu",
        "output_activation": output_activation_token(dec.analytic_cosine),
        "output_offset": OUTPUT_OFFSET,
        "output_clamp": 30.0,
        "decoder_input": (f"[wi in frame 0..{dec.frames - 1} as (t, b, n), wo likewise, latent[{c}]] "
                          f"= {2 * per_dir + c} values" if dec.frames else
                          f"[wi (3), wo (3), latent[{c}]] = {6 + c} values"),
        "frame_layer_output": "per frame: normal offset v0 (3), tangent offset v1 (3); "
                              "n = normalize(v0 + (0,0,1)), t = normalize(v1 + (1,0,0)), b = cross(n, t)",
        "decoder_output": ("rgb = exp(min(x, 30) - output_offset) * max(0, wo.z)" if dec.analytic_cosine
                           else "rgb = exp(min(x, 30) - output_offset)") + ": f(wi, wo) * max(0, wo.z), linear RGB",
        "sampler_input": f"[wi (3), latent[{c}]] = {3 + c} values",
        "sampler_output": "alpha_x, alpha_y, rho, slope_spec (2), slope_diffuse (2), logit_spec, logit_diffuse",
        "proxy_type": "tilted_cosine_aniso_ggx",
        **({"environment_input": "as the albedo head: [wi in the frames, latent]",
            "environment_output": "rgb_sharp, rgb_spec, rgb_diffuse = exp(min(x, 30) - output_offset): the "
                                  "reflectance of the sharp lobe (GGX alpha 0.005 about the specular lobe's mean "
                                  "normal) and of the sampler's specular and diffuse lobe"} if dec.environment is not None else {}),
        "latent_resolution": [int(lat.levels[0].shape[-1]), int(lat.levels[0].shape[-2])],  # width, height
        "levels": int(lat.num_levels),
        # UDIM materials only: the trained tiles, in the order of the latents' leading axis
        **({"udim_tiles": lat.tile_list} if getattr(lat, "tile_list", None) else {}),
        **architecture_entries(getattr(lat, "codec", None)),
    }


def _atomic_write(path: Path, data: bytes) -> None:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def write_weights(model, folder, stem: str = "weights") -> tuple[dict, list[str]]:
    """Write ``folder/<stem>.bin`` and ``folder/<stem>.json``; returns (manifest, FP16 notes)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    blob, entries, notes = bytearray(), [], []
    for name, t in exported_tensors(model):
        half, n = to_fp16(t, f"weight {name}")
        notes += n
        blob += b"\0" * (-len(blob) % ALIGN)
        raw = half.tobytes(order="C")
        entries.append({"name": name, "shape": list(t.shape), "dtype": "float16",
                        "offset": len(blob), "length": len(raw)})
        blob += raw
    blob += b"\0" * (-len(blob) % ALIGN)
    manifest = {"format": FORMAT, "version": VERSION, "file": f"{stem}.bin", "layout": LAYOUT,
                "byte_order": "little", "alignment": ALIGN, "total_bytes": len(blob),
                "sha256": hashlib.sha256(blob).hexdigest(), "architecture": architecture(model),
                "tensors": entries, "notes": notes}
    _atomic_write(folder / f"{stem}.bin", bytes(blob))
    _atomic_write(folder / f"{stem}.json", (json.dumps(manifest, indent=2) + "\n").encode())
    return manifest, notes


def read_weights(manifest_path, weights_path=None) -> tuple[dict, dict[str, torch.Tensor]]:
    """(manifest, {name: float32 tensor holding the stored half values}) from a manifest and its binary
    (``weights_path`` defaults to the manifest's ``file`` beside it). Checks format, size and digest."""
    manifest_path = Path(manifest_path)
    try:
        manifest = json.loads(manifest_path.read_text())
    except (OSError, ValueError) as exc:
        raise InputError(f"{manifest_path}: cannot read the weights manifest ({exc})") from None
    if manifest.get("format") != FORMAT or manifest.get("version") != VERSION:
        raise InputError(f"{manifest_path}: not a {FORMAT} v{VERSION} manifest "
                         f"(format {manifest.get('format')!r}, version {manifest.get('version')!r})")
    bin_path = Path(weights_path) if weights_path else manifest_path.with_name(manifest["file"])
    try:
        blob = bin_path.read_bytes()
    except OSError as exc:
        raise InputError(f"{bin_path}: cannot read the weights ({exc})") from None
    if len(blob) != manifest["total_bytes"] or hashlib.sha256(blob).hexdigest() != manifest["sha256"]:
        raise InputError(f"{bin_path}: size or sha256 differs from {manifest_path}; the weights are corrupt "
                         f"or from another export. Re-run the export.")
    tensors = {}
    for e in manifest["tensors"]:
        a = np.frombuffer(blob, dtype="<f2", count=e["length"] // 2, offset=e["offset"])
        tensors[e["name"]] = torch.from_numpy(a.astype(np.float32).reshape(e["shape"]))
    return manifest, tensors
