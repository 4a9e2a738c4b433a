"""``python -m pipeline ...`` is the ``dynamics`` command (:func:`pipeline.cli.main`)."""

from pipeline.cli import main

if __name__ == "__main__":
    raise SystemExit(main())
