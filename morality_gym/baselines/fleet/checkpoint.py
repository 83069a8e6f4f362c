"""Checkpoints of a fleet's training: a killed fleet resumes where it was, bit for bit.

Why: at the paper's budget a fleet trains for 15-65 minutes before it writes its first run, and a
sweep resumes at run granularity, so every interruption (a shutdown, a preempted SLURM task,
Ctrl-C) used to retrain the whole fleet. :meth:`FleetTrainer.learn
<morality_gym.baselines.fleet.base.FleetTrainer.learn>` with a :class:`FleetCheckpoint` writes the
training state (:meth:`~morality_gym.baselines.fleet.base.FleetTrainer.state_dict`) at update
boundaries, at most every ``every_s`` seconds and once when training ends, and restores a matching
file at its start. The resumed fleet ends with exactly the weights, optimiser states, diagnostics
and learn-time evaluations of the uninterrupted one (tests/test_fleet_checkpoint.py).

The file: a header line, the SHA-256 of the body, and the body, ``torch.save`` of
``{"format", "key", "fleet", "extra"}``, where ``fleet`` is the trainer's state and ``extra``
what the caller asked to keep with it (e.g. the evaluation rows it collected and the time it had
spent). Everything in it is tensors and plain Python data, read back with
``torch.load(weights_only=True)``, which unpickles no arbitrary object. A file is written to a
temporary name, flushed to disk and renamed over the old one, so a kill at any moment leaves the
previous checkpoint or the new one, never half of one.

Why the digest: ``torch.load`` checks no checksum, so one flipped bit in a weight (a bad disk, a
copy gone wrong) resumed silently and changed a run's number. Why the value checks: a state that
reads but holds a non-finite weight, moment or multiplier, or a simulator state outside its tables,
failed every run of the fleet on every rerun. Such a file, and any other damaged one, is *set
aside* (renamed to ``<name>.damaged``, said in one line, kept for a look) and the fleet trains
from the start; a file of another fleet or code is only stale, and is removed.

A file is used only if it matches: the caller's ``key`` (e.g. the runs' ids and the code's commit:
a fleet half-trained by other code must not be finished by this one) and the fleet's own
:meth:`~morality_gym.baselines.fleet.base.FleetTrainer.checkpoint_key` (learner, runs, budget, device).
A file that does not match, or cannot be read, is discarded with one warning, and training starts
from step 0: a checkpoint never fails a sweep. A file that cannot be written (a full disk: torch
raises ``RuntimeError`` for a short write, not ``OSError``) is one warning naming the path and
the free space; its temporary file is removed and training goes on.

A stop can be requested (:meth:`FleetCheckpoint.request_stop`, from a SIGTERM handler:
:mod:`runners.execute.stopping`): the next update boundary writes the state and raises
:class:`TrainingStopped`, so a fleet killed by SLURM's time limit or by preemption resumes from
where it was stopped, not from its last periodic write.
"""

from __future__ import annotations

import hashlib
import io
import logging
import math
import os
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import torch as th

from morality_gym.baselines.fleet.state import CheckpointMismatch, plain_data
from morality_gym.baselines.stopped import TrainingStopped
from morality_gym.clitools import disk_full_error, is_disk_full, one_line

if TYPE_CHECKING:
    from morality_gym.baselines.fleet.base import FleetTrainer

#: Bumped when the layout of the file changes (an older file is then discarded, never misread).
FORMAT = 3
#: The first line of a checkpoint file; the second is the hex SHA-256 of the rest.
MAGIC = b"MoralityGym fleet checkpoint\n"
#: The parts of a fleet's state whose every float must be finite (evaluation rows and diagnostics
#: may hold NaN by design: an undefined KL, a metric with nothing to average).
FINITE_PARTS = ("nets", "optimisers", "extra", "env", "last_obs", "running_ep_cost")

log = logging.getLogger(__name__)


