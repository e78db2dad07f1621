"""Plots that read only results tables."""
