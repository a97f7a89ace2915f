"""``mtlx2neural inspect ASSET``: what a conversion would do, before any training
(:class:`~mtlx2neural.pipeline.options.InspectOptions`; the training flags choose the settings the
latent grid and the source hashes are shown for)."""

from __future__ import annotations

import argparse
import json

from mtlx2neural.commands.convert import PARSERS, TRAIN_BASES, preset_settings
from mtlx2neural.commands.options_cli import add_options, options_from_args
from mtlx2neural.pipeline.options import InspectOptions

NAME = "inspect"
USAGE = "mtlx2neural inspect ASSET"
HELP = "list materials, bound prims, kept/pruned lobes, spatial inputs, textures"


def add_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser(NAME, help=HELP, description=f"{HELP[0].upper()}{HELP[1:]}, and the latent grid and "
                                                    f"source hash a conversion would use.")
    p.add_argument("asset", metavar="ASSET", help=".mtlx file or USD stage (.usda/.usdc/.usd/.usdz)")
    add_options(p, InspectOptions, parsers=PARSERS, bases=TRAIN_BASES)
    return p


def options_of(args: argparse.Namespace) -> InspectOptions:
    """The :class:`InspectOptions` of the flags given (training flags override the preset's)."""
    return options_from_args(InspectOptions, args, base=preset_settings)


def run(args: argparse.Namespace) -> int:
    options = options_of(args)
    # Local: --help and option errors answer without importing torch.
    from mtlx2neural.pipeline.inspection import format_report, inspect_asset

    report = inspect_asset(args.asset, options)
    print(json.dumps(report, indent=2) if options.json else format_report(report))
    return 0
