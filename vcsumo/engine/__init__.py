"""The campaign engine: many runs in processes or on Dask, crash isolation, a store with resume keys."""
