"""Real ArduCopter SITL processes for a swarm run (`plmarl swarm up --autopilot arducopter=PATH`).

Vehicle i is one `arducopter` process (ArduPilot's own flight stack and its built-in
physics), in its own working directory `RUN/arducopter/vehicleI` (it writes eeprom.bin,
logs/ and terrain/ there), started as

    arducopter --model + --speedup S -I B+i --sysid i+1 --home LAT,LON,ALT,0
               --defaults copter.parm,RUN/arducopter/vehicleI/plmarl.parm

with its home at the mission's launch slot i on the ground (the twin's launch position,
`ned_to_geodetic` of the mission origin). Instance B+i puts its ports at 5760 + 10 (B+i)
(SERIAL0, TCP: the agent), 5762 + 10 (B+i) (SERIAL1, TCP: the world), 5763 + 10 (B+i)
(SERIAL2) and 5501 + 10 (B+i) (UDP, RC input); B is the first instance whose ports are
all free for every vehicle, unless given.

The generated plmarl.parm adds to ArduPilot's copter.parm only what the run needs
(`RUN_PARAMS`); everything else keeps ArduPilot's defaults, so the vehicles fly as a
stock ArduCopter does. Measured (docs/RESULTS.md, session 11): under the agent's guided
acceleration setpoints the stock SITL quad cruises at 11 m/s, below the twin's 20 m/s; the
bound is its lean angle against its drag (ANGLE_MAX 30 deg; 45 deg gives 16 m/s), not
WPNAV_SPEED or WPNAV_ACCEL (raised to 20 m/s and 5 m/s^2 they changed nothing).

A process waits for a client on SERIAL0 before its clock starts; SERIAL1 opens only then.
Every process is in a session of its own (Ctrl-C in a terminal reaches the launcher, which
stops the agents first, while the vehicles still answer, then these) and dies with the
launcher even if it is SIGKILLed (PR_SET_PDEATHSIG).
"""

from __future__ import annotations

import asyncio
import contextlib
import signal
import socket
import subprocess
from dataclasses import dataclass
from pathlib import Path

from plmarl_sitl.deploy.mavlink.codec import signing_timestamp
from plmarl_sitl.deploy.mavlink.connect import connect
from plmarl_sitl.errors import UserError, VehicleUnreachable
from plmarl_sitl.mission import Mission
from plmarl_sitl.model.geodesy import ned_to_geodetic
from plmarl_sitl.proc import die_with_parent
from plmarl_sitl.twin.env import launch_positions

SERIAL0_PORT = 5760  # + 10 I: the agent's link
SERIAL1_PORT = 5762  # + 10 I: the world's link
SERIAL2_PORT = 5763
RCIN_PORT = 5501  # UDP
MAX_INSTANCE = 400
PROVISIONER_SYSID = 255  # the launcher speaks as a ground station while it provisions the keys  # ports stay below 65536 with room to spare
COPTER_PARM = Path("Tools") / "autotest" / "default_params" / "copter.parm"

# What the run adds to copter.parm, and why (one line each; written into plmarl.parm).
RUN_PARAMS = {
    # The pre-arm checks need a calibrated RC transmitter and radio failsafe set-up that a
    # companion-computer-only SITL vehicle does not have (ArduPilot's own autotest sets this
    # too). The agent still waits for the EKF: home, then position, before it arms.
    "ARMING_CHECK": 0,
}


def find_copter_parm(binary: Path, given: Path | None = None) -> Path:
    """copter.parm: `given`, else ArduPilot's Tools/autotest/default_params/copter.parm found
    above the binary (its build tree: build/sitl/bin/arducopter). A UserError if missing."""
    if given is not None:
        if not given.is_file():
            raise UserError(f"--copter-parm {given}: no such file")
        return given
    for parent in binary.resolve().parents:
        if (parent / COPTER_PARM).is_file():
            return parent / COPTER_PARM
    raise UserError(f"no {COPTER_PARM} in the ArduPilot tree above {binary}: pass --copter-parm PATH/copter.parm")


def check_binary(binary: Path) -> Path:
    if not binary.is_file():
        raise UserError(f"--autopilot arducopter={binary}: no such file (build ArduPilot's SITL: ./waf copter)")
    return binary


def instance_ports(instance: int) -> tuple[list[int], list[int]]:
    """(TCP, UDP) ports an ArduPilot SITL instance listens on."""
    base = 10 * instance
    return [SERIAL0_PORT + base, SERIAL1_PORT + base, SERIAL2_PORT + base], [RCIN_PORT + base]


