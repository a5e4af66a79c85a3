"""Controllers for the optical pulse stacking simulator: SPGD-PID and a runner for learned stable-baselines3 policies."""
