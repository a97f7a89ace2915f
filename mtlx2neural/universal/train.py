"""Train a shading model's universal network on its parameter atlas, and write the weights the package ships.

``python -m mtlx2neural.universal.train [--model UsdPreviewSurface] [--steps N] [--size S] [--seed K] [--prefetch P]
[--input normalized|raw] [--brdf-eps E] [--brdf-floor F]``

1. Write the model's atlas (:mod:`.atlas`: random parameter textures, ``size``² texels, seeded).
2. Compile it in the canonical form (:mod:`.canonical`) and build its parameter stack, as a conversion
   does for a material.
3. Train one :class:`~mtlx2neural.train.trainer.Trainer` on it with the ``fast`` preset's settings, the
   steps and learning rate given here, and the encoder phase for the whole run
   (``encoder_fraction`` 1): the decoder and the sampler then learn from the encoder's codes, which are
   what a material's latents start from (:mod:`.fit`). The environment head is fitted last, as usual.
   ``prefetch`` draws the rows of that many steps in one call to the reference (``target_prefetch``).
   ``input`` is what the encoder reads (:mod:`mtlx2neural.train.encoder_input`): ``normalized``, the
   atlas's channels standardised by the atlas's own statistics, plus log roughness, which every material
   is then read with; ``brdf_eps`` is log-L1's scale, ``brdf_floor`` its floor and ``energy_gain`` its energy balance
   (``TrainConfig``'s).
4. Save the encoder, decoder (with its environment head) and sampler with the stack's channel layout,
   the encoder's input statistics and the run's provenance (:mod:`.weights`).

The run is deterministic for one seed, torch version and thread count. Its cost grows with ``steps``
(0.05-0.08 s per step on 2 CPU cores: 857-1223 s for 16000 steps, 2026-12-06).
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import sys
import tempfile
import time
from pathlib import Path

import MaterialX as mx
import torch

from mtlx2neural.universal.atlas import ATLAS_MATERIAL, write_atlas
from mtlx2neural.universal.canonical import canonical_document, canonical_name
from mtlx2neural.universal.weights import (
    NETWORK_FIELDS,
    WEIGHTS_DIR,
    save_weights,
    weights_path,
)

DEFAULT_STEPS = 6000
DEFAULT_SIZE = 512
DEFAULT_LR = 2e-3
ENVIRONMENT_FRACTION = 0.1  # of the steps: the environment head fitted last (fast: 1.0 of 1000)
INPUTS = ("normalized", "raw")


def atlas_material(folder: Path, model: str, size: int, seed: int):
    """(compiled canonical atlas, its reference, its parameter stack), the atlas written into ``folder``."""
    from mtlx2neural.graph.compile import compile_material  # Local: fast --help
    from mtlx2neural.reference.material import ReferenceMaterial  # Local: fast --help
    from mtlx2neural.textures.parameter_stack import (
        build_parameter_stack,  # Local: fast --help
    )

    doc = mx.createDocument()
    mx.readFromXmlFile(doc, str(write_atlas(folder, model, size, seed)))
    compiled = compile_material(canonical_document(doc, ATLAS_MATERIAL), ATLAS_MATERIAL)
    return compiled, ReferenceMaterial(compiled), build_parameter_stack(compiled)


def folded_constants(stack) -> dict:
    """{canonical name: [values]} of the atlas's parameters that folded to numbers: a material's channel that
    the atlas lacks is read as the atlas's when it holds this value everywhere (:func:`.fit.encoder_columns`)."""
    out = {}
    for k, v in stack.constants.items():
        if isinstance(v, torch.Tensor) and v.is_floating_point():
            out[canonical_name(k)] = [float(x) for x in v.reshape(-1)]
    return out


def canonical_statistics(stats: dict | None) -> dict | None:
    """The encoder input's statistics with its lobes named canonically (a material's lobe paths name its shader)."""
    return stats and {**stats, "lobes": [canonical_name(lobe) for lobe in stats["lobes"]]}


