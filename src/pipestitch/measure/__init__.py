"""Measurement on the mosaic and the rings: defects (holes, spots), clock positions."""
