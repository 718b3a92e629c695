"""The attack of issue 14, replayed on a whole signed swarm (`plmarl swarm up`, real agents, a
real mosquitto with a login per process and an ACL, started by the test).

The attacker has a broker login of its own that may publish on rx/0 and ctl (a broker
that does not protect those topics, as with radios bridged to it under `--bus direct`),
but not the swarm key. From t = 31 s it publishes, every mission second, forged states of
UAV 1 (a fresh session, at (10, 10, -90) m) on plmarl/sitl/rx/0: unsigned as in the issue,
signed under the swarm's key id with a made-up tag, a replay of the latest genuine rx/0
batch it overheard, and a replay of one 20 s old; plus a retained `ctl` with tup_s 45,
unsigned and forged. Agent 0 must drop and count each, keep every belief and T_up, and the
mission must end with the coverage of the clean run (same seed) within 0.02.
"""

from __future__ import annotations

import asyncio
import json
import os
import random
import shutil
import sys
from pathlib import Path

import aiomqtt
import pytest

from plmarl_sitl.deploy.mqtt.auth import TRAILER_BYTES
from plmarl_sitl.deploy.mqtt.schema import StateMsg, Topics, encode_json, encode_state
from plmarl_sitl.sitl.network.access import BrokerAccess
from plmarl_sitl.sitl.network.broker import MosquittoBroker

pytestmark = [pytest.mark.integration, pytest.mark.slow,
              pytest.mark.skipif(not (shutil.which("mosquitto") or os.path.exists("/usr/sbin/mosquitto")),
                                 reason="mosquitto not installed")]
ROOT = Path(__file__).resolve().parents[2]
T = Topics("sitl")
DURATION, SEED, ATTACK_FROM, TUP = 90, 0, 31, 15
ATTACK_UNTIL = DURATION - 5  # so that every message reaches agent 0 before it stops


async def _swarm(out: Path, url: str, creds: Path) -> dict:
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "plmarl_sitl.cli", "swarm", "up", str(ROOT / "missions" / "paper_urban.yaml"), "--speedup", "10",
        "--duration", str(DURATION), "--seed", str(SEED), "--broker", url, "--broker-credentials", str(creds),
        "--out", str(out), "--json", cwd=ROOT, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE)
    stdout, stderr = await asyncio.wait_for(proc.communicate(), 300)
    log = (out / "launcher.log").read_text()[-3000:] if (out / "launcher.log").exists() else ""
    assert proc.returncode == 0, f"exit {proc.returncode}: {stderr.decode()[-2000:]}\n{log}"
    return json.loads(stdout.decode().strip().splitlines()[-1])


async def _attack(broker: MosquittoBroker, sent: dict[str, int]) -> None:
    """The attacker, until cancelled."""
    user, password = broker.access["intruder"].credentials
    session, seq = random.getrandbits(16), 0
    overheard: list[tuple[float, bytes]] = []  # (mission second, genuine rx/0 payload)
    last_t = None
    mine: set[bytes] = set()  # what we published on rx/0 (we hear it back)
    async with aiomqtt.Client(broker.host, broker.port, username=user, password=password, identifier="intruder") as c:
        await c.subscribe(T.metrics)
        await c.subscribe(T.rx(0))
        async for m in c.messages:
            payload = bytes(m.payload)
            if m.topic.matches(T.rx(0)):
                if last_t is not None and payload not in mine and payload not in [p for _, p in overheard]:
                    overheard.append((last_t, payload))  # a genuine batch (not an echo of our own)
                continue
            t = json.loads(payload).get("t")
            if t is None or not ATTACK_FROM <= t <= ATTACK_UNTIL or t == last_t:
                last_t = t if t is not None else last_t
                continue
            last_t = t
            seq += 1
            fake = encode_state(StateMsg(1, session, seq, t * 1000, (10.0, 10.0, -90.0, 0.0, 0.0, 0.0)))
            mine.add(fake)
            await c.publish(T.rx(0), fake)
            sent["unsigned"] += 1
            if overheard:
                key_id = overheard[-1][1][-TRAILER_BYTES]  # the swarm's key id is on every signed message
                forged = b"\x02" + fake[1:] + bytes((key_id,)) + random.randbytes(8)
                mine.add(forged)
                await c.publish(T.rx(0), forged)
                sent["forged"] += 1
                await c.publish(T.rx(0), overheard[-1][1])  # the latest genuine batch again
                sent["replayed"] += 1
                old = [p for when, p in overheard if when <= t - 20]
                if old:
                    await c.publish(T.rx(0), old[-1])
                    sent["too_old"] += 1
            if sent["ctl"] == 0:
                await c.publish(T.ctl, encode_json({"tup_s": 45}), retain=True)
                if overheard:
                    body = json.dumps({"v": 2, "tup_s": 45, "seq": 99}).encode()
                    await c.publish(T.ctl, body + bytes((overheard[-1][1][-TRAILER_BYTES],)) + random.randbytes(8), retain=True)
                    sent["ctl"] += 1
                sent["ctl"] += 1


