"""Gymnasium environment over the simulator's ROS 2 topics, and the train / evaluate / benchmark command lines."""
