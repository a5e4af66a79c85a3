"""The bridge: a Gymnasium env over the simulator's ROS 2 topics.

:mod:`.bridge_env` keeps the Gymnasium side (spaces, observations, the registered id
``ops_gym_bridge/RosPulseStacking-v0``); :mod:`.lockstep_client` speaks the lockstep protocol
(send, wait, retry). Nothing here trains or evaluates.
"""
