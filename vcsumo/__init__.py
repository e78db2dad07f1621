"""vcsumo: railway capacity studies on Eclipse SUMO.

Fixed-block signalling (FBS), moving block (MB) and virtual coupling (VC) compared on the same
lines, with the same trains and the same physics.  See the README for the architecture.
"""

__version__ = "0.1.0"
