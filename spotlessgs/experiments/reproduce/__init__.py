"""`spotless reproduce`: one resumable, parallel pipeline from the shipped rooms to the paper's tables.

Stages (a DAG, see :mod:`spotlessgs.experiments.reproduce.pipeline`): render the test rooms (uneven, saturated) and
the Cycle-GAN's other rooms; evaluate each test dataset's uneven inputs once; train every 3D method (with intermediate
scores for the speed-against-error curve), relight and evaluate it; train the Cycle-GAN and run the 2D baselines;
write REPORT.md, results.json and figures.

The package imports nothing itself (``spotless --help`` loads only its ``cli`` and ``config``); the entry point is
:func:`spotlessgs.experiments.reproduce.pipeline.reproduce`.
"""
