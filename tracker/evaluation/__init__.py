"""Evaluation of the assembly modes on simulated sessions (the thesis's experiments, spec section 12).

``run_experiment(name, out, sessions=None, poses="groundtruth"|"tracked")`` writes markdown tables, PNG plots
and ``summary.json``; :data:`EXPERIMENTS` lists the experiments.
"""

from tracker.evaluation.experiments import EXPERIMENTS, run_experiment, tracked_available

__all__ = ["EXPERIMENTS", "run_experiment", "tracked_available"]
