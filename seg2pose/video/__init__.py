"""The video path: background subtraction and its checks, the tracker, size classes, detector
input and the scene commands built on them (video -> masks -> tracks)."""
