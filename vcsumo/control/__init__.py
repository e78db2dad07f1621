"""Virtual-coupling controllers: pure Python, no libsumo (see :mod:`vcsumo.control.base`)."""
