"""Geometry: calibrated cameras and lens distortion, the ground surface, normal positions
(paper 3.2) and smoothing along tracks."""
