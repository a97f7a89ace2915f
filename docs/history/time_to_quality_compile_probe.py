"""Session script: the GlazedCeramic's standard step with the reference's eval/pdf/sample torch.compiled
(the cone MIS and the lobe directions call them), against eager, one thread, same seed."""
import logging
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
torch.set_num_threads(int(sys.argv[1]) if len(sys.argv) > 1 else 1)
torch._logging.set_logs(dynamo=logging.ERROR)
from bench_step_profile import build  # noqa: E402  (after the path insert)


class Compiled:
    """The reference with eval, pdf and sample compiled; everything else delegated."""
    def __init__(self, ref):
        self._ref = ref
        self.eval = torch.compile(ref.eval, dynamic=True)
        self.pdf = torch.compile(ref.pdf, dynamic=True)
        self.sample = torch.compile(ref.sample, dynamic=True)

    def __getattr__(self, name):
        return getattr(self._ref, name)


def timed(tr, steps, warm):
    for _ in range(warm):
        tr.train_step()
    t0, c0 = time.perf_counter(), time.process_time()
    for _ in range(steps):
        tr.train_step()
    return (time.perf_counter() - t0) / steps * 1e3, (time.process_time() - c0) / steps * 1e3


for mode in ("eager", "compiled"):
    ref, stack, tr = build("GlazedCeramic", "standard")
    if mode == "compiled":
        tr.ref = Compiled(ref)
    t = time.perf_counter()
    tr.train_step()
    first = time.perf_counter() - t
    enc = timed(tr, 8, 2)
    tr.bake()
    fin = timed(tr, 8, 2)
    print(f"{mode}: first step {first:.1f} s; encoder phase {enc[0]:.0f} ms wall ({enc[1]:.0f} CPU); "
          f"fine-tune {fin[0]:.0f} ms wall ({fin[1]:.0f} CPU) per step", flush=True)
