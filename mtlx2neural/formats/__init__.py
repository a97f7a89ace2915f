"""File formats shared by export and codegen: FP16 conversion (``fp16``) and the weights file (``weights``: FP16 binary + JSON manifest)."""

FORMAT_VERSION = 1
"""Version of the exported format (``neural:version``); bumping it invalidates every cached training."""
