"""Language-model agents on the MoralityGym dilemmas.

:mod:`.text` turns a world state into text (and back); :mod:`.wrapper` is the Gymnasium wrapper
whose observations are that text; :mod:`.agent` is the chat-model agent loop (retries, fallback,
token and call counts); :mod:`.settings` holds every default of the agent and the episode presets;
:mod:`.episode` scores one played episode with a morality chain. None of these import Inspect AI:
:mod:`.inspect_tasks` (the ``llm`` extra) adapts them to Inspect's tasks, solvers and scorers.
"""

from __future__ import annotations
