"""Evaluations: the thesis experiments and the demo (one module each: add_arguments, run)."""
