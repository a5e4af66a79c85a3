"""A simulated lab: instruments that speak the real protocols (SCPI over TCP, an MDT69xB-style
serial protocol on a pseudo-terminal), backed by the project's physics (:mod:`.optics`).
``ros2 run ops_rig_ros simlab --config-out RIG.yaml`` (:mod:`.main`) starts them."""
