"""Depth completion: classical baselines (and, later, the learned generator)."""