@dataclass
class FleetCheckpoint:
    """Where and how often a fleet's training is checkpointed, and the caller's part in it.

    :param path: the checkpoint file (its directory is created when first written).
    :param every_s: the least wall time between two writes during training (0: after every
        update); the last write, when training ends, is always made.
    :param key: plain data that identifies what the file is for; a file saved under another key is
        discarded (the fleet also checks its own checkpoint key).
    :param extra: called at every write: plain data of the caller's to keep with the state.
    :param on_resume: called with ``(steps, extra)`` when a file was restored, before training goes on.
    """

    path: Path
    every_s: float  # no default here: the sweep's one lives in runners.compose.schema.Sweep.checkpoint_every_s
    key: Mapping[str, Any] = field(default_factory=dict)
    extra: Callable[[], Any] | None = None
    on_resume: Callable[[int, Any], None] | None = None
    _last_write: float = field(default=0.0, init=False, repr=False)
    _written_steps: int = field(default=-1, init=False, repr=False)
    _stop_reason: str | None = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        self.path = Path(self.path)
        self._last_write = time.monotonic()

    # ------------------------------------------------------------------ reading
    def restore(self, fleet: FleetTrainer) -> bool:
        """Load the file into ``fleet`` (set up at step 0 by ``learn``) if it exists and matches;
        True if training resumes from it. A mismatched or unreadable file is discarded (one
        warning); ``fleet`` is then left at step 0."""
        self._last_write = time.monotonic()
        if not self.path.exists():
            return False
        try:
            body = _verified_body(self.path.read_bytes())
            payload = th.load(io.BytesIO(body), map_location="cpu", weights_only=True)
        except Exception as exc:  # noqa: BLE001 - any unreadable file (truncated, not ours) is set aside, never fatal
            return self._set_aside(f"cannot be read ({type(exc).__name__}: {str(exc)[:200]})")
        if not isinstance(payload, dict) or payload.get("format") != FORMAT:
            return self._set_aside(f"is not of format {FORMAT}")
        if payload.get("key") != plain_data(dict(self.key)):
            return self._discard(f"was saved for another fleet or code ({_key_difference(dict(self.key), payload.get('key'))})")
        state = payload.get("fleet")
        where = non_finite(state, FINITE_PARTS) if isinstance(state, dict) else None
        if where is not None:
            return self._set_aside(f"holds a non-finite value ({where})")
        try:
            fleet.load_state_dict(state)  # type: ignore[arg-type]
        except CheckpointMismatch as exc:
            return self._discard(f"does not fit this fleet ({exc})")
        except Exception as exc:  # noqa: BLE001 - a damaged state: the fleet put its step-0 state back
            return self._set_aside(f"is damaged ({type(exc).__name__}: {str(exc)[:200]})")
        self._written_steps = fleet.num_timesteps
        log.warning("fleet of %d runs resumed at %s of %s steps from %s", fleet.n_runs, f"{fleet.num_timesteps:,}",
                    f"{fleet.total_timesteps:,}", self.path)
        if self.on_resume is not None:
            self.on_resume(fleet.num_timesteps, payload.get("extra"))
        return True

    def _discard(self, why: str) -> bool:
        """Warn once and remove a stale file (another fleet's or code's: training starts from step 0); False."""
        log.warning("fleet checkpoint %s %s: discarded, training from the start", self.path, why)
        self.remove()
        return False

    def _set_aside(self, why: str) -> bool:
        """Warn once and rename a damaged file to :meth:`damaged_path` (kept for a look, never read
        again; training starts from step 0); False. Where it cannot be renamed it is removed."""
        aside = self.damaged_path()
        try:
            os.replace(self.path, aside)
        except OSError:
            self.remove()
            log.warning("fleet checkpoint %s %s: removed, training from the start", self.path, why)
            return False
        self.path.with_name(self.path.name + ".tmp").unlink(missing_ok=True)
        log.warning("fleet checkpoint %s %s: set aside as %s, training from the start", self.path, why, aside.name)
        return False

    def damaged_path(self) -> Path:
        """Where a damaged file is set aside (the newest damaged one replaces an older one)."""
        return self.path.with_name(self.path.name + ".damaged")

    # ------------------------------------------------------------------ writing
    def due(self) -> bool:
        """True when ``every_s`` seconds have passed since the last write (or the start), or a stop
        was requested (:meth:`request_stop`)."""
        return self._stop_reason is not None or time.monotonic() - self._last_write >= self.every_s

    def write(self, fleet: FleetTrainer) -> None:
        """Write ``fleet``'s state at this update boundary, atomically (a temporary file, flushed
        to disk, renamed over the old one). Nothing is written when nothing changed since the last
        write or restore. A failure to write (a full disk) is a warning: training goes on.

        After :meth:`request_stop`, the write is followed by :class:`TrainingStopped` (the state
        is on disk, or the warning said why not), which ends ``learn`` at this update boundary."""
        self._write(fleet)
        if self._stop_reason is not None:
            raise TrainingStopped(f"{self._stop_reason}: fleet of {fleet.n_runs} runs stopped at {fleet.num_timesteps:,} "
                                  f"of {fleet.total_timesteps:,} steps, checkpoint {self.path}")

    def request_stop(self, reason: str) -> None:
        """Stop training at the next update boundary, after writing the state (a SIGTERM handler
        calls this: SLURM's time limit and preemption send SIGTERM, then SIGKILL after a grace
        period, so the fleet checkpoints and ends instead of losing what it trained since the
        last periodic write). Safe to call from a signal handler: it only sets a flag."""
        self._stop_reason = reason

    def _write(self, fleet: FleetTrainer) -> None:
        if fleet.num_timesteps == self._written_steps:
            return
        payload = {"format": FORMAT, "key": plain_data(dict(self.key)), "fleet": fleet.state_dict(),
                   "extra": plain_data(self.extra()) if self.extra is not None else None}
        tmp = self.path.with_name(self.path.name + ".tmp")
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            buffer = io.BytesIO()
            th.save(payload, buffer)
            body = buffer.getvalue()
            with open(tmp, "wb") as fh:
                fh.write(MAGIC + hashlib.sha256(body).hexdigest().encode("ascii") + b"\n")
                fh.write(body)
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, self.path)
            _fsync_dir(self.path.parent)
        except (OSError, RuntimeError) as exc:
            # torch.save raises RuntimeError ("unexpected pos ...") for a short write on a full disk
            if not isinstance(exc, OSError) and not is_disk_full(exc):
                raise
            log.warning("fleet checkpoint %s could not be written (%s); training goes on without it", self.path,
                        one_line(disk_full_error(self.path, exc)) if is_disk_full(exc) else exc)
            tmp.unlink(missing_ok=True)
            return
        self._last_write = time.monotonic()
        self._written_steps = fleet.num_timesteps

    def remove(self) -> None:
        """Delete the file (and a temporary one a kill left behind)."""
        for path in (self.path, self.path.with_name(self.path.name + ".tmp")):
            path.unlink(missing_ok=True)


