"""Who is who on the fleet's Zenoh network, and what each may say.

Every node has a certificate signed by the fleet's CA, its common name its identity: a
drone's id, :data:`SERVICE` for the service (and operators' tools such as ``drona mail``),
:data:`ROUTER` for a Zenoh router. Links are mutual TLS: a node without a certificate of
the fleet's CA gets no link at all. Zenoh's access control then ties each key to the one
identity that may write it (:func:`access_control`): drone ``dX`` puts only on its own
keys (``proto/dX/<to>``, ``answers/dX``, ``plan/dX``, ``state/dX``, ``held/dX``,
``mail/status/dX/<mail>``), declares only the liveliness token ``alive/dX``, serves only its
own queryables; only the service may ask (assign, cancel mail) and declare the token ``service``.
Everything else is denied.
A router relays what its clients may say, so what comes from a router is taken as its
clients': the router enforces the same rules at its ingress. A *host* (a process flying several
drones in one session, ``--shared-session``: a simulation, or a ground computer) has a certificate
of its own, and ``hosts.json`` beside the certificates says which drones it speaks for. It writes
its drones' keys, and ``proto/<host>/<to>``: its drones' messages to one drone, joined in one
sample; a receiver takes each only from a drone that host flies (:class:`Speakers`).

The CA's key signs; keep it off the drones (``drona certs`` makes everything in one
directory: copy ``ca.pem`` and a node's own folder to each host).
"""

from __future__ import annotations

import datetime
import ipaddress
import json
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from drona_gcs.errors import DronaError
from fleet.transport.keys import FleetKeys, check_name

SERVICE = "service"  #: the service's identity: the only one that may assign or cancel mail
ROUTER = "router"  #: a Zenoh router's identity: relays its clients' messages
CA_FILE, CA_KEY_FILE, HOSTS_FILE = "ca.pem", "ca-key.pem", "hosts.json"
DAYS = 825

#: Every kind of message Zenoh's access control knows.
ALL_MESSAGES = ("put", "delete", "declare_subscriber", "query", "reply", "declare_queryable",
                "liveliness_token", "liveliness_query", "declare_liveliness_subscriber")
_LISTENING = ("declare_subscriber", "liveliness_query", "declare_liveliness_subscriber")


class IdentityError(DronaError):
    """A certificate or key is missing or unreadable."""


@dataclass(frozen=True)
class Identity:
    """One node's TLS files: the fleet's CA, its certificate and key."""

    ca: Path
    cert: Path
    key: Path

    @classmethod
    def of(cls, tls_dir: Path, name: str) -> Identity:
        """``name``'s identity in a folder made by :func:`make_certs`; :class:`IdentityError` naming a missing file."""
        identity = cls(tls_dir / CA_FILE, tls_dir / name / "cert.pem", tls_dir / name / "key.pem")
        for path in (identity.ca, identity.cert, identity.key):
            if not path.is_file():
                raise IdentityError(f"{name}: no {path} (make the fleet's certificates with `drona certs {tls_dir} "
                                    f"--workspace W`, or run with --insecure)")
        return identity

    def tls_config(self) -> dict[str, Any]:
        """Zenoh's ``transport/link/tls`` for mutual TLS with this identity."""
        return {
            "root_ca_certificate": str(self.ca),
            "enable_mtls": True,
            "listen_certificate": str(self.cert),
            "listen_private_key": str(self.key),
            "connect_certificate": str(self.cert),
            "connect_private_key": str(self.key),
            # Who a node is is its certificate's common name (access control reads it), not the address
            # it was dialled at: gossip hands out addresses no certificate lists.
            "verify_name_on_connect": False,
            "close_link_on_expiration": False,  # renew certificates on the ground, not by dropping links in flight
        }


def check_security(tls_dir: Path | None, insecure: bool) -> Path | None:
    """The certificates' folder to use, or None for a plain-TCP fleet, which must be asked for."""
    if tls_dir is None and not insecure:
        raise IdentityError("no fleet certificates: give --tls-dir DIR (made by `drona certs DIR --workspace W`) "
                            "[DRONA_TLS_DIR], or --insecure for a plain-TCP fleet anyone on the network can steer")
    if tls_dir is not None and insecure:
        raise IdentityError("--tls-dir and --insecure: give one")
    if tls_dir is not None and not tls_dir.is_dir():
        raise IdentityError(f"--tls-dir: no such folder {tls_dir}")
    return tls_dir


