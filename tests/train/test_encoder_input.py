"""train/encoder_input.py: what the encoder reads of a texel (raw stack channels, or standardised ones plus
log roughness), on the near-mirror sample's parameter stack at 16²."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from mtlx2neural.train.config import preset
from mtlx2neural.train.encoder_input import ALPHA_FLOOR, EncoderInput

MIRROR = Path(__file__).resolve().parents[2] / "samples" / "mirror" / "polished_metal.usda"


@pytest.fixture(scope="module")
def mirror():
    """(reference, parameter stack at 16²) of the near-mirror sample: one LEAN lobe, five raw channels."""
    from mtlx2neural.graph import compile_material
    from mtlx2neural.reference import ReferenceMaterial
    from mtlx2neural.scene import find_material
    from mtlx2neural.textures.parameter_stack import build_parameter_stack

    src = find_material(MIRROR, "/World/Looks/PolishedMetal")
    compiled = compile_material(src.document, src.material)
    return ReferenceMaterial(compiled), build_parameter_stack(compiled, resolution=(16, 16))


def test_raw_is_the_stack_channels(mirror):
    _, stack = mirror
    raw = stack.levels[0].reshape(stack.levels[0].shape[0], -1).T
    feed = EncoderInput(stack, "raw")
    assert feed.dim == raw.shape[1] and feed(raw) is raw


def test_normalized_standardises_and_adds_log_roughness(mirror):
    """On the finest level the standardised channels have mean 0 and deviation 1 (within float32 rounding,
    1e-4; the population deviation, as a one-texel stack has one), a constant channel reads 0, and the last two
    columns are log(alpha) of the LEAN lobe."""
    _, stack = mirror
    raw = stack.levels[0].float().reshape(stack.levels[0].shape[0], -1).T
    feed = EncoderInput(stack, "normalized")
    assert feed.lobes and feed.dim == raw.shape[1] + 2 * len(feed.lobes)
    x = feed(raw)
    c = raw.shape[1]
    varying = raw.std(0) > 1e-7
    torch.testing.assert_close(x[:, :c].mean(0), torch.zeros(c), atol=1e-4, rtol=0)
    torch.testing.assert_close(x[:, :c].std(0, correction=0)[varying], torch.ones(int(varying.sum())), atol=1e-4, rtol=0)
    alpha = stack.decode(raw)[f"{feed.lobes[0]}.roughness"]
    torch.testing.assert_close(x[:, c:c + 2], torch.log(alpha.clamp_min(ALPHA_FLOOR)))
    assert float(x[:, c:].std()) > 0.1  # the roughness texture shows: alpha 4e-4..0.09 spans 5 in log


def test_a_training_reads_the_normalized_input(mirror, tmp_path):
    """The trainer builds the encoder for the features' width and bakes through them: the baked latents are
    the encoder's codes of the features, not of the raw channels."""
    from mtlx2neural.train.trainer import Trainer

    ref, stack = mirror
    cfg = preset("fast", iterations=4, batch=64, encoder_input="normalized", preview_iterations=0)
    trainer = Trainer(ref, stack, cfg, tmp_path / "run")
    assert trainer.model.encoder.net[0].in_features == stack.levels[0].shape[0] + 2
    for _ in range(2):  # the encoder phase reads the features of the rows' texels
        assert all(v == v for v in trainer.train_step().values() if isinstance(v, float))
    trainer.bake()
    raw = stack.levels[0].float().reshape(stack.levels[0].shape[0], -1).T
    with torch.no_grad():
        want = trainer.model.encoder(trainer.encoder_input(raw)).T.reshape(trainer.model.latents.levels[0].shape)
    torch.testing.assert_close(trainer.model.latents.levels[0].detach(), want)
