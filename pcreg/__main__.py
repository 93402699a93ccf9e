"""``python -m pcreg``: the ``pcreg`` command."""

from pcreg.cli import main

raise SystemExit(main())
