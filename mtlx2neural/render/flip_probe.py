"""A quick quality probe during training: HDR FLIP of the current model against the reference.

The conversion's own figure (``summary.json``'s ``flip_mean``) is measured once, after training,
on :data:`~mtlx2neural.render.renderer.VIEWS` at 96² and 32 samples per pixel. The probe measures
the same three views smaller (48², 4 samples per pixel by default), every ``TrainConfig.probe_every``
steps, so that the report can plot FLIP against training time: the speed/accuracy trade of a
longer run, read off one conversion. The reference's renders are made once, on the first call.
"""

from __future__ import annotations

import numpy as np
import torch

from mtlx2neural.render.renderer import VIEWS, image_errors, render


class FlipProbe:
    """``probe(model)`` -> mean HDR FLIP over ``views`` (each view's directional light on the unit sphere,
    :func:`~mtlx2neural.render.renderer.render` at ``res``² and ``spp`` samples per pixel, seeded per
    view as :func:`~mtlx2neural.render.renderer.compare` seeds them); ``texels`` (h, w) is the latent
    grid the level of detail is measured in. Draws no random numbers from any generator but its own
    seeded ones, so probing does not change a training run."""

    def __init__(self, reference, texels: tuple[int, int], res: int = 48, spp: int = 4, views=VIEWS):
        self.reference, self.texels, self.res, self.spp, self.views = reference, tuple(texels), res, spp, views
        self._references: list[np.ndarray] | None = None

    def _draw(self, material, i: int) -> np.ndarray:
        return render(material, self.views[i], self.res, self.spp, self.texels, seed=i)

    def __call__(self, model) -> float:
        with torch.no_grad():
            if self._references is None:
                self._references = [self._draw(self.reference, i) for i in range(len(self.views))]
            flips = [image_errors(ref, self._draw(model, i))["flip"] for i, ref in enumerate(self._references)]
        return float(np.mean(flips))
