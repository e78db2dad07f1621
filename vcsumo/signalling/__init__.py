"""Signalling: regimes, the separation model, blocking-time theory, UIC 406 and fixed times."""
