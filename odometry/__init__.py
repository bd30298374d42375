"""Visual-LiDAR odometry and the sliding-window factor graph (to come: features, LiDAR association,
factors, fixed-lag smoother, loop closure)."""
