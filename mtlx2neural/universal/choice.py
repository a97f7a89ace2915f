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
STEPS = 900
"""The universal path's fine-tune steps by default (``--universal-steps``), each on :data:`FINE_TUNE_ROWS` rows.
Measured on the scene sample (``fast``, 2 cores, 2026-12-06; own training: lava 0.0114, leaf 0.0381 HDR FLIP):
900 steps of 1024 rows give the lava 0.0124 (1.09x) in 22.8 s and the leaf 0.0302 in 25.4 s, where 300 steps of
2048 gave 0.0170 (1.49x) in 19.2 s and 0.0336 in 20.4 s (docs/history/fine-tune-speed-2026-12-06.md)."""
FINE_TUNE_ROWS = 1024
"""Rows of each fine-tune step, whatever the preset's ``batch``: the step count is fixed (:data:`STEPS`), so the
rows a fine-tune sees are set here. A step's cost on the CPU is mostly fixed (half the rows cost about two
thirds of the time), and more, smaller steps of the same material converge faster: the lava reached 0.0144
with 600 steps of 1024 rows in 11.5 s of training against 0.0146 with 450 of 2048 in 13.2 s."""
SCENE_FINE_TUNE_ROWS = 2048
"""Rows of a joint step of a group whose every material is on the universal path, split between the step's
materials (:func:`~mtlx2neural.train.shared.scene_batch`). Scene sample, 300 joint steps, without the energy
balance (2026-12-07): 2048 rows give HDR FLIP 0.0855 in 28.9 s, 1024 (``fast``'s own batch) 0.1026 in 28.7 s."""
SCENE_STEP_SHARE = 1 / 3
"""``--network scene``, every material of the group encoded by the shipped network: the group's joint steps
are this share of ``--universal-steps`` (300 of the default 900). A joint step trains every material at once on
the group's full batch, so its cost does not shrink with the batch as one material's step does. Measured on the
scene sample (``fast``, 2 cores; per-material training: 105-121 s, mean HDR FLIP 0.121): 300 joint steps 40-44 s,
0.1215 (+0.7 %); 200 steps 36-43 s, 0.1265 (+4.8 %): no time gain beyond this machine's noise; 150 steps 0.139."""


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
