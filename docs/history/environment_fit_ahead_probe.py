"""Time the environment-head fit (the fast preset's steps and rows) with its rows drawn 1 and 25 steps ahead,
alternating, in one process (an untrained, baked model: time only, not fit quality).

Run:  python docs/history/environment_fit_ahead_probe.py [CarPaint|Plastic]
"""

import sys
import tempfile
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests"))
from materials import layered_spheres_material  # noqa: E402 - the tests' sample materials

from mtlx2neural.train import environment_fit  # noqa: E402
from mtlx2neural.train.config import preset  # noqa: E402
from mtlx2neural.train.trainer import Trainer  # noqa: E402

torch.set_num_threads(2)
name = sys.argv[1] if len(sys.argv) > 1 else "CarPaint"
ref, stack = layered_spheres_material(name)
cfg = preset("fast", seed=0)
trainer = Trainer(ref, stack, cfg, tempfile.mkdtemp())
trainer.bake()
seconds = {1: [], 25: []}
for _ in range(2):
    for ahead in seconds:
        environment_fit.AHEAD = ahead
        t = time.time()
        environment_fit.fit_environment_head(trainer, cfg.environment_steps, cfg.environment_batch)
        seconds[ahead].append(round(time.time() - t, 2))
print(f"{name}: {cfg.environment_steps} steps x {cfg.environment_batch} rows; seconds by steps drawn ahead: {seconds}")
