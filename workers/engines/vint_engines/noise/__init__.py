"""Noise stage: a Kinect-like depth-noise model applied to rendered depth maps."""
