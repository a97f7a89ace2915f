"""Flags generated from the options dataclasses (:mod:`mtlx2neural.commands.options_cli`): every
field has a flag and a help, given flags (and only those) override the preset, the old flag
names still work, and docs/cli.md's option tables are the generated ones."""

from __future__ import annotations

import argparse
import dataclasses
import json
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from cli_helpers import assert_clean_input_error, run_cli
from conftest import SIMPLE_MTLX

from mtlx2neural.commands.convert import options_of
from mtlx2neural.commands.options_cli import (
    BEGIN,
    END,
    add_options,
    field_docs,
    flag_names,
    options_from_args,
    options_table,
    replace_between_markers,
)
from mtlx2neural.commands.parser import build_parser, command_parsers
from mtlx2neural.errors import InputError
from mtlx2neural.pipeline.options import ConvertOptions, InspectOptions, options_record
from mtlx2neural.report.options import RenderOptions, ReportOptions
from mtlx2neural.train.config import PRESETS, TrainConfig

ROOT = Path(__file__).resolve().parents[2]


def parse(*argv) -> argparse.Namespace:
    return build_parser()[0].parse_args([str(a) for a in argv])


# ----------------------------------------------------------------------------- docs/cli.md


def test_cli_doc_option_tables_are_up_to_date():
    text = (ROOT / "docs" / "cli.md").read_text()
    assert text.count(BEGIN) == 1 and text.count(END) == 1
    options = text.split("## Every option", 1)[1].split("\n## ", 1)[0]
    assert BEGIN in options and END in options, "the tables belong in docs/cli.md's Every option section"
    expected = replace_between_markers(text, options_table(command_parsers()))
    assert text == expected, ("docs/cli.md's option tables are out of date: run "
                              "python -m mtlx2neural.commands.readme_tables --doc docs/cli.md")
    readme = (ROOT / "README.md").read_text()
    assert BEGIN not in readme and "docs/cli.md" in readme, "README links to the tables instead of holding them"


def test_check_mode_reports_a_stale_table(tmp_path):
    doc = tmp_path / "cli.md"
    doc.write_text(f"# x\n\n{BEGIN}\n| stale |\n{END}\n\nafter\n")
    cmd = [sys.executable, "-m", "mtlx2neural.commands.readme_tables", "--doc", str(doc)]
    stale = subprocess.run([*cmd, "--check"], capture_output=True, text=True, timeout=120, check=False)
    assert stale.returncode == 1 and "out of date" in stale.stderr
    assert "| stale |" in doc.read_text()  # --check writes nothing
    assert subprocess.run(cmd, capture_output=True, timeout=120, check=False).returncode == 0
    new = doc.read_text()
    assert "| stale |" not in new and "`--lr-end LR_END`" in new and new.endswith(f"{END}\n\nafter\n")
    assert subprocess.run([*cmd, "--check"], capture_output=True, timeout=120, check=False).returncode == 0
    with pytest.raises(ValueError, match="markers"):
        replace_between_markers("no markers here", "| table |")


# ----------------------------------------------------------------------------- every field has a flag


@pytest.mark.parametrize("command, classes", [("convert", (ConvertOptions, TrainConfig)),
                                              ("inspect", (InspectOptions, TrainConfig)),
                                              ("render", (RenderOptions,)), ("report", (ReportOptions,))])
def test_every_field_has_a_flag_and_a_help(command, classes):
    actions = {a.dest: a for a in build_parser()[1][command]._actions}
    for cls in classes:
        docs = field_docs(cls)
        prefix = "train." if cls is TrainConfig else ""
        for f in dataclasses.fields(cls):
            if f.metadata.get("cli", True) is False or f.name == "train":  # train: its fields are the flags
                continue
            assert docs.get(f.name, "").strip(), f"{cls.__name__}.{f.name} has no docstring"
            action = actions.get(prefix + f.name)
            assert action is not None, f"{command}: no flag for {cls.__name__}.{f.name}"
            assert action.help and action.help.strip(), f"{command}: {action.option_strings} has no help"
            assert set(flag_names(f)) <= set(action.option_strings) or action.option_strings == [
                f"--no-{f.name.replace('_', '-')}"], (f.name, action.option_strings)
    assert len([d for d in actions if d.startswith("train.")]) == (
        len(dataclasses.fields(TrainConfig)) if TrainConfig in classes else 0)


