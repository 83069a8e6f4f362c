"""Results: Table 1, the paper's figures and a static HTML leaderboard built from Parquet runs."""