def port_free(port: int, kind: int) -> bool:
    """Nobody has bound `port` (TCP or UDP, on any address)."""
    with socket.socket(socket.AF_INET, kind) as s:
        try:
            s.bind(("0.0.0.0", port))
        except OSError:
            return False
    return True


def instance_free(instance: int) -> bool:
    tcp, udp = instance_ports(instance)
    return all(port_free(p, socket.SOCK_STREAM) for p in tcp) and all(port_free(p, socket.SOCK_DGRAM) for p in udp)


def free_instance_base(n: int, first: int = 0) -> int:
    """The first instance B >= `first` such that B .. B+n-1 all have free ports."""
    for base in range(first, MAX_INSTANCE - n + 1):
        if all(instance_free(base + i) for i in range(n)):
            return base
    raise UserError(f"no {n} consecutive free ArduPilot SITL instances (ports 5760 + 10 I) from -I {first}")


def launch_homes(mission: Mission) -> list[tuple[float, float, float, float]]:
    """lat, lon, alt, heading of each UAV's launch slot, on the ground (the twin's t = 0 layout)."""
    o = mission.origin
    out = []
    for north, east, _ in launch_positions(mission, 0.0).tolist():
        out.append((*ned_to_geodetic(o.lat_deg, o.lon_deg, o.alt_m, north, east, 0.0), 0.0))
    return out


@dataclass
class ArduCopterProcess:
    index: int
    instance: int
    workdir: Path
    proc: subprocess.Popen

    @property
    def serial0(self) -> int:
        return SERIAL0_PORT + 10 * self.instance

    @property
    def serial1(self) -> int:
        return SERIAL1_PORT + 10 * self.instance

    @property
    def log_path(self) -> Path:
        return self.workdir / "arducopter.log"

    def tail(self) -> str:
        """The log line that says why it stopped: its last PANIC (ArduPilot follows one with
        dumpstack chatter), else its last line; at most 240 characters, from the start."""
        lines = [ln for ln in self.log_path.read_text(errors="replace").splitlines() if ln.strip()] if self.log_path.exists() else []
        panics = [ln for ln in lines if ln.startswith("PANIC")]
        line = (panics or lines or ["(empty log)"])[-1]
        return line if len(line) <= 240 else line[:237] + "..."

    def exit_reason(self) -> str:
        """One line for a process that has exited: its code, why (`tail`) and where its log is."""
        return f"arducopter {self.index} exited with code {self.proc.returncode}: {self.tail()} (log: {self.log_path})"


