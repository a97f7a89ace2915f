"""ConvertOptions' ``frame``/``fps``: checked up front, threaded to the plans (a note per material that
reads ``time``/``frame``, the instant in its hashes) and recorded in the summaries' options."""

from __future__ import annotations

import pytest
from materials import FOOTER, HEADER, standard_surface

from mtlx2neural.codegen import engine
from mtlx2neural.errors import InputError
from mtlx2neural.graph.ops import Application
from mtlx2neural.pipeline.options import (
    ConvertOptions,
    application_of,
    check_options,
    options_record,
)
from mtlx2neural.pipeline.plan import plan_materials
from mtlx2neural.scene import load_asset
from mtlx2neural.train.config import preset

TINY = preset("fast", iterations=20, batch=256)
CLOCK = HEADER + '''  <time name="t" type="float" />
  <convert name="tc" type="color3">
    <input name="in" type="float" nodename="t" />
  </convert>
''' + standard_surface("Clock", "SR", base_color={"node": "tc"}) + FOOTER
PLAIN = HEADER + standard_surface("Plain", "SR2", base=0.5) + FOOTER


def _plans(tmp_path, text, app):
    path = tmp_path / "m.mtlx"
    path.write_text(text)
    return plan_materials(load_asset(path).materials, TINY, application=app)


def test_a_material_reading_time_is_noted_and_its_hashes_follow_the_frame(tmp_path):
    (at1,) = _plans(tmp_path, CLOCK, None)
    (at48,) = _plans(tmp_path, CLOCK, Application(frame=48.0))
    note = "material Clock reads `time`: baked at frame 48 (time 2 s at 24 fps); set --frame"
    assert any(n.startswith(note) for n in at48.notes), at48.notes
    assert any("baked at frame 1 (time 0.0416667 s" in n for n in at1.notes), at1.notes
    assert at1.digest != at48.digest and at1.content != at48.content  # another instant trains again
    # a material that reads neither keeps its hashes (and its cache) whatever the frame
    (plain1,) = _plans(tmp_path, PLAIN, None)
    (plain48,) = _plans(tmp_path, PLAIN, Application(frame=48.0))
    assert plain1.digest == plain48.digest and not [n for n in plain48.notes if "--frame" in n]


def test_frame_and_fps_are_checked_and_recorded():
    options = ConvertOptions(frame=12.0, fps=30.0)
    check_options(options)
    assert application_of(options) == Application(frame=12.0, fps=30.0)
    assert application_of(options).time == pytest.approx(0.4)
    record = options_record(options)
    assert record["frame"] == 12.0 and record["fps"] == 30.0
    for bad in (ConvertOptions(frame=float("nan")), ConvertOptions(fps=0.0), ConvertOptions(fps=-24.0)):
        with pytest.raises(InputError, match="--f"):
            check_options(bad)


def test_engine_shaders_without_their_tools_fail_before_any_work(monkeypatch):
    """--engine-shaders without slangc is refused when the options are checked, naming the tool and
    its install, not after minutes of training at export time."""
    monkeypatch.setattr(engine, "find_slangc", lambda: None)
    with pytest.raises(InputError, match=r"--engine-shaders needs slangc \(pip install --no-deps slangtorch"):
        check_options(ConvertOptions(engine_shaders=True))
    check_options(ConvertOptions())  # off: no tool needed
