"""Real PX4 SITL processes for a swarm run (`plmarl swarm up --autopilot px4=PATH`).

PATH is PX4's SITL build output (`build/px4_sitl_default`, which holds `bin/px4` and
`etc/`) or its `bin/px4`. Vehicle i is one `px4` process with PX4's built-in SIH simulator
(quadrotor airframe 10040, `sihsim_quadx`: no Gazebo), in its own working directory
`RUN/px4/vehicleI` (parameters, dataman; px4.log), started as

    PX4_SYS_AUTOSTART=10040 PX4_SIMULATOR=sihsim PX4_SIM_MODEL=sihsim_quadx
    PX4_HOME_LAT=.. PX4_HOME_LON=.. PX4_HOME_ALT=.. PX4_SIM_SPEED_FACTOR=S PX4_PARAM_..=..
        px4 -d -i B+i -w RUN/px4/vehicleI BUILD/etc

with its home at the mission's launch slot i on the ground (`arducopter.launch_homes`, as
for ArduCopter). Instance I binds UDP 18570 + I (its GCS link: the world's), 14580 + I (its
onboard/offboard link) and 14280, 13030, 19450 + I (payload, gimbal, SIH display links).

The links. PX4 fixes a UDP link's partner on the first datagram it receives from localhost
(`mavlink_receiver.cpp`) and sends only there from then on. Its offboard link sends to
14540 + I until then, and every instance above 9 to the same 14549: a client listening on
14549 for its own vehicle answers every such instance's heartbeats and so takes their links
(measured: four agents on instances 20-23 got no heartbeat in 30 s while another test
listened on 14549). So agent i listens (`udpin`) on its vehicle's own 14540 + I, with
I <= 9: at most 10 PX4 vehicles, from the first instance B whose ports (bound and
remote) and lock file (/tmp/px4_lock-I) are all free, unless given. The world speaks first
(`udpout`) to the GCS link; that link sends to 14550, shared by every instance, until then, so
a ground station listening on 14550 could take it first (said at start when 14550 is bound).

The pace: SIH runs in lockstep with PX4's modules, PX4_SIM_SPEED_FACTOR times wall time at
most (`simulator_sih/sih.cpp`), slower when the machine cannot keep up (it waits for every
module each step); the world follows each vehicle's clock (`sitl.external`). PX4's rcS
multiplies COM_OF_LOSS_T, COM_DL_LOSS_T, COM_RC_LOSS_T and COM_OBC_LOSS_T by the factor.

MAVLink signing: this PX4 has none (no MAV_SIGN_CFG parameter, no SETUP_SIGNING handler in
`src/modules/mavlink`), so a PX4 swarm flies unsigned and says so.

The launcher waits for each instance's start-up script to finish (`wait_listening`), turns
off the GCS link's streams the world does not read (`quiet_gcs_links`), and only then starts
the world and the agents.

Faults go through PX4's own failure injection (`inject_fault`): SYS_FAILURE_EN is 1 in every
SITL (rcS), and CA_FAILURE_MODE 1 (RUN_PARAMS) lets an injected motor failure stop the motor.

The processes are started, watched and stopped as the ArduCopter ones are: each in a
session of its own, dying with the launcher (PR_SET_PDEATHSIG); `stop()` is SIGTERM (PX4
exits cleanly on it), then SIGKILL, and removes the daemon's /tmp/px4-sock-I it leaves.
"""

from __future__ import annotations

import asyncio
import contextlib
import fcntl
import os
import socket
import struct
import subprocess
from dataclasses import dataclass
from pathlib import Path

from plmarl_sitl.deploy.mavlink.client import VehicleLink
from plmarl_sitl.deploy.mavlink.codec import dialect as d
from plmarl_sitl.errors import CommandRejected, UserError, VehicleUnreachable
from plmarl_sitl.mission import Mission
from plmarl_sitl.proc import die_with_parent
from plmarl_sitl.sitl.arducopter import launch_homes, port_free, stop_processes

