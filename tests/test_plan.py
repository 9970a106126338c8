"""Capture plan: auto exposure brackets (brute-force coverage oracle), shot counts, printed plan."""

from __future__ import annotations

import math

import numpy as np
import pytest

from brdfrig.session.config import session_config_from_dict
from brdfrig.session.plan import SATURATION_HEADROOM, auto_bracket, build_plan, describe_plan, electrons_for_snr

FW, RN, SNR = 4000.0, 4.0, 20.0


def covered(e, times, *, snr=SNR):
    """Brute force: some exposure records irradiance e (e-/s) unclipped and at the target SNR."""
    for t in times:
        s = e * t
        if s <= SATURATION_HEADROOM * FW * (1 + 1e-9) and s / math.sqrt(s + RN**2) >= snr * (1 - 1e-9):
            return True
    return False


def test_electrons_for_snr_solves_the_noise_model():
    for k, r in [(5, 0), (20, 4), (50, 10)]:
        s = electrons_for_snr(k, r)
        assert s / math.sqrt(s + r * r) == pytest.approx(k, rel=1e-12)


@pytest.mark.parametrize("e_lo, e_hi", [(2e4, 6e4), (1e3, 1e5), (50.0, 5e6), (30.0, 1e7)])
def test_bracket_covers_the_range_and_every_exposure_is_needed(e_lo, e_hi):
    times = auto_bracket(e_lo, e_hi, full_well_e=FW, read_noise_e=RN, target_snr=SNR, base_time_s=1 / 60,
                         max_exposures=20, max_gap_stops=10)
    grid = np.geomspace(e_lo, e_hi, 400)
    assert all(covered(e, times) for e in grid)
    for i in range(len(times)):  # minimal: dropping any exposure leaves a gap
        rest = times[:i] + times[i + 1:]
        assert not all(covered(e, rest) for e in grid), f"exposure {times[i]} adds nothing"
    # on the 1-stop grid through 1/60 s
    for t in times:
        assert abs(math.log2(t * 60) - round(math.log2(t * 60))) < 1e-9


def test_default_bracket_keeps_an_overlap_between_neighbours():
    fw, rn = 20000.0, 5.0  # one exposure spans ~5.3 stops at SNR 20: the 3-stop cap binds
    times = auto_bracket(30.0, 1e6, full_well_e=fw, read_noise_e=rn, target_snr=SNR, base_time_s=1 / 60)
    gaps = np.diff(np.log2(times))
    assert len(times) > 1 and np.all(gaps <= 3 + 1e-9) and np.all(gaps >= 1 - 1e-9)


def test_low_contrast_needs_one_exposure_high_contrast_several():
    kw = dict(full_well_e=FW, read_noise_e=RN, target_snr=SNR, base_time_s=1 / 60)
    assert len(auto_bracket(2e4, 6e4, **kw)) == 1
    # per exposure: 0.8*FW / s_min = 3200 / ~407 ~ 7.9x ~ 2.97 stops, but the 1-stop grid loses up to a stop
    n = len(auto_bracket(30.0, 1e7, max_exposures=20, **kw))
    stops = math.log2(1e7 / 30.0)
    assert math.ceil(stops / 2.97) <= n <= math.ceil(stops / 1.97) + 1


def test_impossible_snr_is_refused():
    with pytest.raises(ValueError, match="lower target_snr"):
        auto_bracket(1.0, 10.0, full_well_e=100, read_noise_e=2, target_snr=50, base_time_s=0.01)


def plan_config(exposure, model="full"):
    return session_config_from_dict({
        "rig": {"carries": "rig", "turntable": {"backend": "sim", "speed_deg_s": 30},
                "camera": {"backend": "sim", "overhead_s": 0.5}},
        "plan": {"scene_angles": [0, 30, 60], "exposure": exposure,
                 "samples": [{"name": "a", "circle": [1, 1, 1]}]},
        "fit": {"model": model, "lmax": 4},
    }, "t.toml")


def test_plan_counts_shots_time_and_scenes_needed():
    plan = build_plan(plan_config([0.5, 1.0]))
    assert plan.n_scenes == 3 and plan.max_shots_per_angle() == 2
    # moves 0->30->60 at 30 deg/s = 2 s; 3 angles x (1.5 s exposure + 2 x 0.5 s overhead) = 7.5 s
    assert plan.expected_time_s() == pytest.approx(9.5)
    text = describe_plan(plan)
    assert "6 shots" in text and "about 10 s" in text
    assert "needs >= 5 differing scenes" in text and "WARNING: 3 scene(s) planned, fewer than the 5 needed" in text
    assert "tilted or set up elsewhere" not in text  # the full model: turns are what it needs
    # the tables (auto's candidates) are told that turns of the rig keep the elevations (measured: README, real materials)
    assert "tilted or set up elsewhere in the room" in describe_plan(build_plan(plan_config([0.5], model="auto")))
