"""Untrained neural models for tests that check plumbing rather than fidelity."""

from __future__ import annotations

import torch


def randomise_latents(model, scale: float = 1.0):
    """Overwrite every latent level of ``model`` with Gaussian values of standard deviation ``scale``, drawn
    from torch's global generator (seed it first: the same seed gives the same latents); returns ``model``."""
    with torch.no_grad():
        for lv in model.latents.levels:
            lv.copy_(torch.randn(lv.shape) * scale)
    return model
