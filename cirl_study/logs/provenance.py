"""Provenance: what made a run's logs and a report (docs/design.md §6-7).

:func:`machine_provenance` says which code ran where: the package version and git commit,
Python, the platform and CPU, the BLAS library numpy calls and the kernel (core type) it
picked (:mod:`threadpoolctl`), and the versions of the packages that can change a number.
:func:`collect_provenance` adds the pipeline file: it is the ``provenance`` metadata record of
every log file of a run. ``cirl-study analyze`` writes the run's and its own to the report's
``provenance.json``.
"""

from __future__ import annotations

import hashlib
import os
import platform
import subprocess
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

from cirl_study import __version__
from cirl_study.logs.format import PIPELINE_NAME_KEY

KEY_PACKAGES: tuple[str, ...] = (
    "numpy",
    "scipy",
    "numba",
    "llvmlite",
    "msgspec",
    "pandas",
    "statsmodels",
    "pingouin",
    "matplotlib",
    "mcap",
    "zstandard",
    "threadpoolctl",
)
"""Distributions whose versions can change the numbers or the files a run or report holds."""

LOG_FORMAT_VERSION = "2"
"""Version of the log format: 2 is the typed record (``robot``, ``theta_hat_se``, ...)."""


def collect_provenance(
    pipeline_path: str | Path, pipeline_name: str | None = None
) -> dict[str, str]:
    """Provenance of a run of the pipeline file ``pipeline_path``, as a string-to-string map.

    Keys: ``pipeline_name`` (default: the file's stem), ``pipeline_file``, ``pipeline_sha256``
    (hash of the file's bytes), ``log_format``, then those of :func:`machine_provenance`.
    Nothing depends on the clock, so every file of a run carries the same record.
    """
    path = Path(pipeline_path)
    return {
        PIPELINE_NAME_KEY: pipeline_name if pipeline_name is not None else path.stem,
        "pipeline_file": path.name,
        "pipeline_sha256": hashlib.sha256(path.read_bytes()).hexdigest(),
        "log_format": LOG_FORMAT_VERSION,
        **machine_provenance(),
    }


def machine_provenance() -> dict[str, str]:
    """The code and the machine, as a string-to-string map.

    Keys: ``cirl_study_version``, ``git_commit`` and ``git_dirty`` (of the source tree the
    package runs from; ``unknown`` outside a git checkout), ``python_version``, ``platform``,
    ``cpu`` (the processor's model name), ``blas`` (each BLAS/OpenMP library numpy has loaded,
    with its version, kernel architecture and threads, from :func:`threadpoolctl.threadpool_info`;
    the environment variables that steer OpenBLAS's kernel choice are named when set) and
    ``<package>_version`` for each of :data:`KEY_PACKAGES`.
    """
    provenance = {
        "cirl_study_version": __version__,
        **_git_state(Path(__file__).resolve().parent),
        "python_version": platform.python_version(),
        "platform": platform.platform(),
        "cpu": _cpu_model(),
        "blas": _blas(),
    }
    for package in KEY_PACKAGES:
        try:
            provenance[f"{package}_version"] = version(package)
        except PackageNotFoundError:
            provenance[f"{package}_version"] = "not installed"
    return provenance


def _cpu_model() -> str:
    """The processor's model name (``/proc/cpuinfo`` on Linux), else what Python knows."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown"


def _blas() -> str:
    """numpy's BLAS (and OpenMP) libraries: ``api version architecture threads`` each."""
    import numpy  # noqa: F401  (loads the BLAS library threadpoolctl is to describe)
    from threadpoolctl import threadpool_info

    libraries = [
        " ".join(
            str(info.get(key, "?"))
            for key in ("internal_api", "version", "architecture", "num_threads")
        )
        for info in threadpool_info()
    ]
    steering = [
        f"{name}={os.environ[name]}"
        for name in ("OPENBLAS_CORETYPE", "OPENBLAS_L2_SIZE", "OPENBLAS_NUM_THREADS")
        if name in os.environ
    ]
    return "; ".join(libraries + steering) or "none found"


def _git_state(directory: Path) -> dict[str, str]:
    """``git_commit`` and ``git_dirty`` of the checkout containing ``directory``."""

    def git(*args: str) -> str | None:
        try:
            done = subprocess.run(
                ["git", "-C", str(directory), *args],
                capture_output=True,
                text=True,
                timeout=10,
                check=False,
            )
        except (OSError, subprocess.SubprocessError):
            return None
        return done.stdout.strip() if done.returncode == 0 else None

    commit = git("rev-parse", "HEAD")
    if commit is None:
        return {"git_commit": "unknown", "git_dirty": "unknown"}
    status = git("status", "--porcelain", "--untracked-files=no")
    dirty = "unknown" if status is None else str(bool(status)).lower()
    return {"git_commit": commit, "git_dirty": dirty}
