"""load_reference (mtlx2neural.reference.loading and the public mtlx2neural.load_reference): the instant
``time``/``frame`` nodes fold to, given or read back from a conversion's summary.json."""

from __future__ import annotations

import pytest
import torch
from materials import FOOTER, HEADER, standard_surface

import mtlx2neural as m2n
from mtlx2neural.graph.ops import Application
from mtlx2neural.reference.loading import application_of, load_reference

# base colour = time + u per channel (time = frame / fps seconds; + u keeps it spatial, so the reference's
# parameters_at lists it).
CLOCK = HEADER + '''  <time name="t" type="float" />
  <texcoord name="uv" type="vector2" />
  <extract name="u" type="float">
    <input name="in" type="vector2" nodename="uv" />
    <input name="index" type="integer" value="0" />
  </extract>
  <add name="tu" type="float">
    <input name="in1" type="float" nodename="t" />
    <input name="in2" type="float" nodename="u" />
  </add>
  <convert name="tc" type="color3">
    <input name="in" type="float" nodename="tu" />
  </convert>
''' + standard_surface("Clock", "SR", base=1.0, base_color={"node": "tc"}) + FOOTER


def base_colour(ref) -> torch.Tensor:
    """The base colour minus u at uv (0.3, 0.7): the time."""
    (key,) = [k for k in ref.parameters_at(torch.zeros(1, 2)) if k.endswith("diffuse_bsdf.color")]
    return ref.parameters_at(torch.tensor([[0.3, 0.7]]))[key] - 0.3


def test_the_instant_is_given_or_read_from_a_summary(tmp_path):
    path = tmp_path / "clock.mtlx"
    path.write_text(CLOCK)
    # float32 of frame / fps + 0.3, minus 0.3: 1e-6.
    assert torch.allclose(base_colour(load_reference(str(path))), torch.full((1, 3), 1 / 24), atol=1e-6)
    app = Application(frame=12.0, fps=30.0)
    assert torch.allclose(base_colour(load_reference(str(path), application=app)), torch.full((1, 3), 0.4), atol=1e-6)
    assert torch.allclose(base_colour(m2n.load_reference(str(path), frame=12, fps=30)), torch.full((1, 3), 0.4),
                          atol=1e-6)
    # What a conversion records (MaterialRecord.application) for a material that reads time/frame.
    recorded = {"frame": 12.0, "fps": 30.0, "time": 0.4, "nodes": ["time"]}
    assert application_of(recorded) == app
    assert application_of({}) is None and application_of(None) is None
    assert application_of({"frame": 3.0}) is None  # incomplete: not guessed


@pytest.mark.parametrize("frame", [1.0, 48.0])
def test_a_graph_without_time_ignores_the_instant(tmp_path, frame):
    path = tmp_path / "plain.mtlx"
    path.write_text(HEADER + standard_surface("Plain", "SR", base=1.0, base_color=(0.2, 0.3, 0.4)) + FOOTER)
    ref = load_reference(str(path), application=Application(frame=frame))
    assert not any("baked at frame" in a for a in ref.describe()["approximations"])
