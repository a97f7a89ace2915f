"""How the latent pyramid is laid out and filled, per kind of material.

The model's latents (:class:`~mtlx2neural.model.latent.LatentPyramid`) are a grid per MIP level:
``[C, H, W]``, or ``[T, C, H, W]`` for a UDIM material's ``T`` trained tiles. Three kinds, chosen by
:func:`latent_init_for` from the parameter stack:

* :class:`UniformLatents`: no varying parameter: a 1x1 grid holding the encoder's one code (its
  input has no channels), copied to every tile of a tiled stack;
* :class:`TexturedLatents`: a :class:`~mtlx2neural.textures.parameter_stack.ParameterStack`'s
  grid, every texel of every level encoded from the stack's channels (in chunks of
  ``ENCODE_CHUNK`` texels);
* :class:`UdimLatents`: a :class:`~mtlx2neural.train.udim.TiledStack`'s grid, each tile's latents
  encoded from that tile's stack.

Each gives the grid's ``resolution`` and :meth:`encode` (the bake: the encoder over every texel,
into the pyramid, without gradient). :func:`noise_latents` is the start of a run without an encoder
phase (any kind), and :func:`freeze_encoder` ends the encoder's training.
"""

from __future__ import annotations

import torch

from mtlx2neural.train.udim import is_udim_stack

ENCODE_CHUNK = 65536  # texels per encoder call in the bake of a textured material (bounds its memory)
NOISE_STD = 0.1  # standard deviation of the latents of a run without an encoder phase


def is_textured(stack) -> bool:
    """Whether ``stack`` has varying parameters (channels): a latent per texel, else one code."""
    return stack.levels[0].shape[0] > 0


def encode_level(encoder, level: torch.Tensor, features=None) -> torch.Tensor:
    """The encoder's codes [D, H, W] of one stack level [C, H, W], ``ENCODE_CHUNK`` texels per call;
    ``features`` (:class:`~mtlx2neural.train.encoder_input.EncoderInput`) maps the raw channels to its input."""
    raw = level.float().reshape(level.shape[0], -1).T
    feed = features if features is not None else (lambda x: x)
    codes = torch.cat([encoder(feed(raw[s:s + ENCODE_CHUNK])) for s in range(0, raw.shape[0], ENCODE_CHUNK)])
    return codes.T.reshape(-1, *level.shape[1:])


class UniformLatents:
    """A uniform material's latents: one code on a 1x1 grid (per tile of a tiled stack)."""

    resolution = (1, 1)

    def __init__(self, stack):
        self.stack = stack

    def encode(self, model, features=None) -> None:
        """The encoder's code for no channels, into every level (and tile) of ``model.latents``."""
        with torch.no_grad():
            for lv in model.latents.levels:
                lv.copy_(model.encoder(torch.zeros(1, 0)).T.reshape(lv.shape[-3:]).expand_as(lv))


class TexturedLatents:
    """A textured material's latents: the stack's grid, a code per texel of every level."""

    def __init__(self, stack):
        self.stack = stack
        self.resolution = stack.resolution

    def encode(self, model, features=None) -> None:
        """The encoder over every texel of every stack level, into the matching level of ``model.latents``."""
        with torch.no_grad():
            for k, lv in enumerate(model.latents.levels):
                lv.copy_(encode_level(model.encoder, self.stack.levels[k], features))


class UdimLatents(TexturedLatents):
    """A UDIM material's latents: the tiles' shared grid, each tile encoded from its own stack."""

    def encode(self, model, features=None) -> None:
        """The encoder over every texel of every level of each tile's stack, into that tile's latents."""
        with torch.no_grad():
            for k, lv in enumerate(model.latents.levels):
                for t, tile_stack in enumerate(self.stack.stacks):  # one [C, H, W] stack level per tile
                    lv[t].copy_(encode_level(model.encoder, tile_stack.levels[k], features))


def latent_init_for(stack):
    """The latents of ``stack``'s kind of material (module docstring)."""
    if not is_textured(stack):
        return UniformLatents(stack)
    return UdimLatents(stack) if is_udim_stack(stack) else TexturedLatents(stack)


def noise_latents(model, seed: int) -> None:
    """Every level of ``model.latents`` set to Gaussian noise of std ``NOISE_STD``, from a generator
    seeded with ``seed`` (a run without an encoder phase: the ablation's "vanilla" model)."""
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for lv in model.latents.levels:
            lv.copy_(NOISE_STD * torch.randn(lv.shape, generator=g))


def freeze_encoder(model) -> None:
    """Stop training ``model.encoder`` (after the bake, or with no encoder phase)."""
    for p in model.encoder.parameters():
        p.requires_grad_(False)
