"""Light probe: unwrap, calibration, rotation averaging and lat-long resampling against balls rendered here.

The balls are rendered by the tests from a known lat-long map with their own
mirror-ball geometry (normal from the pixel offset, reflected direction
``2 (n.v) n - v``), not by the unwrapping code.
"""

from __future__ import annotations

import numpy as np
import pytest

from brdfrig.fit.shproject import project
from brdfrig.hdr.envmap import latlong_directions, sample_latlong
from brdfrig.hdr.probe import (
    CHROME_IOR,
    albedo_from_patches,
    average_rotations,
    conductor_fresnel,
    probe_to_latlong,
    unseen_cone_deg,
    unwrap_probe,
)

LMAX = 8


def procedural_map(h=128, w=256):
    """Sky gradient, a warm sun blob, two windows and a floor: a lat-long map with energy in every band."""
    dirs, _ = latlong_directions(h, w)
    x, y, z = dirs[..., 0], dirs[..., 1], dirs[..., 2]
    sky = np.clip(y, 0, None)[..., None] * np.array([0.4, 0.6, 1.0]) + 0.05
    sun_dir = np.array([0.5, 0.6, 0.62]) / np.linalg.norm([0.5, 0.6, 0.62])
    sun = np.exp((dirs @ sun_dir - 1) / 0.004)[..., None] * np.array([30.0, 25.0, 18.0])
    window = ((np.abs(x + 0.6) < 0.2) & (np.abs(y - 0.1) < 0.25)) | ((np.abs(z + 0.5) < 0.15) & (np.abs(y) < 0.3))
    floor = (y < -0.2)[..., None] * np.array([0.3, 0.2, 0.1])
    return sky + sun + window[..., None] * np.array([2.0, 2.0, 1.8]) + floor


def rotation_y(deg):
    a = np.radians(deg)
    return np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])


def lookup_nearest(env, dirs):
    """The map as piecewise constant (what its pixel-sum quadrature assumes): MATH.md's lat-long formulas."""
    h, w = env.shape[:2]
    lam = np.arctan2(dirs[:, 0], dirs[:, 2])
    phi = np.arcsin(np.clip(dirs[:, 1], -1, 1))
    col = np.floor((0.5 - lam / (2 * np.pi)) * w).astype(int) % w
    row = np.clip(np.floor((0.5 - phi / np.pi) * h).astype(int), 0, h - 1)
    return env[row, col]


def render_ball(env, shape, circle, *, reflectance=None, ss=3, background=0.0):
    """Orthographic chrome ball seen along -z, each pixel the mean of ss x ss sub-samples of the map.

    ``reflectance(n) -> (N,)`` or (N, C) multiplies the reflected radiance (albedo, blemishes, Fresnel);
    sub-samples outside the ball see ``background``.
    """
    h, w = shape
    cx, cy, r = circle
    out = np.zeros((h, w, env.shape[2]))
    off = (np.arange(ss) + 0.5) / ss - 0.5
    yy, xx = np.mgrid[0:h, 0:w]
    for oy in off:
        for ox in off:
            dx = (xx + 0.5 + ox - cx) / r
            dy = (cy - (yy + 0.5 + oy)) / r
            inside = dx * dx + dy * dy < 1
            n = np.stack([dx[inside], dy[inside], np.sqrt(1 - dx[inside] ** 2 - dy[inside] ** 2)], axis=-1)
            wdir = 2 * n[:, 2:3] * n - np.array([0.0, 0.0, 1.0])
            val = lookup_nearest(env, wdir / np.linalg.norm(wdir, axis=1, keepdims=True))
            if reflectance is not None:
                refl = np.asarray(reflectance(n))
                val = val * (refl[:, None] if refl.ndim == 1 else refl)
            out[inside] += val
            out[~inside] += background
    return out / ss**2


