"""The DRONA software stack (paper Fig. 2) as sans-I/O state machines.

Each machine takes events (and ``now`` where time matters) and returns
actions, like ``h11.Connection``: the agent daemon runs them over Zenoh and
MAVLink, the systematic tester over an in-memory network. Both run the very
same objects.
"""