class ArduCopterFleet:
    """N ArduCopter SITL processes, one per UAV of `mission`; `stop()` ends them all."""

    def __init__(self, binary: Path, copter_parm: Path, mission: Mission, speedup: float, run_dir: Path,
                 instance_base: int | None = None) -> None:
        self.binary, self.copter_parm, self.mission, self.speedup = binary, copter_parm, mission, speedup
        self.run_dir = run_dir
        n = mission.n_uavs
        if instance_base is None:
            instance_base = free_instance_base(n)
        elif not all(instance_free(instance_base + i) for i in range(n)):
            busy = [instance_base + i for i in range(n) if not instance_free(instance_base + i)]
            raise UserError(f"--instance {instance_base}: ArduPilot SITL instance(s) {busy} have ports in use")
        self.instance_base = instance_base
        self.procs: list[ArduCopterProcess] = []

    def command(self, i: int, workdir: Path) -> list[str]:
        lat, lon, alt, heading = launch_homes(self.mission)[i]
        return [str(self.binary), "--model", "+", "--speedup", f"{self.speedup:g}", "-I", str(self.instance_base + i),
                "--sysid", str(i + 1), "--home", f"{lat:.7f},{lon:.7f},{alt:.2f},{heading:g}",
                # absolute: arducopter runs in `workdir`, and the run directory is often relative (runs/...)
                "--defaults", f"{self.copter_parm.resolve()},{workdir.resolve() / 'plmarl.parm'}"]

    def start(self) -> None:
        """Start every process (from the event loop's thread: PR_SET_PDEATHSIG is tied to it)."""
        for i in range(self.mission.n_uavs):
            workdir = self.run_dir / "arducopter" / f"vehicle{i}"
            workdir.mkdir(parents=True, exist_ok=True)
            (workdir / "plmarl.parm").write_text(
                "# plmarl swarm up: added to ArduPilot's copter.parm (see plmarl_sitl/sitl/arducopter.py)\n"
                + "".join(f"{k} {v}\n" for k, v in RUN_PARAMS.items()))
            with open(workdir / "arducopter.log", "wb") as out:
                proc = subprocess.Popen(self.command(i, workdir), cwd=workdir, stdout=out, stderr=subprocess.STDOUT,
                                        stdin=subprocess.DEVNULL, start_new_session=True, preexec_fn=die_with_parent)
            self.procs.append(ArduCopterProcess(i, self.instance_base + i, workdir, proc))

    def ports_line(self) -> str:
        first, last = self.instance_base, self.instance_base + self.mission.n_uavs - 1
        return (f"ArduCopter SITL -I {first}..{last}: agents on SERIAL0 tcp "
                f"{', '.join(str(p.serial0) for p in self.procs)}; world on SERIAL1 tcp "
                f"{', '.join(str(p.serial1) for p in self.procs)}")

    def exited(self) -> ArduCopterProcess | None:
        """A process that has exited, if any."""
        return next((p for p in self.procs if p.proc.poll() is not None), None)

    async def wait_listening(self, timeout_s: float = 20.0) -> None:
        """Until every process listens on SERIAL0 (RuntimeError naming the one that exited or did not)."""
        loop = asyncio.get_running_loop()
        t_end = loop.time() + timeout_s
        for p in self.procs:
            while port_free(p.serial0, socket.SOCK_STREAM):  # bound by arducopter: listening (a probe would connect)
                if p.proc.poll() is not None:
                    raise RuntimeError(p.exit_reason())
                if loop.time() > t_end:
                    raise RuntimeError(f"arducopter {p.index} did not listen on tcp {p.serial0} within {timeout_s:g} s "
                                       f"(log: {p.log_path})")
                await asyncio.sleep(0.1)

    async def provision_signing(self, keys: list[bytes], timeout_s: float = 30.0) -> None:
        """Give vehicle i the MAVLink signing key `keys[i]` (RuntimeError naming one that did not take it)."""
        try:
            await asyncio.gather(*(provision_signing(f"tcpout://127.0.0.1:{p.serial0}", key, timeout_s)
                                   for p, key in zip(self.procs, keys, strict=True)))
        except RuntimeError:
            # An arducopter that dies on the first connection (e.g. a bad --defaults) says why;
            # its socket closes a moment before its exit code is in.
            loop = asyncio.get_running_loop()
            t_end = loop.time() + 2.0
            while (gone := self.exited()) is None and loop.time() < t_end:
                await asyncio.sleep(0.05)
            if gone is not None:
                raise RuntimeError(gone.exit_reason()) from None
            raise

    async def stop(self, grace_s: float = 5.0) -> None:
        """SIGTERM every process, SIGKILL whoever is left after `grace_s`."""
        await stop_processes([p.proc for p in self.procs], grace_s)


async def stop_processes(procs: list[subprocess.Popen], grace_s: float = 5.0) -> None:
    """SIGTERM every live process of `procs`, SIGKILL whoever is left after `grace_s` (the
    autopilot fleets' stop: ArduCopter's, `sitl.px4`'s)."""
    live = [proc for proc in procs if proc.poll() is None]
    for proc in live:
        with contextlib.suppress(ProcessLookupError):
            proc.send_signal(signal.SIGTERM)
    loop = asyncio.get_running_loop()
    t_end = loop.time() + grace_s
    for proc in live:
        while proc.poll() is None and loop.time() < t_end:
            await asyncio.sleep(0.05)
        if proc.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                proc.kill()
            proc.wait()


async def provision_signing(url: str, key: bytes, timeout_s: float = 30.0) -> None:
    """SETUP_SIGNING to the ArduPilot at `url` (its SERIAL0), checked, then the link closed.

    ArduPilot takes SETUP_SIGNING only disarmed (a vehicle just started is) and, once a key
    is set, only signed, except on its channel 0 (SERIAL0: USB on a board, the agent's TCP
    port in SITL), which it always trusts: that is where a key is provisioned, before the
    agent connects. The key is stored in the vehicle's storage (eeprom.bin in its working
    directory) and takes effect on every link at once; the check is a heartbeat that
    verifies under the key (an unsigned one is not accepted by the signing link)."""
    link = connect(url, sysid=PROVISIONER_SYSID)
    try:
        await link.open(timeout_s)
        link.send(link.codec.mav.setup_signing_encode(link.sysid, 1, list(key), signing_timestamp()))
        link.codec.set_signing_key(key)
        await link.recv("HEARTBEAT", 5.0, lambda m: m.get_srcSystem() == link.sysid and m.get_srcComponent() == 1)
    except VehicleUnreachable as exc:  # silent, or it closed the connection
        raise RuntimeError(f"MAVLink signing: the autopilot on {url} did not take its key ({exc})") from None
    finally:
        link.close()
