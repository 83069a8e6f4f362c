"""The static leaderboard site: each page's data, the run pages' charts, the templates, and the caches that keep rebuilds fast."""
