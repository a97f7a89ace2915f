"""The analytic baseline: a fitted two-lobe model per texel, its USD preview and its Slang CPU harness."""
