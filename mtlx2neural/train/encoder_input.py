"""What the encoder reads of a texel: the parameter stack's raw channels, or those made comparable.

The stack's raw channels (``ParameterStack.sample_raw``) are LEAN moments and plain parameters in their
own units. A near-mirror's roughness lives in the second moments' excess over the squared mean slope,
about 1e-7 against slopes' 1e-4, which an MLP initialised for unit-scale inputs does not resolve in a
`fast` run: measured on the near-mirror sample, every decoded lobe came out 1.5-1.8° wide whatever the
texel's roughness, and the latents explained 32 % of the roughness's variance (docs/history/
energy-and-loss-2026-12-04.md).

``TrainConfig.encoder_input``:

- ``normalized`` (the default since 2026-12-06): every channel standardised by its mean and standard
  deviation over the stack's finest level (the deviation at least 1e-8), followed by log(alpha) of each LEAN
  lobe's decoded roughness (two values per lobe, alpha at least ``ALPHA_FLOOR``). Measured (`fast`, seed 0,
  docs/history/energy-and-loss-2026-12-06.md): HDR FLIP GlazedCeramic 0.079 against raw's 0.086,
  BrushedMetal 0.151 against 0.160, the near mirror 0.35 against 0.46, whose rough texels then decode as
  broad lobes (raw: as sharp as the smooth ones).
- ``raw``: the channels as they are.

A universal network reads the ``normalized`` features with its atlas's fixed statistics
(:meth:`EncoderInput.fixed`, :mod:`mtlx2neural.universal.weights`).

The statistics are recomputed from the stack, so a resumed run reads the same features. A uniform
material has no channels: both modes give the encoder nothing to read.
"""

from __future__ import annotations

import torch

ALPHA_FLOOR = 1e-4
"""Smallest GGX alpha whose log the ``normalized`` input takes (alpha 1e-4: roughness 0.01)."""
MODES = ("raw", "normalized")


def standardised(raw: torch.Tensor, columns: torch.Tensor | None, mean: torch.Tensor, std: torch.Tensor, stack,
                 lobes: list[str]) -> torch.Tensor:
    """The ``normalized`` features of raw channels [N, C]: ``raw[:, columns]`` (every column when None)
    standardised by ``mean`` and ``std`` (one value per column), then log(alpha) of each of ``lobes``' decoded
    roughness (``stack.decode``; two values per lobe, alpha at least :data:`ALPHA_FLOOR`)."""
    x = raw if columns is None else raw[:, columns.to(raw.device)]
    x = (x - mean.to(raw)) / std.to(raw)
    decoded = stack.decode(raw) if lobes else {}
    logs = [torch.log(decoded[f"{lobe}.roughness"].clamp_min(ALPHA_FLOOR)).to(raw) for lobe in lobes]
    return torch.cat([x, *logs], -1)


class EncoderInput:
    """The encoder's input for ``stack`` in ``mode`` (module docstring): call it on raw channels [N, C] to get
    the features [N, dim]. :meth:`fixed` reads given columns with given statistics instead (a universal
    network's)."""

    def __init__(self, stack, mode: str = "raw"):
        if mode not in MODES:
            raise ValueError(f"encoder input {mode!r}: choose one of {MODES}")
        self.stack, self.mode, self.columns = stack, mode, None
        channels = int(stack.levels[0].shape[0])
        self.lobes = list(getattr(stack, "lean_groups", []) or [])
        if mode == "raw" or channels == 0:
            self.mode, self.dim = "raw", channels
            return
        level0 = torch.cat([s.levels[0].float().reshape(channels, -1) for s in getattr(stack, "stacks", [stack])], 1)
        self.mean = level0.mean(1)
        self.std = level0.std(1, correction=0).clamp_min(1e-8)  # one texel: 0, not NaN
        self.dim = channels + 2 * len(self.lobes)

    @classmethod
    def fixed(cls, stack, columns: torch.Tensor, spec: dict | None) -> "EncoderInput":
        """The raw channels ``columns`` of ``stack`` (a shipped layout's order), as they are (``spec`` None) or
        in ``spec``'s mode with its statistics (:meth:`statistics`'s dict; its lobes named as ``stack`` names
        them)."""
        self = cls.__new__(cls)
        self.stack, self.columns = stack, columns
        self.mode = spec["mode"] if spec else "raw"
        self.lobes = list(spec["lobes"]) if spec else []
        if spec:
            self.mean = torch.tensor(spec["mean"], dtype=torch.float32)
            self.std = torch.tensor(spec["std"], dtype=torch.float32)
        self.dim = int(columns.numel()) + 2 * len(self.lobes)
        return self

    def statistics(self) -> dict | None:
        """What reproduces these features on another stack of the same layout (the universal networks ship it:
        :mod:`mtlx2neural.universal.weights`): ``{"mode", "mean", "std", "lobes"}``, or None in the raw mode."""
        if self.mode == "raw":
            return None
        return {"mode": self.mode, "mean": self.mean.tolist(), "std": self.std.tolist(), "lobes": list(self.lobes)}

    def __call__(self, raw: torch.Tensor) -> torch.Tensor:
        if self.mode == "raw":
            return raw if self.columns is None else raw[:, self.columns.to(raw.device)]
        return standardised(raw, self.columns, self.mean, self.std, self.stack, self.lobes)
