"""The simulator: a JSBSim multirotor world speaking PX4's simulator MAVLink protocol in lockstep."""

from simlink import check_compiled

check_compiled(__file__)
