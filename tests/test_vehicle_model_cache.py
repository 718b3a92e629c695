"""A vehicle model file is read once per version: a changed file is read again."""

import os
from pathlib import Path

from plmarl_sitl.config import load_vehicle


def test_a_vehicle_model_is_read_again_only_when_its_file_changes(tmp_path: Path) -> None:
    f = tmp_path / "quad.yaml"
    f.write_text("name: quad\nmax_speed_mps: 12.0\n")
    first = load_vehicle(f)
    assert first.max_speed_mps == 12.0 and load_vehicle(str(f)) is first
    f.write_text("name: quad\nmax_speed_mps: 14.0\n")
    st = f.stat()
    os.utime(f, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000))
    assert load_vehicle(f).max_speed_mps == 14.0