def splat_ball(env, shape, circle, sub=6):
    """Energy-conserving forward render: every map pixel's radiance x solid angle lands on the ball pixel
    where its direction is reflected (sub x sub sub-samples per map pixel, each weighted by its solid angle).

    The map is piecewise constant, as its pixel-sum quadrature assumes, so the ball's integral of each map
    pixel equals the map's, even for an unresolved sun one map pixel wide (real probes).
    """
    h, w = env.shape[:2]
    cx, cy, r = circle
    a = (np.arange(sub) + 0.5) / sub
    u = ((np.arange(w)[:, None] + a[None, :]) / w).ravel()  # (W*sub,)
    t = ((np.arange(h)[:, None] + a[None, :]) / h).ravel()  # (H*sub,)
    lam = -2 * np.pi * (u - 0.5)
    phi = -np.pi * (t - 0.5)
    d_omega = (2 * np.pi / (w * sub)) * (np.pi / (h * sub)) * np.cos(phi)  # per sub-sample
    lam, phi = np.meshgrid(lam, phi)
    dirs = np.stack([np.sin(lam) * np.cos(phi), np.sin(phi), np.cos(lam) * np.cos(phi)], axis=-1).reshape(-1, 3)
    weight = np.broadcast_to(d_omega[:, None], lam.shape).ravel()
    value = np.repeat(np.repeat(env, sub, axis=0), sub, axis=1).reshape(-1, env.shape[2])
    half = dirs + np.array([0.0, 0.0, 1.0])
    norm = np.linalg.norm(half, axis=1)
    keep = norm > 1e-9
    n = half[keep] / norm[keep, None]
    col = np.floor(cx + r * n[:, 0]).astype(int)
    row = np.floor(cy - r * n[:, 1]).astype(int)
    ok = (row >= 0) & (row < shape[0]) & (col >= 0) & (col < shape[1])
    flat = row[ok] * shape[1] + col[ok]
    out = np.stack([np.bincount(flat, weights=value[keep][ok, c] * weight[keep][ok], minlength=shape[0] * shape[1])
                    for c in range(env.shape[2])], axis=-1)
    return out.reshape(shape + (env.shape[2],)) / (4.0 / r**2)


def band_energy(coeffs):
    return np.array([np.sum(coeffs[l * l:(l + 1) ** 2] ** 2) for l in range(LMAX + 1)])


def map_projection_outside_cone(env, cone_deg):
    dirs, solid = latlong_directions(*env.shape[:2])
    solid = np.where(dirs[..., 2] > -np.cos(np.radians(cone_deg)), solid, 0.0)
    return project(dirs.reshape(-1, 3), env.reshape(-1, env.shape[2]), solid.ravel(), LMAX)


def samples_projection(s):
    return project(s.dirs, s.radiance, s.solid_angle, LMAX)


@pytest.fixture(scope="module")
def env():
    return procedural_map()


def _check_band_energies(env, radius, render, tol=0.01):
    size = 2 * radius + 10
    circle = (size / 2 + 0.3, size / 2 - 0.2, radius)
    ball = render(env, (size, size), circle)
    s = unwrap_probe(ball, circle)
    assert s.unseen_cone_deg == pytest.approx(unseen_cone_deg(0.97)) and 28 < s.unseen_cone_deg < 28.2
    ours = band_energy(samples_projection(s))
    truth = band_energy(map_projection_outside_cone(env, s.unseen_cone_deg))
    rel = np.abs(ours / truth - 1)
    print("relative band energy error, l = 0..8:", np.round(rel, 4))
    assert rel.max() < tol, rel
    return rel


@pytest.mark.parametrize("render", [render_ball, splat_ball], ids=["camera-render", "energy-splat"])
def test_unwrapped_ball_matches_map_band_energies_within_1_percent(env, render):
    _check_band_energies(env, 150, render)


def test_real_probes_unwrap_within_1_percent(real_probes):
    from brdfrig.hdr.exr import read_image

    for path in real_probes:
        _check_band_energies(read_image(path).astype(np.float64), 150, splat_ball)


