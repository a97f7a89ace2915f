"""What the encoder reads of a texel: the parameter stack's raw channels, or those made comparable.

The stack's raw channels (``ParameterStack.sample_raw``) are LEAN moments and plain parameters in their
own units. A near-mirror's roughness lives in the second moments' excess over the squared mean slope,
about 1e-7 against slopes' 1e-4, which an MLP initialised for unit-scale inputs does not resolve in a
`fast` run: measured on the near-mirror sample, every decoded lobe came out 1.5-1.8° wide whatever the
texel's roughness, and the latents explained 32 % of the roughness's variance (docs/history/
energy-and-loss-2026-12-04.md).

``TrainConfig.encoder_input``:

- ``raw`` (the default): the channels as they are.
- ``normalized``: every channel standardised by its mean and standard deviation over the stack's finest
  level (the deviation at least 1e-8), followed by log(alpha) of each LEAN lobe's decoded roughness (two
  values per lobe, alpha at least ``ALPHA_FLOOR``). Measured (`fast`, seeds 0 / 1,
  ``benchmarks/bench_energy.py --set encoder_input=normalized``): HDR FLIP GlazedCeramic 0.075 / 0.072 against
  0.083 / 0.079, BrushedMetal 0.163 / 0.170 against 0.174 / 0.184 (energy unchanged), the near mirror 0.393
  against 0.531 (seed 0; its coarse levels then keep 78-82 % of the energy).

The statistics are recomputed from the stack, so a resumed run reads the same features. A uniform
material has no channels: both modes give the encoder nothing to read.
"""

from __future__ import annotations

import torch

ALPHA_FLOOR = 1e-4
"""Smallest GGX alpha whose log the ``normalized`` input takes (alpha 1e-4: roughness 0.01)."""
MODES = ("raw", "normalized")


class EncoderInput:
    """The encoder's input for ``stack`` in ``mode`` (module docstring): call it on raw channels [N, C] to get
    the features [N, dim]."""

    def __init__(self, stack, mode: str = "raw"):
        if mode not in MODES:
            raise ValueError(f"encoder input {mode!r}: choose one of {MODES}")
        self.stack, self.mode = stack, mode
        channels = int(stack.levels[0].shape[0])
        self.lobes = list(getattr(stack, "lean_groups", []) or [])
        if mode == "raw" or channels == 0:
            self.mode, self.dim = "raw", channels
            return
        level0 = torch.cat([s.levels[0].float().reshape(channels, -1) for s in getattr(stack, "stacks", [stack])], 1)
        self.mean = level0.mean(1)
        self.std = level0.std(1).clamp_min(1e-8)
        self.dim = channels + 2 * len(self.lobes)

    def __call__(self, raw: torch.Tensor) -> torch.Tensor:
        if self.mode == "raw":
            return raw
        x = (raw - self.mean.to(raw)) / self.std.to(raw)
        decoded = self.stack.decode(raw) if self.lobes else {}
        logs = [torch.log(decoded[f"{lobe}.roughness"].clamp_min(ALPHA_FLOOR)).to(raw) for lobe in self.lobes]
        return torch.cat([x, *logs], -1)
