"""SOS, the optimizer: DOF as B-spline curves, the scene they live in, spacetime window problems, the
backend plugin interface with its driver loop, the shared SQP, and the continuous-time check.
Imports only ``sym``."""
