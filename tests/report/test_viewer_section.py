"""report/html_report.viewer_section: the record's viewer figure (the prefiltered environment path) as the
report shows it."""

from __future__ import annotations

from mtlx2neural.material_record import MaterialRecord
from mtlx2neural.render.summary_views import describe_viewer
from mtlx2neural.report.html_report import viewer_section


def test_the_viewer_figure_is_shown_beside_the_sampled_view(tmp_path):
    folder, out = tmp_path / "conversion", tmp_path / "report"
    folder.mkdir()
    out.mkdir()
    for kind in ("reference", "neural", "flip"):
        (folder / f"viewer_{kind}.png").write_bytes(kind.encode())
    record = MaterialRecord("M", "/World/Looks/M", "", "0" * 64, flip_mean=0.05,
                            flip_per_view=[0.01, 0.02, 0.03, 0.1034], flip_viewer=0.179,
                            flip_viewer_view=describe_viewer())
    html = viewer_section(record, folder, out, "m0_")
    assert "0.1790" in html and "0.1034" in html and "prefiltered environment path" in html
    # the conversion's images travel with the report (it may be moved without the conversion's folder)
    assert [(out / f"m0_viewer_{k}.png").read_bytes() for k in ("reference", "neural", "flip")] == \
        [b"reference", b"neural", b"flip"]
    assert html.count("<figure>") == 3


def test_records_without_a_viewer_figure_say_so(tmp_path):
    # a model without an environment head, a UDIM material, or a record from before the figure
    html = viewer_section(MaterialRecord("M", "/World/Looks/M", "", "0" * 64), tmp_path, tmp_path, "m0_")
    assert "Not measured" in html and "<img" not in html and not list(tmp_path.iterdir())
