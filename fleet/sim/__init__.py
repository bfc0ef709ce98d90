"""The fake vehicle: a MAVLink quadrotor that behaves like ArduCopter or PX4 SITL, without a simulator.

Layers, from the inside out:

* :mod:`fleet.sim.personality`: what differs between ArduCopter and PX4 (mode numbers, results, streams);
* :mod:`fleet.sim.physics`: point-mass kinematics and the battery, stepped with ``now``;
* :mod:`fleet.sim.model`: :class:`~fleet.sim.model.VehicleModel`, the sans-I/O vehicle: decoded
  messages in, messages out, time passed in as ``now``;
* :mod:`fleet.sim.flight`: the time-driven rules (auto-disarm, offboard loss, touchdown) and motion targets;
* :mod:`fleet.sim.setpoints`: SET_POSITION_TARGET_* and their type_mask to a controller target;
* :mod:`fleet.sim.config`: a vehicle's settings and where it stands;
* :mod:`fleet.sim.telemetry`: the messages the vehicle sends, and when;
* :mod:`fleet.sim.params`: each autopilot's parameters, their protocol, and the values that drive the model;
* :mod:`fleet.sim.mission`: the mission protocol (empty lists but ArduPilot's home);
* :mod:`fleet.sim.ftp`: MAVLink FTP, refused at once (the fake has no files);
* :mod:`fleet.sim.codec`: pymavlink encoding, decoding and signing;
* :mod:`fleet.sim.transport`: asyncio UDP (PX4 SITL style) and TCP (ArduPilot SITL style) links;
* :mod:`fleet.sim.fleet`: many vehicles in one process, one clock, one TaskGroup.
"""
