"""Batch runs over a study folder: the study runner, its steps, and long videos in segments."""
