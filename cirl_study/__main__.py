"""``cirl-study`` and ``python -m cirl_study``: the command line, one computing thread per process.

Every command that computes much spreads its work over processes, one per core: ``run``'s
pool plays the trials, and ``analyze`` reads the log files and draws the figures in forked
workers while its main process computes the statistics. A BLAS library's own threads
(numpy's and scipy's wheels each bring an OpenBLAS, which starts a thread per core) would then
compete with those processes for the same cores, spinning while they wait for work. So
before any numerical library loads, :data:`ONE_THREAD` is set in the environment, where each
library reads it when it loads and every process the command starts inherits it; a value
the user has set is kept. Dask's worker processes get the same three settings
(distributed's ``nanny.pre-spawn-environ``). What this saves is measured in
``benchmarks/README.md``.
"""

from __future__ import annotations

import gc
import os

ONE_THREAD = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
"""The thread count each OpenMP runtime and BLAS library reads when it loads."""


def console_script() -> None:
    """The application (:data:`cirl_study.cli.app`), with :data:`ONE_THREAD` set and the
    stopping signals handled (:func:`cirl_study.interrupts.install`), then a prompt exit.

    At exit the interpreter's last garbage collections walk every object the command left,
    the statistics and plotting libraries among them. Freezing them first (``gc.freeze``)
    leaves them out of those collections; nothing is collected later anyway.
    Tests invoke the application itself, so they keep collecting and Python's own handling of
    signals.
    """
    for name, value in ONE_THREAD.items():
        os.environ.setdefault(name, value)
    from cirl_study import interrupts
    from cirl_study.cli import app

    interrupts.install()

    try:
        app(prog_name="cirl-study")
    finally:
        gc.freeze()


if __name__ == "__main__":
    console_script()
