"""The simulation floor: the SUMO loop (the only libsumo user), the network builder, the VC driver and the offline loop."""
