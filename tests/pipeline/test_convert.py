"""convert_asset: ConvertOptions checked first, and open file-backed stages.

Trainings are tiny (20 steps of 256 samples): these tests check which files are written and
what they point at, not fidelity.
"""

from __future__ import annotations

import json
import warnings

import pytest
from materials import usd_painted_ball
from pxr import Sdf, Usd

from mtlx2neural.errors import InputError
from mtlx2neural.pipeline.convert import convert_asset
from mtlx2neural.pipeline.layout import SNAPSHOT_NAME
from mtlx2neural.pipeline.options import ConvertOptions
from mtlx2neural.train.config import preset

TINY = preset("fast", iterations=20, batch=256)
PAINT = "/World/Looks/Paint"
SCENE = usd_painted_ball("""
    float inputs:base = 0.8
    color3f inputs:base_color = (0.2, 0.5, 0.8)
""", metadata='(\n    defaultPrim = "World"\n    metersPerUnit = 1\n    upAxis = "Y"\n)\n')


def _options(**kw) -> ConvertOptions:
    return ConvertOptions(train=TINY, device="cpu", progress=False, workers=1, **kw)


def test_options_are_checked_first_and_only_convert_options_are_taken(tmp_path):
    asset = tmp_path / "scene.usda"
    asset.write_text(SCENE)
    with pytest.raises(InputError, match="texel-density"):
        convert_asset(asset, _options(texel_density=-1.0))
    with pytest.raises(InputError, match="--preset 'nope'"):
        convert_asset(asset, ConvertOptions(preset="nope"))
    with pytest.raises(TypeError, match="ConvertOptions.*not TrainConfig"):  # the removed (asset, cfg, ...) form
        convert_asset(asset, TINY)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.usda"]  # nothing written


@pytest.mark.slow  # one training and three conversions (about 7 s on 2 cores)
def test_file_stage_with_unsaved_edits_converts_a_snapshot_and_a_clean_one_the_file(tmp_path):
    asset = tmp_path / "scene.usda"
    asset.write_text(SCENE)
    stage = Usd.Stage.Open(str(asset))
    stage.GetAttributeAtPath(f"{PAINT}/SR.inputs:base").Set(0.25)  # unsaved, in the root (file) layer
    with pytest.warns(UserWarning, match="unsaved edits.*Save the stage first"):
        dirty = convert_asset(stage, _options())
    folder, layer = tmp_path / "scene_neural", tmp_path / "scene_neural.usda"  # beside the file, as for a path
    snapshot = folder / SNAPSHOT_NAME
    assert dirty.folder == folder and dirty.layer == layer and dirty[0].source == str(snapshot)
    assert asset.read_text() == SCENE  # the file stays as it was
    written = Sdf.Layer.OpenAsAnonymous(str(layer))
    assert written.subLayerPaths == [f"./scene_neural/{SNAPSHOT_NAME}"]
    assert written.customLayerData["mtlx2neural"]["source"] == f"./scene_neural/{SNAPSHOT_NAME}"
    assert Sdf.Layer.OpenAsAnonymous(str(snapshot)).GetAttributeAtPath(
        f"{PAINT}/SR.inputs:base").default == pytest.approx(0.25)

    # Saved, the same stage is the file: no warning, the layer sublayers the file, and the
    # run may replace the snapshot run's layer (this tool's, for this output folder); the
    # snapshot, which nothing names any more, is deleted.
    stage.Save()
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)
        clean = convert_asset(stage, _options())
    assert not snapshot.exists() and (folder / "World.Looks.Paint" / "checkpoint.pt").is_file()
    # The material is the snapshot's (base 0.25): its training is reused, its source is now the file.
    assert clean[0].source == str(asset) and clean[0].cached
    written = Sdf.Layer.OpenAsAnonymous(str(layer))
    assert written.subLayerPaths == ["./scene.usda"]
    assert written.customLayerData["mtlx2neural"]["source"] == "./scene.usda"
    summary = json.loads((folder / "World.Looks.Paint" / "summary.json").read_text())
    assert summary["source"] == str(asset)

    # ... exactly as the path itself: the same source hash, so the path run reuses the training.
    by_path = convert_asset(asset, _options())
    assert by_path[0].cached and by_path[0].source_hash == clean[0].source_hash
