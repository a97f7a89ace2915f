"""Shared by the Mitsuba tests (tests/mitsuba/): Mitsuba itself (skipping with the reason when it cannot run here) and
small converted samples whose exported layers the ``mtlx_neural`` plugin reads. A test module imports the
fixtures it uses: ``from mitsuba_samples import converted_layers, mi  # noqa: F401``."""

from __future__ import annotations

import atexit
import importlib.util
import shutil
import tempfile
from pathlib import Path

import pytest

from mtlx2neural.mitsuba import load_mitsuba, mitsuba_missing

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "samples"

CONVERTED_SAMPLES = {
    "layered": "layered_spheres.usda",  # CarPaint (uniform, coated), Plastic (uniform)
    "textured": "textured/ceramic_and_metal.usda",  # GlazedCeramic, BrushedMetal (textures, normal maps)
    "mirror": "mirror/polished_metal.usda",  # PolishedMetal (near mirror, textured)
    "scene": "scene/glow_and_leaves.usda",  # Lava (emission), Leaf (cut-out), Gold (near mirror)
}
"""The bundled samples the tests convert, by key: every sample material but the UDIM and rotated ones."""


TEXTURED_RES = 512
"""Texture resolution of the textured sample when a test process writes it (``samples/textured`` is not in the
repository: ``python samples/make_textured_sample.py`` writes it at 1024)."""

_WRITTEN: dict[str, Path] = {}


def sample_asset(key: str) -> Path:
    """The bundled sample ``key`` (:data:`CONVERTED_SAMPLES`). The textured one is generated when the checkout
    lacks it, once per test process, into a temporary folder of its own (never into ``samples/``, where
    several test processes would write at once)."""
    path = SAMPLES / CONVERTED_SAMPLES[key]
    if path.exists():
        return path
    if key not in _WRITTEN:
        spec = importlib.util.spec_from_file_location("make_textured_sample", SAMPLES / "make_textured_sample.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        root = tempfile.mkdtemp(prefix="m2n-textured-")
        atexit.register(shutil.rmtree, root, True)  # removed when the test process ends
        folder = Path(root) / "textured"
        module.build(folder, TEXTURED_RES)
        _WRITTEN[key] = folder / path.name
    return _WRITTEN[key]


@pytest.fixture(scope="session")
def mi():
    """The ``mitsuba`` module (variant set, plugins registered), or a skip naming what to install."""
    reason = mitsuba_missing()
    if reason is not None:
        pytest.skip(reason)
    return load_mitsuba()


def convert_sample(key: str, folder: Path, iterations: int = 40) -> Path:
    """Convert the bundled sample ``key`` (:data:`CONVERTED_SAMPLES`) with a short ``fast`` training into
    ``folder``; returns its neural layer. The model is undertrained: these tests check the plugins'
    contract (eval, sample and pdf agreeing with each other and with the torch model), not fidelity.
    ``flagged="neural"`` keeps the neural variant of every material the quality gate flags."""
    # Local: the conversion (torch training) matters only for the tests that need a layer.
    from mtlx2neural.pipeline.convert import convert_asset
    from mtlx2neural.pipeline.options import ConvertOptions
    from mtlx2neural.train.config import preset

    src = sample_asset(key)
    shutil.copytree(src.parent, folder, dirs_exist_ok=True)
    asset = folder / src.name
    train = preset("fast", iterations=iterations, batch=256, probe_every=0, preview_iterations=2)
    convert_asset(asset, ConvertOptions(train=train, progress=False, device="cpu", workers=1, flagged="neural"))
    return folder / f"{asset.stem}_neural.usda"


@pytest.fixture(scope="session")
def converted_layers(tmp_path_factory):
    """``{key: neural layer path}`` for every sample of :data:`CONVERTED_SAMPLES`, converted once per
    test process (built lazily: ask for a key with :func:`layer_of`)."""
    cache: dict[str, Path] = {}

    def get(key: str) -> Path:
        if key not in cache:
            cache[key] = convert_sample(key, tmp_path_factory.mktemp(key))
        return cache[key]

    return get
