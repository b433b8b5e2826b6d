"""``python -m jaxcal.cli``: the same as the ``jaxcal`` command."""

from . import main

if __name__ == "__main__":
    raise SystemExit(main())
