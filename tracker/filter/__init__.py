"""The multi-object depth particle filter: motion model, likelihood, penalties, resampling, connections."""
