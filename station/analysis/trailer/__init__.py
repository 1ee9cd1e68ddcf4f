"""Trailer link-length calibration (seed 003): the patent's estimators and the station's."""
