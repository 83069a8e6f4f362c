"""What every mark on the leaderboard's pages means: one definition, shown under every page.

Why one place: the marks used to mean different things on different pages (Table 1's bold was
"interval overlaps no other learner's" while the ranking page bolded the best value whatever its
interval, and a shaded best cell was also drawn bold). Every page now draws each mark by the rule
stated here, and :data:`MARKS` is the legend the page frame (``base.html``) prints once. No import
beyond the standard library: the page frame loads this before SciPy may be imported (a bad
``SOURCE_DATE_EPOCH`` must be refused first, :mod:`leaderboard.build`).
"""

from __future__ import annotations

#: What bold means, stated next to every table that uses it (applied by :mod:`leaderboard.outputs.intervals`).
BOLD_RULE = ("highest mean of the row whose 95% interval overlaps no other learner's (complete cells only); "
             "no bold = not separated from another learner, or an interval is missing (one seed).")
BOLD_RULE_TEX = ("bold: highest mean of the row whose 95\\% bootstrap interval overlaps no other learner's; "
                 "no bold: not separated, or no interval (one seed).")
#: |ours - paper| from which the difference is highlighted (orange) on the site.
NOTABLE_DELTA = 0.05

#: (how the mark looks, what it means), in the order the legend lists them. ``kind`` picks the style.
MARKS: tuple[tuple[str, str, str], ...] = (
    ("bold", "0.123", ("bold = the best value among the learners compared (Table 1: a row's complete cells; ranking: "
                       "a column) whose 95% interval overlaps no other learner's; not bold = not separated, or an "
                       "interval is missing (one seed)")),
    ("best", "0.123", "shaded (outlined in the coloured grid) = the highest value of its row or column, bold or not"),
    ("warn", "⚠ incomplete", "fewer results than the scenario's variants × the preset's seeds: never bold, no Δ"),
    ("off", "+0.080", (f"Δ = ours − paper, orange from |Δ| ≥ {NOTABLE_DELTA}; given only for complete cells trained "
                       "at the paper's budget (preset paper)")),
    ("muted", "not comparable: preset smoke", ("trained at another budget than the paper's: no Δ (the paper's value "
                                               "is shown for reference only)")),
)
