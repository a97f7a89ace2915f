"""Command line: a thin shell over the library API.

    mtlx2neural inspect ASSET [--material M] [--json]

Exit codes: 0 ok, 1 failure, 2 bad input (the message names the file, prim or
node and what to do).
"""

from __future__ import annotations

import argparse
import json
import sys

from .errors import Mtlx2NeuralError

SUBCOMMANDS = ("inspect",)


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="mtlx2neural", description="Bake MaterialX materials into neural materials.")
    sub = p.add_subparsers(dest="command", required=True)
    ins = sub.add_parser("inspect", help="list materials, bound prims, kept/pruned lobes, spatial inputs, textures")
    ins.add_argument("asset", help=".mtlx file or USD stage (.usda/.usdc/.usd)")
    ins.add_argument("--material", help="only this material (prim path, prim name or MaterialX name)")
    ins.add_argument("--json", action="store_true", help="print JSON instead of text")
    ins.add_argument("--allow-missing-textures", action="store_true",
                     help="use an image node's declared default when its file is missing")
    return p


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] not in SUBCOMMANDS and not argv[0].startswith("-"):
        print(f"mtlx2neural: cannot convert '{argv[0]}': training and export are not available yet in this "
              f"version. Run 'mtlx2neural inspect {argv[0]}' to see what would be converted.", file=sys.stderr)
        return 1
    args = _parser().parse_args(argv)
    try:
        if args.command == "inspect":
            from .inspect import format_report, inspect_asset

            report = inspect_asset(args.asset, args.material, args.allow_missing_textures)
            print(json.dumps(report, indent=2) if args.json else format_report(report))
        return 0
    except Mtlx2NeuralError as exc:
        print(f"mtlx2neural: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("mtlx2neural: interrupted", file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