def test_solid_angles_and_masks():
    shape, circle = (200, 220), (110.4, 99.7, 90.0)
    s = unwrap_probe(np.ones(shape + (3,)), circle, rim=1.0)
    assert s.solid_angle.sum() == pytest.approx(4 * np.pi, rel=1e-9)  # the whole sphere, 4/r^2 per pixel
    s = unwrap_probe(np.ones(shape + (3,)), circle, camera_mask_deg=10.0)
    ok = s.dirs[s.valid]
    # Valid samples are outside both cones, and the masked ones inside one of them.
    assert np.all(ok[:, 2] < np.cos(np.radians(10.0)))
    assert np.all(ok[:, 2] > -np.cos(np.radians(s.unseen_cone_deg)) - 1e-9)
    bad = s.dirs[~s.valid]
    assert np.all((bad[:, 2] >= np.cos(np.radians(10.0))) | (bad[:, 2] < -np.cos(np.radians(s.unseen_cone_deg)) + 0.02))
    # Seen solid angle = 4 pi minus the two cones (2 pi (1 - cos a) each), to the pixel discretisation.
    expect = 4 * np.pi - 2 * np.pi * (1 - np.cos(np.radians(10.0))) - 2 * np.pi * (
        1 - np.cos(np.radians(s.unseen_cone_deg)))
    assert s.solid_angle.sum() == pytest.approx(expect, rel=0.01)


def test_albedo_ratio_method_and_fresnel_calibration(env):
    size, radius = 220, 90
    circle = (100.5, 110.0, radius)
    albedo = np.array([0.62, 0.60, 0.58])
    # Ratio method: a diffuse grey patch of radiance 3 seen directly (box in the corner) and in the ball,
    # where the map shows it (directions within 8 deg of +x, seen at the ball's right-hand side).
    patch_env = env.copy()
    dirs, _ = latlong_directions(*env.shape[:2])
    patch_env[dirs[..., 0] > np.cos(np.radians(8))] = 3.0
    ball = render_ball(patch_env, (size, size), circle, reflectance=lambda n: np.broadcast_to(albedo, (len(n), 3)))
    ball[5:25, 195:215] = 3.0  # the patch seen directly
    # +x is seen where the normal bisects +x and +z: offset (sin 45, 0) from the centre.
    px = circle[0] + radius * np.sin(np.radians(45))
    found = albedo_from_patches(ball, (195, 5, 215, 25), (px - 3, circle[1] - 3, px + 3, circle[1] + 3))
    assert np.allclose(found, albedo, rtol=0.005)
    # Fresnel: a chrome ball whose reflectance is albedo * F(theta) / F(0); the calibrated unwrap recovers the map.
    f0 = conductor_fresnel(1.0)

    def chrome(n):
        return albedo[None, :] * (conductor_fresnel(n[:, 2]) / f0)[:, None]

    ball = render_ball(env, (size, size), circle, reflectance=chrome)
    plain = unwrap_probe(ball, circle, albedo=albedo)
    cal = unwrap_probe(ball, circle, albedo=albedo, fresnel=CHROME_IOR)
    truth = sample_latlong(env, cal.dirs)
    rim_zone = cal.valid & (cal.dirs[:, 2] < -0.7)  # grazing on the ball (> 67 deg): Fresnel matters
    err_cal = np.median(np.abs(cal.radiance[rim_zone] / truth[rim_zone] - 1))
    err_plain = np.median(np.abs(plain.radiance[rim_zone] / truth[rim_zone] - 1))
    assert err_cal < 0.01 and err_plain > 5 * err_cal, (err_cal, err_plain)


def test_conductor_fresnel_closed_forms():
    n, k = CHROME_IOR
    assert conductor_fresnel(1.0) == pytest.approx(((n - 1) ** 2 + k**2) / ((n + 1) ** 2 + k**2), rel=1e-12)
    assert conductor_fresnel(0.0) == pytest.approx(1.0)
    # A dielectric (k = 0) at Brewster's angle: rp = 0, R = rs^2 / 2.
    eta = 1.5
    tb = np.arctan(eta)
    cos_t = np.cos(np.arcsin(np.sin(tb) / eta))  # refracted angle (Snell)
    rs = (np.cos(tb) - eta * cos_t) / (np.cos(tb) + eta * cos_t)
    assert conductor_fresnel(np.cos(tb), (eta, 0.0)) == pytest.approx(rs**2 / 2, rel=1e-9)


