"""Small fully connected networks with ReLU hidden layers (the paper's decoder, encoder and sampler)."""

from __future__ import annotations

from torch import nn


def mlp(in_dim: int, hidden: tuple[int, ...], out_dim: int) -> nn.Sequential:
    """Linear -> ReLU for each hidden width, then a linear output layer."""
    layers, d = [], in_dim
    for h in hidden:
        layers += [nn.Linear(d, h), nn.ReLU()]
        d = h
    layers.append(nn.Linear(d, out_dim))
    return nn.Sequential(*layers)


DECODER_SIZES = {"2x16": (16, 16), "2x32": (32, 32), "3x64": (64, 64, 64)}


def parse_hidden(spec: str | tuple) -> tuple[int, ...]:
    """'2x32' -> (32, 32); a tuple passes through."""
    if isinstance(spec, tuple):
        return spec
    if spec in DECODER_SIZES:
        return DECODER_SIZES[spec]
    layers, width = spec.lower().split("x")
    return (int(width),) * int(layers)
