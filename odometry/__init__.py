"""Visual-LiDAR odometry and the sliding-window factor graph of LeoVR Sec. III-C: ORB features,
LiDAR association, initial poses (KISS-ICP or PnP), the depth correction field, factors and the
fixed-lag smoother."""
