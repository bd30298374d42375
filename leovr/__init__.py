"""leovr: motion-aware visual-LiDAR fusion for dense depth and drift-free trajectories."""

__version__ = "0.1.0"
