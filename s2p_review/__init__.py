"""Everything Rerun: entity layout, blueprint, logging, viewer control, MCAP export."""