GCS_PORT = 18570  # + I: the world's link (PX4 binds it)
OFFBOARD_PORT = 14580  # + I: the offboard link (PX4 binds it; "onboard" mode, high rate)
AGENT_PORT = 14540  # + I: where that link sends (its remote), the agent listens there
GCS_REMOTE_PORT = 14550  # where every instance's GCS link sends until the world speaks
OTHER_PORTS = (14280, 13030, 19450)  # + I: payload, gimbal, SIH display links (bound too)
MAX_INSTANCE = 9  # above, every instance's offboard link sends to 14549 (ROMFS px4-rc.mavlink)
AIRFRAME = "10040"  # sihsim_quadx
LOCK_FILE = "/tmp/px4_lock-{}"  # the px4 daemon's per-instance lock (platforms/posix/.../main.cpp)
STARTED_LINE = "Startup script returned successfully"  # px4.log: rcS has run to its end

# What the run sets on top of the airframe's defaults (PX4_PARAM_<NAME>, applied after the
# airframe); everything else keeps PX4's defaults, so the vehicles fly as a stock PX4 does.
RUN_PARAMS = {
    # No .ulg per vehicle and run: the logger costs CPU and disk on a shared machine.
    "SDLOG_BACKEND": 0,
    # An injected motor failure (below) reaches the motors only through the control allocator,
    # which reads the failure detector's motor_stop_mask only when CA_FAILURE_MODE > 0
    # (ControlAllocator::check_for_motor_failures); at PX4's default 0 the command is ACCEPTED
    # and the motor keeps turning (measured: the vehicle flew on). 1 also takes the stopped
    # motor out of the allocation, as PX4 does for a motor failure it detects itself.
    "CA_FAILURE_MODE": 1,
}

# SIH's quadrotor airframe drag per unit mass, 1/s: its defaults SIH_KDV 1 N/(m/s) on SIH_MASS
# 1 kg (the run sets neither; `simulator_sih/sih.cpp`: F_drag = -SIH_KDV v). PX4 flies the
# agents' acceleration-only setpoints open loop, so their agents add it back
# (`plmarl agent --airframe-drag`).
SIH_DRAG_PER_S = 1.0

# The GCS link's streams the world does not read, and their rates there (ROMFS px4-rc.mavlink
# sets most of them to 50 Hz on it: about 350 messages a vehicle-second, four vehicles at 2x
# some 2800 a wall second for the world's process to parse). Set with PX4's own
# `mavlink stream` through its client (bin/px4-mavlink --instance I) once the start-up is over.
GCS_STREAMS = {"ATTITUDE": 0, "ATTITUDE_QUATERNION": 0, "ATTITUDE_TARGET": 0, "GLOBAL_POSITION_INT": 0,
               "SERVO_OUTPUT_RAW_0": 0, "RC_CHANNELS": 0, "OPTICAL_FLOW_RAD": 0, "GPS_RAW_INT": 0,
               "MOUNT_ORIENTATION": 0, "GIMBAL_DEVICE_ATTITUDE_STATUS": 0, "GIMBAL_DEVICE_SET_ATTITUDE": 0,
               "GLOBAL_POSITION_SENSOR": 0, "LOCAL_POSITION_NED": 10, "POSITION_TARGET_LOCAL_NED": 2}

# Fault injection (PX4's own). The motor: MAV_CMD_INJECT_FAILURE (420), unit
# FAILURE_UNIT_SYSTEM_MOTOR (101), type FAILURE_TYPE_OFF (1), instance 1: commander's
# FailureInjector stops motor 1 in the control allocator (motor_stop_mask). The GPS:
# INJECT_FAILURE of FAILURE_UNIT_SENSOR_GPS is handled only by the Gazebo/jMAVSim bridge
# (simulator_mavlink), not by SIH, whose GPS is sensor_gps_sim: its SIM_GPS_USED parameter
# (satellites used, default 10) below 4 makes it report no fix.
MAV_CMD_INJECT_FAILURE = 420
FAILURE_UNIT_SYSTEM_MOTOR = 101
FAILURE_TYPE_OFF = 1
GPS_PARAM = "SIM_GPS_USED"
GPS_SATS_ON = 10
GPS_SATS_OFF = 0


