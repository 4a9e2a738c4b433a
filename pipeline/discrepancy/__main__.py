"""``python -m pipeline.discrepancy run|benchmark ...``: the same commands as ``dynamics
discrepancy`` and ``dynamics discrepancy-benchmark`` (:func:`pipeline.discrepancy.cli._main`)."""

import sys

from pipeline.discrepancy.cli import _main

sys.exit(_main())
