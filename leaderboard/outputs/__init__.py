"""What a leaderboard build writes besides the site: Table 1's files, its intervals and marks, the figures, the downloads."""
