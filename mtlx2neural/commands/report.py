"""``mtlx2neural report LAYER``: the HTML report of a neural layer
(:class:`~mtlx2neural.report.options.ReportOptions`)."""

from __future__ import annotations

import argparse

from mtlx2neural.commands import values
from mtlx2neural.commands.options_cli import add_options, options_from_args
from mtlx2neural.report.options import ReportOptions

NAME = "report"
USAGE = "mtlx2neural report LAYER"
HELP = ("HTML report of a neural layer: renders, FLIP, analytic baseline, error versus cost, polar plots, "
        "training curves, latents, memory")


def add_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser(NAME, help=HELP, description=f"{HELP[0].upper()}{HELP[1:]}.")
    p.add_argument("layer", metavar="LAYER",
                   help="the neural USD layer that `mtlx2neural ASSET` wrote (ASSET_neural.usda)")
    add_options(p, ReportOptions, parsers={"texels_at": values.uv})
    return p


def run(args: argparse.Namespace) -> int:
    options = options_from_args(ReportOptions, args)
    # Local: --help and option errors answer without importing torch.
    from mtlx2neural.report.html_report import write_report

    r = write_report(args.layer, **options.kwargs())
    for m in r["materials"]:
        print(f"{m['material']}: HDR FLIP neural {m['flip']['neural']:.4f}, analytic {m['flip']['analytic']:.4f}")
    print(f"wrote {r['html']}")
    return 0
