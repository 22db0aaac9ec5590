"""The T-Analyst replacement: keyframes, interpolation, edit journal, UI (later issue)."""
