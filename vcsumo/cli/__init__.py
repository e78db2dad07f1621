"""The ``vcsumo`` command line."""
