"""Bodies the sheet is glued onto: the generator registry, one module per body, the glue model."""
