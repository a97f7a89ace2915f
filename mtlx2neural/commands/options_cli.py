"""Command-line flags generated from options dataclasses, and docs/cli.md's option tables.

Every field of an options dataclass (:class:`~mtlx2neural.pipeline.options.ConvertOptions`,
:class:`~mtlx2neural.train.config.TrainConfig`, ...) becomes a flag ``--field-name``
(underscores to dashes), unless its ``metadata`` names the flag (``{"flag": "-o/--output"}``,
names separated by ``/``) or keeps it off the command line (``{"cli": False}``). The help is
the field's attribute docstring (the string literal after it in the class body, read with
:mod:`ast`: :func:`field_docs`); the type comes from the annotation: ``bool`` is a switch
(``--x``, or ``--no-x`` when the default is True), ``int``/``float``/``str`` (optionally
``| None``) take a value, ``list[...]`` a repeatable one; ``metadata`` may add ``choices`` and
a ``metavar``, and the command passes a parser for values argparse cannot type by itself
(``--workers``). A field holding another dataclass (``ConvertOptions.train``) has all its fields
as flags too; they override a base instance (the preset's), so they take both ``--x`` and
``--no-x`` for a switch.

Generated flags have no argparse default (:data:`argparse.SUPPRESS`): the namespace holds
exactly the flags given, which :func:`options_from_args` turns into an instance (unset fields
keep the dataclass's, or the base's, default).

docs/cli.md's tables: ``python -m mtlx2neural.commands.readme_tables --doc docs/cli.md`` rewrites the
text between ``<!-- options:begin -->`` and ``<!-- options:end -->`` (``--check``: exit 1 when
it is out of date, writing nothing).
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import inspect
import re
import textwrap
import types
import typing
from collections.abc import Callable
from typing import Any

BEGIN, END = "<!-- options:begin -->", "<!-- options:end -->"
"""docs/cli.md's markers around the generated option tables."""

_ROLE = re.compile(r":[a-z]+:`(~?)([^`]+)`")


def field_docs(cls) -> dict[str, str]:
    """The attribute docstring of each field of ``cls`` (a dataclass, its bases included): the
    string literal right after the field's annotation in the class source, read with :mod:`ast`
    and cleaned of indentation (:func:`inspect.cleandoc`). Fields without one are left out."""
    docs: dict[str, str] = {}
    for klass in reversed([k for k in cls.__mro__ if dataclasses.is_dataclass(k)]):
        tree = ast.parse(textwrap.dedent(inspect.getsource(klass)))
        body = next(n for n in tree.body if isinstance(n, ast.ClassDef)).body
        for node, after in zip(body, body[1:]):
            if (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)
                    and isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant)
                    and isinstance(after.value.value, str)):
                docs[node.target.id] = inspect.cleandoc(after.value.value)
    return docs


def _role(m: re.Match) -> str:
    return m.group(2).rsplit(".", 1)[-1] if m.group(1) else m.group(2)


def plain_text(doc: str) -> str:
    """A docstring as one line of plain text (argparse help): reST roles and literals unwrapped."""
    return " ".join(_ROLE.sub(_role, doc).replace("``", "").split())


def markdown_text(doc: str) -> str:
    """A docstring as one line of Markdown for a table cell: literals in backticks, ``|`` escaped."""
    text = _ROLE.sub(lambda m: f"`{_role(m)}`", doc).replace("``", "`")
    return " ".join(text.split()).replace("|", "\\|")


def _unwrap(hint) -> tuple[Any, bool]:
    """(the annotation without ``| None``, whether None is allowed)."""
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        args = typing.get_args(hint)
        rest = tuple(a for a in args if a is not type(None))
        return (rest[0] if len(rest) == 1 else typing.Union[rest]), len(rest) < len(args)
    return hint, False


def nested_dataclass(hint):
    """The dataclass a field of annotation ``hint`` holds (``TrainConfig | None``), else None."""
    base, _ = _unwrap(hint)
    return base if isinstance(base, type) and dataclasses.is_dataclass(base) else None


def flag_names(f: dataclasses.Field, negate: bool = False) -> tuple[str, ...]:
    """The flags of field ``f``: its ``flag`` metadata, else ``--field-name`` (``--no-field-name``
    for a switch that turns a True default off)."""
    if f.metadata.get("flag"):
        return tuple(f.metadata["flag"].split("/"))
    return (f"--{'no-' if negate else ''}{f.name.replace('_', '-')}",)


