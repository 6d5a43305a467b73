"""Physical parameters of objects: densities by label, and where each value came from."""
