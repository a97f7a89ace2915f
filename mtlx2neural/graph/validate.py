"""Compile-time checks of input values that MaterialX's own ``validate()`` accepts.

MaterialX nodedefs list the values an enumerated input allows in its ``enum``
attribute (``uaddressmode``: ``constant,clamp,periodic,mirror``; integer
inputs also carry the matching ``enumvalues``). ``Document.validate()`` does
not check them, so a typo such as ``uaddressmode="bogus"`` would otherwise
surface as a raw error when the image is first sampled, after ``inspect`` had
said the material is fine. These checks run while the graph is compiled, which
both ``inspect`` and conversion do before any training.
"""

from __future__ import annotations

import MaterialX as mx

from mtlx2neural.errors import InputError
from mtlx2neural.graph.ir import Const, IRGraph
from mtlx2neural.imaging.texel_lookup import ADDRESS_MODES, FILTER_TYPES

# Address-mode spellings the image operator accepts besides MaterialX's own:
# UsdUVTexture's "black" reaches the inner image node of its library nodegraph unchanged.
ADDRESS_ALIASES = {"black": "constant"}


def _split(text: str) -> list[str]:
    return [part.strip() for part in text.split(",") if part.strip()]


def allowed_values(ndin: mx.Input) -> list | None:
    """The values nodedef input ``ndin`` allows, from its ``enum`` attribute, or None when any value goes.

    String inputs allow the enum's names; integer inputs the numbers of ``enumvalues``
    (the enum's names are only labels for them). Other types (a colour with named
    presets, say) are not restricted.
    """
    names = _split(ndin.getAttribute("enum"))
    if not names:
        return None
    if ndin.getType() == "string":
        return names
    if ndin.getType() == "integer":
        try:
            return [int(v) for v in _split(ndin.getAttribute("enumvalues"))] or None
        except ValueError:
            return None
    return None


def check_enum_inputs(source: str, node_path: str, nodedef: mx.NodeDef, inputs: dict) -> None:
    """Raise InputError when a constant of ``inputs`` (name -> IR input) is not among its nodedef input's enum.

    ``source`` names the file and ``node_path`` the node in the message.
    """
    for ndin in nodedef.getActiveInputs():
        allowed = allowed_values(ndin)
        value = inputs.get(ndin.getName())
        if allowed is None or not isinstance(value, Const) or value.value is None:
            continue
        # Step 1: the constant in the enum's terms (a string, or an integer for integer inputs).
        v = value.value
        if ndin.getType() == "integer":
            if isinstance(v, str) or not v:
                continue
            v = int(v[0])
        elif not isinstance(v, str) or v == "":
            continue  # "" means the nodedef's default
        # Step 2: refuse a value outside the enum, listing the allowed ones.
        if v not in allowed:
            raise InputError(
                f"{source}: node '{node_path}' ({nodedef.getName()}) has {ndin.getName()}={v!r}, which is not "
                f"an allowed value; {ndin.getName()} must be one of: {', '.join(str(a) for a in allowed)}. "
                f"Set one of these values (they are case-sensitive).", node=node_path)


def check_image_modes(source: str, graph: IRGraph, nodes: list[int]) -> None:
    """Raise InputError when an image node among ``nodes`` would be sampled with an unknown mode.

    Catches values that reached the node through a nodegraph interface, which
    :func:`check_enum_inputs` did not see on the node itself.
    """
    for i in nodes:
        n = graph[i]
        if n.category != "image":
            continue
        for name, allowed in (("uaddressmode", ADDRESS_MODES), ("vaddressmode", ADDRESS_MODES),
                              ("filtertype", FILTER_TYPES)):
            value = n.inputs.get(name)
            if not isinstance(value, Const) or not isinstance(value.value, str) or value.value == "":
                continue
            ok = value.value in allowed or (allowed is ADDRESS_MODES and value.value in ADDRESS_ALIASES)
            if not ok:
                raise InputError(
                    f"{source}: image node '{n.path}' would be sampled with {name}={value.value!r}, which is not "
                    f"an allowed value; {name} must be one of: {', '.join(allowed)}. Fix the value where it is "
                    f"set (the node or the nodegraph input it is connected to).", node=n.path)
