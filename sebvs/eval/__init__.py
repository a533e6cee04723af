"""Closed-loop evaluation: runs the policy topologies over conditions, then tables, plots and episode videos.

run     the plan (tasks, conditions, modalities, seeds) and its runs through the supervisor
report  the paper's tables (4 and 5) and the paired comparisons, success plot
video   one MP4 per episode: what the policy saw, events, truth and the centre error
cli     `sebvs eval`

Per-episode metrics live in sebvs.metrics, below both this and the experts' rollouts.
"""