def _verified_body(data: bytes) -> bytes:
    """The body of a checkpoint file, after its header and digest were checked (ValueError if not)."""
    if not data.startswith(MAGIC):
        raise ValueError("no checkpoint header")
    digest, newline, body = data[len(MAGIC):].partition(b"\n")
    if not newline or len(digest) != 64:
        raise ValueError("no digest line")
    if hashlib.sha256(body).hexdigest().encode("ascii") != digest:
        raise ValueError("its contents do not match their SHA-256 (changed or damaged after it was written)")
    return body


def non_finite(state: Mapping[str, Any], parts: tuple[str, ...]) -> str | None:
    """Where the first NaN or infinity in ``state[part]`` is (``"nets.pi[0]"``), or None."""
    for part in parts:
        where = _first_non_finite(state.get(part), part)
        if where is not None:
            return where
    return None


def _first_non_finite(value: Any, where: str) -> str | None:
    if isinstance(value, th.Tensor):
        if value.is_floating_point() and not bool(th.isfinite(value).all()):
            return where
        return None
    if isinstance(value, float):
        return None if math.isfinite(value) else where
    items = value.items() if isinstance(value, Mapping) else enumerate(value) if isinstance(value, (list, tuple)) else ()
    for key, item in items:
        found = _first_non_finite(item, f"{where}.{key}" if isinstance(key, str) else f"{where}[{key}]")
        if found is not None:
            return found
    return None


def _key_difference(mine: dict[str, Any], theirs: Any) -> str:
    """Which key field differs, in words (the commit, the device...)."""
    if not isinstance(theirs, dict):
        return "no key saved"
    mine = plain_data(mine)
    for name in sorted(set(mine) | set(theirs)):
        if mine.get(name) != theirs.get(name):
            return f"{name}: saved {_short(theirs.get(name))}, now {_short(mine.get(name))}"
    return "keys differ"


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def _fsync_dir(directory: Path) -> None:
    """Make a rename in ``directory`` durable (a no-op where directories cannot be opened)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
