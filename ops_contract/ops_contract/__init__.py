"""The contract every OPS package shares: what a simulator, a rig and a controller agree on.

``config`` (modes, rig keys, limits), ``node_params`` (parameters declared once, with range and
description), ``ros_interface`` (topics, QoS, node start and shutdown), ``cdr`` (the per-step
messages in their serialized form), ``command_inbox`` (how a delay command is received),
``observation`` (what a learned policy sees), ``held`` (decisions held over readings), ``rig_file``
/ ``rig_params`` / ``rig_randomization`` (a rig's description). Nothing here imports the simulator,
a controller or the bridge.
"""
