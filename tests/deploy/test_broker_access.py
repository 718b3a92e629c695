"""Broker access control (issue 14): the mosquitto and the embedded amqtt a SITL run starts,
with a login per process and an ACL (`sitl/network/access.py`), tried by real MQTT clients."""

from __future__ import annotations

import asyncio
import os
import shutil
import stat
from pathlib import Path

import aiomqtt
import pytest

from plmarl_sitl.deploy.mqtt.credentials import load_credentials
from plmarl_sitl.deploy.mqtt.schema import Topics
from plmarl_sitl.sitl.network.access import BrokerAccess
from plmarl_sitl.sitl.network.broker import AmqttProcess, MosquittoBroker

pytestmark = [pytest.mark.integration, pytest.mark.timeout(60)]
HAVE_MOSQUITTO = bool(shutil.which("mosquitto") or os.path.exists("/usr/sbin/mosquitto"))
T = Topics("sitl")


@pytest.fixture(params=["mosquitto", "amqtt"])
def broker(request: pytest.FixtureRequest):  # noqa: ANN201
    if request.param == "mosquitto" and not HAVE_MOSQUITTO:
        pytest.skip("mosquitto not installed")
    access = BrokerAccess("sitl", 3)
    b = (MosquittoBroker if request.param == "mosquitto" else AmqttProcess)(access=access)
    b.start(timeout_s=20)
    try:
        yield b
    finally:
        b.stop()


def client(b, name: str | None, identifier: str | None = None) -> aiomqtt.Client:  # noqa: ANN001
    creds = b.access[name].credentials if name else (None, None)
    return aiomqtt.Client(b.host, b.port, username=creds[0], password=creds[1], identifier=identifier or f"test-{name}", timeout=5)


async def _heard(b, publisher: str, topic: str, reader: str, read: str) -> list[bytes]:  # noqa: ANN001
    """What `reader` (subscribed to `read`) receives within 1 s of `publisher` sending on `topic`."""
    got: list[bytes] = []
    async with client(b, reader) as sub, client(b, publisher) as pub:
        await sub.subscribe(read)
        await asyncio.sleep(0.2)
        await pub.publish(topic, b"hello", qos=1)  # QoS 1: the broker acknowledges, whatever it then does

        async def collect() -> None:
            async for m in sub.messages:
                got.append(bytes(m.payload))

        with pytest.raises(TimeoutError):
            async with asyncio.timeout(1.0):
                await collect()
        # The publisher's connection is still up: a refused publish is dropped in silence.
        await pub.publish(f"{T.root}/tx/zz-probe", b"", qos=1)
    return got


def test_a_client_without_credentials_is_refused(broker) -> None:  # noqa: ANN001
    async def main() -> None:
        with pytest.raises(aiomqtt.MqttError) as anon:
            async with client(broker, None):
                pass
        with pytest.raises(aiomqtt.MqttError) as wrong:
            async with aiomqtt.Client(broker.host, broker.port, username="agent0", password="guess", timeout=5):
                pass
        print(f"\n{broker.what}: anonymous -> {anon.value}; wrong password -> {wrong.value}")

    asyncio.run(main())


def test_an_agent_may_publish_only_its_own_tx(broker) -> None:  # noqa: ANN001
    """Agent 1's login publishing as agent 2 (tx/2), as the world (rx/0, retained ctl):
    the broker keeps the connection and drops the message (MQTT 3.1.1 has no way to say
    no to a publish); its own tx/1 goes through."""
    async def main() -> None:
        assert await _heard(broker, "agent1", T.tx(1), "world", T.tx("+")) == [b"hello"]
        assert await _heard(broker, "agent1", T.tx(2), "world", T.tx("+")) == []
        assert await _heard(broker, "agent1", T.rx(0), "agent0", T.rx(0)) == []
        assert await _heard(broker, "agent1", T.ctl, "agent0", T.ctl) == []
        assert await _heard(broker, "view", T.ctl, "agent0", T.ctl) == []  # the view only reads
        assert await _heard(broker, "world", T.ctl, "agent0", T.ctl) == [b"hello"]

    asyncio.run(main())


def test_an_agent_reads_only_what_is_addressed_to_it(broker) -> None:  # noqa: ANN001
    async def main() -> None:
        assert await _heard(broker, "world", T.rx(0), "agent1", T.rx("+")) == []  # subscription refused
        assert await _heard(broker, "world", T.rx(0), "agent1", T.rx(0)) == []
        assert await _heard(broker, "world", T.rx(1), "agent1", T.rx(1)) == [b"hello"]
        assert await _heard(broker, "world", T.sense(0), "agent1", T.sense(0)) == []

    asyncio.run(main())


def test_credentials_files_are_private(tmp_path: Path) -> None:
    access = BrokerAccess("sitl", 2)
    paths = access.write_credentials(tmp_path / "credentials")
    assert set(paths) == {"world", "monitor", "view", "agent0", "agent1"}
    assert stat.S_IMODE((tmp_path / "credentials").stat().st_mode) == 0o700
    for name, p in paths.items():
        assert stat.S_IMODE(p.stat().st_mode) == 0o600 and load_credentials(p) == access[name].credentials
    assert "user agent1\ntopic write plmarl/sitl/tx/1\ntopic read plmarl/sitl/rx/1" in access.acl_text()


def test_a_20_uav_swarm_logs_in_at_once_within_the_connect_timeout() -> None:
    """All 20 agents, the world and the monitor log in together, as `swarm up` does. amqtt
    checks each password in its event loop: at argon2's default cost (0.3 s each here) the
    22 logins held it past every client's 3-s connect timeout and the swarm never formed."""
    access = BrokerAccess("sitl", 20)
    b = AmqttProcess(access=access)
    b.start(timeout_s=20)
    names = [f"agent{i}" for i in range(20)] + ["world", "monitor"]

    async def login(name: str) -> None:
        creds = access[name].credentials
        async with aiomqtt.Client(b.host, b.port, username=creds[0], password=creds[1], identifier=f"t-{name}", timeout=3):
            pass

    async def main() -> None:
        await asyncio.gather(*(login(n) for n in names))

    try:
        asyncio.run(main())
    finally:
        b.stop()
