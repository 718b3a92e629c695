"""Start a real PX4 SITL vehicle with its built-in SIH simulator, for tests.

The build is found through $PX4_SITL, the build output of `make px4_sitl_default`
(`.../build/px4_sitl_default`, holding `bin/px4` and `etc/`); without it the caller skips
(`px4_build_or_skip`). Nothing of PX4 is in this repository (docs/CONFORMANCE.md).

One instance `i` (PX4's `-i`) runs in a working directory of its own, as sysid i + 1, with
home at `home` and the logger off. Its links, all UDP on 127.0.0.1 (/work/shared/REAL_PX4.md):

- offboard/API link: PX4 binds 14580 + i and sends to 14540 + i (a client listens there:
  pymavlink `udpin:127.0.0.1:14540+i`, the agent `udpin://127.0.0.1:14540+i`);
- GCS link: PX4 binds 18570 + i and answers whoever sends it a HEARTBEAT
  (pymavlink `udpout:127.0.0.1:18570+i`).

PX4_INSTANCE (default 8) picks `i`, away from the 0-3 a launcher would use.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

HOME = (47.397742, 8.545594, 488.0)
PX4_INSTANCE = int(os.environ.get("PX4_INSTANCE", "8"))


def px4_build_or_skip() -> Path:
    """$PX4_SITL as a checked build directory; skips (with the reason) when it is not set."""
    build = os.environ.get("PX4_SITL")
    if not build:
        pytest.skip("real PX4 not given: set PX4_SITL=/path/to/build/px4_sitl_default (see docs/CONFORMANCE.md)")
    path = Path(build)
    if not os.access(path / "bin" / "px4", os.X_OK) or not (path / "etc").is_dir():
        pytest.fail(f"PX4_SITL={build} has no executable bin/px4 and etc/ (a `make px4_sitl_default` build output)")
    return path


@dataclass
class Px4Instance:
    proc: subprocess.Popen
    instance: int
    workdir: Path
    log: Path

    @property
    def sysid(self) -> int:
        return self.instance + 1

    @property
    def api_port(self) -> int:
        """Where PX4's onboard (offboard/API) link sends to: listen here."""
        return 14540 + self.instance

    @property
    def gcs_port(self) -> int:
        """PX4's GCS link: send a HEARTBEAT here and it answers."""
        return 18570 + self.instance

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)  # PX4 exits cleanly on SIGTERM
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)

    def tail(self, n: int = 1500) -> str:
        return self.log.read_text(errors="replace")[-n:] if self.log.exists() else ""


def start_px4(build: Path, workdir: Path, instance: int = PX4_INSTANCE,
              home: tuple[float, float, float] = HOME, params: dict[str, float] | None = None) -> Px4Instance:
    """`bin/px4 -d -i I -w WORKDIR/px4 ETC` with SIH airframe 10040 (sihsim_quadx): returns at
    once (PX4 boots in ~1.5 s: a client listening before sees the whole start-up)."""
    wd = workdir / "px4"  # PX4 writes parameters, dataman and logs here: its own, wiped
    shutil.rmtree(wd, ignore_errors=True)
    wd.mkdir(parents=True)
    env = {**os.environ, "PX4_SYS_AUTOSTART": "10040", "PX4_SIMULATOR": "sihsim", "PX4_SIM_MODEL": "sihsim_quadx",
           "PX4_HOME_LAT": str(home[0]), "PX4_HOME_LON": str(home[1]), "PX4_HOME_ALT": str(home[2]),
           "PX4_PARAM_SDLOG_BACKEND": "0"}
    for name, value in (params or {}).items():
        env[f"PX4_PARAM_{name}"] = str(value)
    log = workdir / f"px4-{instance}.log"  # not in PX4's working directory: it makes a log/ there
    with open(log, "wb") as out:
        proc = subprocess.Popen([str(build / "bin" / "px4"), "-d", "-i", str(instance), "-w", str(wd), str(build / "etc")],
                                cwd=wd, stdout=out, stderr=subprocess.STDOUT, env=env, start_new_session=True)
    px4 = Px4Instance(proc, instance, workdir, log)
    time.sleep(0.2)
    if proc.poll() is not None:
        raise RuntimeError(f"px4 exited with {proc.returncode}: {px4.tail()}")
    return px4
