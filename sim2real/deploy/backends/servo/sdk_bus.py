"""The part of the servo-bus backends that both vendors' SDKs share.

``scservo_sdk`` (feetech-servo-sdk) is a port of ROBOTIS' ``dynamixel_sdk``: the same
``PortHandler``, ``PacketHandler``, ``GroupSyncRead`` / ``GroupSyncWrite`` API and result codes.
:class:`SdkServoBus` drives a bus through that API;
:class:`~sim2real.deploy.backends.servo.feetech.FeetechBackend` and
:class:`~sim2real.deploy.backends.servo.dynamixel.DynamixelBackend` name the SDK module, the packet protocol
and where a status packet's parameters start, and decode their own error bytes.
"""

from __future__ import annotations

import importlib
from types import ModuleType

from sim2real.deploy.backends.servo.servo_bus import ServoBusBackend, ServoBusError

#: s one poll of the port waits for a reply's bytes (pyserial's read timeout): short against a
#: control period, so the SDK still checks its packet timeout at least this often.
RECEIVE_WAIT = 5e-4


class SdkServoBus(ServoBusBackend):
    """A :class:`~sim2real.deploy.backends.servo.servo_bus.ServoBusBackend` on a vendor SDK of the
    dynamixel_sdk family. Subclasses set :attr:`packet_protocol`, :attr:`sdk_module` and implement
    :meth:`_parameter_start` and ``_hardware_error``.

    Attributes:
        packet_protocol: The ``PacketHandler`` argument: 0 (Feetech, protocol end 0 = little
            endian) or 2.0 (Dynamixel Protocol 2.0).
        status_trailer: Bytes after a status packet's parameters: 1 (checksum) or 2 (CRC-16).
        sdk_module, sdk_package: The SDK's import name and its PyPI package (extra ``servo``).
    """

    packet_protocol: float = 0
    status_trailer: int = 1
    sdk_module: str = ""
    sdk_package: str = ""

    def _sdk_module(self) -> ModuleType:
        """The SDK module :attr:`sdk_module` (from the PyPI package :attr:`sdk_package`).

        Raises:
            ServoBusError: the SDK is not installed (naming the package and the extra).
        """
        try:
            return importlib.import_module(self.sdk_module)
        except ImportError as exc:  # the optional dependency
            raise ServoBusError(
                f"the {self.protocol} backend needs {self.sdk_package}: pip install '.[servo]'"
            ) from exc

    def _parameter_start(self, sdk: ModuleType) -> int:
        """Index of a status packet's first parameter byte."""
        raise NotImplementedError

    def _connect(self) -> None:
        sdk = self._sdk = self._sdk_module()
        self._port = sdk.PortHandler(self.port_name)
        try:
            opened = self._port.openPort()
        except Exception as exc:  # pyserial raises SerialException (an OSError) or others
            raise ServoBusError(f"cannot open {self.port_name}: {exc}") from exc
        if not opened or not self._port.setBaudRate(self.baudrate):
            raise ServoBusError(f"cannot open {self.port_name} at {self.baudrate} bit/s")
        # The SDKs open the port with pyserial's timeout 0 and poll it in a busy loop until a
        # reply's bytes are in: a whole core spent waiting, taken from the servos' emulator (or
        # anything else) on a small computer. A read timeout of RECEIVE_WAIT makes each poll
        # wait in select() for the bytes instead; the SDK's own packet timeout is unchanged.
        self._port.ser.timeout = RECEIVE_WAIT
        self._ph = sdk.PacketHandler(self.packet_protocol)
        start, length = self.block_start, self.block_length
        self._reader = sdk.GroupSyncRead(self._port, self._ph, start, length)
        reg = self.goal_register
        self._writer = sdk.GroupSyncWrite(self._port, self._ph, reg.address, reg.size)
        torque = self.models[0].register("torque_enable")
        self._torque_reader = sdk.GroupSyncRead(self._port, self._ph, torque.address, torque.size)
        for sid in self.ids:
            self._reader.addParam(sid)
            self._torque_reader.addParam(sid)
            self._writer.addParam(sid, [0] * reg.size)

    def _ping(self, servo_id: int) -> tuple[int, int]:
        """``(model number, SDK result)`` of one PING and model-number read. A late reply of an
        earlier packet is dropped first; the Feetech SDK indexes a reply shorter than the model
        number it asked for (IndexError), which here is a corrupt reply, tried again by the
        caller."""
        self._port.ser.reset_input_buffer()
        try:
            model, result, _ = self._ph.ping(self._port, servo_id)
        except IndexError:
            return 0, self._sdk.COMM_RX_CORRUPT
        return model, result

    def _write_register(self, servo_id: int, address: int, data: bytes) -> tuple[int, int]:
        return self._ph.writeTxRx(self._port, servo_id, address, len(data), list(data))

    def _read_register(self, servo_id: int, address: int, length: int) -> bytes | None:
        data, result, _ = self._ph.readTxRx(self._port, servo_id, address, length)
        return bytes(data) if result == self._sdk.COMM_SUCCESS else None

    def _receive(self, port):
        """One status packet: ``(packet, result)`` from the SDK's own ``rxPacket``."""
        return self._ph.rxPacket(port)

    def _sync_read(self) -> tuple[dict[int, tuple[bytes, int]], int]:
        return self._group_read(self._reader, self.block_length)

    def _read_torque(self) -> dict[int, int]:
        replies, _ = self._group_read(self._torque_reader, 1)
        return {sid: data[0] for sid, (data, _error) in replies.items()}

    def _group_read(self, reader, length: int) -> tuple[dict[int, tuple[bytes, int]], int]:
        """Send the SDK group ``reader``'s SYNC READ of ``length`` bytes, then receive every
        status packet with ``rxPacket`` (the group's own receive stops at the first missing reply
        and drops the error bytes).

        Returns:
            ``({servo_id: (parameter bytes, error byte)}, corrupt replies)``.
        """
        sdk, port = self._sdk, self._port
        port.ser.reset_input_buffer()  # a late reply of the last tick is not this tick's
        replies: dict[int, tuple[bytes, int]] = {}
        corrupt = 0
        if reader.txPacket() != sdk.COMM_SUCCESS:
            return replies, corrupt
        port.setPacketTimeoutMillis(1e3 * self.read_timeout)
        p0 = self._parameter_start(sdk)
        end = p0 + length
        for _ in range(2 * self.n + 2):  # every reply, plus room for corrupt ones
            packet, result = self._receive(port)
            if result == sdk.COMM_SUCCESS:
                sid = packet[sdk.PKT_ID]
                # exactly this read's length: a late reply to the other group is not this one's
                if sid in reader.data_dict and len(packet) == end + self.status_trailer:
                    replies[sid] = (bytes(packet[p0:end]), packet[sdk.PKT_ERROR])
            elif result == sdk.COMM_RX_CORRUPT:
                corrupt += 1
            else:
                break
            if len(replies) == self.n:
                break
        return replies, corrupt

    def _sync_write(self, data: list[bytes]) -> None:
        for sid, value in zip(self.ids, data, strict=True):
            self._writer.changeParam(sid, list(value))
        self._writer.txPacket()

    def _close_port(self) -> None:
        self._port.closePort()

    def _result_text(self, result: int) -> str:
        return self._ph.getTxRxResult(result)
