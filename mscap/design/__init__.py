"""Layout design: the forward + gradient pipeline, the objective J, the deformer, the optimiser."""
