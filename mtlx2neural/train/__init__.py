"""Training of the neural material (docs/ARCHITECTURE.md, "train")."""
