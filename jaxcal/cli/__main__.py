"""``python -m jaxcal.cli``: the same as the ``jaxcal`` command."""

from . import console_main

if __name__ == "__main__":
    raise SystemExit(console_main())
