"""Cyclone DDS for the low-level interface: a domain on one network interface, raw writers and
readers of pre-encoded samples.

:class:`DdsLink` joins DDS domain ``domain_id`` (Unitree robots use 0, their simulation bridges 1)
on one network interface (Cyclone DDS's ``General/Interfaces/NetworkInterface``, as unitree_sdk2's
``ChannelFactoryInitialize(domain, interface)`` configures it; None: Cyclone chooses). Topics
are created with our IdlStruct types, so that the type names and type information on the wire are
Unitree's; samples are written and taken as bytes (:class:`RawWriter`, :class:`RawReader`) that
:class:`sim2real.deploy.backends.unitree.codec.MessageCodec` encodes and decodes: Cyclone DDS's Python
serializer is too slow for 500 samples a second.

QoS: writers reliable (Cyclone's default; a best-effort reader still matches), readers best effort
(a late state is worth less than the next) keeping the last ``depth`` samples.

One :class:`cyclonedds.domain.Domain` per domain id and process (Cyclone DDS's rule): links of
one process on the same domain share it, and must agree on the interface.
"""

from __future__ import annotations

import ipaddress
import socket
import threading
import time

from cyclonedds._clayer import ddspy_take, ddspy_write_ts
from cyclonedds.core import DDSException, InstanceState, SampleState, ViewState
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.qos import Policy, Qos
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

from sim2real.robots.errors import Sim2RealError

_ANY = SampleState.Any | ViewState.Any | InstanceState.Any
_DOMAINS: dict[int, tuple[Domain, str | None]] = {}
_LOCK = threading.Lock()


class DdsError(Sim2RealError, OSError):
    """DDS cannot be set up: an unknown interface, a domain id in use with another interface."""


def cyclone_config(interface: str | None) -> str:
    """The Cyclone DDS XML configuration of a domain on ``interface`` (None: Cyclone chooses)."""
    nic = (
        f'<NetworkInterface name="{interface}" priority="default" multicast="default"/>'
        if interface
        else '<NetworkInterface autodetermine="true" priority="default" multicast="default"/>'
    )
    return (
        '<?xml version="1.0" encoding="UTF-8" ?><CycloneDDS><Domain Id="any"><General>'
        f"<Interfaces>{nic}</Interfaces></General></Domain></CycloneDDS>"
    )


def check_interface(interface: str | None) -> None:
    """Refuse a network interface this machine does not have, before Cyclone DDS is asked (it
    would print a line of its own to stderr, then fail); None (Cyclone chooses) and an IP
    address pass.

    Raises:
        DdsError: no interface of that name (the message lists the ones there are).
    """
    if not interface:
        return
    try:
        ipaddress.ip_address(interface)
        return
    except ValueError:
        pass
    names = [name for _, name in socket.if_nameindex()]
    if interface not in names:
        raise DdsError(
            f"--network-interface {interface!r}: no such network interface on this machine; "
            f"expected one of {', '.join(names)}"
        )


def _domain(domain_id: int, interface: str | None) -> Domain:
    with _LOCK:
        if domain_id in _DOMAINS:
            domain, where = _DOMAINS[domain_id]
            if where != interface:
                raise DdsError(
                    f"DDS domain {domain_id} is open on interface {where!r} in this process; "
                    f"cannot join it on {interface!r}"
                )
            return domain
        check_interface(interface)
        try:
            domain = Domain(domain_id, cyclone_config(interface))
        except DDSException as exc:
            raise DdsError(
                f"cannot join DDS domain {domain_id} on network interface {interface!r}: {exc} "
                "(is the interface up? `ip addr` lists them)"
            ) from None
        _DOMAINS[domain_id] = (domain, interface)
        return domain


class RawWriter(DataWriter):
    """A DataWriter of pre-encoded samples (:meth:`write_raw`)."""

    def write_raw(self, sample: bytes, timestamp_ns: int | None = None) -> None:
        """Write one encoded sample (header and body, a multiple of 4 bytes); its source
        timestamp ``timestamp_ns`` (ns since the UNIX epoch; default now).

        Raises:
            DdsError: Cyclone DDS refused the sample.
        """
        stamp = time.time_ns() if timestamp_ns is None else int(timestamp_ns)
        ret = ddspy_write_ts(self._ref, sample, stamp)
        if ret < 0:
            raise DdsError(f"writing on {self.topic.name} failed: DDS return code {ret}")


class RawReader(DataReader):
    """A DataReader whose samples are taken as bytes (:meth:`take_raw`)."""

    def take_raw(self, n: int = 64) -> list[tuple[bytes, int]]:
        """Up to ``n`` samples received since the last take, oldest first: (encoded sample,
        source timestamp in ns since the UNIX epoch).

        Raises:
            DdsError: Cyclone DDS refused the take.
        """
        got = ddspy_take(self._ref, _ANY, n)
        if isinstance(got, int):
            raise DdsError(f"taking from {self.topic.name} failed: DDS return code {got}")
        return [(data, info.source_timestamp) for data, info in got if info.valid_data]


class DdsLink:
    """A participant in DDS domain ``domain_id`` on ``interface`` (module docstring).

    Raises:
        DdsError: the domain cannot be joined (unknown interface, conflicting interface).
    """

    def __init__(self, domain_id: int = 0, interface: str | None = None):
        if not 0 <= domain_id <= 232:
            raise DdsError(f"DDS domain id {domain_id}: expected 0..232")
        self.domain_id, self.interface = domain_id, interface
        self._domain = _domain(domain_id, interface)
        self.participant = DomainParticipant(domain_id)
        self._topics: dict[str, Topic] = {}
        self._entities: list = []

    def topic(self, name: str, cls: type) -> Topic:
        """The topic ``name`` of IdlStruct type ``cls`` (created once per link)."""
        if name not in self._topics:
            self._topics[name] = Topic(self.participant, name, cls)
        return self._topics[name]

    def writer(self, name: str, cls: type) -> RawWriter:
        """A reliable :class:`RawWriter` on topic ``name``."""
        qos = Qos(Policy.Reliability.Reliable(max_blocking_time=0), Policy.History.KeepLast(1))
        w = RawWriter(self.participant, self.topic(name, cls), qos=qos)
        self._entities.append(w)
        return w

    def reader(self, name: str, cls: type, depth: int = 64) -> RawReader:
        """A best-effort :class:`RawReader` on topic ``name`` keeping the last ``depth``."""
        qos = Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(depth))
        r = RawReader(self.participant, self.topic(name, cls), qos=qos)
        self._entities.append(r)
        return r

    def generic_writer(self, name: str, cls: type) -> DataWriter:
        """A reliable DataWriter of IdlStruct samples (Cyclone DDS serializes; for the services'
        occasional requests)."""
        w = DataWriter(self.participant, self.topic(name, cls))
        self._entities.append(w)
        return w

    def generic_reader(self, name: str, cls: type, depth: int = 16) -> DataReader:
        """A reliable DataReader of IdlStruct samples keeping the last ``depth``."""
        qos = Qos(Policy.Reliability.Reliable(max_blocking_time=0), Policy.History.KeepLast(depth))
        r = DataReader(self.participant, self.topic(name, cls), qos=qos)
        self._entities.append(r)
        return r

    def close(self) -> None:
        """Delete this link's readers, writers, topics and participant (the domain stays)."""
        self._entities.clear()
        self._topics.clear()
        self.participant = None