def _default(f: dataclasses.Field):
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return dataclasses.MISSING


def shown(value) -> str:
    """A default as the help and the table show it."""
    if value is None:
        return "none"
    if isinstance(value, bool):
        return "on" if value else "off"
    return str(value)


def add_options(parser, cls, *, parsers: dict[str, Callable[[str], Any]] | None = None,
                bases: dict[str, tuple[str, Any]] | None = None, prefix: str = "",
                base: tuple[str, Any] | None = None) -> list[argparse.Action]:
    """Add a flag for every field of dataclass ``cls`` to ``parser``; return the actions.

    ``parsers``: field name -> a function turning the flag's text into the value (raising
    :class:`argparse.ArgumentTypeError` with the message to show). ``bases``: nested dataclass
    field name -> (label, instance) whose values the nested flags override, shown as their
    defaults (``{"train": ("the preset's; fast", PRESETS["fast"])}``). Each action gets
    ``table_default`` and ``table_help`` (Markdown) for docs/cli.md's tables; its ``dest`` is
    ``prefix + field name``.
    """
    parsers, bases = parsers or {}, bases or {}
    hints = typing.get_type_hints(cls)
    docs = field_docs(cls)
    actions = []
    for f in dataclasses.fields(cls):
        if f.metadata.get("cli", True) is False:
            continue
        inner = nested_dataclass(hints[f.name])
        if inner is not None:
            label, instance = bases.get(f.name, ("default", inner()))
            group = parser.add_argument_group(f"{f.name} ({inner.__name__})", plain_text(docs.get(f.name, "")))
            nested = add_options(group, inner, parsers=parsers, prefix=f"{prefix}{f.name}.", base=(label, instance))
            for action in nested:
                action.table_group = (inner.__name__, label)
            actions += nested
            continue
        doc = docs.get(f.name, "")
        if not doc.strip():
            raise TypeError(f"{cls.__name__}.{f.name} has no docstring: it is the flag's help")
        default = getattr(base[1], f.name) if base else _default(f)
        if default is dataclasses.MISSING:
            text, cell = "required", "required"
        elif base:
            text, cell = f"{base[0]}: {shown(default)}", f"{base[0]}: `{shown(default)}`"
        else:
            text, cell = shown(default), ("—" if default is None else _code(shown(default)))
        kw: dict[str, Any] = {"dest": prefix + f.name, "default": argparse.SUPPRESS}
        hint, _ = _unwrap(hints[f.name])  # None comes from a parser (--max-texels 0) or an absent flag
        if hint is bool:
            if base:  # overrides a base value that may be either: both spellings
                kw["action"] = argparse.BooleanOptionalAction
                names = flag_names(f)
            else:
                kw["action"] = "store_false" if default else "store_true"
                names = flag_names(f, negate=bool(default))
        else:
            names = flag_names(f)
            element = hint
            if typing.get_origin(hint) is list:
                kw["action"] = "append"
                element = typing.get_args(hint)[0]
            if f.name in parsers:
                kw["type"] = parsers[f.name]
            elif element in (int, float, str):
                kw["type"] = element
            else:
                raise TypeError(f"{cls.__name__}.{f.name}: give a parser for values of type {hints[f.name]}")
            if "choices" in f.metadata:
                kw["choices"] = list(f.metadata["choices"])
            else:
                kw["metavar"] = f.metadata.get("metavar", f.name.upper())
            if default is dataclasses.MISSING:
                kw["required"] = True
        help_text = plain_text(doc) + ("" if default is None and not base
                                       else " (required)" if text == "required" else f" (default: {text})")
        action = parser.add_argument(*names, help=help_text.replace("%", "%%"), **kw)
        action.table_default = cell
        action.table_help = markdown_text(doc)
        actions.append(action)
    return actions


def given(args: argparse.Namespace, cls, prefix: str = "") -> dict[str, Any]:
    """The fields of ``cls`` whose flags were given in ``args``, by name (nested ones left out)."""
    return {f.name: getattr(args, prefix + f.name) for f in dataclasses.fields(cls)
            if hasattr(args, prefix + f.name)}


