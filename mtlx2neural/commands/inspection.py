"""``mtlx2neural inspect ASSET``: what a conversion would do, before any training
(:class:`~mtlx2neural.pipeline.options.InspectOptions`; the training flags choose the settings the
latent grid and the source hashes are shown for).

``mtlx2neural inspect --coverage`` prints the node coverage table instead
(:func:`mtlx2neural.graph.coverage.format_coverage`, which docs/coverage.md records): which MaterialX
node categories compile, partly or not at all, and why. ASSET is optional with that flag only."""

from __future__ import annotations

import argparse
import json

from mtlx2neural.commands.convert import PARSERS, TRAIN_BASES, preset_settings
from mtlx2neural.commands.options_cli import add_options, options_from_args
from mtlx2neural.pipeline.options import InspectOptions

NAME = "inspect"
USAGE = "mtlx2neural inspect ASSET | mtlx2neural inspect --coverage"
HELP = "list materials, bound prims, kept/pruned lobes, spatial inputs, textures"


def add_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser(NAME, help=HELP, description=f"{HELP[0].upper()}{HELP[1:]}, and the latent grid and "
                                                    f"source hash a conversion would use.")
    p.add_argument("asset", metavar="ASSET", nargs="?", default=None,
                   help=".mtlx file, USD stage (.usda/.usdc/.usd/.usdz) or MERL .binary; not needed with --coverage")
    p.add_argument("--coverage", action="store_true",
                   help="print which MaterialX node categories are supported (the coverage table) and exit")
    p.set_defaults(_inspect_parser=p)
    add_options(p, InspectOptions, parsers=PARSERS, bases=TRAIN_BASES)
    return p


def options_of(args: argparse.Namespace) -> InspectOptions:
    """The :class:`InspectOptions` of the flags given (training flags override the preset's)."""
    return options_from_args(InspectOptions, args, base=preset_settings)


def run(args: argparse.Namespace) -> int:
    if getattr(args, "coverage", False):
        if args.asset is not None:
            args._inspect_parser.error("--coverage takes no ASSET: it reports the tool, not an asset")
        # Local: the coverage walk compiles every library nodedef; only this flag needs it.
        from mtlx2neural.graph.coverage import format_coverage

        print(format_coverage())
        return 0
    if args.asset is None:
        args._inspect_parser.error("the following arguments are required: ASSET (or give --coverage for the "
                                   "node coverage table)")
    options = options_of(args)
    # Local: --help and option errors answer without importing torch.
    from mtlx2neural.pipeline.inspection import format_report, inspect_asset

    report = inspect_asset(args.asset, options)
    print(json.dumps(report, indent=2) if options.json else format_report(report))
    return 0
