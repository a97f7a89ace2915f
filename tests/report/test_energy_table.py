"""report/html_report.energy_table: the energy check of a material's record as the report shows it."""

from __future__ import annotations

from mtlx2neural.material_record import MaterialRecord
from mtlx2neural.report.html_report import energy_table


def _record(energy: dict | None) -> MaterialRecord:
    return MaterialRecord("M", "/World/Looks/M", "", "0" * 64, flip_mean=0.1, energy=energy)


ENERGY = {"min_ratio": 0.91, "max_ratio": 0.95, "by_level": [0.95, 0.91], "reference_by_level": [0.58, 0.59],
          "model_by_level": [0.55, 0.54], "texels": 64, "samples": 64, "view_degrees": [0.0, 30.0, 60.0, 80.0]}


def test_each_level_and_each_view_is_shown():
    html = energy_table(_record({**ENERGY, "by_view": [0.9, 0.92, 0.93, 1.21]}))
    assert html.count("<tr><td") == 2 and "0.91" in html and "0.95" in html  # one row per MIP level
    assert "By view angle" in html and "0°: 0.90" in html and "80°: 1.21" in html


def test_records_without_the_views_show_the_levels_alone():
    html = energy_table(_record(ENERGY))  # a record written before by_view was measured
    assert html.count("<tr><td") == 2 and "By view angle" not in html
    assert "Not measured" in energy_table(_record(None))
