"""Provenance: what made a run's logs and a report (docs/design.md §6-7).

:func:`machine_provenance` says which code ran where: the package version and git commit,
Python, the platform and CPU, the BLAS library numpy calls and the kernel (core type) it
picked (:mod:`threadpoolctl`), and the versions of the packages that can change a number.
:func:`collect_provenance` adds the run's identity (:class:`RunIdentity`: the run id and the
whole pipeline file): it is the ``provenance`` metadata record of every log file of a run, so
the logs alone say which run they belong to and what that run plans. Whether the pipeline
text is a pipeline is the study's to say: every reader of a run is given that judgement
(:data:`PipelineOf`). ``cirl-study analyze`` writes the run's and its own to the report's
``provenance.json``.
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
import subprocess
import tomllib
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

from cirl_study.core.players import HUMANS, PACKAGES, ROBOTS
from cirl_study.escape import terminal
from cirl_study.logs.format import (
    DEMONSTRATIONS_SHA_KEY,
    DEMONSTRATIONS_TEXT_KEY,
    IDENTITY_KEYS,
    LOG_FORMAT_KEY,
    MAX_DEMONSTRATIONS_BYTES,
    MAX_PIPELINE_BYTES,
    PIPELINE_FILE_KEY,
    PIPELINE_NAME_KEY,
    PIPELINE_SHA_KEY,
    PIPELINE_TEXT_KEY,
    RUN_ID_KEY,
)
from cirl_study.logs.versions import LOG_FORMAT, READABLE, pipeline_table, readable
from cirl_study.version import __version__

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


@dataclass(frozen=True)
class RunIdentity:
    """The run a log file belongs to: its id and the pipeline file it plays.

    ``pipeline_sha256`` is the SHA-256 of the file's UTF-8 text: two files belong to one run
    exactly when their identities are equal, which the file's path does not enter (the same
    pipeline copied under another name is the same run). ``pipeline_file`` is where the run
    found the file (as a run names the path of its pipeline), only for advice.
    ``log_format`` is the format the file was written in (:mod:`cirl_study.logs.versions`),
    in which its pipeline text is read. ``demonstrations`` is the text of the file of
    demonstrations of a pipeline with participants (empty for any other), which the pipeline
    is read with: the logs carry the people's demonstrations as they carry the pipeline.
    """

    run_id: str
    pipeline_name: str
    pipeline_file: str = field(compare=False)
    pipeline_text: str
    log_format: str = field(default=LOG_FORMAT, compare=False)
    demonstrations: str = field(default="", repr=False)

    @property
    def pipeline_sha256(self) -> str:
        return hashlib.sha256(self.pipeline_text.encode()).hexdigest()

    def provenance(self) -> dict[str, str]:
        """The identity's entries of a ``provenance`` metadata record."""
        entries = {
            RUN_ID_KEY: self.run_id,
            PIPELINE_NAME_KEY: self.pipeline_name,
            PIPELINE_FILE_KEY: self.pipeline_file,
            PIPELINE_TEXT_KEY: self.pipeline_text,
            PIPELINE_SHA_KEY: self.pipeline_sha256,
            LOG_FORMAT_KEY: self.log_format,
        }
        if self.demonstrations:
            entries[DEMONSTRATIONS_TEXT_KEY] = self.demonstrations
            entries[DEMONSTRATIONS_SHA_KEY] = _sha256(self.demonstrations)
        return entries

    @classmethod
    def of(cls, provenance: Mapping[str, str]) -> RunIdentity:
        """The identity a ``provenance`` record states, as far as the record shows it: every
        key present, a log format this version reads, and the recorded hash that of the
        recorded pipeline text. Whether that text is a pipeline of the recorded name and run
        id, a reader asks its :data:`PipelineOf`.

        Raises:
            ValueError: a key is missing or any of these does not hold; the message names
                the key.
        """
        missing = [key for key in IDENTITY_KEYS if key not in provenance]
        if missing:
            raise ValueError(f"provenance lacks {', '.join(missing)} (log format < 3?)")
        log_format = provenance.get(LOG_FORMAT_KEY, "")
        if not readable(log_format):
            raise ValueError(
                f"log format '{terminal(log_format[:20])}' is not one this version reads "
                f"({', '.join(READABLE)})"
            )
        identity = cls(
            run_id=provenance[RUN_ID_KEY],
            pipeline_name=provenance[PIPELINE_NAME_KEY],
            pipeline_file=provenance[PIPELINE_FILE_KEY],
            pipeline_text=provenance[PIPELINE_TEXT_KEY],
            log_format=log_format,
            demonstrations=provenance.get(DEMONSTRATIONS_TEXT_KEY, ""),
        )
        if identity.pipeline_sha256 != provenance[PIPELINE_SHA_KEY]:
            raise ValueError(
                f"provenance's {PIPELINE_SHA_KEY} is not the hash of its {PIPELINE_TEXT_KEY}"
            )
        if len(identity.demonstrations) > MAX_DEMONSTRATIONS_BYTES:
            raise ValueError(
                f"provenance's {DEMONSTRATIONS_TEXT_KEY} is longer than the "
                f"{MAX_DEMONSTRATIONS_BYTES} bytes a file of demonstrations may be"
            )
        if (DEMONSTRATIONS_TEXT_KEY in provenance) != (DEMONSTRATIONS_SHA_KEY in provenance) or (
            identity.demonstrations
            and _sha256(identity.demonstrations) != provenance[DEMONSTRATIONS_SHA_KEY]
        ):
            raise ValueError(
                f"provenance's {DEMONSTRATIONS_SHA_KEY} is not the hash of its "
                f"{DEMONSTRATIONS_TEXT_KEY}"
            )
        return identity


