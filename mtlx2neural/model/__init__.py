"""The neural material as torch modules (docs/ARCHITECTURE.md, "model"): latent pyramid, encoder,
BRDF decoder with learned shading frames, and the learned sampler's analytic proxy."""
