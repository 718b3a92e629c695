"""The benchmark's trial machinery works end to end (tiny load, so it stays cheap)."""

from __future__ import annotations

import pytest

from plmarl_sitl.bench.autopilot import trial

pytestmark = [pytest.mark.integration, pytest.mark.timeout(90)]


def test_small_trial_is_sustained_and_measured() -> None:
    r = trial(5, 2.0, warmup=1.0, window=2.0)
    assert "error" not in r, r
    assert r["ok"], r
    assert r["clock_rate"] == pytest.approx(2.0, rel=0.05)
    assert r["sent"] > 5 * 2.0 * 20 * 2.0 * 0.9  # 20 Hz of sim time per vehicle
