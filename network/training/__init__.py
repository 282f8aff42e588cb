"""Training: the paper's losses, the training loop, multi-process support, learning curves, and the
stages that fit the depth heads and calibrate decisions on a trained network."""
