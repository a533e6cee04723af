"""Closed-loop evaluation: runs the policy topologies over conditions, then tables, plots and episode videos.

plan    the plan (modalities, conditions, scenarios, seeds) and each run's overrides; the
        conditions and scenarios themselves are sebvs/conditions.py's
run     the runner: each run through the supervisor (or fanned out), the health files,
        results.json
report  the paper's tables (4 and 5), the paired comparisons, and every plot
video   one MP4 per episode: what the policy saw, events, truth and the centre error
cli     `sebvs eval`

Per-episode metrics live in sebvs.metrics, below both this and the experts' rollouts.
"""
