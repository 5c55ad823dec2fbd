"""Episodes and the paper's tables."""