def int32_wire(value: int) -> float:
    """An INT32 parameter's value as PX4 puts it on the wire: its bytes in the float (bytewise)."""
    return struct.unpack("<f", struct.pack("<i", int(value)))[0]


def wire_int32(value: float) -> int:
    return struct.unpack("<i", struct.pack("<f", value))[0]


def find_build(path: Path) -> tuple[Path, Path]:
    """(bin/px4, etc) of PX4's SITL build output PATH (or of PATH = its bin/px4); a UserError if not one."""
    build = path.parent.parent if path.name == "px4" and path.is_file() else path
    binary, etc = build / "bin" / "px4", build / "etc"
    if not binary.is_file():
        raise UserError(f"--autopilot px4={path}: no bin/px4 there (build PX4's SITL: make px4_sitl_default, "
                        "and give build/px4_sitl_default)")
    if not (etc / "init.d-posix" / "airframes").is_dir():
        raise UserError(f"--autopilot px4={path}: no etc/init.d-posix/airframes beside bin/px4 (not a PX4 SITL build?)")
    if not any((etc / "init.d-posix" / "airframes").glob(f"{AIRFRAME}_*")):
        raise UserError(f"--autopilot px4={path}: this build has no SIH quadrotor airframe {AIRFRAME}")
    return binary, etc


def instance_ports(instance: int) -> list[int]:
    """The UDP ports a PX4 SITL instance binds, and the one its agent listens on."""
    return [base + instance for base in (GCS_PORT, OFFBOARD_PORT, *OTHER_PORTS, AGENT_PORT)]


