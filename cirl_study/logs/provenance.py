"""The ``provenance`` metadata record every log file carries (docs/design.md §6-7)."""

from __future__ import annotations

import hashlib
import platform
import subprocess
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

from cirl_study import __version__
from cirl_study.logs.format import PIPELINE_NAME_KEY

#: Distributions whose versions can change the numbers or the files a run produces.
KEY_PACKAGES: tuple[str, ...] = ("numpy", "scipy", "mcap", "zstandard")

LOG_FORMAT_VERSION = "1"


def collect_provenance(
    pipeline_path: str | Path, pipeline_name: str | None = None
) -> dict[str, str]:
    """Provenance of a run of the pipeline file ``pipeline_path``, as a string-to-string map.

    Keys: ``pipeline_name`` (default: the file's stem), ``pipeline_file``, ``pipeline_sha256``
    (hash of the file's bytes), ``log_format``, ``cirl_study_version``, ``git_commit`` and
    ``git_dirty`` (of the source tree the package runs from; ``unknown`` outside a git
    checkout), ``python_version``, ``platform`` and ``<package>_version`` for each of
    :data:`KEY_PACKAGES`. Nothing depends on the clock, so every file of a run carries the
    same record.
    """
    path = Path(pipeline_path)
    provenance = {
        PIPELINE_NAME_KEY: pipeline_name if pipeline_name is not None else path.stem,
        "pipeline_file": path.name,
        "pipeline_sha256": hashlib.sha256(path.read_bytes()).hexdigest(),
        "log_format": LOG_FORMAT_VERSION,
        "cirl_study_version": __version__,
        **_git_state(Path(__file__).resolve().parent),
        "python_version": platform.python_version(),
        "platform": platform.platform(),
    }
    for package in KEY_PACKAGES:
        try:
            provenance[f"{package}_version"] = version(package)
        except PackageNotFoundError:
            provenance[f"{package}_version"] = "not installed"
    return provenance


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
