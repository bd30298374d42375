"""Loop closure (LeoVR Sec. IV-B): a bag-of-binary-words vocabulary over ORB descriptors, the
co-visibility detection rule, geometric validation and a global pose graph."""