def _lock_free(instance: int) -> bool:
    """No px4 daemon holds instance I's lock file."""
    path = LOCK_FILE.format(instance)
    if not os.path.exists(path):
        return True
    try:
        fd = os.open(path, os.O_RDWR)
    except OSError:
        return False  # someone else's, unreadable: not ours to take
    try:
        fcntl.lockf(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        fcntl.lockf(fd, fcntl.LOCK_UN)
        return True
    except OSError:
        return False
    finally:
        os.close(fd)


def instance_free(instance: int) -> bool:
    return _lock_free(instance) and all(port_free(p, socket.SOCK_DGRAM) for p in instance_ports(instance))


def free_instance_base(n: int, first: int = 0) -> int:
    """The first instance B >= `first` such that B .. B+n-1 are all free (and at most MAX_INSTANCE)."""
    check_count(n)
    for base in range(first, MAX_INSTANCE - n + 2):
        if all(instance_free(base + i) for i in range(n)):
            return base
    raise UserError(f"no {n} consecutive free PX4 SITL instances in -i {first}..{MAX_INSTANCE} (udp 18570 + I, "
                    "14580 + I, 14540 + I in use, or a px4 daemon's /tmp/px4_lock-I)")


def check_count(n: int, base: int = 0) -> None:
    if base + n - 1 > MAX_INSTANCE:
        raise UserError(f"{n} PX4 vehicles from instance {base}: PX4 SITL gives an instance an offboard port of its own "
                        f"only up to -i {MAX_INSTANCE} (above, all send to 14549): at most {MAX_INSTANCE + 1 - base}")


@dataclass
class Px4Process:
    index: int
    instance: int
    workdir: Path
    proc: subprocess.Popen

    @property
    def gcs_port(self) -> int:
        return GCS_PORT + self.instance

    @property
    def offboard_port(self) -> int:
        return OFFBOARD_PORT + self.instance

    @property
    def agent_port(self) -> int:
        return AGENT_PORT + self.instance

    @property
    def log_path(self) -> Path:
        return self.workdir / "px4.log"

    def tail(self) -> str:
        """Its last ERROR line, else its last line; at most 240 characters."""
        lines = [ln for ln in self.log_path.read_text(errors="replace").splitlines() if ln.strip()] if self.log_path.exists() else []
        errors = [ln for ln in lines if ln.startswith("ERROR") and "not found" not in ln]
        line = (errors[-1:] if lines and lines[-1].startswith(("PX4 Exiting", "Exiting")) else []) or lines[-1:] or ["(empty log)"]
        text = line[0]
        return text if len(text) <= 240 else text[:237] + "..."

    def exit_reason(self) -> str:
        return f"px4 {self.index} (instance {self.instance}) exited with code {self.proc.returncode}: {self.tail()} (log: {self.log_path})"


class Px4Fleet:
    """N PX4 SITL (SIH) processes, one per UAV of `mission`; `stop()` ends them all."""

    kind = "px4"

    def __init__(self, build: Path, mission: Mission, speedup: float, run_dir: Path, instance_base: int | None = None) -> None:
        self.binary, self.etc = find_build(build)
        self.mission, self.speedup, self.run_dir = mission, speedup, run_dir
        n = mission.n_uavs
        if instance_base is None:
            instance_base = free_instance_base(n)
        elif check_count(n, instance_base) is None and not all(instance_free(instance_base + i) for i in range(n)):
            busy = [instance_base + i for i in range(n) if not instance_free(instance_base + i)]
            raise UserError(f"--instance {instance_base}: PX4 SITL instance(s) {busy} are in use (ports or lock file)")
        self.instance_base = instance_base
        self.procs: list[Px4Process] = []

    def environment(self, i: int) -> dict[str, str]:
        lat, lon, alt, _ = launch_homes(self.mission)[i]
        env = {k: v for k, v in os.environ.items() if not k.startswith("PX4_")}  # only what this run says
        env.update(PX4_SYS_AUTOSTART=AIRFRAME, PX4_SIMULATOR="sihsim", PX4_SIM_MODEL="sihsim_quadx",
                   PX4_HOME_LAT=f"{lat:.7f}", PX4_HOME_LON=f"{lon:.7f}", PX4_HOME_ALT=f"{alt:.2f}",
                   PX4_SIM_SPEED_FACTOR=f"{self.speedup:g}")
        # MAV_SYS_ID i + 1, as an ArduCopter swarm's (PX4 would give instance + 1).
        env.update({f"PX4_PARAM_{k}": str(v) for k, v in {**RUN_PARAMS, "MAV_SYS_ID": i + 1}.items()})
        return env

    def command(self, i: int, workdir: Path) -> list[str]:
        return [str(self.binary.resolve()), "-d", "-i", str(self.instance_base + i), "-w", str(workdir.resolve()),
                str(self.etc.resolve())]

    def start(self) -> None:
        """Start every process (from the event loop's thread: PR_SET_PDEATHSIG is tied to it)."""
        for i in range(self.mission.n_uavs):
            workdir = self.run_dir / "px4" / f"vehicle{i}"
            workdir.mkdir(parents=True, exist_ok=True)
            with open(workdir / "px4.log", "wb") as out:
                proc = subprocess.Popen(self.command(i, workdir), cwd=workdir, env=self.environment(i), stdout=out,
                                        stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, start_new_session=True,
                                        preexec_fn=die_with_parent)
            self.procs.append(Px4Process(i, self.instance_base + i, workdir, proc))

    def agent_urls(self) -> list[str]:
        return [f"udpin://127.0.0.1:{p.agent_port}" for p in self.procs]

    def world_urls(self) -> list[str]:
        return [f"udpout://127.0.0.1:{p.gcs_port}" for p in self.procs]

    def ports_line(self) -> str:
        first, last = self.instance_base, self.instance_base + self.mission.n_uavs - 1
        return (f"PX4 SITL (SIH) -i {first}..{last} at {self.speedup:g}x: agents listen on udp "
                f"{', '.join(str(p.agent_port) for p in self.procs)}; world on udp "
                f"{', '.join(str(p.gcs_port) for p in self.procs)}")

    async def quiet_gcs_links(self) -> None:
        """`mavlink stream -u GCS_PORT -s NAME -r HZ` for each of GCS_STREAMS on every instance.
        A stream a build does not have is left alone (the client says so and exits non-zero)."""
        client = self.binary.parent / "px4-mavlink"
        if not client.exists():
            return

        async def one(p: Px4Process, name: str, hz: float) -> None:
            proc = await asyncio.create_subprocess_exec(
                str(client), "--instance", str(p.instance), "stream", "-u", str(p.gcs_port), "-s", name, "-r", f"{hz:g}",
                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            await proc.wait()

        await asyncio.gather(*(one(p, name, hz) for p in self.procs for name, hz in GCS_STREAMS.items()))

    def gcs_warning(self) -> str | None:
        """A line to say when something listens on 14550 (a ground station could take the GCS links first)."""
        if port_free(GCS_REMOTE_PORT, socket.SOCK_DGRAM):
            return None
        return (f"udp {GCS_REMOTE_PORT} is in use: a ground station there gets every PX4's GCS link until the world "
                "speaks, and if it answers first, PX4 answers only it (the world then waits for telemetry)")

    def exited(self) -> Px4Process | None:
        return next((p for p in self.procs if p.proc.poll() is not None), None)

    async def wait_listening(self, timeout_s: float = 90.0) -> None:
        """Until every process has bound its GCS and offboard ports and run its start-up script
        to the end (STARTED_LINE in its log). An agent that connects earlier competes with
        PX4's start-up for the CPU: on a loaded 2-core machine one waited more than its 3 s
        for the ACK of its first command."""
        loop = asyncio.get_running_loop()
        t_end = loop.time() + timeout_s
        for p in self.procs:
            while (port_free(p.gcs_port, socket.SOCK_DGRAM) or port_free(p.offboard_port, socket.SOCK_DGRAM)
                   or STARTED_LINE not in p.log_path.read_text(errors="replace")):
                if p.proc.poll() is not None:
                    raise RuntimeError(p.exit_reason())
                if loop.time() > t_end:
                    raise RuntimeError(f"px4 {p.index} did not finish its start-up (udp {p.gcs_port} and {p.offboard_port} "
                                       f"bound, \"{STARTED_LINE}\") within {timeout_s:g} s (log: {p.log_path})")
                await asyncio.sleep(0.2)

    async def stop(self, grace_s: float = 5.0) -> None:
        await stop_processes([p.proc for p in self.procs], grace_s)
        for p in self.procs:  # the daemon's socket stays behind on SIGTERM (harmless, but ours)
            with contextlib.suppress(OSError):
                os.unlink(f"/tmp/px4-sock-{p.instance}")


SIGNING_UNSUPPORTED = ("MAVLink signing: PX4 has no MAVLink 2 signing to provision (no MAV_SIGN_CFG, no SETUP_SIGNING "
                       "handler): the PX4 links fly unsigned")


async def inject_fault(link: VehicleLink, unit: str, ok: bool) -> dict:
    """PX4's own failure injection on `link`: unit "gps" (ok: back) or "motor" (motor 1 off).
    Returns what to record: what was sent and what PX4 answered (or "error")."""
    if unit == "gps":
        sats = GPS_SATS_ON if ok else GPS_SATS_OFF
        out: dict = {"param": GPS_PARAM, "set": sats, "via": "PARAM_SET (sensor_gps_sim)"}
        for _ in range(3):
            try:
                echo = await link.param_set(GPS_PARAM, int32_wire(sats), d.MAV_PARAM_TYPE_INT32)
            except VehicleUnreachable as exc:
                out["error"] = str(exc)
                continue
            out.pop("error", None)
            out["echo"] = wire_int32(echo)
            break
        return out
    if unit == "motor":
        out = {"command": "MAV_CMD_INJECT_FAILURE", "unit": "FAILURE_UNIT_SYSTEM_MOTOR", "failure": "FAILURE_TYPE_OFF",
               "instance": 1, "via": "COMMAND_LONG"}
        try:
            await link.command(MAV_CMD_INJECT_FAILURE, FAILURE_UNIT_SYSTEM_MOTOR, FAILURE_TYPE_OFF, 1, timeout=2.0)
            out["result"] = "ACCEPTED"
        except CommandRejected as exc:
            out["error"] = str(exc)
        except VehicleUnreachable as exc:
            out["error"] = str(exc)
        return out
    raise ValueError(unit)
