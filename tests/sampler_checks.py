"""The chi-square check of a Material's sampler against its own pdf, shared by the reference materials' tests."""

from __future__ import annotations

import torch

from mtlx2neural.verify.chi2 import chi2_test


def sampler_chi2(material, wi: torch.Tensor, test_count: int):
    """``verify.chi2.chi2_test`` of ``material.sample`` at the fixed ``wi`` [1, 3] (local frame) against
    ``material.pdf`` (solid angle): 100k samples, seed 7; ``test_count`` is the module's number of such
    tests, for the significance level's Sidak correction."""

    def sample_fn(u):
        wo, _, pdf = material.sample(wi.expand(u.shape[0], 3), u.float())
        return wo, pdf > 0

    def pdf_fn(wo):
        return material.pdf(wi.expand(wo.shape[0], 3), wo.float())

    return chi2_test(sample_fn, pdf_fn, sample_count=100_000, test_count=test_count, seed=7)
