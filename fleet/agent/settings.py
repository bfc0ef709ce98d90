"""The agent process's settings: one pydantic-settings class, from flags and ``DRONA_*`` variables.

Flags win over the environment (``drona agent --fleet x`` over ``DRONA_FLEET``);
lists come comma-separated (``DRONA_CONNECT=tcp/10.0.0.2:7448,tcp/10.0.0.3:7448``).
A signing key comes only from the environment or a file, never from a flag (``ps`` shows flags).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field, SecretStr, field_validator, model_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

from fleet.transport.identity import IdentityError, check_security
from fleet.transport.keys import check_name
from fleet.vehicle.signing import parse_key, read_key_file

Endpoints = Annotated[list[str], NoDecode]


class AgentSettings(BaseSettings):
    # hide_input_in_errors: a validation error must not print a signing key
    model_config = SettingsConfigDict(env_prefix="DRONA_", extra="forbid", hide_input_in_errors=True)

    workspace: Path
    drone: str | None = None  #: the drone to run; with count > 1, the first of ``count`` consecutive ones
    count: Annotated[int, Field(ge=1)] = 1
    vehicle: str | None = None  #: MAVLink URL; default udpin://127.0.0.1:(base + i), as `drona sim-vehicle`
    vehicle_base_port: Annotated[int, Field(ge=1, le=65535)] = 14540  #: base of the default vehicle URLs
    fleet: str = "default"
    zenoh_config: Path | None = None
    listen: Endpoints = Field(default_factory=list)
    connect: Endpoints = Field(default_factory=list)
    lease_s: Annotated[float, Field(gt=0)] = 10.0
    epoch: float = 0.0  #: fleet epoch, Unix seconds: step k starts at epoch + k * tau
    record: Path | None = None
    clock_offset_s: float = 0.0  #: simulation only: shift this process's clock to test the skew check
    clock_step_on_signal: bool = False  #: simulation only: the shift from SIGUSR1 on (a clock stepped in flight)
    lead_steps: Annotated[int, Field(ge=1)] | None = None  #: steps between planning and a plan's start
    hover_lead_steps: Annotated[int, Field(ge=1)] | None = None  #: the same for a drone in the air
    #: the rate the link streams the setpoint at (PX4 leaves OFFBOARD at 2 Hz or less): between two, the
    #: autopilot carries a sweep on at its last velocity, off the sweep's curve where it turns
    rate_hz: Annotated[float, Field(gt=2)] = 20.0
    telemetry_hz: Annotated[float, Field(gt=0)] = 10.0  #: the rate asked of the vehicle's position streams
    #: battery points a step of flight costs (planning model); default 0.33 a second of flight
    drain_per_step: Annotated[float, Field(gt=0)] | None = None
    safe_threshold: Annotated[float, Field(ge=0, lt=100)] = 20.0
    clock_check_s: Annotated[float, Field(gt=0)] = 5.0  #: how often to measure the peers' clock offsets
    #: at start-up, how long a vehicle may take to be ready before its drone joins anyway, waiting for it
    ready_timeout_s: Annotated[float, Field(ge=0)] = 5.0
    backend: Literal["pymavlink", "mavsdk"] = "pymavlink"  #: the vehicle link's MAVLink library
    takeoff_timeout_s: Annotated[float, Field(gt=0)] = 10.0  #: an accepted take-off to leaving the ground
    command_timeout_s: Annotated[float, Field(gt=0)] = 30.0  #: a whole take-off or landing
    shared_session: bool = False  #: simulation: the process's drones share one Zenoh session (one each by default)
    #: take over a departed peer's mail; off when a service dispatches it (it clears mail for pickup)
    adopt_mail: bool = True
    signing_key: SecretStr | None = None  #: DRONA_SIGNING_KEY: the vehicle's MAVLink 2 key, 64 hex digits (one drone)
    #: MAVLink 2 keys: one key (one drone), or a line "DRONE KEY" per drone (fleet.vehicle.signing)
    signing_key_file: Path | None = None
    log_level: str = "INFO"
    tls_dir: Path | None = None  #: the fleet's certificates (drona certs): mutual TLS and access control
    insecure: bool = False  #: plain TCP, anyone on the network may speak for any drone

    @field_validator("listen", "connect", mode="before")
    @classmethod
    def _split(cls, value: object) -> object:
        if isinstance(value, str):
            return [part.strip() for part in value.split(",") if part.strip()]
        return value

    @field_validator("signing_key")
    @classmethod
    def _key(cls, value: SecretStr | None) -> SecretStr | None:
        if value is not None:
            parse_key(value.get_secret_value(), "DRONA_SIGNING_KEY")
        return value

    @field_validator("fleet")
    @classmethod
    def _fleet_name(cls, value: str) -> str:
        return check_name("fleet", value)

    @model_validator(mode="after")
    def _one_vehicle_per_drone(self) -> AgentSettings:
        if self.count > 1 and self.vehicle is not None:
            raise ValueError("--vehicle names one vehicle: with --count > 1 each drone i uses the default "
                             "udpin://127.0.0.1:(14540 + i)")
        if self.zenoh_config is not None and not self.zenoh_config.is_file():
            raise ValueError(f"zenoh_config: no such file {self.zenoh_config}")
        if self.signing_key is not None and self.signing_key_file is not None:
            raise ValueError("give the signing key in DRONA_SIGNING_KEY or in --signing-key-file, not both")
        if self.count > 1 and self.signing_key is not None:
            raise ValueError("DRONA_SIGNING_KEY is one vehicle's key: with --count > 1 give each drone its own "
                             "in --signing-key-file, a line 'DRONE KEY' each")
        self._check_security()
        if self.signing_key_file is not None and not self.signing_key_file.is_file():
            raise ValueError(f"signing_key_file: no such file {self.signing_key_file}")
        return self

    def _check_security(self) -> None:
        try:
            check_security(self.tls_dir, self.insecure)
        except IdentityError as exc:
            raise ValueError(str(exc)) from exc

    def signing_keys(self, drones: Sequence[str]) -> dict[str, bytes]:
        """Each of ``drones``' MAVLink 2 signing key; {} when signing is off. SigningKeyError if one is
        missing or malformed."""
        if self.signing_key_file is not None:
            return read_key_file(self.signing_key_file, drones)
        if self.signing_key is not None:
            return dict.fromkeys(drones, parse_key(self.signing_key.get_secret_value(), "DRONA_SIGNING_KEY"))
        return {}
