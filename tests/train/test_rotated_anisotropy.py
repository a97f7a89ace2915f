"""A short seeded training on the rotated-anisotropy sample (samples/make_rotated_sample.py: a metal brushed in
circles, its specular_rotation textured) learns the lobe's orientation: at a texel brushed along u and one
brushed along v, the trained highlight is elongated along the reference's axis. Before the LEAN tangent was
carried through the parameter stack (textures.parameter_stack.LEAN_TANGENT = False) both the encoder's input
and the native-resolution targets lost the rotation, and every texel learned an x-aligned lobe.

Measurements: docs/history/paper-choices-2026-12-02.md ("LEAN tangent")."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import pytest
import torch

import mtlx2neural as m2n
from mtlx2neural.contract import ShadingPoint
from mtlx2neural.textures.parameter_stack import build_parameter_stack
from mtlx2neural.train.config import preset
from mtlx2neural.train.trainer import Trainer

SAMPLES = Path(__file__).resolve().parents[2] / "samples"
# The run: the fast preset shortened as the quality guard's (tests/train/test_quality.py GUARD_RUN), with a
# larger batch: about 60-90 s of one core. Shorter runs were marginal: 400 x 256 left a round blob, 600 x 512
# learned both probes' axes on seed 1 but only half-turned the second one on seed 2 (44 degrees off).
ROTATED_RUN = {"iterations": 900, "batch": 512, "footprint_samples": 4}
# Two texel centres of the 16x16 rotation map: row 0 col 7 (top edge, tangent ~4 degrees from u) and
# row 7 col 0 (left edge, ~86 degrees from u).
PROBES = ((7.5 / 16, 1 - 0.5 / 16), (0.5 / 16, 1 - 7.5 / 16))
# Largest allowed difference between the trained and the reference highlight's axis, degrees: measured at
# most 5.4 with the tangent (seeds 1 and 2), 86 without it at the probe brushed along v (every texel learns a
# lobe along x); the tolerance leaves room for seed and platform noise, far from a lobe that missed its turn.
ANGLE_TOLERANCE = 25.0
# Largest allowed minor/major spread of the trained highlight (reference 0.22, trained 0.23-0.28; a round
# blob, which has no axis to speak of, is ~0.95).
MAX_SPREAD_RATIO = 0.5


def rotated_sample(directory: Path):
    """The rotated-anisotropy sample written into ``directory`` by its generator (16x16 rotation map)."""
    spec = importlib.util.spec_from_file_location("make_rotated_sample", SAMPLES / "make_rotated_sample.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return m2n.load_reference(mod.build(directory), "SpunMetal")


def highlight_axis(eval_fn, uv, res: int = 48) -> tuple[float, float]:
    """(angle in degrees in [0, 180) from +x, minor/major spread ratio) of the highlight seen from the normal.

    ``eval_fn(wi, wo, at)`` (f * cos, local frame) is evaluated with wi = +z over a ``res`` x ``res`` grid of wo
    on the projected unit disk (x, y); the brightest part (luminance above a quarter of the peak) is weighted
    by its luminance, and its (x, y) covariance gives the axis (major eigenvector) and the spread ratio
    (sqrt of minor/major eigenvalue: 1 isotropic, small elongated)."""
    c = (torch.arange(res, dtype=torch.float64) + 0.5) / res * 2 - 1
    y, x = torch.meshgrid(c, c, indexing="ij")
    keep = (x * x + y * y) < 0.98
    x, y = x[keep], y[keep]
    wo = torch.stack([x, y, (1 - x * x - y * y).sqrt()], -1)
    wi = torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64).expand_as(wo)
    at = ShadingPoint(uv=torch.tensor([uv], dtype=torch.float64).expand(wo.shape[0], 2))
    with torch.no_grad():
        f = eval_fn(wi, wo, at).double().mean(-1)
    w = torch.where(f > 0.25 * f.max(), f, torch.zeros_like(f))
    w = w / w.sum()
    mx, my = (w * x).sum(), (w * y).sum()
    cxx, cyy = (w * (x - mx) ** 2).sum(), (w * (y - my) ** 2).sum()
    cxy = (w * (x - mx) * (y - my)).sum()
    angle = math.degrees(0.5 * math.atan2(2 * float(cxy), float(cxx - cyy))) % 180.0
    mean, radius = 0.5 * float(cxx + cyy), math.hypot(0.5 * float(cxx - cyy), float(cxy))
    return angle, math.sqrt(max(mean - radius, 0.0) / max(mean + radius, 1e-30))


def axis_error(a: float, b: float) -> float:
    """Difference of two axes (degrees, modulo 180) in [0, 90]."""
    d = abs(a - b) % 180.0
    return min(d, 180.0 - d)


def model_eval(model):
    """The trained model's eval in float32, returning float64 (highlight_axis's grid is float64)."""
    def f(wi, wo, at):
        return model.eval(wi.float(), wo.float(), ShadingPoint(uv=at.uv.float())).double()
    return f


def train_rotated(reference, stack, out_dir, seed: int = 1, **overrides):
    """Train ROTATED_RUN (then ``overrides``) on ``reference`` and return the model."""
    cfg = preset("fast", seed=seed, **{**ROTATED_RUN, **overrides})
    return Trainer(reference, stack, cfg, out_dir).run(progress=False)


@pytest.fixture
def one_thread():
    """One torch thread for the training (restored after): batches of 512 rows run faster on one thread than
    on two contended ones, and the run's time was measured so (~85 s on an idle core; 346 s with the default
    two threads while other processes shared the 2-core machine)."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="module")
def rotated(tmp_path_factory):
    ref = rotated_sample(tmp_path_factory.mktemp("rotated"))
    return ref, build_parameter_stack(ref.compiled)


def test_reference_highlights_follow_the_rotation(rotated):
    """The probes are what the test needs: two strongly elongated reference highlights ~90 degrees apart."""
    ref, _ = rotated
    (a0, r0), (a1, r1) = (highlight_axis(ref.eval, uv) for uv in PROBES)
    # The lobes' tangents are at ~4 and ~86 degrees (alpha 0.56 x 0.11, anisotropy 0.8): the highlights'
    # axes follow within a few degrees and are far from round.
    assert axis_error(a0, 0.0) < 10.0 and axis_error(a1, 90.0) < 10.0, (a0, a1)
    assert r0 < 0.5 and r1 < 0.5, (r0, r1)


@pytest.mark.slow
def test_training_learns_the_lobes_orientation(rotated, tmp_path, one_thread):
    ref, stack = rotated
    model = train_rotated(ref, stack, tmp_path, seed=1)
    for uv in PROBES:
        want, _ = highlight_axis(ref.eval, uv)
        got, ratio = highlight_axis(model_eval(model), uv)
        assert axis_error(got, want) < ANGLE_TOLERANCE, (uv, got, want)
        assert ratio < MAX_SPREAD_RATIO, (uv, ratio)