def access_control(keys: FleetKeys, drones: Sequence[str],
                   hosts: Mapping[str, Sequence[str]] | None = None) -> dict[str, Any]:
    """Zenoh's ``access_control``: each identity may write only its own keys (see the module's docstring);
    a host (``hosts``: name -> drones) those of the drones it flies, in one session."""
    root, hosts = keys.root, {h: [d for d in ds if d in drones] for h, ds in (hosts or {}).items()}
    fleet = [*drones, *hosts]
    rules: list[dict[str, Any]] = [
        _rule("listen", ["ingress"], _LISTENING, [f"{root}/**"]),
        _rule("ask-drones", ["ingress"], ["query"], [keys.clock(), keys.held(), keys.state()]),
        _rule("ask-all", ["ingress"], ["query"], [f"{root}/**"]),
        _rule("service-token", ["ingress"], ["liveliness_token"], [keys.service()]),
        _rule("relay", ["ingress"], ALL_MESSAGES, [f"{root}/**"]),
        _rule("tell", ["egress"], ALL_MESSAGES, [f"{root}/**"]),
    ]
    subjects = [{"id": name, "cert_common_names": [name]} for name in [*fleet, SERVICE, ROUTER]]
    policies: list[dict[str, Any]] = [
        {"id": "everyone", "rules": ["listen", "tell"], "subjects": [*fleet, SERVICE, ROUTER]},
        {"id": "drones", "rules": ["ask-drones"], "subjects": fleet},
        {"id": "service", "rules": ["ask-all", "service-token"], "subjects": [SERVICE]},
        {"id": "router", "rules": ["relay"], "subjects": [ROUTER]},
    ]
    for drone in drones:
        rules += _own_keys(keys, check_name("drone", drone))
        speakers = [drone, *(host for host, flown in hosts.items() if drone in flown)]
        policies.append({"id": f"own-{drone}", "rules": [f"{drone}-{kind}" for kind in ("puts", "token", "serves")],
                         "subjects": speakers})
    for host in hosts:  # its drones' protocol messages, joined (a receiver checks each one's sender is its drone)
        rules.append(_rule(f"{host}-puts", ["ingress"], ["put"], [keys.proto("*", check_name("host", host))]))
        policies.append({"id": f"own-{host}", "rules": [f"{host}-puts"], "subjects": [host]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}


def _own_keys(keys: FleetKeys, drone: str) -> list[dict[str, Any]]:
    puts = [keys.proto("*", drone), keys.answers(drone), keys.plan(drone), keys.state(drone), keys.held(drone),
            keys.status(drone)]
    serves = [keys.state(drone), keys.held(drone), keys.clock(drone), keys.assign(drone), keys.cancel(drone),
              keys.clear(drone), keys.command(drone)]
    return [_rule(f"{drone}-puts", ["ingress"], ["put"], puts),
            _rule(f"{drone}-token", ["ingress"], ["liveliness_token"], [keys.alive(drone)]),
            _rule(f"{drone}-serves", ["ingress"], ["declare_queryable", "reply"], serves)]


def _rule(rule_id: str, flows: Sequence[str], messages: Sequence[str], key_exprs: Sequence[str]) -> dict[str, Any]:
    return {"id": rule_id, "permission": "allow", "flows": list(flows), "messages": list(messages),
            "key_exprs": list(key_exprs)}


@dataclass(frozen=True)
class Speakers:
    """The drones each host flies: on ``proto/<host>/<to>``, each frame is from one of them."""

    hosts: Mapping[str, frozenset[str]] = field(default_factory=dict)  #: host -> the drones it flies

    @classmethod
    def of(cls, tls_dir: Path | None, drones: Collection[str]) -> Speakers:
        """The hosts in ``tls_dir``'s ``hosts.json`` (none without TLS: no access control names them), but one
        named as a drone, the service or a router is."""
        hosts = read_hosts(tls_dir) if tls_dir is not None else {}
        taken = {*drones, SERVICE, ROUTER}
        return cls({host: frozenset(flown) for host, flown in hosts.items() if host not in taken})

    def flies(self, host: str, drone: str) -> bool:
        return drone in self.hosts.get(host, ())


# ------------------------------------------------------------------ certificates
def read_hosts(tls_dir: Path) -> dict[str, list[str]]:
    """The hosts of the fleet (name -> the drones each flies in one session), from ``hosts.json``."""
    path = tls_dir / HOSTS_FILE
    if not path.is_file():
        return {}
    try:
        hosts = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise IdentityError(f"{path}: {exc}") from exc
    if not isinstance(hosts, dict) or not all(isinstance(v, list) for v in hosts.values()):
        raise IdentityError(f"{path}: expected {{host: [drone, ...]}}")
    return {str(h): [str(d) for d in ds] for h, ds in hosts.items()}


def identity_for(tls_dir: Path, drones: Sequence[str]) -> str:
    """The identity a session flying ``drones`` presents: the drone's own, or the smallest host that flies
    them all (``--shared-session``)."""
    if len(drones) == 1:
        return drones[0]
    covering = sorted((len(ds), h) for h, ds in read_hosts(tls_dir).items() if set(drones) <= set(ds))
    if not covering:
        raise IdentityError(f"no host certificate in {tls_dir} speaks for {', '.join(drones)} in one session: "
                            f"make one with `drona certs {tls_dir} --host NAME={','.join(drones)}`")
    return covering[0][1]


def make_certs(out: Path, names: Sequence[str], sans: Sequence[str] = (), days: int = DAYS,
               hosts: Mapping[str, Sequence[str]] | None = None) -> list[Path]:
    """The fleet's CA (made once in ``out``, reused after) and a certificate per name, each good for both ends
    of a link; the certificates made. ``sans``: more names and addresses (``DNS:x``, ``IP:a.b.c.d``) for all.
    ``hosts``: name -> drones, a certificate each for a process flying those drones in one session (recorded
    in ``hosts.json``, which every node reads for its access control)."""
    extra = [_san(entry) for entry in sans]
    out.mkdir(parents=True, exist_ok=True)
    if hosts:
        clash = set(hosts) & {*names, SERVICE, ROUTER}
        if clash:
            raise IdentityError(f"a host may not be called as a drone or service is: {', '.join(sorted(clash))}")
        known = read_hosts(out) | {h: list(ds) for h, ds in hosts.items()}
        _write(out / HOSTS_FILE, json.dumps(known, indent=1, sort_keys=True).encode())
        names = [*names, *hosts]
    ca_cert, ca_key = _ca(out, days)
    made = []
    for name in names:
        check_name("certificate name", name)
        key = ec.generate_private_key(ec.SECP256R1())
        alt = [x509.DNSName(name), x509.DNSName("localhost"), x509.IPAddress(ipaddress.ip_address("127.0.0.1")),
               *extra]
        usage = x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH])
        cert = (_builder(name, ca_cert.subject, key, days)
                .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
                .add_extension(_key_usage(sign_certs=False), critical=True)
                .add_extension(usage, critical=False)
                .add_extension(x509.SubjectAlternativeName(alt), critical=False)
                .sign(ca_key, hashes.SHA256()))
        folder = out / name
        folder.mkdir(exist_ok=True)
        _write(folder / "key.pem", _pem_key(key), private=True)
        _write(folder / "cert.pem", cert.public_bytes(serialization.Encoding.PEM))
        made.append(folder / "cert.pem")
    return made


