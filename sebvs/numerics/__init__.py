"""Studies of the numerical knobs: error against run time (work-precision) and stability on stiff and extreme settings.

work_precision  Pareto fronts, CSV, plots and summary shared by every study
wp_physics      integrator x timestep against a fine reference (nav, belt, conveyor)
wp_events       event-stream errors (counts per tick, timestamps) against a reference
wp_events_run   the event study's motions: dvs sampling rate against a fast-sampled one
wp_policy       policy input size against validation error and inference time
sweep           what every stability case shares: the case, its classes, exceptions
stability       the grids, the nav and belt cases, and the whole sweep
arm_cases       the arm scene's cases and their plausibility test
dvs_cases       the emulator's extreme cases
dvs_adapter     the one place the studies touch the emulator's API

tools/checks/work_precision.py and tools/checks/stability_sweep.py are the command lines.
"""
