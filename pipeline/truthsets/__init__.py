"""Truth sets: rendered clips with true instance masks from two engines (MuJoCo, PyBullet), to
benchmark the project's observation (pseudo masks from background subtraction) against the
truth. ``python -m pipeline.truthsets generate --help``; layout in :mod:`pipeline.truthsets.common`,
scenarios in :mod:`pipeline.truthsets.scenario`."""
