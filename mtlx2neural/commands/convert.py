"""``mtlx2neural ASSET`` / ``mtlx2neural convert ASSET``: train a neural material for every selected
material and export them (:class:`~mtlx2neural.pipeline.options.ConvertOptions`, every field a flag,
and every :class:`~mtlx2neural.train.config.TrainConfig` field a flag overriding the preset's)."""

from __future__ import annotations

import argparse
import dataclasses
import sys

from mtlx2neural.commands import values
from mtlx2neural.commands.options_cli import add_options, options_from_args
from mtlx2neural.errors import InputError
from mtlx2neural.pipeline.options import ConvertOptions
from mtlx2neural.train.config import PRESETS, TrainConfig

NAME = "convert"
USAGE = "mtlx2neural [convert] ASSET"
HELP = "train a neural material for every selected material (default command)"

PARSERS = {"workers": values.workers, "max_error": values.flip_budget, "texel_density": values.texel_density,
           "max_resolution": values.texel_cap}
"""Fields whose flag values argparse cannot type by itself (convert and inspect)."""
TRAIN_BASES = {"train": ("the preset's; fast", PRESETS["fast"])}
"""The training flags override the preset's values: shown as fast's."""


def preset_settings(_field: str, top: dict) -> TrainConfig:
    """The settings the training flags override: the given ``--preset``'s, else the default's."""
    return dataclasses.replace(PRESETS[top.get("preset", ConvertOptions.preset)])


EXIT_OK, EXIT_FAILED, EXIT_BAD_INPUT, EXIT_SKIPPED = 0, 1, 2, 3
EPILOG = ("exit codes: 0 every selected material converted; 3 some were skipped (they cannot be converted, or "
          "their training failed: "
          "each is printed with its node and reason, and recorded in the layer; the others converted); "
          "2 bad input, or nothing convertible (with --strict: any material that cannot be converted), "
          "nothing written; 1 a failure during the run (a write, Ctrl-C).")
"""The exit codes of a conversion (``--help``; docs/cli.md, "Exit codes and failure modes")."""


def add_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser(NAME, help=HELP, description=f"{HELP[0].upper()}{HELP[1:]}.", epilog=EPILOG)
    p.add_argument("asset", metavar="ASSET", help=".mtlx file, USD stage (.usda/.usdc/.usd/.usdz), or measured BRDF (MERL .binary)")
    add_options(p, ConvertOptions, parsers=PARSERS, bases=TRAIN_BASES)
    return p


def options_of(args: argparse.Namespace) -> ConvertOptions:
    """The :class:`ConvertOptions` of the flags given (InputError for ``--decoder`` with ``--max-error``)."""
    decoder, budget = getattr(args, "train.decoder", None), getattr(args, "max_error", None)
    if decoder and budget is not None:
        raise InputError(f"--decoder {decoder} and --max-error {budget} conflict: --decoder forces "
                         f"one size, --max-error picks the smallest of 2x16, 2x32, 3x64 that meets the budget. "
                         f"Give one of them.")
    return options_from_args(ConvertOptions, args, base=preset_settings)


def run(args: argparse.Namespace) -> int:
    return convert(args.asset, options_of(args))


def convert(asset, options: ConvertOptions) -> int:
    """Convert ``asset`` with ``options``, print a line per material; the exit code (:data:`EPILOG`):
    3 when some selected materials were skipped because they cannot be converted."""
    # Local: --help and option errors answer without importing torch.
    from mtlx2neural.pipeline.convert import convert_asset

    # Local: --help and option errors answer without importing torch.
    from mtlx2neural.train.trainer import TrainingInterrupted

    try:
        summaries = convert_asset(asset, options)
    except TrainingInterrupted as exc:
        print(f"mtlx2neural: {exc}", file=sys.stderr)
        return EXIT_FAILED
    except OSError as exc:  # writing failed after the up-front checks (disk full...); nothing partial was left
        where = f" {exc.filename}" if getattr(exc, "filename", None) else ""
        print(f"mtlx2neural: error: cannot write the output{where} ({exc.strerror or exc}); the previous export, "
              f"if any, is unchanged", file=sys.stderr)
        return EXIT_FAILED
    print_summaries(summaries)
    failed = getattr(summaries, "failed", [])
    for f in failed:
        node = f" (node '{f['node']}')" if f.get("node") else ""
        print(f"mtlx2neural: skipped {f['material']}{node}: {f['reason']}", file=sys.stderr)
    if failed:
        print(f"mtlx2neural: {len(failed)} material(s) not converted; they keep their original network "
              f"(--strict makes this an error)", file=sys.stderr)
        return EXIT_SKIPPED
    return EXIT_OK


def print_summaries(summaries) -> None:
    """A line per material (how it was obtained, decoder, errors; budget, warnings, notes), then the
    folder and layer written."""
    for s in summaries:
        if s.shared_with:
            how = f"identical to {s.shared_with} (same graph, textures and settings): trained once, shared"
        elif s.cached:
            how = "reused (unchanged; --force retrains)"
        else:
            how = f"{s.steps} steps in {s.seconds} s"
        print(f"{s.material}: {how}, decoder {s.decoder}, held-out log-L1 {s.held_out_log_l1:.4f}, "
              f"HDR FLIP {s.flip_mean:.4f} "
              + (f"(UDIM tiles {s.flip_per_tile})" if s.flip_per_tile else f"(views {s.flip_per_view})")
              + (f", in scene {s.flip_in_scene:.4f}" if s.flip_in_scene is not None else "")
              + (f", viewer (prefiltered sky) {s.flip_viewer:.4f}" if s.flip_viewer is not None else ""))
        if s.budget:
            tried = ", ".join(f"{k} {v:.4f}" for k, v in s.budget["flip_by_decoder"].items())
            where = " in scene" if s.budget["metric"] == "flip_in_scene" else ""
            print(f"  budget HDR FLIP{where} <= {s.budget['max_error']}: {'met' if s.budget['met'] else 'NOT met'} "
                  f"(tried {tried})")
        for w in s.warnings:
            print(f"  warning: {w}")
        for n in (s.latent or {}).get("notes", []):
            print(f"  note: {n}")
        for note in s.export_notes[:3]:
            print(f"  fp16: {note}")
        if len(s.export_notes) > 3:
            print(f"  fp16: ... and {len(s.export_notes) - 3} more (see neural/weights.json and export.json)")
    for k in getattr(summaries, "skipped", []):
        print(f"{k['material']}: skipped ({k['reason']})")
    print(f"wrote {summaries.folder} (checkpoints, training curves, summaries, latent EXRs, weights)")
    if summaries:
        kept = getattr(summaries, "kept", [])
        also = f"; kept from earlier runs: {', '.join(kept)}" if kept else ""
        print(f"wrote {summaries[0].usd} (USD layer with the neural materials{also})")

