"""Offline reproductions of the seed papers' own experiments (no SUMO: :class:`vcsumo.plant.TrainPlant`)."""
