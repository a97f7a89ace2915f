"""Compute kernels that drive a generated Slang material module the way an engine would, for the tests that
compile (and run) them: one thread per latent read from ``gIn``, a material built from a network and the
latent, and a shading expression written to ``gOut``."""

from __future__ import annotations

_TEMPLATE = """import {module};
StructuredBuffer<float> gIn;
RWStructuredBuffer<float> gOut;
ByteAddressBuffer gWeights;
[shader("compute")]
[numthreads(32, 1, 1)]
void csShade(uint3 t : SV_DispatchThreadID)
{{
    NMLatent<8> lat;
    for (int c = 0; c < 8; c++)
        lat.v[c] = gIn[t.x * 8 + c];
    {setup}
    {material} m = {material}(net, lat);
    float3 wi = normalize(float3(gIn[0], gIn[1], 1.0));
{shade}
}}
"""


def shade_kernel(module: str, setup: str, material: str, shade: str) -> str:
    """Slang source of ``csShade``: imports ``module``; ``setup`` declares the network ``net`` (e.g.
    ``NM_X_FP16 net;``); ``material`` is the material type built from ``net`` and the latent; ``shade``
    (statements, with ``m``, ``wi`` and ``t`` in scope) writes ``gOut[t.x]``. ``gWeights`` is bound for
    a network that reads its weights from a buffer."""
    return _TEMPLATE.format(module=module, setup=setup, material=material, shade=shade)
