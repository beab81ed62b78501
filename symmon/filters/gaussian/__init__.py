"""The Gaussian family: the linear Kalman filter, the nonlinear Kalman filters (EKF, IEKF,
EKF2, UKF, CKF, Gauss–Hermite, square-root forms), their strategies, smoothers, maximum-likelihood
fit, C export and compiled steps.  Names are imported from their modules, not from here."""
