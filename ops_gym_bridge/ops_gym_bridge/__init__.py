"""Gymnasium environment over the OPS simulator topics; train, evaluate, benchmark CLIs."""
