"""Evaluation: image metrics against ground truth, temporal consistency, downstream SfM, reports and plots."""
