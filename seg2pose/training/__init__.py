"""Training Seg2PoseNet: configuration, examples and their data, augmentation, rough models,
zero-annotation, the training loop and its fan-out over independent runs."""
