"""A Griffe extension for the API pages: the docstrings' Sphinx markup, rendered as Markdown.

The code's docstrings use reStructuredText roles (``:class:`~morality_gym.envs.trolley.TrolleyEnv```,
``:func:`record_episode```) and double-backtick literals. Markdown shows the roles verbatim, so
each role becomes inline code of its last name part (as Sphinx shows it with ``~``).
"""

from __future__ import annotations

import re
from typing import Any

import griffe

ROLE = re.compile(r":(?:py:)?\w+:`~?([\w.]+)`")


class SphinxRoles(griffe.Extension):
    def on_object(self, *, obj: Any, **kwargs: Any) -> None:  # griffe >= 1.x event
        if obj.docstring is not None:
            obj.docstring.value = ROLE.sub(lambda m: f"`{m.group(1).rsplit('.', 1)[-1]}`", obj.docstring.value)
