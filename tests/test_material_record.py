"""MaterialRecord: the one typed record of a material's conversion, and its ``summary.json`` form."""

import dataclasses
import json
import math

import pytest

from mtlx2neural.material_record import (
    RECORD_VERSION,
    MaterialRecord,
    RecordError,
    read_record,
    read_record_or_none,
    record_path,
    write_record,
)


def _record(**changes) -> MaterialRecord:
    base = MaterialRecord(material="/Materials/Red", mtlx_material="Red", source="/a/red.usda", source_hash="abc",
                          bound_prims=["/World/Sphere"], decoder="small", resolution=[64, 64], steps=30,
                          seconds=2.5, train_seconds=2.0, final_loss_brdf=0.25, held_out_log_l1=0.125,
                          flip_mean=0.0625, relmse_mean=0.01, flip_per_view=[0.05, 0.075], flip_in_scene=None,
                          budget={"max_error": 0.1, "met": True}, budget_met=True, udim_tiles=[1001, 1002],
                          flip_per_tile={"1001": 0.05, "1002": 0.07}, notes=["a note"], warnings=[])
    return dataclasses.replace(base, **changes)


def test_round_trip_keeps_every_field(tmp_path):
    record = _record()
    path = write_record(tmp_path, record)
    assert path == record_path(tmp_path) and path.name == "summary.json"
    assert json.loads(path.read_text())["record_version"] == RECORD_VERSION
    assert read_record(tmp_path) == record


def test_nan_figures_survive_the_round_trip(tmp_path):
    """An untrained material has no loss: NaN is written (Python's JSON extension) and read back as NaN."""
    write_record(tmp_path, _record(final_loss_brdf=float("nan")))
    assert math.isnan(read_record(tmp_path).final_loss_brdf)


def test_budget_error_prefers_the_in_scene_figure():
    assert _record().budget_error() == 0.0625
    assert _record(flip_in_scene=0.2).budget_error() == 0.2


def test_with_warning_puts_it_first_in_notes_and_leaves_the_original():
    record = _record()
    warned = record.with_warning("budget missed")
    assert warned.warnings == ["budget missed"] and warned.notes == ["budget missed", "a note"]
    assert record.warnings == [] and record.notes == ["a note"]


@pytest.mark.parametrize("edit, says", [
    (lambda d: d.pop("record_version"), "no record_version"),
    (lambda d: d.update(record_version=RECORD_VERSION + 1), f"record_version {RECORD_VERSION + 1}"),
    (lambda d: d.update(summary_of_old=1), "unknown keys ['summary_of_old']"),
    (lambda d: d.pop("source_hash"), "missing keys ['source_hash']"),
])
def test_a_bad_or_old_record_names_the_file(tmp_path, edit, says):
    data = _record().to_json()
    edit(data)
    record_path(tmp_path).write_text(json.dumps(data))
    with pytest.raises(RecordError) as err:
        read_record(tmp_path)
    assert str(record_path(tmp_path)) in str(err.value) and says in str(err.value)
    assert read_record_or_none(tmp_path) is None  # a cache check trains again instead


def test_not_json_and_missing_file_name_the_file(tmp_path):
    with pytest.raises(RecordError, match="cannot read"):
        read_record(tmp_path)
    record_path(tmp_path).write_text("{not json")
    with pytest.raises(RecordError, match="not JSON") as err:
        read_record(tmp_path)
    assert str(record_path(tmp_path)) in str(err.value)


def test_a_failed_write_keeps_the_previous_record(tmp_path, monkeypatch):
    write_record(tmp_path, _record(steps=30))

    def fail(*_a, **_k):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(json, "dumps", fail)
    with pytest.raises(OSError):
        write_record(tmp_path, _record(steps=99))
    monkeypatch.undo()
    assert read_record(tmp_path).steps == 30
    assert [p.name for p in tmp_path.iterdir()] == ["summary.json"]  # no temporary left behind
