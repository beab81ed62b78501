"""The ensemble family: the ensemble Kalman filter (perturbed observations) and the
deterministic square-root ensemble filter (ETKF), with their ensemble RTS smoother
(:mod:`.enkf`).  Names are imported from their modules, not from here."""
