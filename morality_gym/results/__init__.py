"""The results contract: what a run is, how it is identified, written and found, below both the runners and the leaderboard.

Everything that writes results (``runners``' workers, ``leaderboard.submit``, ``leaderboard.llm``)
and everything that reads them (the leaderboard, ``runners.migrate``, a user's notebook) agrees
through these modules, and nothing here imports either side:

- :mod:`.schema`: the Parquet files of a run (its row, its learn-time evaluations, its update
  diagnostics), their columns and version, and how to read them;
- :mod:`.identity`: a run's id and its configuration key, hashes of its resolved configuration;
- :mod:`.run_config`: :class:`~.run_config.RunConfig`, one resolved run (what a worker executes,
  what its id hashes, what its row records as ``config``);
- :mod:`.manifest`: the sweep manifests (which runs a sweep planned, so readers can tell missing runs);
- :mod:`.quarantine`: unreadable result files moved aside, with the reason;
- :mod:`.recording`: what every writer of a row uses (the per-run lock, finished status, commit,
  versions, clock);
- :mod:`.presets`: the presets' files (how much a run trains, which seeds make a cell whole);
- :mod:`.track_runs`: a generalisation-track run's files, the record its command shares, the check of a done run.

Layer: ``results``, above ``baselines`` (a run's configuration holds a learner's spec) and below
``runners`` and ``leaderboard`` (docs/architecture.md).
"""
