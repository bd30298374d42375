"""Self-supervised training of the depth generator (to come: warping, losses, flow mask, trainer)."""
