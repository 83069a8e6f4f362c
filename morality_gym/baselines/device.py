"""Where a sweep's fleets train: the ``device=`` setting, resolved once into a :class:`Device`.

Why one object: the setting used to cross about 16 modules as a string, be cut into its kind
(``cuda:1`` -> ``cuda``) in two places and be checked by the fleet engine's ``fleet_device`` three
times (the configuration, the job, the fleet). :meth:`Device.parse` and :meth:`Device.checked` check it once, when the
configuration is validated, on the machine that trains (a dry run plans and a SLURM submission
trains on other nodes: there the check waits for the node, :meth:`Device.check_here`). The
fleet engine receives the object itself and takes it as it is
(:func:`morality_gym.baselines.fleet.base.fleet_device`); its spelling (``name``) is what a fleet
checkpoint's key holds.

torch is imported only by :meth:`Device.check_here`, and only for an accelerator: whether it sees a
GPU is torch's answer, and a CPU sweep's checks must not load it (seconds).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from morality_gym.baselines.specs import SpecError

#: The kinds of device the fleet engine trains on.
KINDS = ("cpu", "cuda")
_SPELLING = re.compile(r"^(?P<kind>[a-z]+)(?::(?P<index>\d+))?$")


@dataclass(frozen=True)
class Device:
    """A device the fleet engine trains on: ``cpu``, ``cuda`` or ``cuda:N`` (as torch spells it).

    ``checked_here``: torch in the process that resolved it can use it; a worker that inherits a
    checked device on the same machine (the local pool) need not ask torch again, one on another
    machine (a SLURM node) must (:meth:`usable`)."""

    name: str
    checked_here: bool = False

    @property
    def kind(self) -> str:
        """``cuda:1`` -> ``cuda``: fleet sizes and planning rates are per kind of device, not per card."""
        return self.name.split(":", 1)[0]

    @property
    def on_cpu(self) -> bool:
        return self.kind == "cpu"

    @classmethod
    def parse(cls, text: str) -> Device:
        """``text`` checked for its spelling only (a :class:`SpecError` names what is valid)."""
        found = _SPELLING.match(str(text))
        if found is None or found["kind"] not in KINDS or (found["kind"] == "cpu" and found["index"] not in (None, "0")):
            raise SpecError(f"device={text!r}: not a device the fleet engine trains on; use cpu, cuda or cuda:N")
        return cls(str(text))

    def checked(self, here: bool) -> Device:
        """This device, with ``here`` (fleets will train on this process's machine) checked against
        what torch sees (:meth:`check_here`) and marked so; without, as it is (checked where it trains)."""
        if not here or self.checked_here:
            return self
        self.check_here()
        return Device(self.name, checked_here=True)

    def check_here(self) -> None:
        """Raise :class:`SpecError` when torch in this process cannot use the device."""
        if self.on_cpu:
            return
        import torch  # a heavy package: only an accelerator's check needs it (module docstring)

        if not torch.cuda.is_available():
            raise SpecError(f"device={self.name!r}: torch sees no GPU here (torch.cuda.is_available() is False); use device=cpu")
        index = int(self.name.split(":", 1)[1]) if ":" in self.name else 0
        if index >= torch.cuda.device_count():
            raise SpecError(f"device={self.name!r}: torch sees {torch.cuda.device_count()} GPU(s) here, numbered from 0")

    def usable(self) -> None:
        """:meth:`check_here` unless the device was already checked on this machine (:meth:`checked`).

        A job may run on another machine than the one that resolved the setting (a SLURM node): there
        ``checked_here`` is False (a SLURM sweep is checked with ``here=False``) and the node checks."""
        if not self.checked_here:
            self.check_here()

    def __str__(self) -> str:
        return self.name


#: The default: fleets train on the CPU (nothing to check).
CPU = Device("cpu", checked_here=True)
