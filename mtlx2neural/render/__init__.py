"""Renderers that draw any material of the contract (mtlx2neural.contract): geometry, lights, Monte Carlo shading, image errors."""
