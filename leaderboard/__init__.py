"""Results: Table 1, the paper's figures and a static HTML leaderboard built from Parquet runs.

The package is grouped by job, one folder per floor, each importing only the floors below it
(and :mod:`morality_gym.results`, the results contract, below them all):

``runs/`` - reading runs
    :mod:`~leaderboard.runs.sources` (a results directory, releases, or both),
    :mod:`~leaderboard.runs.releases` (reading a verified release), :mod:`~leaderboard.runs.selection`
    (which runs count), :mod:`~leaderboard.runs.cells` (the numbers of each Table 1 cell),
    :mod:`~leaderboard.runs.reference_rows` (the rows computed from the environments),
    :mod:`~leaderboard.runs.aggregate` (all of it as one :class:`~leaderboard.runs.aggregate.Leaderboard`),
    :mod:`~leaderboard.runs.display_order` (order, names and colours),
    :mod:`~leaderboard.runs.opening` (which sweep a build shows first), :mod:`~leaderboard.runs.stamp`
    (the build's date).
``stats/`` - statistics
    bootstrap intervals, rankings, probability of improvement, learning curves, trade-offs, their plots.
``outputs/`` - what a build writes besides the site
    :mod:`~leaderboard.outputs.tables` (Table 1 as CSV, Markdown, LaTeX),
    :mod:`~leaderboard.outputs.intervals` (Table 1 with interval estimates),
    :mod:`~leaderboard.outputs.precision` (the decimals a bound is printed with),
    :mod:`~leaderboard.outputs.marks` (what every mark means), :mod:`~leaderboard.outputs.paper_figures`
    (Figure 2 bars and radars), :mod:`~leaderboard.outputs.stats_figures` (the statistics' figures),
    :mod:`~leaderboard.outputs.downloads` (every table as CSV, all runs as Parquet).
``web/`` - the static site
    :mod:`~leaderboard.web.site` (the build), :mod:`~leaderboard.web.site_target` (where a site may
    be written), :mod:`~leaderboard.web.pages`,
    :mod:`~leaderboard.web.ranking_page`, :mod:`~leaderboard.web.table1_grid`,
    :mod:`~leaderboard.web.llm_entries` (each page's data), :mod:`~leaderboard.web.run_charts`,
    :mod:`~leaderboard.web.run_figures` (the run pages' charts), :mod:`~leaderboard.web.render`
    (Jinja2, ``templates/``, ``static/``), :mod:`~leaderboard.web.site_state`, and the caches
    (:mod:`~leaderboard.web.content_cache`, :mod:`~leaderboard.web.cached_stages`,
    :mod:`~leaderboard.web.page_cache`, :mod:`~leaderboard.web.leftovers`).
the top level - the command-line tools (``python -m leaderboard.<tool>``)
    :mod:`~leaderboard.build` (results -> tables, figures, site; its stages:
    :mod:`~leaderboard.build_stages`), :mod:`~leaderboard.submit`
    (score a policy trained elsewhere), :mod:`~leaderboard.llm` (a language-model agent),
    :mod:`~leaderboard.release` (freeze runs into ``releases/``), :mod:`~leaderboard.reproduction`
    (Table 1 against the paper, cell by cell), :mod:`~leaderboard.compare` and
    :mod:`~leaderboard.engines` (two result sets side by side), :mod:`~leaderboard.screenshot`,
    :mod:`~leaderboard.track` (the generalisation track's table and page; the site's build calls it
    for its track page, the one place a floor reaches up to a tool).
"""
