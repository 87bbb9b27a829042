"""Video in: the synthetic WAMI generator and reading frames from disk."""