def options_from_args(cls, args: argparse.Namespace, base: Callable[[str, dict], Any] | None = None,
                      **extra):
    """An instance of ``cls`` from the flags given in ``args`` (others keep their defaults).

    A nested dataclass field whose flags were given becomes ``base(field name, the top-level values
    given)`` (the preset's :class:`TrainConfig`) with those values replaced; left at its default
    when none was. ``extra`` sets fields that are not flags.
    """
    hints = typing.get_type_hints(cls)
    values = given(args, cls)
    for f in dataclasses.fields(cls):
        inner = nested_dataclass(hints[f.name])
        if inner is None:
            continue
        sub = given(args, inner, prefix=f"{f.name}.")
        if sub:
            start = base(f.name, values) if base else inner()
            values[f.name] = dataclasses.replace(start, **sub)
    return cls(**values, **extra)


# ----------------------------------------------------------------------------- docs/cli.md's tables


def _cell_flags(action: argparse.Action) -> str:
    if not action.option_strings:
        return f"`{action.metavar or action.dest.upper()}`"
    names = list(action.option_strings)
    if action.nargs != 0:
        metavar = action.metavar or (f"{{{','.join(map(str, action.choices))}}}" if action.choices
                                     else action.dest.rsplit(".", 1)[-1].upper())
        names = [f"{names[0]} {metavar}"] + names[1:]
    return ", ".join(f"`{n}`" for n in names).replace("|", "\\|")


def _code(text: str) -> str:
    """``text`` as Markdown code, except the words that describe a default."""
    return text if text in ("on", "off", "none") else f"`{text}`"


def _cell_default(action: argparse.Action) -> str:
    cell = getattr(action, "table_default", None)
    if cell is None:  # a hand-written argument (ASSET, --list)
        if action.nargs in ("*", "?"):
            cell = "—"
        elif action.required or not action.option_strings:
            cell = "required"
        elif action.nargs == 0:
            cell = _code(shown(bool(action.default)))
        elif action.default in (None, argparse.SUPPRESS) or action.default == []:
            cell = "—"
        else:
            cell = _code(shown(action.default))
    return cell.replace("|", "\\|")


def _cell_help(action: argparse.Action) -> str:
    text = getattr(action, "table_help", None)
    return text if text is not None else markdown_text((action.help or "").replace("%%", "%"))


def options_table(commands: dict[str, tuple[str, argparse.ArgumentParser]]) -> str:
    """Markdown: per command (name -> (usage line, its parser)), a table of every argument and flag
    (``--help`` left out), with the default and the help. A nested dataclass's flags (the
    :class:`TrainConfig` ones) are listed once, under the first command that has them; later
    commands get one row naming them."""
    out, listed = [], {}
    for name, (usage, parser) in commands.items():
        out += [f"**`{usage}`**", "", "| flag | default | help |", "| --- | --- | --- |"]
        collapsed = {}
        for action in parser._actions:  # argparse has no public list of a parser's arguments
            if isinstance(action, argparse._HelpAction):
                continue
            group = getattr(action, "table_group", None)
            if group in listed and listed[group] != name:
                collapsed.setdefault(group, []).append(action.option_strings[0])
                if len(collapsed[group]) == 1:
                    out.append(group)  # placeholder, filled in below
                continue
            if group is not None:
                listed.setdefault(group, name)
            out.append(f"| {_cell_flags(action)} | {_cell_default(action)} | {_cell_help(action)} |")
        for group, flags in collapsed.items():
            cls_name, label = group
            row = (f"| `{flags[0]}` ... `{flags[-1]}` | {label} | the {len(flags)} {cls_name} flags, as for "
                   f"`{commands[listed[group]][0]}` above |")
            out[out.index(group)] = row
        out.append("")
    return "\n".join(out).rstrip() + "\n"


def replace_between_markers(text: str, table: str) -> str:
    """``text`` with what lies between :data:`BEGIN` and :data:`END` replaced by ``table``
    (ValueError when the markers are missing or out of order)."""
    start, stop = text.find(BEGIN), text.find(END)
    if start < 0 or stop < start:
        raise ValueError(f"the markers {BEGIN} and {END} are missing or out of order")
    return text[:start + len(BEGIN)] + "\n" + table + text[stop:]
