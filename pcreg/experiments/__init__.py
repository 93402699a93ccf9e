"""The evaluations as pure functions of their configs: the thesis's experiments (classification, rotation,
sequence), the stream and the demo. Each returns a :class:`~pcreg.experiments.results.Results`, whose
``to_dict()`` is results.json; :mod:`.reports` turns that document into tables, checks and figures, and
:mod:`pcreg.commands` parses the command line that runs them."""
