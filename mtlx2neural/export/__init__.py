"""Export stage: trained neural materials as USD with NeuralMaterialAPI, latent EXR MIP chains and FP16 weights.

Modules: ``latents`` (EXR MIP chains), ``usd_writer`` (the neural layer), ``bundle``
(one export of an asset: latents, weights, shaders and the layer, staged and committed
together), ``load`` (rebuild a material from the files alone). The weights format and
FP16 conversion are in :mod:`mtlx2neural.formats`, shared with codegen; the output
layout and the source hash are in :mod:`mtlx2neural.pipeline`.
"""

from mtlx2neural.export.bundle import export_asset, layer_path
from mtlx2neural.export.load import load_neural
from mtlx2neural.export.usd_writer import ExportedMaterial, write_neural_layer
from mtlx2neural.formats import FORMAT_VERSION

__all__ = [
           "FORMAT_VERSION",
           "ExportedMaterial",
           "export_asset",
           "layer_path",
           "load_neural",
           "write_neural_layer",
]
