"""Is a SLURM controller up? Checked before a sweep is planned, so that a missing cluster is one
clear line instead of a traceback from inside submitit's ``sbatch``.

Apart from :mod:`runners.launch.slurm` (which dispatches planned runs and so builds on
:mod:`runners.plan.runs`) so that validating a configuration does not import the planner it feeds.
"""

from __future__ import annotations

import shutil
import subprocess

#: How long ``scontrol ping`` may take before the controller counts as unreachable.
PING_TIMEOUT_S = 20.0
_FIX = "start the single-node cluster with `make slurm-up` (or point SLURM_CONF at your cluster), or use launcher=local"


class SlurmUnavailable(RuntimeError):
    """No SLURM controller answers; the message says how to start one or run locally instead."""


def check_controller(timeout: float = PING_TIMEOUT_S) -> None:
    """Raise :class:`SlurmUnavailable` unless ``scontrol ping`` reports a controller that is UP.

    Without this, submitit's ``sbatch`` fails deep inside the first submission with a long
    traceback that never says what to do.
    """
    scontrol = shutil.which("scontrol")
    if scontrol is None:
        raise SlurmUnavailable(f"launcher=slurm: SLURM is not installed here (no scontrol on PATH); {_FIX}")
    try:
        out = subprocess.run([scontrol, "ping"], check=False, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        raise SlurmUnavailable(f"launcher=slurm: no SLURM controller answered `scontrol ping` within {timeout:g} s; {_FIX}") from None
    text = (out.stdout + out.stderr).strip()
    if out.returncode != 0 or " is UP" not in text:
        lines = [ln.strip() for ln in text.splitlines() if ln.strip() and not ln.strip().startswith("*")]
        detail = lines[0] if lines else f"exit code {out.returncode}"
        raise SlurmUnavailable(f"launcher=slurm: no SLURM controller is up (scontrol ping: {detail}); {_FIX}")
