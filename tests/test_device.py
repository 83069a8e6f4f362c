"""``device=`` is resolved once into a :class:`Device` and carried down (issue 50).

It used to cross the runners as a string, be cut into its kind in two places and be checked by
``fleet_device`` in the configuration, again in the job and again in the fleet."""

from __future__ import annotations

import pickle
import subprocess
import sys
from pathlib import Path

import pytest

from morality_gym.baselines.device import CPU, Device
from morality_gym.baselines.fleet.base import fleet_device
from morality_gym.baselines.specs import SpecError

REPO = Path(__file__).resolve().parents[1]


def test_the_spelling_is_checked_without_torch() -> None:
    assert Device.parse("cpu") == Device("cpu") and Device.parse("cuda:1").kind == "cuda"
    assert Device.parse("cuda").name == "cuda" and not Device.parse("cuda").on_cpu and CPU.on_cpu
    for bad in ("tpu", "mps", "cuda:x", "CUDA", "cpu:1", "", "cuda:0:1"):
        with pytest.raises(SpecError, match=r"not a device the fleet engine trains on; use cpu, cuda or cuda:N"):
            Device.parse(bad)
    # parsing and a CPU check never load torch (a CPU sweep's checks must not pay its import)
    code = ("import sys; from morality_gym.baselines.device import Device; "
            "Device.parse('cuda:0'); Device.parse('cpu').checked(True).usable(); print('torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_a_device_is_checked_on_the_machine_that_trains_and_only_once_there(monkeypatch: pytest.MonkeyPatch) -> None:
    asked: list[str] = []
    monkeypatch.setattr(Device, "check_here", lambda self: asked.append(self.name))
    planned = Device.parse("cuda").checked(here=False)  # a dry run, or a SLURM submission: not asked here
    assert asked == [] and not planned.checked_here
    local = Device.parse("cuda").checked(here=True)  # a local sweep: asked once, when validated
    assert asked == ["cuda"] and local.checked_here
    shipped = pickle.loads(pickle.dumps(local))  # what a local worker receives
    shipped.usable()
    assert asked == ["cuda"]  # the worker on the same machine does not ask again
    pickle.loads(pickle.dumps(planned)).usable()  # a SLURM node asks, for itself
    assert asked == ["cuda", "cuda"]
    assert local.checked(here=True) is local


def test_without_a_gpu_an_accelerator_is_refused_with_the_fix() -> None:
    import torch

    if torch.cuda.is_available():
        pytest.skip("this machine has a GPU")
    with pytest.raises(SpecError, match=r"device='cuda:1': torch sees no GPU here .*use device=cpu"):
        Device.parse("cuda:1").checked(here=True)
    with pytest.raises(SpecError, match="torch sees no GPU"):
        Device("cuda").usable()
    Device("cuda", checked_here=True).usable()  # checked on its machine: not asked again


def test_a_fleet_takes_the_device_the_sweep_checked_as_it_is(monkeypatch: pytest.MonkeyPatch) -> None:
    """The sweep resolves ``device`` once into a :class:`Device` and the job checks it on the
    machine that trains; the fleet receives that object and neither parses nor checks it again
    (a device not yet checked on this machine is checked once, here)."""
    import torch

    asked: list[str] = []
    monkeypatch.setattr(Device, "check_here", lambda self: asked.append(self.name))
    assert fleet_device(Device("cuda:1", checked_here=True)) == torch.device("cuda:1") and asked == []
    assert fleet_device(Device("cuda")) == torch.device("cuda") and asked == ["cuda"]
    assert fleet_device(CPU) == torch.device("cpu") and asked == ["cuda"]

