"""Evaluation: pose errors and their tables and plots, the paper table, mask scores and the
accuracy benchmark's bookkeeping."""
