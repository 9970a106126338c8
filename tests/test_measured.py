"""Measured BRDFs: Rusinkiewicz coordinates, MERL files, tables and the neural fits (fit/measured.py)."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from scipy.interpolate import RegularGridInterpolator
from scipy.spatial.transform import Rotation

from brdfrig.fit.analytic import BlinnPhong, Lambertian
from brdfrig.fit.brdf import brdf_from_dict
from brdfrig.fit.measured import (
    CUBIC_NODES,
    MERL_SCALES,
    NeuralBRDF,
    TabulatedBRDF,
    load_measured,
    read_merl,
    rusinkiewicz_coordinates,
    rusinkiewicz_directions,
    tabulate,
    write_merl,
)

MEASURED = Path(__file__).resolve().parents[2] / "shared" / "data" / "measured"


def _material(name: str) -> Path:
    path = MEASURED / name
    if not path.is_file():
        pytest.skip("../shared/data/measured is absent")
    return path


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def _random_table(seed: int, missing: float = 0.01) -> np.ndarray:
    """A table of stored MERL values times the channel scales (as read from a file), some samples missing."""
    rng = np.random.default_rng(seed)
    t = rng.lognormal(3.0, 2.0, size=(90, 90, 180, 3)) * np.asarray(MERL_SCALES)
    t[rng.random(t.shape[:3]) < missing] = np.nan
    return t


# ----------------------------------------------------------------------------- coordinates


def test_coordinates_match_explicit_rotations_reciprocity_and_isotropy():
    # Independent construction: wi = Q Rz(phi_h) Ry(th) d, wo = Q Rz(phi_h) Ry(th) (-dx, -dy, dz), n = Q z.
    rng = np.random.default_rng(0)
    for _ in range(50):
        th, td = rng.uniform(0.01, 1.5, 2)
        pd, ph = rng.uniform(0, 2 * np.pi, 2)
        q = Rotation.random(random_state=rng).as_matrix()
        d = np.array([np.sin(td) * np.cos(pd), np.sin(td) * np.sin(pd), np.cos(td)])
        frame = q @ _rz(ph) @ _ry(th)
        wi, wo, n = frame @ d, frame @ (d * [-1, -1, 1]), q @ [0, 0, 1.0]
        got = rusinkiewicz_coordinates(wi, wo, n)
        assert got[0] == pytest.approx(th, abs=1e-12) and got[1] == pytest.approx(td, abs=1e-12)
        assert np.cos(got[2] - pd) == pytest.approx(1.0, abs=1e-12)  # same phi_d for every phi_h and frame
        swapped = rusinkiewicz_coordinates(wo, wi, n)  # reciprocity: phi_d -> phi_d + pi
        assert swapped[0] == pytest.approx(th, abs=1e-12) and swapped[1] == pytest.approx(td, abs=1e-12)
        assert np.cos(swapped[2] - pd - np.pi) == pytest.approx(1.0, abs=1e-12)
        # The inverse in the local frame is the same construction with Q = I, phi_h = 0.
        li, lo = rusinkiewicz_directions(th, td, pd)
        np.testing.assert_allclose(li, _ry(th) @ d, atol=1e-15)
        np.testing.assert_allclose(lo, _ry(th) @ (d * [-1, -1, 1]), atol=1e-15)


def test_coordinates_at_the_specular_configuration():
    wi = np.array([np.sin(0.4), 0.0, np.cos(0.4)])
    th, td, _ = rusinkiewicz_coordinates(wi, wi * [-1, -1, 1], [0.0, 0.0, 1.0])
    assert th == pytest.approx(0.0, abs=1e-15) and td == pytest.approx(0.4, abs=1e-15)


# ----------------------------------------------------------------------------- MERL files


def test_merl_round_trip_is_bit_identical(tmp_path):
    table = _random_table(1)
    path = write_merl(tmp_path / "m.binary", TabulatedBRDF(table))
    back = read_merl(path)
    assert back.source == str(path)
    np.testing.assert_array_equal(np.isnan(back.table), np.isnan(table))
    present = ~np.isnan(table)
    assert np.array_equal(back.table[present].view(np.uint64), table[present].view(np.uint64))
    # Rewriting what was read reproduces the file byte for byte.
    again = write_merl(tmp_path / "again.binary", back)
    assert again.read_bytes() == path.read_bytes()


def test_merl_round_trip_of_arbitrary_values_within_one_ulp(tmp_path):
    table = np.random.default_rng(2).uniform(0.0, 50.0, size=(90, 90, 180, 3))
    back = read_merl(write_merl(tmp_path / "u.binary", TabulatedBRDF(table))).table
    np.testing.assert_array_max_ulp(back, table, maxulp=1)


def test_independent_reader_agrees_with_write_merl(tmp_path):
    table = _random_table(3)
    path = write_merl(tmp_path / "m.binary", TabulatedBRDF(table))
    header = np.fromfile(path, dtype="<i4", count=3)
    data = np.fromfile(path, dtype="<f8", offset=12)
    assert header.tolist() == [90, 90, 180] and data.size == 3 * 1_458_000
    rng = np.random.default_rng(4)
    for _ in range(200):
        ith, itd, ipd, c = rng.integers(90), rng.integers(90), rng.integers(180), rng.integers(3)
        stored = data[c * 1_458_000 + ipd + 180 * (itd + 90 * ith)]
        value = table[ith, itd, ipd, c]
        if np.isnan(value):
            assert stored < 0
        else:
            assert stored * MERL_SCALES[c] == value


@pytest.mark.parametrize(
    "content,message",
    [
        (b"\x00" * 8, "too short"),
        (np.array([90, 90, 90], "<i4").tobytes() + b"\x00" * (8 * 3 * 90 * 90 * 90), r"dimensions \(90, 90, 90\)"),
        (np.array([90, 90, 180], "<i4").tobytes() + b"\x00" * 1000, "truncated"),
        (np.array([90, 90, 180], "<i4").tobytes() + b"\x00" * (8 * 3 * 1_458_000 + 8), "trailing"),
    ],
)
def test_bad_merl_files_name_the_file(tmp_path, content, message):
    path = tmp_path / "bad.binary"
    path.write_bytes(content)
    with pytest.raises(ValueError, match=message) as info:
        read_merl(path)
    assert str(path) in str(info.value)


def test_negative_stored_values_are_missing_and_filled_from_neighbours(tmp_path):
    path = tmp_path / "neg.binary"
    data = np.full((3, 90, 90, 180), 1500.0)  # 1 / sr in R after scaling
    data[:, 10:20, 30:40, :] = -1.0
    data[0, 50, 50, 50] = 3000.0
    path.write_bytes(np.array([90, 90, 180], "<i4").tobytes() + data.astype("<f8").tobytes())
    t = read_merl(path)
    assert t.missing == 3 * 10 * 10 * 180 and np.isnan(t.table[15, 35, 0]).all()
    assert t.filled[15, 35, 0, 0] == 1.0 and np.all(np.isfinite(t.filled))
    assert t.filled[50, 50, 50, 0] == 2.0


def test_table_values_are_validated():
    good = np.ones((90, 90, 180, 3))
    for bad, message in [(-1.0, "negative"), (np.inf, "infinite")]:
        t = good.copy()
        t[1, 2, 3, 0] = bad
        with pytest.raises(ValueError, match=message):
            TabulatedBRDF(t)
    with pytest.raises(ValueError, match="shape"):
        TabulatedBRDF(np.ones((90, 90, 90, 3)))
    with pytest.raises(ValueError, match="no present sample"):
        TabulatedBRDF(np.full((90, 90, 180, 1), np.nan))


# ----------------------------------------------------------------------------- table evaluation


def test_interpolation_matches_scipy_in_index_space():
    # Peer: scipy, on log1p of the table: linear in (theta_d index, periodic phi_d index) at every theta_h node
    # (RegularGridInterpolator), then along the sqrt-spaced theta_h index Catmull-Rom below node CUBIC_NODES
    # (CubicHermiteSpline with central-difference slopes, node 0 repeated), linear above.
    from scipy.interpolate import CubicHermiteSpline

    rng = np.random.default_rng(5)
    table = rng.uniform(0.1, 2.0, size=(90, 90, 180, 2))
    brdf = TabulatedBRDF(table)
    th = (np.concatenate([rng.uniform(0, 15, 250), rng.uniform(0, 89, 250)]) / 90) ** 2 * np.pi / 2
    td = rng.uniform(0, 89, 500) / 90 * np.pi / 2
    pd = rng.uniform(0, 2 * np.pi, 500)
    wi, wo = rusinkiewicz_directions(th, td, pd)
    keep = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    got = brdf.rho(wi[keep], wo[keep], [0.0, 0.0, 1.0])
    log = np.log1p(table)
    wrapped = np.concatenate([log, log[:, :, :1]], axis=2)
    peer = RegularGridInterpolator((np.arange(90.0), np.arange(90.0), np.arange(181.0)), wrapped)
    uh = np.sqrt(th / (np.pi / 2)) * 90
    ud, up = td / (np.pi / 2) * 90, (pd % np.pi) / np.pi * 180
    nodes = np.arange(90.0)
    expected = []
    for k in np.flatnonzero(keep):
        g = peer(np.stack([nodes, np.full(90, ud[k]), np.full(90, up[k])], 1))  # (90, C) along theta_h
        padded = np.concatenate([g[:1], g, g[-1:]])
        slope = (padded[2:] - padded[:-2]) / 2
        if uh[k] < CUBIC_NODES:
            value = CubicHermiteSpline(nodes, g, slope)(uh[k])
        else:
            value = np.array([np.interp(min(uh[k], 89.0), nodes, g[:, c]) for c in range(g.shape[1])])
        expected.append(np.expm1(value))
    np.testing.assert_allclose(got, np.maximum(expected, 0), rtol=1e-9)  # angles recomputed from directions


def test_tabulated_analytic_brdfs_evaluate_back():
    lam = tabulate(Lambertian([0.2, 0.5, 0.9]))
    got = lam.evaluate(np.linspace(0, 1.5, 7), 0.7, np.linspace(0, 6, 7))
    np.testing.assert_allclose(got, np.broadcast_to([0.2, 0.5, 0.9], got.shape) / np.pi, rtol=1e-14)
    assert lam.evaluate(1.6, 0.3, 0.0).tolist() == [0.0, 0.0, 0.0]  # below the horizon
    phong = BlinnPhong(0.3, 0.5, 20.0)
    rng = np.random.default_rng(6)
    ti, to, dp = rng.uniform(0, 1.3, 300), rng.uniform(0, 1.3, 300), rng.uniform(0, 2 * np.pi, 300)
    np.testing.assert_allclose(tabulate(phong).evaluate(ti, to, dp), phong.evaluate(ti, to, dp), rtol=2e-3)


# ----------------------------------------------------------------------------- neural fits


def test_spectralon_is_about_albedo_over_pi():
    brdf = load_measured(_material("rgl/spectralon_rgb.h5"))
    assert isinstance(brdf, NeuralBRDF) and brdf.channels == 3
    ti, to, dp = np.meshgrid(np.radians([0, 20, 40]), np.radians([0, 20, 40]), [0.0, 1.5, 3.0])
    rho = brdf.evaluate(ti, to, dp)
    assert np.median(rho) == pytest.approx(0.98 / np.pi, rel=0.02)  # README: ~0.31 = 0.98 / pi
    assert np.all(np.abs(rho / (0.98 / np.pi) - 1) < 0.1)  # measured: 0.292 .. 0.332 up to 40 degrees
    assert brdf.evaluate(1.7, 0.2, 0.0).tolist() == [0.0, 0.0, 0.0]


def test_network_brdf_is_the_reciprocal_part_and_round_trips_through_a_dict():
    path = _material("rgl/cc_amber_citrine_rgb.h5")
    brdf = load_measured(path)
    rng = np.random.default_rng(7)
    wi = rng.normal(size=(100, 3)) * [1, 1, 0] + [0, 0, 1.5]
    wo = rng.normal(size=(100, 3)) * [1, 1, 0] + [0, 0, 1.5]
    wi, wo = (w / np.linalg.norm(w, axis=1, keepdims=True) for w in (wi, wo))
    n = np.array([0.0, 0.0, 1.0])
    th, td, pd = rusinkiewicz_coordinates(wi, wo, n)
    rho = brdf.rho(wi, wo, n)
    np.testing.assert_allclose(rho, 0.5 * (brdf.network(th, td, pd) + brdf.network(th, td, pd + np.pi)), rtol=1e-13)
    np.testing.assert_allclose(brdf.rho(wo, wi, n), rho, rtol=1e-9)  # reciprocal by construction
    again = brdf_from_dict(json.loads(json.dumps(brdf.to_dict())))
    np.testing.assert_array_equal(again.rho(wi, wo, n), brdf.rho(wi, wo, n))


def test_network_with_other_layer_shapes_is_rejected(tmp_path):
    import h5py

    src = _material("rgl/spectralon_rgb.h5")
    bad = tmp_path / "bad_rgb.h5"
    shutil.copy(src.with_suffix(".json"), bad.with_suffix(".json"))
    with h5py.File(src, "r") as f_in, h5py.File(bad, "w") as f_out:
        for i in (1, 2, 3):
            for k in ("kernel", "bias"):
                w = f_in[f"dense_{i}/dense_{i}/{k}:0"][()]
                f_out[f"dense_{i}/dense_{i}/{k}:0"] = w[:, :20] if (i, k) == (1, "kernel") else w
    with pytest.raises(ValueError, match="layer shapes") as info:
        load_measured(bad)
    assert str(bad) in str(info.value)
    layout = json.loads(src.with_suffix(".json").read_text())
    layout["config"]["layers"][1]["config"]["units"] = 32
    bad.with_suffix(".json").write_text(json.dumps(layout))
    with pytest.raises(ValueError, match="expected Dense"):
        load_measured(bad)
    bad.with_suffix(".json").unlink()
    with pytest.raises(ValueError, match="layout file"):
        load_measured(bad)
    with pytest.raises(ValueError, match="unknown measured-BRDF file type"):
        load_measured(tmp_path / "x.exr")


def test_tabulated_network_matches_the_network_between_samples():
    brdf = load_measured(_material("rgl/paper_blue_rgb.h5"))
    table = brdf.table()
    assert brdf.table() is table  # made once
    rng = np.random.default_rng(8)
    ti, to, dp = rng.uniform(0, 1.2, 400), rng.uniform(0, 1.2, 400), rng.uniform(0, 2 * np.pi, 400)
    net, tab = brdf.evaluate(ti, to, dp), table.evaluate(ti, to, dp)
    assert np.sqrt(np.mean((tab - net) ** 2) / np.mean(net**2)) < 1e-3  # measured 2.4e-4
    assert math.isclose(float(np.nanmax(table.table)), float(np.max(table.filled)))


# ----------------------------------------------------------------------------- ground-truth renders


def _sphere_normals(size: int) -> np.ndarray:
    from brdfrig.hdr.sphere import sphere_pixels

    return sphere_pixels((size, size), (size / 2, size / 2, size / 2), margin_px=0.0).normals


def _rel_rms(a, b) -> float:
    return float(np.sqrt(np.mean((a - b) ** 2) / np.mean(b**2)))


def _lighting(seed: int = 9):
    """A 64x32 lat-long map with a few bright small sources over a dim sky, turned about +y."""
    from brdfrig.lighting import environment_from_latlong

    rng = np.random.default_rng(seed)
    img = rng.uniform(0.05, 0.2, (32, 64, 3))
    img[rng.integers(0, 32, 6), rng.integers(0, 64, 6)] = rng.uniform(20, 60, (6, 3))
    return environment_from_latlong(img, Rotation.from_euler("y", 25, degrees=True).as_matrix())


def test_table_render_of_a_lambertian_matches_the_analytic_render():
    from brdfrig.fit.groundtruth import render_groundtruth, render_tabulated

    env, normals = _lighting(), _sphere_normals(24)
    model = Lambertian([0.2, 0.5, 0.9])
    table = tabulate(model)
    expected = render_groundtruth(model, normals, env)  # analytic kernel, cell centres
    np.testing.assert_allclose(render_tabulated(table, normals, env, 0.0, 1), expected, rtol=1e-12, atol=1e-14)
    # Sub-cells change only the cosine's sampling within each cell: measured 2e-4.
    assert _rel_rms(render_tabulated(table, normals, env, 20.0, 8), expected) < 1e-3


def test_numpy_quadrature_render_matches_the_analytic_kernel():
    # Brute-force oracle: the same cell-centre samples, the BRDF through numpy rho instead of the numba kernel.
    from brdfrig.fit.analytic import GGX
    from brdfrig.fit.groundtruth import render_groundtruth, render_rho

    env, normals = _lighting(), _sphere_normals(16)
    model = GGX(0.3, [0.04, 0.5, 0.9], [0.3, 0.2, 0.1])
    np.testing.assert_allclose(render_rho(model, normals, env, 0.0, 1, block=999), render_groundtruth(model, normals, env), rtol=1e-11, atol=1e-14)


def test_network_tabulated_and_rendered_matches_the_network_rendered_directly():
    # Must show (issue 10): table render vs direct network render, the sharpest material, within 0.5%.
    from brdfrig.evaluate.probes import probe_environment
    from brdfrig.fit.groundtruth import render_rho, render_tabulated

    brdf = load_measured(_material("rgl/cc_amber_citrine_rgb.h5"))
    env = probe_environment("grace", 64)
    normals = _sphere_normals(32)[::4]  # every fourth pixel of a 32 px sphere
    table = brdf.table()
    by_table = render_tabulated(table, normals, env)
    direct = render_rho(brdf, normals, env)
    assert np.all(np.isfinite(by_table)) and np.all(by_table >= 0)
    assert _rel_rms(by_table, direct) < 5e-3  # measured 3e-4 on the whole sphere (trilinear in rho: 3.6%)
    np.testing.assert_array_equal(brdf.predict(env, normals), by_table)


# ----------------------------------------------------------------------------- brdfrig render


def _brdfrig(*args):
    import subprocess
    import sys

    return subprocess.run([sys.executable, "-m", "brdfrig", *map(str, args)], capture_output=True, text=True, timeout=600)


def test_render_command_takes_measured_materials(tmp_path):
    from brdfrig.fit.groundtruth import render_tabulated
    from brdfrig.hdr.exr import read_exr, write_exr
    from brdfrig.hdr.sphere import sphere_pixels
    from brdfrig.lighting import environment_from_latlong

    rng = np.random.default_rng(10)
    img = rng.uniform(0.05, 0.3, (16, 32, 3)).astype(np.float32)
    img[4, 20] = 40.0
    write_exr(tmp_path / "sky.exr", img)
    env = environment_from_latlong(img.astype(np.float64))
    table = tabulate(BlinnPhong([0.2, 0.4, 0.6], 0.5, 200.0))
    write_merl(tmp_path / "m.binary", table)
    r = _brdfrig("render", tmp_path / "m.binary", "--lighting", tmp_path / "sky.exr", "--size", 12, "-o", tmp_path / "m.exr")
    assert r.returncode == 0, r.stderr
    got = read_exr(tmp_path / "m.exr")
    got = got[0] if isinstance(got, tuple) else got
    px = sphere_pixels((12, 12), (6, 6, 6), margin_px=0.0)
    expected = render_tabulated(read_merl(tmp_path / "m.binary"), px.normals, env)
    np.testing.assert_allclose(got[px.rows, px.cols], expected, rtol=1e-6)  # float32 file
    assert np.count_nonzero(got.any(axis=2)) == len(px.rows)

    bad = tmp_path / "bad.binary"
    bad.write_bytes(b"\x00" * 100)
    r = _brdfrig("render", bad, "--lighting", tmp_path / "sky.exr", "--size", 12, "-o", tmp_path / "bad.exr")
    assert r.returncode == 2 and str(bad) in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "bad.exr").exists()


def test_render_command_takes_a_neural_fit(tmp_path):
    from brdfrig.hdr.exr import read_exr

    path = _material("rgl/spectralon_rgb.h5")
    sky = tmp_path / "sky.exr"
    from brdfrig.hdr.exr import write_exr

    write_exr(sky, np.ones((8, 16, 3), np.float32))  # white furnace: B = directional albedo ~ 0.98
    r = _brdfrig("render", path, "--lighting", sky, "--size", 8, "-o", tmp_path / "s.exr")
    assert r.returncode == 0, r.stderr
    got = read_exr(tmp_path / "s.exr")
    got = got[0] if isinstance(got, tuple) else got
    centre = got[3:5, 3:5]
    assert np.all(np.abs(centre - 0.98) < 0.05)
