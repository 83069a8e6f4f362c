"""Which sweep a build shows first: the user's newest, with a release's sweep beside it.

Why: after ``make reproduce-table1 PRESET=smoke`` the user wants their 630 runs, not the release
that ships with the code (issue 36): the index opened on the release's ``paper · paper`` sweep and
``results/table1.csv`` held the release's numbers. So with runs of their own, the build's primary
sweep (``table1.csv``, ``table1.tex``, the first table of ``table1.md``) and the index's grid are
the sweep of the user's newest run; the release's sweep of the same protocol is shown beside it.
Without own runs, :func:`leaderboard.runs.aggregate.choose_primary` decides as before. Kept apart from
the site's modules so that the build can ask before anything heavy is imported.
"""

from __future__ import annotations

import pandas as pd

from leaderboard.runs.aggregate import Group, Leaderboard, choose_primary
from leaderboard.runs.sources import RESULTS_SOURCE
from morality_gym.results.identity import SUBMITTED_ALGO


def _own_runs(lb: Leaderboard) -> pd.DataFrame:
    if "source" not in lb.runs.columns:
        return lb.runs
    return lb.runs.loc[lb.runs["source"] == RESULTS_SOURCE]


def _swept(own: pd.DataFrame) -> pd.DataFrame:
    """The runs a sweep trained, when the user has any: a submission (``leaderboard.submit``, the torch
    example) lands in the group of its ``--preset`` (``paper`` by default), and opened the index on
    it, 36 runs beside the release, the user's 630 smoke runs out of view (issue 45). It is the
    default view only when the user ran no sweep."""
    if "algo" not in own.columns:
        return own
    swept = own.loc[own["algo"].astype(object) != SUBMITTED_ALGO]
    return swept if not swept.empty else own


def newest_own_group(lb: Leaderboard) -> Group | None:
    """The sweep the user ran last: among the groups of the preset of their newest sweep run (their
    newest submission only when they ran no sweep), the one :func:`choose_primary` prefers (most
    rows, then protocol paper). None without runs of their own."""
    own = _swept(_own_runs(lb))
    if own.empty:
        return None
    when = pd.to_datetime(own["finished_at"].fillna(own["started_at"]), utc=True, errors="coerce")
    newest = own.loc[when.fillna(pd.Timestamp(0, tz="UTC")).idxmax()]
    presets = {(str(p), str(s)) for p, s in zip(own["protocol"], own["preset"]) if str(s) == str(newest["preset"])}
    candidates = [g for g in lb.groups if (g.protocol, g.preset) in presets]
    return choose_primary(lb.table, candidates) if candidates else None


def release_match(lb: Leaderboard, mine: Group) -> Group | None:
    """The release's sweep to compare ``mine`` with: same protocol, a group holding released runs,
    the paper's budget preferred (:func:`choose_primary`). None when no release has that protocol."""
    if "source" not in lb.runs.columns:
        return None
    released = lb.runs.loc[lb.runs["source"] != RESULTS_SOURCE]
    have = {(str(p), str(s)) for p, s in zip(released["protocol"], released["preset"])}
    candidates = [g for g in lb.groups if g != mine and g.protocol == mine.protocol and (g.protocol, g.preset) in have]
    return choose_primary(lb.table, candidates) if candidates else None


def opening_groups(lb: Leaderboard) -> tuple[Group | None, Group | None]:
    """(the sweep the index opens on, the sweep shown beside it or None)."""
    mine = newest_own_group(lb)
    if mine is None:
        return lb.primary, None
    return mine, release_match(lb, mine)




def whose_runs(lb: Leaderboard, group: Group, newest: Group | None) -> str:
    """Whose runs a sweep's grid holds, in a few words, above it: "Your newest sweep" over release
    runs was a wrong caption (issue 45); this one is computed for each sweep, on every page."""
    part = lb.runs.loc[(lb.runs["protocol"] == group.protocol) & (lb.runs["preset"] == group.preset)]
    sources = set(part["source"]) if "source" in part.columns else {RESULTS_SOURCE}
    mine, released = RESULTS_SOURCE in sources, bool(sources - {RESULTS_SOURCE})
    if group == newest:
        return "Your newest sweep" + (", with a release's runs" if released else "")
    if mine and released:
        return "Your runs and a release's"
    return "Your runs" if mine else "A release's runs (none of yours)"


def display_order(lb: Leaderboard) -> list[Group]:
    """The sweeps in the order a page shows them: the one the index opens on, the one beside it,
    then the others (:attr:`Leaderboard.groups`' order). The ranking and scenario pages opened on
    the release's section, the user's own sweep further down (issue 45)."""
    first = [g for g in opening_groups(lb) if g is not None]
    return list(dict.fromkeys([*first, *lb.groups]))


def primary_choice(lb: Leaderboard, protocol: str | None, preset: str | None) -> tuple[str | None, str | None]:
    """The primary sweep's protocol and preset: as asked (``--protocol``/``--preset``), else those of
    the user's newest sweep, else (None, None): :func:`choose_primary`'s rule."""
    if protocol is not None or preset is not None:
        return protocol, preset
    mine = newest_own_group(lb)
    return (mine.protocol, mine.preset) if mine is not None else (None, None)
