"""Arm kinematic calibration: identification, its split and figures, pose choice, jig features."""
