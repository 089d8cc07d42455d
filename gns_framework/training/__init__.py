"""Training a learned simulator from a recipe."""