def train_universal(model: str = "UsdPreviewSurface", steps: int = DEFAULT_STEPS, size: int = DEFAULT_SIZE,
                    seed: int = 0, lr: float = DEFAULT_LR, workdir: Path | None = None, progress: bool = True,
                    prefetch: int = 1, encoder_input: str = "normalized", brdf_eps: float | None = None,
                    brdf_floor: float | None = None, energy_gain: float | None = None) -> dict:
    """Steps 1-3 of the module docstring; returns the weights' dict (:mod:`.weights`)."""
    from mtlx2neural.train.config import PRESETS  # Local: fast --help
    from mtlx2neural.train.trainer import Trainer  # Local: fast --help

    t0 = time.time()
    with tempfile.TemporaryDirectory(prefix="m2n_atlas_") as tmp:
        folder = Path(workdir or tmp)
        _, ref, stack = atlas_material(folder / "atlas", model, size, seed)
        cfg = dataclasses.replace(PRESETS["fast"], iterations=steps, seed=seed, lr_start=lr, encoder_fraction=1.0,
                                  preview_iterations=0, probe_every=0, checkpoint_every=max(1000, steps),
                                  environment_fraction=ENVIRONMENT_FRACTION, target_prefetch=prefetch,
                                  encoder_input=encoder_input,
                                  brdf_eps=PRESETS["fast"].brdf_eps if brdf_eps is None else brdf_eps,
                                  brdf_floor=PRESETS["fast"].brdf_floor if brdf_floor is None else brdf_floor,
                                  energy_gain=PRESETS["fast"].energy_gain if energy_gain is None else energy_gain)
        trainer = Trainer(ref, stack, cfg, folder / "train")
        net = trainer.run(progress=progress)
    last = trainer.history[-1] if trainer.history else {}
    return {
        "model": model,
        "channels": [[canonical_name(c.name), c.width] for c in stack.channels],
        "constants": folded_constants(stack),
        "shape": {f: getattr(cfg, f) for f in NETWORK_FIELDS},
        "input": canonical_statistics(trainer.encoder_input.statistics()),
        "encoder": net.encoder.state_dict(), "decoder": net.decoder.state_dict(), "sampler": net.sampler.state_dict(),
        "provenance": {
            "command": f"python -m mtlx2neural.universal.train --model {model} --steps {steps} --size {size} "
                       f"--seed {seed} --lr {lr} --input {encoder_input} --brdf-eps {cfg.brdf_eps} "
                       f"--brdf-floor {cfg.brdf_floor} --energy-gain {cfg.energy_gain}"
                       + (f" --prefetch {prefetch}" if prefetch > 1 else ""),
            "config": dataclasses.asdict(cfg), "atlas": {"size": size, "seed": seed},
            "seconds": round(time.time() - t0, 1), "torch": torch.__version__, "threads": torch.get_num_threads(),
            "final_loss_brdf": last.get("loss_brdf"), "final_loss_kl": last.get("loss_kl"),
            "date": datetime.date.today().isoformat()},
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m mtlx2neural.universal.train", description=__doc__.split("\n\n")[0])
    p.add_argument("--model", default="UsdPreviewSurface", help="shading model to train (default: %(default)s)")
    p.add_argument("--steps", type=int, default=DEFAULT_STEPS, help="training steps (default: %(default)s)")
    p.add_argument("--size", type=int, default=DEFAULT_SIZE, help="atlas texels per side (default: %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="seed of the atlas and the training (default: %(default)s)")
    p.add_argument("--lr", type=float, default=DEFAULT_LR, help="Adam's starting learning rate (default: %(default)s)")
    p.add_argument("--prefetch", type=int, default=1, help="steps whose rows are drawn in one call (default: %(default)s)")
    p.add_argument("--input", choices=INPUTS, default="normalized",
                   help="what the encoder reads: channels standardised by the atlas's statistics plus log roughness, "
                        "or the raw channels (default: %(default)s)")
    p.add_argument("--brdf-eps", type=float, default=None,
                   help="log-L1's scale in f*cos units (default: the fast preset's)")
    p.add_argument("--brdf-floor", type=float, default=None,
                   help="the smallest f the decoder predicts without a penalty (default: the fast preset's)")
    p.add_argument("--energy-gain", type=float, default=None,
                   help="how fast each level's loss quantile follows the energy it keeps; 0: plain log-L1 "
                        "(default: the fast preset's)")
    p.add_argument("--out", type=Path, default=WEIGHTS_DIR, help="folder of the weights file (default: the package's)")
    p.add_argument("--workdir", type=Path, default=None, help="keep the atlas and checkpoint here (default: a temporary folder)")
    a = p.parse_args(argv)
    data = train_universal(a.model, a.steps, a.size, a.seed, a.lr, a.workdir, prefetch=a.prefetch,
                           encoder_input=a.input, brdf_eps=a.brdf_eps, brdf_floor=a.brdf_floor,
                           energy_gain=a.energy_gain)
    path = weights_path(a.model, a.out)
    save_weights(path, data)
    print(f"{path}: {len(data['channels'])} channel groups, {data['provenance']['seconds']} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
