"""MaterialX's unit system for the oracle's shader generator, set up as MaterialX's viewers set it up:
values with a distance ``unit`` are converted to metres (the reference reads them the same way:
:data:`mtlx2neural.graph.expand.TARGET_UNITS`)."""

from __future__ import annotations

import MaterialX as mx
import MaterialX.PyMaterialXGenShader as mxgen

TARGET_DISTANCE_UNIT = "meter"


def use_metres(gen, context, doc: mx.Document) -> None:
    """Give ``gen`` (a shader generator) a unit system with MaterialX's linear distance converter, from
    the unit definitions of ``doc`` (with the standard libraries), and set ``context``'s target distance
    unit to metres."""
    registry = mx.UnitConverterRegistry.create()
    distance = doc.getUnitTypeDef("distance")
    if distance is not None:
        registry.addUnitConverter(distance, mx.LinearUnitConverter.create(distance))
    units = mxgen.UnitSystem.create(gen.getTarget())
    units.setUnitConverterRegistry(registry)
    units.loadLibrary(doc)
    gen.setUnitSystem(units)
    context.getOptions().targetDistanceUnit = TARGET_DISTANCE_UNIT
