"""The simulator: a JSBSim multirotor world speaking PX4's simulator MAVLink protocol in lockstep."""