def test_rotation_averaging_removes_blemishes(env):
    size, radius = 180, 80
    rng = np.random.default_rng(0)
    # Dark blemishes fixed on the ball: spherical caps around random body-frame normals, 10% of the visible disc.
    centres = rng.normal(size=(40, 3))
    centres /= np.linalg.norm(centres, axis=1, keepdims=True)

    def blemish_factor(n_body, cap):
        hit = np.max(n_body @ centres.T, axis=1) > np.cos(cap)
        return np.where(hit, 0.15, 1.0) * 0.7

    # Pick the cap size so blemishes cover 10% of the visible disc at rotation 0.
    from scipy.optimize import brentq

    yy, xx = np.mgrid[0:200, 0:200]
    dx, dy = (xx - 99.5) / 100, (99.5 - yy) / 100
    inside = dx * dx + dy * dy < 1
    n_test = np.stack([dx[inside], dy[inside], np.sqrt(1 - dx[inside] ** 2 - dy[inside] ** 2)], axis=-1)
    cap = brentq(lambda c: np.mean(blemish_factor(n_test, c) < 0.5) - 0.10, np.radians(1), np.radians(40), xtol=1e-4)
    assert abs(np.mean(blemish_factor(n_test, cap) < 0.5) - 0.10) < 0.01

    angles = np.arange(8) * 45.0
    images, circles = [], []
    for a in angles:
        circle = (size / 2 + rng.uniform(-0.7, 0.7), size / 2 + rng.uniform(-0.7, 0.7), radius + rng.uniform(-0.3, 0.3))
        rot = rotation_y(-a)  # world normal -> body normal for a ball turned by a about +y
        images.append(render_ball(env, (size, size), circle, reflectance=lambda n: blemish_factor(n @ rot.T, cap)))
        circles.append(circle)
    ref = (size / 2, size / 2, radius)
    clean = render_ball(env, (size, size), ref, reflectance=lambda n: np.full(len(n), 0.7))
    truth = samples_projection(unwrap_probe(clean, ref, albedo=0.7))

    def err(image, circle):
        c = samples_projection(unwrap_probe(image, circle, albedo=0.7))
        return np.linalg.norm(c - truth) / np.linalg.norm(truth)

    single = np.mean([err(im, c) for im, c in zip(images, circles)])
    combined, circle = average_rotations(images, circles, ref_circle=ref)
    averaged = err(combined, circle)
    print(f"SH lighting error (l <= {LMAX}): single capture {single:.4f}, median of 8 rotations {averaged:.4f}")
    assert averaged * 5 <= single, (single, averaged)


def test_probe_to_latlong_matches_the_map_where_seen(env):
    size, radius = 420, 200
    circle = (size / 2 - 0.4, size / 2 + 0.3, radius)
    smooth_env = procedural_map(64, 128)  # the map at the output resolution
    ball = render_ball(smooth_env, (size, size), circle)
    latlong, seen = probe_to_latlong(ball, circle, 128)
    assert latlong.shape == (64, 128, 3) and seen.shape == (64, 128)
    dirs, solid = latlong_directions(64, 128)
    cone = np.cos(np.radians(unseen_cone_deg(0.97)))
    # Seen = outside the unseen cone around -z.
    assert np.array_equal(seen, dirs[..., 2] > -cone - 1e-9) or np.mean(seen != (dirs[..., 2] > -cone)) < 0.005
    assert np.all(latlong[~seen] == 0)
    # Away from the cone's edge, where the ball is not squeezed, the map comes back.
    good = seen & (dirs[..., 2] > 0)
    rel = np.abs(latlong[good] - smooth_env[good]) / smooth_env[good]
    assert np.median(rel) < 0.01


def test_bad_probe_input_is_a_clear_error():
    img = np.ones((100, 100, 3))
    with pytest.raises(ValueError, match=r"probe circle \(50.00, 50.00, 60.00\) extends outside the 100x100 image"):
        unwrap_probe(img, (50, 50, 60))
    with pytest.raises(ValueError, match="outside the 100x100 image"):
        probe_to_latlong(img, (10, 50, 30), 64)
    with pytest.raises(ValueError, match="lat-long width"):
        probe_to_latlong(img, (50, 50, 30), 63)
    with pytest.raises(ValueError, match="different sizes"):
        average_rotations([img, np.ones((90, 100, 3))], [(50, 50, 30)] * 2)
    with pytest.raises(ValueError, match="direct patch box .* outside"):
        albedo_from_patches(img, (90, 90, 120, 95), (10, 10, 20, 20))


