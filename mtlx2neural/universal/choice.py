"""Which path a material's conversion takes: its own training, or its shading model's universal network.

:func:`choose_encoder` decides per material, before training, from ``--encoder``:

- ``material``: every material trains its own encoder, decoder and sampler;
- ``universal``: a material takes the universal path (:mod:`.fit`) when its surface shader is a
  shading model with a shipped network (:mod:`.canonical`, :mod:`.weights`), its parameters vary over
  its surface (a uniform material has one code to fit and trains quickly on its own), and the
  settings' network shape is the shipped one's; else it trains on its own, and the choice says why.

``inspect`` and the summary print :attr:`EncoderChoice.text`.
"""

from __future__ import annotations

from dataclasses import dataclass

ENCODERS = ("material", "universal")
TUNES = ("networks", "latents")
"""What the universal path's fine-tune trains besides the latents (:mod:`mtlx2neural.universal.fit`)."""
STEPS = 300
"""The universal path's fine-tune steps by default (``--universal-steps``): on the scene sample (``fast``,
2 cores) 200 steps leave the lava at 1.43x its own network's HDR FLIP, 300 at 1.14x, 400 at 1.03x
(docs/history/universal-2026-12-05.md)."""


@dataclass
class EncoderChoice:
    """The path of one material: ``universal`` with the ``model`` and fine-tune ``steps``, or ``material``
    (``reason``: why, when ``universal`` was asked for)."""

    path: str
    model: str | None = None
    steps: int = 0
    tune: str = "networks"
    """What the fine-tune trains besides the latents (:data:`TUNES`)."""
    weights_sha: str | None = None
    reason: str = ""

    @property
    def universal(self) -> bool:
        return self.path == "universal"

    @property
    def text(self) -> str:
        if self.universal:
            return (f"universal {self.model} network (weights {self.weights_sha[:12]}): encode the parameter "
                    f"pyramid, fine-tune {'the latents and networks' if self.tune == 'networks' else 'the latents alone'} "
                    f"for {self.steps} steps")
        return "own network (per-material training)" + (f": {self.reason}" if self.reason else "")

    @property
    def tag(self) -> str:
        """What joins the material's cache key: the path, and for a universal one the weights and steps."""
        return f"\0encoder={self.path}|{self.model}|{self.weights_sha}|{self.steps}|{self.tune}" if self.universal else ""

    def record(self) -> dict:
        return {"path": self.path, "model": self.model, "steps": self.steps, "tune": self.tune,
                "weights_sha256": self.weights_sha,
                "text": self.text}


def choose_encoder(asked: str, document, material: str | None, compiled, cfg, steps: int,
                   tune: str = "networks") -> EncoderChoice:
    """The path of one material (module docstring); ``compiled`` its CompiledMaterial (None for a measured
    table), ``cfg`` its TrainConfig, ``steps`` and ``tune`` the universal path's fine-tune."""
    if asked != "universal":
        return EncoderChoice("material")
    if compiled is None:
        return EncoderChoice("material", reason="a measured BRDF has no shading model")
    from mtlx2neural.universal.canonical import eligibility  # Local: only when asked
    from mtlx2neural.universal.weights import (  # Local: only when asked
        load_weights,
        shape_mismatch,
    )

    elig = eligibility(document, material)
    if elig.model is None:
        return EncoderChoice("material", reason=elig.reason)
    if not compiled.varying_parameters():
        return EncoderChoice("material", reason="spatially uniform (one latent code: its own training is short)")
    weights = load_weights(elig.model)
    if weights is None:
        return EncoderChoice("material", reason=f"no universal {elig.model} network is shipped")
    differ = shape_mismatch(weights, cfg)
    if differ:
        return EncoderChoice("material", reason=f"the settings' network differs from the shipped universal "
                                                f"{elig.model} network's in {', '.join(differ)}")
    return EncoderChoice("universal", elig.model, steps, tune, weights["sha256"])
