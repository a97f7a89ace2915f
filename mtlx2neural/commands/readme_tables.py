"""``python -m mtlx2neural.commands.readme_tables --readme README.md [--check]``: README's command-line
option tables, generated from every command's parser (:mod:`.parser`) by :func:`.options_cli.options_table`.

It sits above the parser, which imports every command module, so that no command module imports
the parser back (``tests/test_layering.py`` refuses import circles)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mtlx2neural.commands.options_cli import options_table, replace_between_markers
from mtlx2neural.commands.parser import command_parsers


def main(argv: list[str] | None = None) -> int:
    """``python -m mtlx2neural.commands.readme_tables --readme README.md [--check]``: write (or
    check) the option tables between the markers; print them without ``--readme``."""
    ap = argparse.ArgumentParser(prog="python -m mtlx2neural.commands.readme_tables",
                                 description="Generate README's command-line option tables.")
    ap.add_argument("--readme", type=Path, help="the README to update between the markers")
    ap.add_argument("--check", action="store_true", help="exit 1 if the README's tables are out of date")
    args = ap.parse_args(argv)
    table = options_table(command_parsers())
    if args.readme is None:
        sys.stdout.write(table)
        return 0
    text = args.readme.read_text()
    new = replace_between_markers(text, table)
    if args.check:
        if new != text:
            print(f"{args.readme}: the option tables are out of date: run python -m "
                  f"mtlx2neural.commands.readme_tables --readme {args.readme}", file=sys.stderr)
            return 1
        return 0
    if new != text:
        args.readme.write_text(new)
        print(f"updated {args.readme}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
