"""Launching a sweep's jobs: the machine checked first, then a local pool of workers or a SLURM job array."""
