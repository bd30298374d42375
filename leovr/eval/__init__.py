"""Depth and trajectory metrics, and held-out LiDAR ground truth."""
