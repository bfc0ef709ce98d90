"""The mail-request service: a FastAPI app, its SQLite store, the dispatcher and the dashboard.

``api.main.create_app`` builds the app; ``drona serve`` (:mod:`fleet.cli.serve`) runs it.
The service talks to the drones only through a :class:`api.gateway.FleetGateway`.
"""
