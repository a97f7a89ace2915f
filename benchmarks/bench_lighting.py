"""Neural 3x64 versus the analytic baseline under a directional light and under environments.

Run:  python benchmarks/bench_lighting.py CarPaint [GlazedCeramic ...]   (from the repository root)

Trains the case (``bench_fidelity.CASES``) with the ``fast`` preset and 3x64, fits the
analytic baseline (1000 steps), and reports mean HDR FLIP over the three fixed views
(sphere, 96², 64 spp) under: the views' directional lights; the procedural sky
(``EnvironmentMap.sky``); and MaterialX's ``goegap.hdr`` (``../shared``, pre-filtered).
A single directional light shows one highlight per point, which hides a layered
material's structure (a sharp coat over a broad base reads as one lobe); an environment
shows the whole lobe at once.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_fidelity import ROOT, train_and_model  # noqa: E402

from mtlx2neural.baseline.analytic_model import fit_analytic  # noqa: E402
from mtlx2neural.render.lighting import EnvironmentMap  # noqa: E402
from mtlx2neural.render.renderer import compare  # noqa: E402
from mtlx2neural.train.config import preset  # noqa: E402

GOEGAP = ROOT.parent / "shared/assets/materialx/resources/Lights/irradiance/goegap.hdr"


def main(names):
    lightings = {"directional": {}, "sky": {"lights": [EnvironmentMap.sky()]}}
    if GOEGAP.exists():
        lightings["goegap"] = {"lights": [EnvironmentMap.from_file(GOEGAP)]}
    print("| material | lighting | analytic FLIP | neural 3x64 FLIP | analytic / neural |")
    print("|---|---|---|---|---|")
    for name in names:
        ref, stack, model, _ = train_and_model(name, preset("fast", decoder="3x64"))
        analytic = fit_analytic(ref, stack, iterations=1000, batch=4096, seed=0)
        for label, kw in lightings.items():
            def flip(m):
                return float(np.mean([e["flip"] for e in compare(ref, m, texels=tuple(stack.resolution), spp=64, **kw)]))
            a, n = flip(analytic), flip(model)
            print(f"| {name} | {label} | {a:.3f} | {n:.3f} | {a / n:.2f}x |", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:] or ["CarPaint", "GlazedCeramic"])
