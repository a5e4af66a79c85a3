"""The rig: a real optical pulse stacker's instruments on the project's ``ops/`` topics.

Pure modules (no rclpy): :mod:`.drivers` (instrument interface and drivers), :mod:`.rig_config`
(the rig YAML), :mod:`.safety` (voltage limits, slew, fs <-> volts), :mod:`.trace` (scope record
-> pulse trace and power), :mod:`.fringe` (calibration fits), :mod:`.rig` (instruments and safety
together), :mod:`.simlab` (simulated instruments). ROS 2 adapters: :mod:`.rig_node`,
:mod:`.calibrate`. See docs/rig.md.
"""