def test_chrome_ball_detected_in_front_of_a_backdrop(env):
    """A chrome ball (textured reflection, rim squeezing bright windows) in front of a grey backdrop."""
    from brdfrig.hdr.detect import detect_sphere

    size, circle = 260, (131.3, 127.6, 110.2)
    ball = render_ball(env, (size, size), circle, reflectance=lambda n: np.full(len(n), 0.7), background=0.3)
    found = detect_sphere(ball)
    assert np.abs(np.subtract(found, circle)).max() <= 0.25, found


def test_probe_cli_writes_latlong_with_unseen_mask(env, tmp_path, capsys):
    from brdfrig.cli.main import main
    from brdfrig.hdr.exr import read_exr, write_exr

    size, radius = 300, 130
    circle = (151.2, 148.7, radius)
    small_env = procedural_map(32, 64)
    rng = np.random.default_rng(5)
    files = []
    for k, a in enumerate((0, 120, 240)):  # three rotations of a ball with one dark blemish
        rot = rotation_y(-a)
        blemish = lambda n, rot=rot: np.where((n @ rot.T) @ np.array([0.6, 0.3, 0.74]) > 0.97, 0.1, 0.7)  # noqa: E731
        files.append(tmp_path / f"probe{k}.exr")
        write_exr(files[-1], render_ball(small_env, (size, size), circle, reflectance=blemish, background=0.3)
                  * (1 + 0.002 * rng.standard_normal((size, size, 3))))
    out = tmp_path / "env.exr"
    assert main(["probe", *map(str, files), "--albedo", "0.7", "--width", "64", "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "3 rotations combined" in printed and "unseen: cone of 28.1 deg" in printed
    latlong, extra, attrs = read_exr(out)
    assert latlong.shape == (32, 64, 3) and attrs["unseen_cone_deg"] == pytest.approx(unseen_cone_deg(0.97))
    assert np.abs(np.subtract(attrs["circle_px"], circle)).max() < 0.25  # detected in each image
    seen = extra["mask"] > 0.5
    dirs, _ = latlong_directions(32, 64)
    assert np.array_equal(seen, dirs[..., 2] > -np.cos(np.radians(attrs["unseen_cone_deg"])))
    assert np.all(latlong[~seen] == 0)
    front = seen & (dirs[..., 2] > 0)
    assert np.median(np.abs(latlong[front] / small_env[front] - 1)) < 0.02
    # --circle overrides detection; a circle partly outside the frame is a clear error, nothing written.
    assert main(["probe", str(files[0]), "--circle", "151.2,148.7,130", "--width", "64", "-o", str(out)]) == 0
    before = out.read_bytes()
    assert main(["probe", str(files[0]), "--circle", "100,148.7,130", "--width", "64", "-o", str(out)]) == 2
    assert "probe circle (100.00, 148.70, 130.00) extends outside the 300x300 image" in capsys.readouterr().err
    assert out.read_bytes() == before


def test_probe_cli_no_sphere_and_bad_files(tmp_path, capsys):
    from brdfrig.cli.main import main
    from brdfrig.hdr.exr import write_exr

    flat = tmp_path / "flat.exr"
    write_exr(flat, np.full((120, 160, 3), 0.5, np.float32))
    assert main(["probe", str(flat), "-o", str(tmp_path / "e.exr")]) == 2
    assert "flat.exr: no sphere found" in capsys.readouterr().err
    broken = tmp_path / "broken.exr"
    broken.write_bytes(flat.read_bytes()[:200])
    assert main(["probe", str(broken), "--circle", "80,60,50", "-o", str(tmp_path / "e.exr")]) == 2
    assert "broken.exr" in capsys.readouterr().err
    assert not (tmp_path / "e.exr").exists()