def _sha256(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()


NO_IDENTITY = "no run identity: "
"""The start of the fault of a file whose provenance states no run identity."""

PipelineOf = Callable[[RunIdentity], object]
"""The study's judgement of the pipeline a run identity carries, which every reader of a run
is given: a call that raises :class:`ValueError`, naming the provenance key at fault, unless
the identity's pipeline text is a valid pipeline whose name and run id are the identity's.
Nothing a log says of its run is believed unchecked: a file whose identity it refuses states
no run identity (:func:`pipeline_faults`)."""


def pipeline_faults(provenance: Mapping[str, str] | None, pipeline_of: PipelineOf) -> list[str]:
    """``no run identity: <why>`` when ``provenance`` states an identity whose pipeline
    ``pipeline_of`` refuses, else nothing: a file's fault, as :meth:`RunIdentity.of` refusing
    its provenance is (one that states no identity is a fault of its own)."""
    try:
        identity = RunIdentity.of(provenance or {})
    except ValueError:
        return []
    missing = missing_players(provenance or {})
    if missing:
        return missing[:1]
    try:
        pipeline_of(identity)
    except ValueError as error:
        return [f"{NO_IDENTITY}{error}"]
    return []


PLAYERS_KEY = "players"
"""Provenance key: the players of installed packages that the run's pipeline names, as JSON
``{name: "package version"}`` (absent when it names none)."""


def collect_provenance(
    identity: RunIdentity, run_dir: Path | None = None, players: Iterable[str] = ()
) -> dict[str, str]:
    """Provenance of the log files of a run, as a string-to-string map.

    The entries of :meth:`RunIdentity.provenance` (``log_format`` among them), then those of
    :func:`machine_provenance` (``git_dirty`` judged without the run directory ``run_dir``),
    then :data:`PLAYERS_KEY` for those of the ``players`` (the names the pipeline plays)
    that come from installed packages (:data:`cirl_study.core.players.PACKAGES`). Nothing
    depends on the clock, so every file of a run carries the same record.
    """
    provenance = {
        **identity.provenance(),
        **machine_provenance(outputs=() if run_dir is None else (run_dir,)),
    }
    installed = {name: PACKAGES[name] for name in sorted(set(players)) if name in PACKAGES}
    if installed:
        provenance[PLAYERS_KEY] = json.dumps(installed, sort_keys=True)
    return provenance


def missing_players(provenance: Mapping[str, str]) -> list[str]:
    """Each player the pipeline of ``provenance`` names that is not registered here, as
    ``human 'greedy' is not installed; it came from package my-players 0.1`` (the package
    as :data:`PLAYERS_KEY` names it, where it does). Empty when every one is, or when the
    pipeline text cannot be read (its own check says why).
    """
    text = provenance.get(PIPELINE_TEXT_KEY, "")
    try:
        if len(text) > MAX_PIPELINE_BYTES:
            return []
        main = pipeline_table(tomllib.loads(text), provenance.get(LOG_FORMAT_KEY, "")).get("main")
        origins = json.loads(provenance.get(PLAYERS_KEY, "{}"))
    except (tomllib.TOMLDecodeError, ValueError, RecursionError, AttributeError):
        return []
    if not isinstance(main, dict) or not isinstance(origins, dict):
        return []
    faults = []
    for kind, key, registry in (("human", "humans", HUMANS), ("robot", "robots", ROBOTS)):
        names = main.get(key)
        for name in names if isinstance(names, list) else []:
            if isinstance(name, str) and name not in registry:
                origin = origins.get(name)
                came = (
                    f"it came from package {origin}"
                    if isinstance(origin, str)
                    else "the run's logs name no package of it"
                )
                faults.append(f"{kind} {name!r} is not installed; {came}")
    return faults


def machine_provenance(outputs: Iterable[Path] = ()) -> dict[str, str]:
    """The code and the machine, as a string-to-string map.

    Keys: ``cirl_study_version``, ``git_commit`` and ``git_dirty`` (of the source tree the
    package runs from; ``unknown`` outside a git checkout; changes to tracked files in the
    ``outputs``, the directories the command writes, do not count: a report committed in
    the checkout and written again does not make the code dirty), ``python_version``,
    ``platform``,
    ``cpu`` (the processor's model name), ``blas`` (each BLAS/OpenMP library numpy has loaded,
    with its version, kernel architecture and threads, from :func:`threadpoolctl.threadpool_info`;
    the environment variables that steer OpenBLAS's kernel choice are named when set) and
    ``<package>_version`` for each of :data:`KEY_PACKAGES`.
    """
    # Loaded here, not with the reader and every command that imports this module.
    from importlib.metadata import PackageNotFoundError, version

    provenance = {
        "cirl_study_version": __version__,
        **git_state(Path(__file__).resolve().parent, outputs),
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
    """The BLAS (and OpenMP) libraries loaded (numpy's, and scipy's once it is imported):
    ``api version architecture threads`` each, sorted, whatever the order they loaded in."""
    import numpy  # noqa: F401  (loads the BLAS library threadpoolctl is to describe)
    from threadpoolctl import threadpool_info

    libraries = sorted(
        " ".join(
            str(info.get(key, "?"))
            for key in ("internal_api", "version", "architecture", "num_threads")
        )
        for info in threadpool_info()
    )
    steering = [
        f"{name}={os.environ[name]}"
        for name in ("OPENBLAS_CORETYPE", "OPENBLAS_L2_SIZE", "OPENBLAS_NUM_THREADS")
        if name in os.environ
    ]
    return "; ".join(libraries + steering) or "none found"


def git_state(directory: Path, outputs: Iterable[Path]) -> dict[str, str]:
    """``git_commit`` and ``git_dirty`` of the checkout containing ``directory``; changes to
    tracked files in the ``outputs`` (directories or files, anywhere) are not counted."""

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
    top = git("rev-parse", "--show-toplevel")
    excluded = []
    for output in outputs if top is not None else ():
        try:
            inside = Path(os.path.realpath(output)).relative_to(os.path.realpath(top))
        except ValueError:
            continue  # outside the checkout
        excluded.append(f":(top,exclude,literal){inside.as_posix()}")
    status = git("status", "--porcelain", "--untracked-files=no", "--", ":(top)", *excluded)
    dirty = "unknown" if status is None else str(bool(status)).lower()
    return {"git_commit": commit, "git_dirty": dirty}
