"""The RMI client (drivers/fanuc_rmi.py) against a scripted controller on loopback: the handshake and its RMIT-026
retry, replies matched by name in order, ErrorIDs as exceptions, the in-flight window, a system fault failing and
latching, the socket's end failing what waits. Each controller here answers exactly what the test says, which the
fake FANUC (tests/drivers/test_fanuc.py) cannot be made to do."""

from __future__ import annotations

import asyncio
import contextlib
import json
from collections.abc import AsyncIterator, Awaitable, Callable
from typing import Any

import pytest

from drivers.errors import ConnectionLost, DeviceTimeout, RMIError, SystemFault
from drivers.fanuc_protocol import ErrorID, RMIMotionRejected
from drivers.fanuc_rmi import RMIClient, _check_reply

Packet = dict[str, Any]
Session = Callable[[asyncio.StreamReader, asyncio.StreamWriter], Awaitable[None]]


async def read(reader: asyncio.StreamReader) -> Packet:
    doc: Packet = json.loads(await reader.readuntil(b"\r\n"))
    return doc


def send(writer: asyncio.StreamWriter, packet: Packet | bytes) -> None:
    writer.write(packet if isinstance(packet, bytes) else json.dumps(packet).encode() + b"\r\n")


async def controller(session: Session, *, busy_first: int = 0) -> tuple[int, list[asyncio.Server]]:
    """A connect port that answers FRC_Connect (RMIT-026 ``busy_first`` times first) with the session port, where
    ``session`` talks to the client."""
    sessions = await asyncio.start_server(session, "127.0.0.1", 0)
    session_port = sessions.sockets[0].getsockname()[1]
    busy = [busy_first]

    async def handshake(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        assert await read(reader) == {"Communication": "FRC_Connect"}
        if busy[0]:
            busy[0] -= 1
            send(writer, {"Communication": "FRC_Connect", "ErrorID": int(ErrorID.ALREADY_CONNECTED)})
        else:
            send(writer, {"Communication": "FRC_Connect", "ErrorID": 0, "PortNumber": session_port})
        await writer.drain()
        writer.close()

    connects = await asyncio.start_server(handshake, "127.0.0.1", 0)
    return connects.sockets[0].getsockname()[1], [connects, sessions]


@contextlib.asynccontextmanager
async def connected(session: Session, *, busy_first: int = 0, max_in_flight: int = 8) -> AsyncIterator[RMIClient]:
    """A client connected to a scripted controller; closed, and the controller's ports with it, afterwards."""
    port, servers = await controller(session, busy_first=busy_first)
    client = RMIClient("127.0.0.1", port, timeout_s=3.0, max_in_flight=max_in_flight)
    await client.connect()
    try:
        yield client
    finally:
        await client.close()
        for server in servers:
            server.close()


def run(test: Callable[[], Awaitable[None]]) -> None:
    asyncio.run(asyncio.wait_for(test(), 10.0))


@pytest.mark.timeout(20)
def test_a_busy_controller_is_asked_again_and_replies_are_matched_by_name_in_order() -> None:
    async def ordered(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        for _ in range(3):
            msg = await read(reader)
            if msg["Command"] == "FRC_ReadTCPSpeed":
                send(writer, b"not json\r\n")  # ignored, the session goes on
                send(writer, {"Command": "FRC_ReadTCPSpeed", "ErrorID": 0, "Speed": 125.5})
            elif msg["Command"] == "FRC_WriteDOUT":
                assert (msg["PortNumber"], msg["PortValue"]) == (3, "ON")
                send(writer, {"Command": "FRC_WriteDOUT", "ErrorID": 0})
            else:
                assert msg == {"Command": "FRC_SetUFrameUTool", "UFrameNumber": 1, "UToolNumber": 9, "Group": 1}
                send(writer, {"Command": "FRC_SetUFrameUTool", "ErrorID": int(ErrorID.INVALID_UTOOL_NUMBER)})
            await writer.drain()
        await reader.read()  # until the client closes

    async def test() -> None:
        async with connected(ordered, busy_first=2) as client:  # two RMIT-026 answers before the session port
            assert client.connected and client.session_port is not None
            speed, _ = await asyncio.gather(client.read_tcp_speed_mm_s(), client.write_dout(3, True))
            assert speed == 125.5
            with pytest.raises(RMIMotionRejected, match="FRC_SetUFrameUTool refused by the controller: RMIT-002") as e:
                await client.set_uframe_utool(uframe=1, utool=9)
            assert e.value.code == ErrorID.INVALID_UTOOL_NUMBER
        assert not client.connected
        with pytest.raises(ConnectionLost, match="RMI session closed by the client"):
            await client.read_tcp_speed_mm_s()

    run(test)


@pytest.mark.timeout(20)
def test_at_most_max_in_flight_instructions_are_outstanding_and_ids_are_consecutive() -> None:
    seen: list[int] = []
    release: list[asyncio.Event] = []

    async def session(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        seen.append((await read(reader))["SequenceID"])
        seen.append((await read(reader))["SequenceID"])
        await release[0].wait()
        send(writer, {"Instruction": "FRC_LinearMotion", "ErrorID": 0, "SequenceID": 1})
        await writer.drain()
        seen.append((await read(reader))["SequenceID"])  # the third, sent once the first completed
        for seq in (2, 3):
            send(writer, {"Instruction": "FRC_LinearMotion", "ErrorID": 0, "SequenceID": seq})
        await writer.drain()
        await reader.read()

    async def test() -> None:
        release.append(asyncio.Event())
        async with connected(session, max_in_flight=2) as client:
            move = {"Instruction": "FRC_LinearMotion"}
            s1, f1 = await client.submit(move)
            s2, f2 = await client.submit(move)
            assert (s1, s2, client.in_flight, client.next_sequence_id) == (1, 2, 2, 3)
            third = asyncio.ensure_future(client.submit(move))  # waits for the window
            await asyncio.sleep(0.2)
            assert not third.done() and seen == [1, 2]
            release[0].set()
            s3, f3 = await third
            assert s3 == 3 and seen == [1, 2, 3]
            for seq, fut in ((s1, f1), (s2, f2), (s3, f3)):
                assert (await RMIClient.wait_instruction(seq, fut, timeout_s=3.0))["SequenceID"] == seq
            assert client.in_flight == 0
        with pytest.raises(ValueError, match=r"max_in_flight must be 1\.\.8, got 9"):
            RMIClient("127.0.0.1", 1, max_in_flight=9)

    run(test)


@pytest.mark.timeout(20)
def test_a_system_fault_fails_what_is_in_flight_and_stays_latched_until_a_reset() -> None:
    async def session(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        await read(reader)  # the instruction, never answered
        send(writer, {"Communication": "FRC_SystemFault", "SequenceID": 1})
        await writer.drain()
        assert await read(reader) == {"Command": "FRC_Reset"}
        send(writer, {"Command": "FRC_Reset", "ErrorID": 0})
        await writer.drain()
        assert await read(reader) == {"Command": "FRC_GetStatus"}  # then silence: a hung controller
        await reader.read()

    async def test() -> None:
        async with connected(session) as client:
            seq, fut = await client.submit({"Instruction": "FRC_LinearMotion"})
            with pytest.raises(SystemFault, match="reported FRC_SystemFault at SequenceID 1"):
                await RMIClient.wait_instruction(seq, fut, timeout_s=3.0)
            assert client.system_fault is not None and client.in_flight == 0
            with pytest.raises(SystemFault, match="still latched: reset before sending motion"):
                await client.submit({"Instruction": "FRC_LinearMotion"})
            await client.reset()
            assert client.system_fault is None
            with pytest.raises(DeviceTimeout, match=r"did not answer FRC_GetStatus within 0\.3 s"):
                await client.get_status(timeout_s=0.3)

    run(test)


@pytest.mark.timeout(20)
def test_the_controller_closing_the_session_fails_every_waiter_with_connection_lost() -> None:
    async def session(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        await read(reader)
        await read(reader)
        writer.close()

    async def test() -> None:
        async with connected(session) as client:
            seq, fut = await client.submit({"Instruction": "FRC_LinearMotion"})
            with pytest.raises(ConnectionLost, match="closed the RMI session"):
                await client.command("FRC_GetStatus")
            with pytest.raises(ConnectionLost, match="closed the RMI session"):
                await RMIClient.wait_instruction(seq, fut, timeout_s=3.0)
            assert not client.connected and client.in_flight == 0

    run(test)


def test_a_non_zero_error_id_is_an_rmi_error_and_a_rejection_code_a_rejected_motion() -> None:
    _check_reply("FRC_Initialize", {"ErrorID": 0})
    with pytest.raises(RMIError, match="FRC_Initialize refused by the controller: RMIT-015") as err:
        _check_reply("FRC_Initialize", {"ErrorID": int(ErrorID.INVALID_CONTROLLER_STATE)})
    assert err.value.code == ErrorID.INVALID_CONTROLLER_STATE and not isinstance(err.value, RMIMotionRejected)
    with pytest.raises(RMIMotionRejected, match="RMIT-023"):
        _check_reply("instruction 4", {"ErrorID": int(ErrorID.INVALID_POSITION_DATA)})


def test_connecting_to_nothing_is_connection_lost_naming_the_address() -> None:
    async def test() -> None:
        probe = await asyncio.start_server(lambda r, w: None, "127.0.0.1", 0)
        port = probe.sockets[0].getsockname()[1]
        probe.close()
        await probe.wait_closed()
        with pytest.raises(ConnectionLost, match=rf"cannot reach FANUC RMI at 127.0.0.1:{port}"):
            await RMIClient("127.0.0.1", port, timeout_s=2.0).connect()

    run(test)
