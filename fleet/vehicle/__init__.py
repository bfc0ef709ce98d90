"""The vehicle link: one async interface to an autopilot, with pymavlink and MAVSDK backends."""
