"""The evaluations as pure functions of their configs: the thesis's experiments (classification, rotation,
sequence) and the demo. Each returns its results (what results.json holds); :mod:`.reports` turns them
into tables, checks and figures, and :mod:`pcreg.commands` parses the command line that runs them."""
