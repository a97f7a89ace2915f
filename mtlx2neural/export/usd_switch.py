"""The switch that lets the ``neuralMaterial`` variant win over terminal outputs the USD input connects itself.

The neural layer sublayers the input (:mod:`.usd_writer`), so for a composed Material the input's
opinions are *local* (the L of LIVRPS) and beat every opinion authored inside the layer's
``neuralMaterial`` variant set (the V). A Material of the input that connects, say,
``outputs:mtlx:surface`` itself would keep that connection whatever the variant authors, and a
viewer reading that render context would keep drawing the original.

The fix needs an opinion outside the variants, which is only possible if that opinion is the same
for both variants. So, for each terminal output that the input connects and that the ``neural``
variant replaces, the layer authors, outside the variants (our layer is the stronger sublayer, so
this local opinion beats the input's)::

    Material  outputs:<ctx:>surface.connect = </Material/NeuralSwitch.outputs:<port>>

and, inside **each** variant, a NodeGraph ``NeuralSwitch`` that only this layer defines::

    NodeGraph NeuralSwitch
        token inputs:<port>.connect  -> the variant's shader output
        token outputs:<port>.connect -> </Material/NeuralSwitch.inputs:<port>>   (a pass-through)

``<port>`` is the output's name without ``outputs:``, ``:`` as ``_`` (``mtlx_surface``,
``surface``). In ``neural`` the input connects to the neural network (``SR_neural_<ident>``
or the ``NeuralPreview`` UsdPreviewSurface); in ``original`` to exactly what the input's own
output connected to (read from the composed input before anything is authored). The
pass-through through an input keeps UsdShade's encapsulation rules
(``UsdShadeConnectableAPI.CanConnect``): a NodeGraph's *output* may only be connected to an
input of its own prim or to an output of a prim inside it, while its *inputs* may be connected to
outputs of its siblings, the Material's shaders.

Outputs that the input does not connect get no switch: no input opinion shadows them, so the
``neural`` variant authors them directly on the Material as before, and ``original`` leaves them
absent, as in the input.

Why renderers follow the switch (OpenUSD sources): ``UsdShadeMaterial::ComputeSurfaceSource``
resolves the Material output with ``UsdShadeUtils::GetValueProducingAttributes(output,
shaderOutputsOnly=true)``, which follows connections through NodeGraph outputs and inputs to the
shader output producing the value, and falls back to the universal ``outputs:surface`` when a
render context's output resolves to nothing. Hydra builds its material networks from the same
resolution: ``pxr/usdImaging/usdImaging/dataSourceMaterial.cpp`` (scene-index path) takes each
terminal's node from ``UsdShadeMaterial::ComputeSurfaceSource`` (``_ComputeOutputSource``) and walks
upstream with ``UsdShadeInput::GetValueProducingAttributes(shaderOutputsOnly=true)``
(``_WalkGraph``); ``pxr/usdImaging/usdImaging/materialParamUtils.cpp``
(``UsdImaging_BuildHdMaterialNetworkFromTerminal``, the scene-delegate path) starts from the
terminal shader prim and walks with ``GetValueProducingAttribute``. NodeGraphs do not appear in the
Hydra network; the resolved shaders do. (On the scene-index path the terminal's upstream output
name is the Material output's direct source, here the switch's port; render delegates select the
terminal's shader by its node, ``upstreamNode``.)
"""

from __future__ import annotations

SWITCH = "NeuralSwitch"
"""Name of the switch NodeGraph under each Material that has one."""
OUTPUTS_PREFIX = "outputs:"


def port(output: str) -> str:
    """The switch's port name for the Material output ``output`` (``outputs:mtlx:surface`` ->
    ``mtlx_surface``, ``outputs:surface`` -> ``surface``)."""
    return output[len(OUTPUTS_PREFIX):].replace(":", "_")


def input_connections(material, outputs) -> dict:
    """``{output: [Sdf.Path]}`` for those of ``outputs`` (full names, ``outputs:...``) that the
    composed ``material`` already has connections for (an authored connection opinion, possibly an
    empty list), in the composed stage's namespace. Read before the layer authors anything on the
    Material: that is what the input itself connects."""
    prim = material.GetPrim()
    found = {}
    for output in outputs:
        attr = prim.GetAttribute(output) if prim else None
        if attr and attr.HasAuthoredConnections():
            found[output] = list(attr.GetConnections())
    return found


def take_variant_connections(stage, material, outputs) -> dict:
    """At ``stage``'s edit target (a variant of ``material``): ``{output: [Sdf.Path]}``, the
    connections of each of ``outputs`` that the edit target itself holds, and remove those output
    specs there (the switch routes them instead, :func:`author_switch`)."""
    target = stage.GetEditTarget()
    taken = {}
    for output in outputs:
        spec = target.GetPropertySpecForScenePath(material.GetPath().AppendProperty(output))
        taken[output] = list(spec.connectionPathList.GetAddedOrExplicitItems()) if spec else []
        if spec:
            material.GetPrim().RemoveProperty(output)
    return taken


def author_switch(stage, material, sources: dict):
    """At ``stage``'s edit target (one variant of ``material``), define the ``NeuralSwitch``
    NodeGraph: per ``{output: [source attribute paths]}`` of ``sources``, ``inputs:<port>``
    connected to those sources (left unconnected when the list is empty) and ``outputs:<port>``
    passing it through. Returns the NodeGraph."""
    # Local: pxr loads USD's plugins on import (about 0.15 s); only USD work needs it.
    from pxr import Sdf, UsdShade

    t = Sdf.ValueTypeNames.Token
    graph = UsdShade.NodeGraph.Define(stage, material.GetPath().AppendChild(SWITCH))
    for output, paths in sources.items():
        name = port(output)
        inp = graph.CreateInput(name, t)
        if paths:
            inp.GetAttr().SetConnections(list(paths))
        graph.CreateOutput(name, t).ConnectToSource(inp)
    return graph


def connect_material_to_switch(material, outputs) -> None:
    """At the edit target (outside the variants): connect each of ``outputs`` of ``material`` to the
    switch's ``outputs:<port>``, as an explicit list that replaces the input's connections."""
    # Local: pxr loads USD's plugins on import (about 0.15 s); only USD work needs it.
    from pxr import Sdf

    for output in outputs:
        attr = material.GetPrim().CreateAttribute(output, Sdf.ValueTypeNames.Token, custom=False)
        target = material.GetPath().AppendChild(SWITCH).AppendProperty(OUTPUTS_PREFIX + port(output))
        attr.SetConnections([target])
