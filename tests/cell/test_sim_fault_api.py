"""cell.sim_fault_api: the test-only fault switches of ``weldcell serve --sim-faults``, over HTTP against the
daemon's own simulators, and the request parsing against handles that record what they are told."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from cell.daemon import Daemon
from cell.errors import ConfigError, WeldcellError
from cell.sim_fault_api import SimFaultSwitch
from tests.cell.runner_rig import cell_config
from tests.cell.test_daemon import request


class Handle:
    """A simulator's fault handle that records the faults switched on."""

    supported_faults = frozenset({"protective_stop", "drop_connection"})

    def __init__(self, *, broken: bool = False) -> None:
        self.faults: list[tuple[str, dict[str, Any]]] = []
        self.cleared = 0
        self.broken = broken

    def inject(self, fault: str, **params: Any) -> None:
        if self.broken:
            raise TimeoutError("no answer from the simulator process")
        if fault not in self.supported_faults:
            raise ValueError(f"does not support fault {fault!r}")
        self.faults.append((fault, params))

    def clear_faults(self) -> None:
        self.cleared += 1


def test_commands_switch_faults_and_journal_each_switch() -> None:
    notes: list[str] = []
    robot, track = Handle(), Handle()
    sim = SimFaultSwitch({"robot": robot, "track": track}, note=notes.append, arc_output=lambda: 0)
    body = json.dumps({"device": "robot", "fault": "drop_connection", "params": {"after_s": 0.5}}).encode()
    assert sim.command("/sim/faults", body) == {
        "device": "robot",
        "fault": "drop_connection",
        "params": {"after_s": 0.5},
    }
    assert robot.faults == [("drop_connection", {"after_s": 0.5})]
    view = sim.view()
    assert view["devices"]["robot"]["injected"] == [{"fault": "drop_connection", "params": {"after_s": 0.5}}]
    assert view["devices"]["track"] == {"supported": ["drop_connection", "protective_stop"], "injected": []}
    assert view["arc_output_on"] is None  # a handle that is neither fake robot can say nothing about the arc
    assert sim.command("/sim/faults/clear", b'{"device": "robot"}') == {"cleared": ["robot"]}
    assert (robot.cleared, track.cleared) == (1, 0)
    assert sim.command("/sim/faults/clear", b"") == {"cleared": ["robot", "track"]}
    assert notes == [
        'test fault injected into the simulated robot: drop_connection {"after_s": 0.5}',
        "test faults cleared in the simulated robot",
        "test faults cleared in the simulated robot, track",
    ]


@pytest.mark.parametrize(
    ("path", "body", "error"),
    [
        ("/sim/faults", b"[1]", "send a JSON object"),
        ("/sim/faults", b"\xff", "not UTF-8"),
        ("/sim/faults", b'{"device": "robot"}', '"fault": "<name>"'),
        ("/sim/faults", b'{"device": "robot", "fault": "x", "params": []}', '"params": {}'),
        ("/sim/faults", b'{"device": "welder", "fault": "x"}', "no simulated device 'welder'; choose one of ['robot']"),
        ("/sim/faults", b'{"device": "robot", "fault": "earthquake"}', "simulated robot: does not support"),
        ("/sim/faults/clear", b'{"device": 3}', '"device" must be a device name'),
    ],
)
def test_bad_commands_are_config_errors_that_say_what_is_allowed(path: str, body: bytes, error: str) -> None:
    sim = SimFaultSwitch({"robot": Handle()}, note=lambda _t: None, arc_output=lambda: 0)
    with pytest.raises(ConfigError, match=None) as info:
        sim.command(path, body)
    assert error in str(info.value)


def test_a_simulator_that_does_not_answer_is_a_service_error_not_a_bad_request() -> None:
    sim = SimFaultSwitch({"robot": Handle(broken=True)}, note=lambda _t: None, arc_output=lambda: 0)
    with pytest.raises(WeldcellError, match="did not take the fault: no answer") as info:
        sim.inject("robot", "protective_stop", {})
    assert not isinstance(info.value, ConfigError)


@pytest.mark.timeout(30)
def test_the_sim_fault_endpoints_switch_the_faults_of_the_daemons_own_simulators(tmp_path: Path) -> None:
    config = cell_config(tmp_path, "sim-cell-fanuc.toml", daemon={"port": 0})
    with Daemon(config, sim_faults=True) as d:
        host, port = d.address
        base = f"http://{host}:{port}"

        def post(path: str, obj: Any) -> tuple[int, Any]:
            return request(f"{base}{path}", method="POST", body=json.dumps(obj).encode())

        assert request(f"{base}/status")[1]["sim_faults"] is True
        status, view = request(f"{base}/sim/faults")
        assert status == 200 and sorted(view["devices"]) == ["camera", "robot", "track"]
        assert "protective_stop" in view["devices"]["robot"]["supported"]
        camera = {"supported": ["corrupt_frame", "drop_connection", "frame_timeout"], "injected": []}
        assert view["devices"]["camera"] == camera
        # mistakes are 400s that say what is allowed
        status, answer = post("/sim/faults", {"device": "welder", "fault": "no_gas"})
        assert (
            status == 400
            and "no simulated device 'welder'; choose one of ['camera', 'robot', 'track']" in answer["error"]
        )
        status, answer = post("/sim/faults", {"device": "camera", "fault": "earthquake"})
        assert status == 400 and "does not support fault 'earthquake'" in answer["error"]
        status, answer = post("/sim/faults", {"device": "track", "fault": "track_fault"})
        assert status == 400 and "needs code=" in answer["error"]
        status, answer = post("/sim/faults", {"fault": "protective_stop"})
        assert status == 400 and '"device"' in answer["error"]

        # a protective stop in the fake controller: the driver reads it as it would on a real one
        status, answer = post("/sim/faults", {"device": "robot", "fault": "protective_stop"})
        assert status == 200 and answer == {"device": "robot", "fault": "protective_stop", "params": {}}
        assert d.cell.robot.state().protective_stop
        injected = request(f"{base}/sim/faults")[1]["devices"]["robot"]["injected"]
        assert injected == [{"fault": "protective_stop", "params": {}}]
        status, answer = post("/sim/faults/clear", {})
        assert status == 200 and answer == {"cleared": ["camera", "robot", "track"]}
        assert request(f"{base}/sim/faults")[1]["devices"]["robot"]["injected"] == []
        assert d.cell.robot.state().protective_stop  # latched until an acknowledgement resets it, as on the robot
        reasons = [e.reason for e in d.journal.events(None)]
        assert "test fault injected into the simulated robot: protective_stop {}" in reasons
        assert "test faults cleared in the simulated camera, robot, track" in reasons
    assert d.arc_on_at_exit is False  # switched off once more and read back at shutdown