def test_the_issue_attack_is_dropped_counted_and_changes_nothing(tmp_path: Path) -> None:
    access = BrokerAccess("sitl", 4)
    access.add("intruder", [T.rx(0), T.ctl], [T.metrics, T.rx(0)])
    creds = tmp_path / "credentials"
    access.write_credentials(creds)
    sent = {"unsigned": 0, "forged": 0, "replayed": 0, "too_old": 0, "ctl": 0}

    async def main() -> tuple[dict, dict]:
        with MosquittoBroker(access=access) as broker:
            with pytest.raises(aiomqtt.MqttError, match="Not authorized"):  # the issue's anonymous client
                async with aiomqtt.Client(broker.host, broker.port, timeout=5):
                    pass
            clean = await _swarm(tmp_path / "clean", broker.url, creds)
            attacker = asyncio.create_task(_attack(broker, sent))
            try:
                attacked = await _swarm(tmp_path / "attacked", broker.url, creds)
            finally:
                attacker.cancel()
                await asyncio.gather(attacker, return_exceptions=True)
        return clean, attacked

    clean, attacked = asyncio.run(main())
    out = tmp_path / "attacked"
    stats = json.loads((out / "agents" / "agent0.stats.json").read_text())
    rx = stats["rx"]
    print(f"\nattacker sent {sent}\nagent 0 rx counters: {rx}\ncoverage clean {clean['coverage_mean']:.4f}, "
          f"attacked {attacked['coverage_mean']:.4f}")
    assert sent["unsigned"] >= 40 and sent["forged"] >= 30 and sent["replayed"] >= 30 and sent["too_old"] >= 10 and sent["ctl"] == 2
    # Each kind dropped and counted (a state under its reason, the ctl under ctl_<reason>).
    assert rx["auth_state_unsigned"] == sent["unsigned"] and rx["auth_state_forged"] == sent["forged"]
    assert rx["duplicate"] >= 30 and rx["out_of_window"] >= 10
    assert rx["auth_ctl_unsigned"] >= 1 and rx["auth_ctl_forged"] >= 1
    # No belief changed: UAV 1 is held only at its real signalling instants (the issue saw 33, 36, 40, ...).
    trace = [json.loads(x) for x in (out / "agents" / "agent0.trace.jsonl").read_text().splitlines() if x.strip()]
    held = {r["t_rx"][1] for r in trace if r["t_rx"][1] is not None}
    assert held and all(t % TUP == 0 for t in held), sorted(held)
    # T_up stayed 15 s: the agents still signal at 60 and 75 (not multiples of 45).
    assert {60.0, 75.0} <= {r["t_rx"][j] for r in trace for j in (1, 2, 3) if r["t_rx"][j] is not None}
    assert not any("T_up changed" in p.read_text() for p in (out / "agents").glob("agent*.log"))
    # The mission completes, as well as without the attacker.
    rows = (out / "metrics.jsonl").read_text().splitlines()
    assert json.loads(rows[-1])["t"] == DURATION
    assert abs(attacked["coverage_mean"] - clean["coverage_mean"]) <= 0.02