def test_field_docs_reads_attribute_docstrings():
    @dataclass
    class Probe:
        """Class docstring, not a field's."""

        a: int = 1
        """First line.

            Indented continuation."""
        b: str = "x"
        c: float = field(default=0.5, metadata={"flag": "--see"})
        """C's doc."""
        "a stray string after a docstring is no field's"

    docs = field_docs(Probe)
    assert docs == {"a": "First line.\n\nIndented continuation.", "c": "C's doc."}
    assert field_docs(TrainConfig)["seed"].startswith("Seed of the initial weights")
    assert field_docs(TrainConfig)["lr_end"]


def test_generated_flags_follow_the_annotations():
    @dataclass
    class Probe:
        path: str = field(metadata={"flag": "-p/--path"})
        """Required (no default)."""
        on: bool = True
        """A switch on by default."""
        off: bool = False
        """A switch off by default."""
        count: int | None = None
        """A count, 100% optional."""
        mode: str = field(default="a", metadata={"choices": ("a", "b")})
        """A choice."""
        tags: list[str] | None = None
        """Repeatable."""
        hidden: int = field(default=3, metadata={"cli": False})
        """Library only."""

    p = argparse.ArgumentParser(prog="probe")
    add_options(p, Probe)
    flags = {s for a in p._actions for s in a.option_strings}
    assert flags == {"-h", "--help", "-p", "--path", "--no-on", "--off", "--count", "--mode", "--tags"}
    assert options_from_args(Probe, p.parse_args(["-p", "x"])) == Probe("x")
    got = options_from_args(Probe, p.parse_args(["--path", "y", "--no-on", "--off", "--count", "4", "--mode", "b",
                                                 "--tags", "t1", "--tags", "t2"]), hidden=5)
    assert got == Probe("y", False, True, 4, "b", ["t1", "t2"], 5)
    assert "100% optional" in p.format_help()  # a % in a docstring does not break argparse's help
    for bad in (["--count", "x"], ["--mode", "c"], []):  # not an int, not a choice, the required flag missing
        with pytest.raises(SystemExit):
            p.parse_args(bad)


# ----------------------------------------------------------------------------- conversion flags


def test_only_the_training_flags_given_override_the_preset():
    assert options_of(parse("convert", "a.usda")) == ConvertOptions()
    assert options_of(parse("convert", "a.usda", "--preset", "paper")).train is None
    o = options_of(parse("convert", "a.usda", "--preset", "paper", "--lr-end", "0.01", "--no-compile"))
    assert o.train == dataclasses.replace(PRESETS["paper"], lr_end=0.01, compile=False)
    assert o.train_config() == o.train and o.preset == "paper"
    o = options_of(parse("convert", "a.usda", "--no-mollify-mis", "--albedo-head"))
    assert o.train == dataclasses.replace(PRESETS["fast"], mollify_mis=False, albedo_head=True)


def test_old_flag_names_still_work():
    o = options_of(parse("convert", "a.usda", "--max-texels", "0", "--iterations", "7", "--batch", "64",
                         "--frames", "0", "--seed", "5", "--decoder", "2x16", "--quiet", "-o", "out",
                         "--workers", "ray", "--max-texels", "0"))
    assert o.train == dataclasses.replace(PRESETS["fast"], max_resolution=None, iterations=7, batch=64, frames=0,
                                          seed=5, decoder="2x16")
    assert (o.progress, o.out, o.workers) == (False, "out", "ray")
    assert options_of(parse("convert", "a.usda", "--max-texels", "32")).train.max_resolution == 32
    assert options_of(parse("convert", "a.usda", "--no-progress")).progress is False


