"""Synthetic traffic scenes (the CARLA stand-in) and rough 3D models (paper 3.5)."""
