"""Procedural driving world rendered with Open3D ray casting: camera, LiDAR, depth and motion ground truth."""