@pytest.mark.parametrize("argv, message", [
    (("--max-texels", "-1"), "not a texel count"),
    (("--texel-density", "0"), "not a texel density"),
    (("--max-error", "inf"), "not an HDR FLIP budget"),
    (("--workers", "0"), "--workers must be at least 1"),
    (("--decoder", "4x4"), "invalid choice"),
])
def test_bad_flag_values_are_usage_errors(argv, message, capsys):
    with pytest.raises(SystemExit) as exc:
        parse("convert", "a.usda", *argv)
    assert exc.value.code == 2 and message in capsys.readouterr().err


def test_decoder_and_max_error_conflict(tmp_path, capsys):
    asset = tmp_path / "red.mtlx"
    asset.write_text(SIMPLE_MTLX)
    code, out, err = run_cli(capsys, asset, "--decoder", "2x16", "--max-error", "0.1", "--quiet")
    assert_clean_input_error(code, out, err, "--decoder 2x16 and --max-error 0.1 conflict")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["red.mtlx"]


def test_options_record_is_json():
    o = options_of(parse("convert", "a.usda", "--iterations", "3", "-o", "x", "--workers", "2"))
    record = options_record(o)
    assert json.loads(json.dumps(record)) == record
    assert record["out"] == "x" and record["workers"] == 2 and "train" not in record
    assert set(record) == {f.name for f in dataclasses.fields(ConvertOptions)} - {"train"}


# ----------------------------------------------------------------------------- other commands


def test_render_and_report_options_are_the_library_keywords(tmp_path):
    """render_asset(asset, RenderOptions) checks its options exactly as the keyword call does (no render)."""
    import inspect

    from mtlx2neural.report.html_report import write_report
    from mtlx2neural.report.views import render_asset

    ren = options_from_args(RenderOptions, parse("render", "a.usda", "-o", "x.exr", "--spp", "3", "--mis", "none"))
    assert ren == RenderOptions("x.exr", spp=3, mis="none")
    assert set(ren.kwargs()) == set(inspect.signature(render_asset).parameters) - {"asset"}
    rep = options_from_args(ReportOptions, parse("report", "l.usda", "--texel", "0.25,0.75", "--material", "A",
                                                 "--material", "B"))
    assert rep == ReportOptions(materials=["A", "B"], texels_at=[(0.25, 0.75)])
    assert set(rep.kwargs()) == set(inspect.signature(write_report).parameters) - {"layer"}
    for call in (lambda: render_asset("a.usda", RenderOptions(str(tmp_path / "x.png"))),
                 lambda: render_asset("a.usda", str(tmp_path / "x.png"))):
        with pytest.raises(InputError, match="must be an .exr"):
            call()


def test_inspect_takes_its_options(tmp_path):
    from mtlx2neural.pipeline.inspection import inspect_asset

    asset = tmp_path / "red.mtlx"
    asset.write_text(SIMPLE_MTLX)
    from mtlx2neural.commands.inspection import options_of as inspect_options_of

    o = inspect_options_of(parse("inspect", asset, "--iterations", "5", "--json"))
    assert o.json and o.train == dataclasses.replace(PRESETS["fast"], iterations=5)
    by_options = inspect_asset(asset, o)
    assert by_options == inspect_asset(asset, None, False, o.train)
    # The source hash covers the training settings: other settings, another hash.
    assert by_options["materials"][0]["source_hash"] != inspect_asset(asset)["materials"][0]["source_hash"]


def test_help_imports_no_torch():
    code = ("import sys\nfrom mtlx2neural.cli import main\n"
            "for c in ('convert', 'inspect', 'render', 'report', 'bench'):\n"
            "    try:\n        main([c, '--help'])\n    except SystemExit:\n        pass\n"
            "print('torch' in sys.modules)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip().splitlines()[-1] == "False"
