"""A ``pcreg run`` output folder: its state (``run.json``, :mod:`pcreg.runs.state`) and every other file
in it (:mod:`pcreg.runs.files`), each written and read by one pair of functions.

The folder's files:

- ``run.json``: the run's identity (its inputs and options) and the commit point of every frame;
- ``NAME.png`` per frame: its labels (a key frame's own labels as given);
- ``steps.jsonl``: one line per labelled frame;
- ``carry-0.npz``, ``carry-1.npz``: what a step handed to the next, for a resumed run;
- ``confidence/NAME.png`` (with ``--confidence``): 255 times the probability that each label is right;
- ``suggest.txt`` (with ``--suggest N``): the frames to label next, best first.
"""
