"""Matplotlib figures (PNG): episodes, closed-loop comparisons (Fig. 2), Kalman fusion (Fig. 3)."""
