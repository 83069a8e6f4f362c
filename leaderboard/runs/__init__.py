"""Reading runs: where they come from, which count, and the numbers of each Table 1 cell (the leaderboard's lowest floor)."""
