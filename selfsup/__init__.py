"""Self-supervised cold-start training of the depth generator (LeoVR Sec. IV): view warping, the
photometric / feature-point / refined-depth / smoothness losses, the motion-optical-flow mask, the
graph supervision (poses, landmarks, refined depth) and the trainer."""
