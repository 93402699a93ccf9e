"""``python -m pcreg``: the ``pcreg`` command."""

from pcreg.cli import main

if __name__ == "__main__":  # imported (by a documentation tool walking the package), it runs nothing
    raise SystemExit(main())
