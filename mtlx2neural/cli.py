"""Command line: a thin shell over the command modules (:mod:`mtlx2neural.commands`).

    mtlx2neural ASSET [-o OUT] [--preset fast|standard|balanced|paper] [--decoder 2x16|2x32|3x64 | --max-error F]
                      [--max-texels N] [--texel-density D] [--workers N|ray|ray://HOST:PORT] [--force] ...
    mtlx2neural inspect ASSET [--material M] [--json] [--preset P] [--max-texels N] [--texel-density D]
    mtlx2neural render ASSET [--material M] [--model reference|neural] [--checkpoint PATH]
                       [--geometry sphere|plane|teapot|FILE.obj] [--env sky|FILE.hdr] [--mis own|none] -o OUT.exr
    mtlx2neural report OUT_neural.usda [--analytic-iterations N] [--texel U,V ...] [--train-sizes] [-o REPORT_DIR]
    mtlx2neural bench [NAME ...] [--list]

Every flag comes from a field of an options dataclass (docs/cli.md's option tables list them all).
Exit codes: 0 ok, 1 failure, 2 bad input or nothing convertible (the message names the
file, prim or node and what to do), 3 a conversion that skipped some materials it cannot
convert (printed with node and reason) and converted the others (``--strict``: 2 instead). A missed ``--max-error`` budget is not a failure: exit 0, with
a warning line per material and ``budget_met: false`` in its summary.
"""

from __future__ import annotations

import signal
import sys
import threading

from mtlx2neural.commands.parser import (
    ASSET_SUFFIXES,
    COMMANDS,
    build_parser,
    looks_like_asset,
)
from mtlx2neural.errors import Mtlx2NeuralError


def main(argv: list[str] | None = None) -> int:
    """Run ``mtlx2neural`` with ``argv`` (default: the process's arguments); the exit code."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] not in COMMANDS and not argv[0].startswith("-"):
        if not looks_like_asset(argv[0]):
            print(f"mtlx2neural: error: unknown command '{argv[0]}': give one of {', '.join(COMMANDS)}, or an "
                  f"asset to convert (a path ending in {', '.join(ASSET_SUFFIXES)})", file=sys.stderr)
            return 2
        argv = ["convert"] + argv  # `mtlx2neural ASSET ...` is the conversion
    parser, _ = build_parser()
    args = parser.parse_args(argv)
    _stop_on_sigterm()
    try:
        return COMMANDS[args.command].run(args)
    except Mtlx2NeuralError as exc:
        print(f"mtlx2neural: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("mtlx2neural: interrupted", file=sys.stderr)
        return 1


def _terminated(signum, frame):
    raise KeyboardInterrupt  # as Ctrl-C: a running training saves its checkpoint, the output stays as it was


def _stop_on_sigterm() -> None:
    """SIGTERM (``kill``, a job scheduler, a container stop) stops the command as Ctrl-C does."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, _terminated)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
