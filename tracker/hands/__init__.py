"""Hand tracking (seed 004): skin colour model, ROI optical flow, motion clusters, particle filter and Kalman
reference, track management. See ``tracker.hands.tracker.HandTracker``."""
