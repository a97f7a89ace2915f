"""Run-time closure tree: combinators over instantiated lobes.

Each node answers three questions for a batch:
- ``eval(wi, wo)`` -> (response [N,3], throughput [N,3]) with MaterialX's combinator rules;
- ``throughput(wi)`` -> [N,3], the same throughput without a light direction (for sampling);
- ``leaves(wi, coef)`` -> [(lobe, coef)], every live lobe with the RGB factor that the
  combinators above it apply to its response (used to choose a lobe when sampling).
"""

from __future__ import annotations

import torch


class LobeNode:
    def __init__(self, lobe):
        self.lobe = lobe

    def eval(self, wi, wo):
        return self.lobe.eval(wi, wo)

    def throughput(self, wi):
        return self.lobe.throughput(wi)

    def leaves(self, wi, coef):
        return [(self.lobe, coef)]


class ZeroNode:
    def __init__(self, throughput: float):
        self.t = throughput

    def eval(self, wi, wo):
        return torch.zeros_like(wi), torch.full_like(wi, self.t)

    def throughput(self, wi):
        return torch.full_like(wi, self.t)

    def leaves(self, wi, coef):
        return []


class LayerNode:
    def __init__(self, top, base):
        self.top, self.base = top, base

    def eval(self, wi, wo):
        rt, tt = self.top.eval(wi, wo)
        rb, tb = self.base.eval(wi, wo)
        return rt + rb * tt, tt * tb

    def throughput(self, wi):
        return self.top.throughput(wi) * self.base.throughput(wi)

    def leaves(self, wi, coef):
        return self.top.leaves(wi, coef) + self.base.leaves(wi, coef * self.top.throughput(wi).clamp_min(0.0))


class MixNode:
    def __init__(self, fg, bg, amount):
        self.fg, self.bg, self.m = fg, bg, amount

    def eval(self, wi, wo):
        rf, tf = self.fg.eval(wi, wo)
        rb, tb = self.bg.eval(wi, wo)
        return rb + (rf - rb) * self.m, tb + (tf - tb) * self.m

    def throughput(self, wi):
        tf, tb = self.fg.throughput(wi), self.bg.throughput(wi)
        return tb + (tf - tb) * self.m

    def leaves(self, wi, coef):
        m = self.m.clamp(0.0, 1.0)
        return self.fg.leaves(wi, coef * m) + self.bg.leaves(wi, coef * (1.0 - m))


class AddNode:
    def __init__(self, a, b):
        self.a, self.b = a, b

    def eval(self, wi, wo):
        ra, ta = self.a.eval(wi, wo)
        rb, tb = self.b.eval(wi, wo)
        return ra + rb, (ta + tb - 1.0).clamp_min(0.0)

    def throughput(self, wi):
        return (self.a.throughput(wi) + self.b.throughput(wi) - 1.0).clamp_min(0.0)

    def leaves(self, wi, coef):
        return self.a.leaves(wi, coef) + self.b.leaves(wi, coef)


class MultiplyNode:
    def __init__(self, child, tint):
        self.child, self.tint = child, tint.clamp(0.0, 1.0)

    def eval(self, wi, wo):
        r, t = self.child.eval(wi, wo)
        return r * self.tint, t

    def throughput(self, wi):
        return self.child.throughput(wi)

    def leaves(self, wi, coef):
        return self.child.leaves(wi, coef * self.tint)
