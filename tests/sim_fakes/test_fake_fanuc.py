"""The fake FANUC controller in this process (sim_fakes/fake_fanuc.py), spoken to through the RMI client: one session
at a time, the commands the cell uses beside motion (numeric registers, digital outputs, frames, status) with
their refusals. (Motion, the instruction window, faults and recovery: tests/drivers/test_fanuc.py.)"""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable

import pytest

from drivers.errors import ConnectionLost, RMIError
from drivers.fanuc_protocol import ErrorID
from drivers.fanuc_rmi import RMIClient
from sim_fakes.fake_fanuc import N_DOUT, N_REGISTERS, N_UFRAME, FakeFanucController


def session(test: Callable[[RMIClient, FakeFanucController], Awaitable[None]]) -> None:
    with FakeFanucController() as fake:

        async def run() -> None:
            client = RMIClient("127.0.0.1", fake.port, timeout_s=3.0)
            await client.connect()
            try:
                await test(client, fake)
            finally:
                await client.disconnect()

        asyncio.run(asyncio.wait_for(run(), 15.0))


@pytest.mark.timeout(30)
def test_one_session_at_a_time_a_second_client_hears_already_connected() -> None:
    async def test(client: RMIClient, fake: FakeFanucController) -> None:
        second = RMIClient("127.0.0.1", fake.port, timeout_s=0.4)
        with pytest.raises(ConnectionLost, match=r"did not complete the FRC_Connect handshake within 0\.4 s"):
            await second.connect()  # RMIT-026 asked again and again until its timeout
        status = await client.command("FRC_GetStatus")
        assert (status["RMIMotionStatus"], status["NextSequenceID"], status["NumberUFrame"]) == (0, 1, N_UFRAME)
        await client.initialize()
        assert (await client.command("FRC_GetStatus"))["RMIMotionStatus"] == 1  # RMI_MOVE runs
        with pytest.raises(RMIError, match="RMIT-015") as err:  # not twice
            await client.initialize()
        assert err.value.code == ErrorID.INVALID_CONTROLLER_STATE

    session(test)


@pytest.mark.timeout(30)
def test_numeric_registers_hold_integers_and_reals_in_their_range() -> None:
    async def test(client: RMIClient, fake: FakeFanucController) -> None:
        await client.write_numeric_register(90, 7)
        await client.command("FRC_WriteNumericRegister", {"RegisterNumber": 5, "RegisterValue": 1.5})
        assert fake.register(90) == 7.0 and fake.register(5) == 1.5
        read = await client.command("FRC_ReadNumericRegister", {"RegisterNumber": 90})
        assert read["RegisterValue"] == 7 and isinstance(read["RegisterValue"], int)
        unset = await client.command("FRC_ReadNumericRegister", {"RegisterNumber": N_REGISTERS})
        assert unset["RegisterValue"] == 0
        for fields in ({"RegisterNumber": 0, "RegisterValue": 1}, {"RegisterNumber": N_REGISTERS + 1,
                       "RegisterValue": 1}, {"RegisterNumber": 5, "RegisterValue": True}):  # fmt: skip
            with pytest.raises(RMIError, match="RMIT-021") as err:
                await client.command("FRC_WriteNumericRegister", fields)
            assert err.value.code == ErrorID.INVALID_VALUE
        assert fake.register(5) == 1.5  # refused writes change nothing

    session(test)


@pytest.mark.timeout(30)
def test_digital_outputs_are_one_based_and_read_back_as_written() -> None:
    async def test(client: RMIClient, fake: FakeFanucController) -> None:
        await client.write_dout(3, True)
        assert await client.read_dout(3) is True and fake.digital_output(3) is True
        assert await client.read_dout(4) is False
        [event] = [e for e in fake.events() if e["kind"] == "dout"]
        assert (event["port"], event["value"]) == (3, True)
        await client.write_dout(3, False)
        assert fake.digital_output(3) is False
        for port in (0, N_DOUT + 1):
            with pytest.raises(RMIError, match="RMIT-038"):
                await client.write_dout(port, True)
        with pytest.raises(RMIError, match="RMIT-021"):  # only digital outputs are modelled
            await client.command("FRC_ReadIOPort", {"PortType": "AI", "PortNumber": 1})

    session(test)


@pytest.mark.timeout(30)
def test_frames_are_checked_and_an_unknown_command_is_invalid() -> None:
    async def test(client: RMIClient, fake: FakeFanucController) -> None:
        await client.set_uframe_utool(uframe=2, utool=4)
        got = await client.command("FRC_GetUFrameUTool")
        assert (got["UFrameNumber"], got["UToolNumber"]) == (2, 4)
        with pytest.raises(RMIError, match="RMIT-003"):
            await client.set_uframe_utool(uframe=N_UFRAME + 1, utool=4)
        with pytest.raises(RMIError, match="RMIT-002"):
            await client.set_uframe_utool(uframe=0, utool=0)
        got = await client.command("FRC_GetUFrameUTool")
        assert (got["UFrameNumber"], got["UToolNumber"]) == (2, 4)  # unchanged by the refusals
        with pytest.raises(RMIError, match="RMIT-013") as err:
            await client.command("FRC_Teleport")
        assert err.value.code == ErrorID.INVALID_COMMAND

    session(test)
