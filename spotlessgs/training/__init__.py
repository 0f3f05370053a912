"""Training: data loading, losses, densification strategy, checkpoints and the optimisation loop."""
