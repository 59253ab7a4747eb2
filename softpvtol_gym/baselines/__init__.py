"""Baselines: paper reproduction, training, evaluation and the leaderboard (scripts live here)."""
