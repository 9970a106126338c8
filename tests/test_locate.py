"""brdfrig locate on a simulated bench frame: the probe and both samples, at their true circles."""

from __future__ import annotations

import re
import subprocess
import sys

import numpy as np

from brdfrig.hdr.exr import write_exr
from brdfrig.sim.bench import SimBench


def test_locate_finds_the_probe_and_the_samples(tmp_path):
    bench = SimBench(scale=0.5, env_height=32)
    frame = bench.radiance(30.0)
    path = tmp_path / "shot.exr"
    write_exr(path, frame.astype(np.float32))
    r = subprocess.run([sys.executable, "-m", "brdfrig", "locate", str(path)], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr
    circles = [tuple(map(float, m.split(","))) for m in re.findall(r"circle = \[([^\]]+)\]", r.stdout)]
    assert "[plan.probe]" in r.stdout.splitlines()[0] and len(circles) == 3
    np.testing.assert_allclose(circles[0], bench.probe_circle, atol=0.5)  # the probe is named first
    want = sorted(bench.sample_circles.values())
    np.testing.assert_allclose(sorted(circles[1:]), want, atol=0.5)


def test_locate_names_the_file_when_it_finds_nothing(tmp_path):
    path = tmp_path / "flat.exr"
    write_exr(path, np.full((64, 96, 3), 0.5, np.float32))
    r = subprocess.run([sys.executable, "-m", "brdfrig", "locate", str(path)], capture_output=True, text=True)
    assert r.returncode == 2 and "flat.exr" in r.stderr and "no sphere" in r.stderr


def test_template_writes_a_shipped_config_that_loads_and_never_overwrites(tmp_path):
    from brdfrig.cli.template import CONFIG_DIR
    from brdfrig.session.config import load_session_config

    out = tmp_path / "plan.toml"
    r = subprocess.run([sys.executable, "-m", "brdfrig", "template", "plan-bench", "-o", str(out)],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    cfg = load_session_config(out, rig_path=CONFIG_DIR / "rig-bench.toml")
    assert cfg.plan.probe.circle == (500.0, 800.0, 300.0) and out.read_bytes() == (CONFIG_DIR / "plan-bench.toml").read_bytes()
    out.write_text("# edited\n")
    r = subprocess.run([sys.executable, "-m", "brdfrig", "template", "plan-bench", "-o", str(out)],
                       capture_output=True, text=True)
    assert r.returncode == 2 and out.read_text() == "# edited\n"
