"""Controllers for the OPS simulator: SPGD-PID and a runner for learned policies."""
