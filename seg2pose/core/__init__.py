"""Infrastructure every layer uses: errors, messages, input validation, digests, timestamps,
locks and the Ray helpers. Imports nothing else of seg2pose."""
