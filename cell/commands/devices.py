"""``weldcell devices check``: connect to every configured device, print its state, fail on the first unreachable."""

from __future__ import annotations

import argparse
import json
import logging
import sys
from dataclasses import asdict, dataclass, field
from typing import Any


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "devices",
        help="check the cell's devices",
        description="'check' connects to each device of a cell config and prints its state: the robot's "
        "mode and tool pose, the track's position and status, one camera frame's size and valid-depth share. "
        "Exit code 1 with the reason when a device is unreachable or faulty.",
    )
    actions = p.add_subparsers(dest="devices_action", metavar="ACTION")
    actions.required = True
    check = actions.add_parser("check", help="connect to every device and print its state")
    check.add_argument("--config", required=True, help="cell config file (TOML)")
    check.add_argument(
        "--with-sims",
        action="store_true",
        help="start the config's simulators in this process first (default: connect to a running 'weldcell sim up')",
    )
    check.add_argument("--json", action="store_true", help="print the results as JSON")
    check.set_defaults(func=run_check)


@dataclass
class DeviceResult:
    role: str
    kind: str
    address: str
    ok: bool = False
    state: dict[str, Any] = field(default_factory=dict)
    summary: str = ""
    error: str = ""


def run_check(args: argparse.Namespace) -> int:
    from cell.config import load_config
    from cell.factory import build_cell

    if args.verbose < 2:  # pymodbus logs every refused connection at ERROR; the result line says it once
        logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
    config = load_config(args.config)
    results: list[DeviceResult] = []
    with build_cell(config, start_simulators=args.with_sims) as cell:
        for role, device in cell.devices():
            results.append(_check(role, device, config))
    failed = [r for r in results if not r.ok]
    if args.json:
        print(json.dumps({"config": str(config.source), "ok": not failed, "devices": [asdict(r) for r in results]}))
    else:
        for r in results:
            status = "ok  " if r.ok else "FAIL"
            print(f"{r.role:<7} {r.kind:<11} {r.address:<22} {status} {r.summary if r.ok else r.error}")
    if failed:
        first = failed[0]
        print(f"weldcell devices check: {first.role} ({first.kind} at {first.address}): {first.error}", file=sys.stderr)
        return 1
    return 0


def _address(role: str, config: Any) -> str:
    if role == "robot":
        rc = config.robot
        return f"{rc.host}:30004" if rc.kind in ("ur", "fake-ur") else f"{rc.host}:{rc.rmi_port}"
    if role == "track":
        return f"{config.track.host}:{config.track.port}"
    cc = config.camera
    return "in-process" if cc.kind == "fake" else (cc.device_id or "first OAK found")


def _check(role: str, device: Any, config: Any) -> DeviceResult:
    from drivers.errors import ConnectionLost, DeviceTimeout
    from perception.errors import WeldcellError

    result = DeviceResult(role, getattr(config, role).kind, _address(role, config))
    try:
        device.connect()
        if role == "robot":
            _robot_state(device, result)
        elif role == "track":
            _track_state(device, result)
        else:
            _camera_state(device, result, timeout_s=config.camera.timeout_s)
    except (ConnectionLost, DeviceTimeout) as err:
        result.ok = False
        result.error = f"unreachable: {err}"
    except WeldcellError as err:
        result.ok = False
        result.error = str(err)
    return result


def _robot_state(robot: Any, result: DeviceResult) -> None:
    state = robot.state()
    xyz = [float(v) for v in state.X_base_tool[:3, 3]]
    result.state = {
        "mode": str(state.mode),
        "healthy": state.healthy,
        "X_base_tool": state.X_base_tool.tolist(),
        "protective_stop": state.protective_stop,
        "emergency_stop": state.emergency_stop,
    }
    result.summary = f"mode={state.mode} tool at ({xyz[0]:.4f}, {xyz[1]:.4f}, {xyz[2]:.4f}) m"
    result.ok = state.healthy
    if not state.healthy:
        result.error = f"not ready: mode={state.mode} {state.message}".strip()


def _track_state(track: Any, result: DeviceResult) -> None:
    st = track.status()
    result.state = asdict(st)

    def yn(flag: bool) -> str:
        return "yes" if flag else "no"

    result.summary = (
        f"position={st.position_m:.4f} m enabled={yn(st.enabled)} moving={yn(st.moving)} "
        f"in_position={yn(st.in_position)} fault={yn(st.fault)}"
    )
    result.ok = not st.fault
    if st.fault:
        result.error = f"fault latched (code {st.fault_code}) at {st.position_m:.4f} m; reset it on the drive"


def _camera_state(camera: Any, result: DeviceResult, *, timeout_s: float) -> None:
    from drivers.oakd import valid_depth_share

    cap = camera.capture(timeout_s=timeout_s)
    height, width = cap.shape
    share = valid_depth_share(cap.depth_m)
    result.state = {"width": width, "height": height, "valid_depth_share": share}
    result.summary = f"frame {width}x{height}, valid depth {share * 100:.1f}%"
    result.ok = True
