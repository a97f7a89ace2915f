"""Training of the neural material (DESIGN.md, "train")."""