def _ca(out: Path, days: int) -> tuple[x509.Certificate, ec.EllipticCurvePrivateKey]:
    cert_path, key_path = out / CA_FILE, out / CA_KEY_FILE
    if cert_path.is_file() and key_path.is_file():
        try:
            key = serialization.load_pem_private_key(key_path.read_bytes(), password=None)
            cert = x509.load_pem_x509_certificate(cert_path.read_bytes())
        except ValueError as exc:
            raise IdentityError(f"the fleet's CA in {out}: {exc}") from exc
        if not isinstance(key, ec.EllipticCurvePrivateKey):
            raise IdentityError(f"{key_path}: not an EC key")
        return cert, key
    key = ec.generate_private_key(ec.SECP256R1())
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "drona fleet CA")])
    cert = (_builder("drona fleet CA", subject, key, days)
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(_key_usage(sign_certs=True), critical=True)
            .sign(key, hashes.SHA256()))
    _write(key_path, _pem_key(key), private=True)
    _write(cert_path, cert.public_bytes(serialization.Encoding.PEM))
    return cert, key


def _builder(common_name: str, issuer: x509.Name, key: ec.EllipticCurvePrivateKey,
             days: int) -> x509.CertificateBuilder:
    now = datetime.datetime.now(datetime.UTC)
    return (x509.CertificateBuilder()
            .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, common_name)]))
            .issuer_name(issuer)
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5))  # hosts' clocks differ a little
            .not_valid_after(now + datetime.timedelta(days=days)))


def _key_usage(*, sign_certs: bool) -> x509.KeyUsage:
    return x509.KeyUsage(digital_signature=not sign_certs, content_commitment=False, key_encipherment=False,
                         data_encipherment=False, key_agreement=False, key_cert_sign=sign_certs,
                         crl_sign=sign_certs, encipher_only=False, decipher_only=False)


def _san(entry: str) -> x509.GeneralName:
    kind, _, value = entry.partition(":")
    try:
        if kind == "DNS" and value:
            return x509.DNSName(value)
        if kind == "IP":
            return x509.IPAddress(ipaddress.ip_address(value))
    except ValueError as exc:
        raise IdentityError(f"subject alternative name {entry!r}: {exc}") from exc
    raise IdentityError(f"subject alternative name {entry!r}: write DNS:name or IP:address")


def _pem_key(key: ec.EllipticCurvePrivateKey) -> bytes:
    return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                             serialization.NoEncryption())


def _write(path: Path, data: bytes, *, private: bool = False) -> None:
    path.write_bytes(data)
    path.chmod(0o600 if private else 0o644)
