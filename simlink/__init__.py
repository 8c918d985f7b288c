"""The simulator link's wire format, shared by sim_bridge and the bundled autopilot.

A precompiled codec for the two messages exchanged on every lockstep step (HIL_SENSOR and
HIL_ACTUATOR_CONTROLS) and a MAVLink 2 frame splitter; pymavlink stays the codec for every
other message. Its own package so that the autopilot need not import the simulator.
"""
