"""Checks of the machine a valid sweep is about to use, before it writes its plan or starts a run.

:func:`runners.compose.sweep_config.validate` says whether a sweep's configuration makes sense; whether this
machine can carry it out is a different question with different answers from one minute to the
next: the results directory may not be writable, the MLflow store may not answer, no SLURM
controller may be up. Each is asked here, after the configuration is known to be valid (a typo is
reported before a slow network time-out), and answered with the same one-line
:class:`~runners.compose.sweep_config.ConfigError` the configuration's checks raise, so that the sweep stops
with exit status 2 before anything is written. A dry run trains nothing, mirrors nothing and writes
nothing, so it asks only that the results directory, if it exists, is a directory.
"""

from __future__ import annotations

import tempfile

from runners.compose.sweep_config import ConfigError, SweepConfig
from runners.launch.slurm_controller import SlurmUnavailable, check_controller
from runners.record.mlflow_mirror import TrackingError, check_reachable


def check_results_dir(sweep: SweepConfig) -> None:
    """The results directory exists (created if needed) and takes a new file: a probe is written."""
    path, value = sweep.results_dir, sweep.results_dir_setting or str(sweep.results_dir)
    if path.exists() and not path.is_dir():
        raise ConfigError(f"results_dir={value}: exists and is not a directory")
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path, prefix=".write-probe-"):
            pass
    except OSError as exc:
        raise ConfigError(f"results_dir={value}: not a writable directory ({exc.strerror or exc})") from exc


def check_mlflow(sweep: SweepConfig) -> None:
    """The sweep's MLflow store can be reached and written (:func:`runners.record.mlflow_mirror.check_reachable`)."""
    try:
        check_reachable(sweep.results_dir)
    except TrackingError as exc:
        raise ConfigError(str(exc)) from exc


def check_slurm() -> None:
    """A SLURM controller answers (:func:`runners.launch.slurm_controller.check_controller`)."""
    try:
        check_controller()
    except SlurmUnavailable as exc:
        raise ConfigError(str(exc)) from exc


def preflight(sweep: SweepConfig) -> None:
    """Every check the sweep needs of this machine, in the order the sweep has always asked them
    (its MLflow store, which lives in the results directory; the SLURM controller; the results
    directory itself). Raises :class:`~runners.compose.sweep_config.ConfigError` for the first that fails."""
    if sweep.mlflow and not sweep.dry_run:
        check_results_dir(sweep)
        check_mlflow(sweep)
    if sweep.launcher["name"] == "slurm" and not sweep.dry_run:
        check_slurm()
    if sweep.dry_run:
        if sweep.results_dir.exists() and not sweep.results_dir.is_dir():
            raise ConfigError(f"results_dir={sweep.results_dir_setting or sweep.results_dir}: exists and is not a directory")
        return
    check_results_dir(sweep)
