"""The MaterialX-code oracle: MaterialX's own generated shader code, run on the CPU, as ground truth for the torch reference."""
