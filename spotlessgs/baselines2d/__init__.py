"""Single-view 2D baselines."""
