"""Export stage: trained neural materials as USD with NeuralMaterialAPI, latent EXR MIP chains and FP16 weights.

Modules: ``fp16`` (range check and quantisation), ``latents`` (EXR MIP chains),
``weights`` (binary + manifest), ``usd_writer`` (the neural layer), ``staging``
(all-or-nothing writes), ``bundle`` (one export of an asset; the output layout is
described there), ``cache`` (source hash), ``load`` (rebuild from the files alone).
"""

from .bundle import export_asset, layer_path
from .cache import FORMAT_VERSION, source_hash
from .load import load_neural
from .usd_writer import ExportedMaterial, write_neural_layer

__all__ = [
           "FORMAT_VERSION",
           "ExportedMaterial",
           "export_asset",
           "layer_path",
           "load_neural",
           "source_hash",
           "write_neural_layer",
]
