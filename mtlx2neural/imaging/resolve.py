"""Texture files named with the wrong case: the one lookup every texture read goes through.

Libraries authored on a case-insensitive file system (Windows, macOS) often name
``wood_baseColor.png`` while the file is ``wood_basecolor.png``. On a case-sensitive
file system the path then does not exist. :func:`resolve_case` takes such a path and,
when exactly one existing file matches it with the case of every path component ignored,
returns that file and a warning naming both spellings. Two or more matches are an error
naming them (the tool cannot choose); ``strict`` makes any case mismatch an error.

Paths that exist, empty paths and UDIM/UV-tile patterns (``<UDIM>``, ``<UVTILE>``,
resolved tile by tile by :mod:`.udim`) are returned unchanged, as are paths that match
nothing: the reader then reports the missing file.
"""

from __future__ import annotations

import os

from mtlx2neural.errors import InputError

TILE_TOKENS = ("<UDIM>", "<UVTILE>")


def case_matches(path: str) -> list[str]:
    """Every existing path equal to ``path`` (made absolute and normalised) when the case of
    each component is ignored, sorted; the exact spelling is included when it exists."""
    full = os.path.normpath(os.path.abspath(path))
    drive, rest = os.path.splitdrive(full)
    parts = [p for p in rest.split(os.sep) if p]
    found = [drive + os.sep]
    for k, part in enumerate(parts):
        want, last = part.casefold(), k == len(parts) - 1
        nxt = []
        for base in found:
            try:
                names = os.listdir(base)
            except OSError:  # not a folder, or not listable: no match below it
                continue
            for name in names:
                cand = os.path.join(base, name)
                if name.casefold() == want and (last or os.path.isdir(cand)):
                    nxt.append(cand)
        found = nxt
        if not found:
            break
    return sorted(found)


def _where(node: str | None) -> str:
    return f" (node '{node}')" if node else ""


def resolve_case(path: str, *, node: str | None = None, strict: bool = False) -> tuple[str, str | None]:
    """(the file to read for ``path``, a warning or None).

    ``path``: the texture file a document names (absolute, as the scene stage writes
    them). When it does not exist but exactly one file matches it with case ignored per
    component, that file is returned with a warning naming both spellings; ``strict``
    raises :class:`InputError` instead. Two or more such files raise :class:`InputError`
    naming them. ``node`` names the image node in messages.
    """
    if not path or any(t in path for t in TILE_TOKENS) or os.path.exists(path):
        return path, None
    matches = [m for m in case_matches(path) if os.path.isfile(m)]
    if not matches:
        return path, None
    if len(matches) > 1:
        raise InputError(f"texture file '{path}'{_where(node)} does not exist, and {len(matches)} files match it "
                         f"when case is ignored: {', '.join(repr(m) for m in matches)}. Fix the spelling in the "
                         f"document, or rename the files so that only one matches.", node=node)
    found = matches[0]
    if strict:
        raise InputError(f"texture file '{path}'{_where(node)} does not exist; '{found}' differs from it only in "
                         f"case, which --strict refuses. Fix the spelling in the document or rename the file "
                         f"(without --strict it is used, with a warning).", node=node)
    return found, (f"texture file '{path}'{_where(node)} does not exist; using '{found}', whose name differs "
                   f"only in case (the document was probably authored on a case-insensitive file system)")


def on_disk(path: str) -> str:
    """``path``, or the one file that matches it when case is ignored (:func:`resolve_case` without
    its warning; an ambiguous or missing path is returned unchanged). For hashing and dependency
    lists, which must name the file a conversion reads."""
    try:
        return resolve_case(path)[0]
    except InputError:
        return path
