"""Sweeps: from a command line to a results directory of runs, locally or on SLURM, and the generalisation track.

The package is grouped by the job each step of a sweep does, one folder per step, in the order a
sweep takes them (docs/architecture.md, "The runners, by job"); the command-line tools sit at the
top level (``python -m runners.<tool>``), as in :mod:`leaderboard`:

``compose/`` - what the user typed, made a validated configuration
    :mod:`~runners.compose.command_line` (the sweep's flags and overrides, ``--help``, ``--cfg``,
    ``--info``), :mod:`~runners.compose.options` (user scenarios, chain files, spellings),
    :mod:`~runners.compose.search_path` (where ``conf/`` and the user's and plugins' config
    directories are), :mod:`~runners.compose.schema` (the typed schemas Hydra composes over),
    :mod:`~runners.compose.sweep_config` (the composed configuration checked and resolved into a
    :class:`~runners.compose.sweep_config.SweepConfig`).
``plan/`` - what the sweep will run, and how long it will take
    :mod:`~runners.plan.runs` (the runs, each with its content-hash id), :mod:`~runners.plan.fleets`
    (the runs cut into jobs: single runs or fleets), :mod:`~runners.plan.estimate` (the time
    estimate: rates, sharing, machine load, notes; ``compose/`` reads its rate types, since an algo
    file's ``planning`` is part of its configuration).
``execute/`` - the work, in a worker process
    :mod:`~runners.execute.jobs` (a job executed: its runs trained one by one or as one fleet),
    :mod:`~runners.execute.run` (one run: learn, evaluate, save, its Parquet row last),
    :mod:`~runners.execute.stopping` (SIGTERM: checkpoint the fleet, then end cleanly),
    :mod:`~runners.execute.track_fleet` (the generalisation track's learners trained as fleets).
``launch/`` - where the jobs run
    :mod:`~runners.launch.preflight` (the machine checked before anything is written),
    :mod:`~runners.launch.entry_points` (what a worker runs, named, so that torch loads only there),
    :mod:`~runners.launch.local_pool` (worker processes that survive each other's death),
    :mod:`~runners.launch.slurm` (one submitit job array), :mod:`~runners.launch.slurm_controller`
    (whether a SLURM controller is up).
``record/`` - what a results directory keeps beside its runs (the lowest floor)
    :mod:`~runners.record.mlflow_mirror` (finished runs mirrored into MLflow),
    :mod:`~runners.record.fleet_checkpoints` (which fleets have a training checkpoint),
    :mod:`~runners.record.leftovers` (temporary files a killed sweep left),
    :mod:`~runners.record.rename_history` (the renames :mod:`runners.migrate` applies).
the top level - the command-line tools
    :mod:`~runners.sweep` (compose, plan, launch, record), :mod:`~runners.table1` (Table 1, one sweep
    per protocol), :mod:`~runners.migrate` (old runs to the current run ids), :mod:`~runners.track`
    (the generalisation track), :mod:`~runners.cache` (the simulator-table cache: what it holds, pruning).
"""
