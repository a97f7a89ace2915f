"""``python -m mtlx2neural.commands.readme_tables [--doc docs/cli.md] [--check]``: the command-line
option tables of docs/cli.md, generated from every command's parser (:mod:`.parser`) by
:func:`.options_cli.options_table`.

It sits above the parser, which imports every command module, so that no command module imports
the parser back (``tests/test_layering.py`` refuses import circles)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mtlx2neural.commands.options_cli import options_table, replace_between_markers
from mtlx2neural.commands.parser import command_parsers

DOC = Path("docs/cli.md")
"""The document that holds the tables, relative to a source checkout's root."""


def main(argv: list[str] | None = None) -> int:
    """``python -m mtlx2neural.commands.readme_tables [--doc docs/cli.md] [--check]``: write (or
    check) the option tables between the markers of the document; ``--print`` prints them."""
    ap = argparse.ArgumentParser(prog="python -m mtlx2neural.commands.readme_tables",
                                 description="Generate the command-line option tables of docs/cli.md.")
    ap.add_argument("--doc", type=Path, default=DOC,
                    help="the Markdown document to update between the markers (default: docs/cli.md)")
    ap.add_argument("--check", action="store_true", help="exit 1 if the document's tables are out of date")
    ap.add_argument("--print", action="store_true", help="print the tables to stdout; write nothing")
    args = ap.parse_args(argv)
    table = options_table(command_parsers())
    if args.print:
        sys.stdout.write(table)
        return 0
    text = args.doc.read_text()
    new = replace_between_markers(text, table)
    if args.check:
        if new != text:
            print(f"{args.doc}: the option tables are out of date: run python -m "
                  f"mtlx2neural.commands.readme_tables --doc {args.doc}", file=sys.stderr)
            return 1
        return 0
    if new != text:
        args.doc.write_text(new)
        print(f"updated {args.doc}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
