"""Perception: table plane, colour detection and calibration, same-colour identities, first-frame pose finding."""
