"""Judging Table 1: each cell against the paper by one stated rule, the evidence behind a cell, and
one protocol against the other (the pieces of ``python -m leaderboard.reproduction``)."""
