"""The data structures of masks: run-length encoded masks, their runs and crops."""
