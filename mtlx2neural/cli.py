"""Command line: a thin shell over the library API.

    mtlx2neural ASSET [-o OUT] [--preset fast|balanced|paper] [--decoder 2x16|2x32|3x64] ...
    mtlx2neural inspect ASSET [--material M] [--json]

Exit codes: 0 ok, 1 failure, 2 bad input (the message names the file, prim or
node and what to do).
"""

from __future__ import annotations

import argparse
import json
import sys

from .errors import Mtlx2NeuralError

SUBCOMMANDS = ("inspect", "convert")


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="mtlx2neural", description="Bake MaterialX materials into neural materials.")
    sub = p.add_subparsers(dest="command", required=True)
    ins = sub.add_parser("inspect", help="list materials, bound prims, kept/pruned lobes, spatial inputs, textures")
    ins.add_argument("asset", help=".mtlx file or USD stage (.usda/.usdc/.usd)")
    ins.add_argument("--material", help="only this material (prim path, prim name or MaterialX name)")
    ins.add_argument("--json", action="store_true", help="print JSON instead of text")
    ins.add_argument("--allow-missing-textures", action="store_true",
                     help="use an image node's declared default when its file is missing")
    conv = sub.add_parser("convert", help="train a neural material for every selected material (default command)")
    conv.add_argument("asset", help=".mtlx file or USD stage")
    conv.add_argument("-o", "--output", help="output folder (default: ASSET_neural next to the input)")
    conv.add_argument("--preset", default="fast", choices=["fast", "balanced", "paper"])
    conv.add_argument("--decoder", choices=["2x16", "2x32", "3x64"])
    conv.add_argument("--iterations", type=int)
    conv.add_argument("--batch", type=int)
    conv.add_argument("--frames", type=int)
    conv.add_argument("--material", help="only this material (prim path, prim name or MaterialX name)")
    conv.add_argument("--device", default="auto", help="cpu, cuda or auto (CUDA when present)")
    conv.add_argument("--seed", type=int)
    conv.add_argument("--resume", action="store_true", help="continue from the checkpoints in the output folder")
    conv.add_argument("--allow-missing-textures", action="store_true")
    conv.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


def _convert(args) -> int:
    from .convert import convert_asset, default_output
    from .train.config import preset
    from .train.trainer import TrainingInterrupted

    cfg = preset(args.preset, decoder=args.decoder, iterations=args.iterations, batch=args.batch,
                 frames=args.frames, seed=args.seed)
    try:
        summaries = convert_asset(args.asset, cfg, args.output, args.material, args.device, args.resume,
                                  not args.quiet, args.allow_missing_textures)
    except TrainingInterrupted as exc:
        print(f"mtlx2neural: {exc}", file=sys.stderr)
        return 1
    out = args.output or default_output(args.asset)
    for s in summaries:
        print(f"{s['material']}: {s['steps']} steps in {s['seconds']} s, held-out log-L1 "
              f"{s['held_out_log_l1']:.4f}, HDR FLIP {s['flip_mean']:.4f} (views {s['flip_per_view']})")
    print(f"wrote {out} (checkpoints, training curves, summaries); USD export comes with a later stage")
    return 0


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] not in SUBCOMMANDS and not argv[0].startswith("-"):
        argv = ["convert"] + argv  # `mtlx2neural ASSET ...` is the conversion
    args = _parser().parse_args(argv)
    try:
        if args.command == "inspect":
            from .inspect import format_report, inspect_asset

            report = inspect_asset(args.asset, args.material, args.allow_missing_textures)
            print(json.dumps(report, indent=2) if args.json else format_report(report))
            return 0
        return _convert(args)
    except Mtlx2NeuralError as exc:
        print(f"mtlx2neural: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("mtlx2neural: interrupted", file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
